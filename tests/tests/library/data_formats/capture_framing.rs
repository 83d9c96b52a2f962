//! Where a capture is placed: an object-centred one centred and scaled like NeRF-synthetic,
//! a stated box kept before a plain backdrop and unbounded before a room, a forward one framed
//! like LLFF, a masked one put in the unit sphere from its visual hull (and the masks' errors).

use ins_scene::data::colmap_model::Encoding;
use ins_scene::data::synthetic::CaptureLayout;
use ins_scene::geometry::Bounds;

use super::bad_inputs::{assert_names, load_err};
use super::captures::{assert_rays_equal_generating_cameras, capture};
use super::*;

#[test]
fn object_centred_captures_are_centred_and_scaled_like_nerf_synthetic() {
    let (dir, synth) = capture(
        SceneFormat::Colmap,
        CaptureLayout::ObjectCentred,
        Encoding::Binary,
    );
    let scene = load(dir.path());
    // Cameras at radius 4 around the point they look at (the analytic scene's centre).
    let r: f32 = scene
        .views
        .iter()
        .map(|v| v.camera.origin().length())
        .sum::<f32>()
        / 9.0;
    assert!((r - 4.0).abs() < 1e-3, "mean camera radius {r}");
    let centre = synth.scene.to_world.apply_point(Vec3::new(0.0, 0.0, -0.1));
    assert!(scene.to_scene.apply_point(centre).length() < 1e-3);
    // Up (the analytic scene's z) becomes +z.
    let up = scene
        .to_scene
        .apply_direction(synth.scene.to_world.rotation * Vec3::Z);
    assert!(up.dot(Vec3::Z) > 0.999, "up {up:?}");
    assert!(!scene.per_ray_range && !scene.white_background);
    // The sparse points reach the room's dome, three times farther out than the cameras: space
    // past the cameras' radius is contracted, and the box is the part left as it is.
    let c = scene
        .contraction
        .expect("a room past the cameras is contracted");
    assert!((c.radius - 4.0).abs() < 1e-6);
    let (min, max) = scene.bounds.aabb();
    assert!((max - Vec3::splat(4.0)).length() < 1e-6 && (min + max).length() < 1e-6);
    assert!(scene.far >= 1000.0 * c.radius);
    // The objects (the mask) lie inside the uncontracted box; the dome, beyond it.
    let (mut objects_inside, mut objects, mut far_background) = (0, 0, 0);
    for (v, gt) in scene.views.iter().zip(&synth.views) {
        for (i, &t) in gt.render.depth.iter().enumerate() {
            if t.is_finite() {
                let (x, y) = (i as u32 % v.camera.width, i as u32 / v.camera.width);
                let (o, d) = v.camera.pixel_ray(x, y);
                let p = o + d * t * scene.to_scene.scale;
                if gt.render.mask[i] {
                    objects += 1;
                    objects_inside += usize::from(scene.bounds.contains(p));
                } else if !scene.bounds.contains(p) {
                    far_background += 1;
                    assert!(c.apply(p).abs().max_element() < c.extent());
                }
            }
        }
    }
    assert!(objects > 0 && objects_inside == objects);
    assert!(far_background > 0);
}

#[test]
fn a_stated_box_is_kept_before_a_plain_backdrop_and_unbounded_where_the_photos_show_a_room() {
    // instant-ngp's aabb_scale boxes the subject; photos whose edges show a room need space
    // past the cameras for it, photos before a plain backdrop do not.
    let state_box = |d: &std::path::Path| {
        let json = d.join("transforms.json");
        let mut v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        v["aabb_scale"] = 1.into();
        std::fs::write(&json, v.to_string()).unwrap();
    };
    let (room, _) = capture(
        SceneFormat::Transforms,
        CaptureLayout::ObjectCentred,
        Encoding::Binary,
    );
    state_box(room.path());
    let scene = load(room.path());
    assert!(scene.contraction.is_some(), "a room boxed in");
    assert_eq!(scene.notes.len(), 1, "{:?}", scene.notes);
    assert!(
        scene.notes[0].contains("aabb_scale 1") && scene.notes[0].contains("unbounded"),
        "{}",
        scene.notes[0]
    );
    let (studio, _) = capture(
        SceneFormat::Transforms,
        CaptureLayout::Studio,
        Encoding::Binary,
    );
    state_box(studio.path());
    let scene = load(studio.path());
    assert!(scene.contraction.is_none(), "a plain backdrop unbounded");
    assert!(scene.notes.is_empty(), "{:?}", scene.notes);
    match scene.bounds {
        Bounds::Aabb { min, max } => assert_eq!((min.x, max.x), (-1.5, 1.5)),
        b => panic!("not the stated box: {b:?}"),
    }
}

#[test]
fn forward_captures_frame_like_llff() {
    // The sparse points give the depth bounds: the nearest maps to 1/0.75, as LLFF's does.
    let (dir, synth) = capture(
        SceneFormat::Colmap,
        CaptureLayout::ForwardFacing,
        Encoding::Binary,
    );
    let scene = load(dir.path());
    let nearest = scene
        .views
        .iter()
        .filter_map(|v| v.depth_range.map(|r| r.0))
        .fold(f32::INFINITY, f32::min);
    assert!((nearest - 1.0 / 0.75).abs() < 1e-3, "{nearest}");
    // The points were sampled from the renders: each view's bounds hold its rendered depths
    // (to the sampling's percentile).
    for (v, gt) in scene.views.iter().zip(&synth.views) {
        let (n, f) = v.depth_range.unwrap();
        let sc = scene.to_scene.scale;
        assert!(n <= gt.depth_bounds.1 * sc && f >= gt.depth_bounds.0 * sc);
    }
}

/// The capture's foreground surface points in its scene frame: every masked pixel's ray run to
/// its rendered depth.
fn object_points(scene: &Scene, synth: &SynthScene) -> Vec<Vec3> {
    let mut out = Vec::new();
    for (v, gt) in scene.views.iter().zip(&synth.views) {
        for (i, &t) in gt.render.depth.iter().enumerate() {
            if t.is_finite() && gt.render.mask[i] {
                let (x, y) = (i as u32 % v.camera.width, i as u32 / v.camera.width);
                let (o, d) = v.camera.pixel_ray(x, y);
                out.push(o + d * t * scene.to_scene.scale);
            }
        }
    }
    out
}

#[test]
fn captures_are_placed_in_the_unit_sphere_from_their_masks_points_or_cameras() {
    use ins_scene::data::unit_sphere::{
        MIN_POINTS, SPHERE_MARGIN, SphereSource, UNMASKED_CAMERA_DISTANCE, into_unit_sphere,
    };
    for (format, enc) in [
        (SceneFormat::Colmap, Encoding::Binary),
        (SceneFormat::Transforms, Encoding::Binary),
    ] {
        let (dir, synth) = capture(format, CaptureLayout::ObjectCentred, enc);
        let scene = load(dir.path());
        assert!(
            scene.views.iter().all(|v| v.mask.is_some()),
            "{format}: masks read"
        );
        let (unit, sphere) = into_unit_sphere(scene.clone(), true).unwrap();
        assert_eq!(sphere.source, SphereSource::Masks);
        // The rays are the generating cameras' in the new frame too.
        assert_rays_equal_generating_cameras(&unit, &synth);
        // Every point of the objects lies inside the unit sphere, and the sphere is tight:
        // the farthest lies past the margin's share of the radius less the hull's slack.
        let points = object_points(&unit, &synth);
        let reach = points.iter().map(|p| p.length()).fold(0.0f32, f32::max);
        assert!(reach < 1.0, "{format}: an object point at radius {reach}");
        assert!(
            reach > 0.6 / SPHERE_MARGIN,
            "{format}: objects reach only {reach}"
        );
        // Cameras outside, rays cut to the sphere, nothing contracted.
        assert!(unit.views.iter().all(|v| v.camera.origin().length() > 1.0));
        assert!(unit.per_ray_range && unit.contraction.is_none());
        assert!(matches!(unit.bounds, Bounds::Sphere { radius, .. } if radius == 1.0));
        // Without masks: centred where the cameras look, holding the sparse points.
        let (bare, sphere) = into_unit_sphere(scene.clone(), false).unwrap();
        assert!(
            matches!(sphere.source, SphereSource::Points(n) if n >= MIN_POINTS),
            "{format}: {:?}",
            sphere.source
        );
        assert!(bare.notes.iter().any(|n| n.contains("sparse points")));
        let reach = object_points(&bare, &synth)
            .iter()
            .map(|p| p.length())
            .fold(0.0f32, f32::max);
        assert!(
            reach < 1.0 && reach > 0.6 / SPHERE_MARGIN,
            "{format} without masks: objects reach {reach}"
        );
        // Without points either: the cameras DTU's distance away.
        let mut pointless = scene;
        pointless.points.clear();
        let (bare, sphere) = into_unit_sphere(pointless, false).unwrap();
        assert_eq!(sphere.source, SphereSource::Cameras);
        let mean = bare
            .views
            .iter()
            .map(|v| v.camera.origin().length())
            .sum::<f32>()
            / bare.views.len() as f32;
        assert!(
            (mean - UNMASKED_CAMERA_DISTANCE).abs() < 1e-4,
            "mean distance {mean}"
        );
        let reach = object_points(&bare, &synth)
            .iter()
            .map(|p| p.length())
            .fold(0.0f32, f32::max);
        assert!(
            reach < 1.0,
            "{format} without masks: an object point at {reach}"
        );
    }
}

#[test]
fn masks_that_agree_on_nothing_or_a_forward_capture_cannot_be_placed() {
    use ins_scene::data::unit_sphere::into_unit_sphere;
    let (dir, _) = capture(
        SceneFormat::Transforms,
        CaptureLayout::ObjectCentred,
        Encoding::Binary,
    );
    // Every mask empty: no point is held by the masks.
    for entry in std::fs::read_dir(dir.path().join("masks")).unwrap() {
        let p = entry.unwrap().path();
        image::GrayImage::new(40, 30).save(&p).unwrap();
    }
    let err = into_unit_sphere(load(dir.path()), true)
        .unwrap_err()
        .to_string();
    assert!(err.contains("agree on no point"), "{err}");
    assert_names(&err, &dir.path().display().to_string());
    let (dir, _) = capture(
        SceneFormat::Colmap,
        CaptureLayout::ForwardFacing,
        Encoding::Binary,
    );
    let err = into_unit_sphere(load(dir.path()), true)
        .unwrap_err()
        .to_string();
    assert!(err.contains("forward-facing"), "{err}");
}

#[test]
fn a_colmap_masks_folder_missing_a_photos_mask_is_named() {
    let (dir, _) = capture(
        SceneFormat::Colmap,
        CaptureLayout::ObjectCentred,
        Encoding::Binary,
    );
    let gone = dir.path().join("masks/frame_004.png.png");
    std::fs::remove_file(&gone).unwrap();
    let err = load_err(dir.path());
    assert!(err.contains("mask of image"), "{err}");
    assert_names(&err, "frame_004.png.png");
}
