//! Users' own captures: COLMAP workspaces (binary and text) and transforms.json, through a lens
//! with distortion, in a world frame of their own; and a real COLMAP model (pycolmap on fern's
//! photos) checked against COLMAP's own definition of a pixel: its observations of its points.

use ins_scene::data::colmap::image_pose;
use ins_scene::data::colmap_model::{Encoding, read_model};
use ins_scene::data::synthetic::{CaptureLayout, write_colmap, write_transforms};
use ins_scene::geometry::Bounds;

use super::bad_inputs::{assert_names, load_err};
use super::*;

fn capture(
    format: SceneFormat,
    layout: CaptureLayout,
    enc: Encoding,
) -> (tempfile::TempDir, SynthScene) {
    let dir = tempfile::tempdir().unwrap();
    let opts = SynthOptions { size: 40, views: 9 };
    let synth = match format {
        SceneFormat::Colmap => write_colmap(dir.path(), &opts, layout, enc),
        _ => write_transforms(dir.path(), &opts, layout),
    }
    .unwrap();
    (dir, synth)
}

/// Every pixel's loaded ray is the generating camera's ray (distortion included), mapped into
/// the scene frame: origins and unit directions within 1e-5 of the scene's scale.
fn assert_rays_equal_generating_cameras(scene: &Scene, synth: &SynthScene) {
    assert_eq!(scene.views.len(), synth.views.len());
    let to = scene.to_scene;
    let mut worst = (0.0f32, 0.0f32);
    for (v, gt) in scene.views.iter().zip(&synth.views) {
        assert_eq!(v.camera.distortion, gt.camera.distortion);
        for y in (0..v.camera.height).step_by(3) {
            for x in (0..v.camera.width).step_by(3) {
                let (o, d) = v.camera.pixel_ray(x, y);
                let (go, gd) = gt.camera.pixel_ray(x, y);
                let want_o = to.apply_point(go);
                let want_d = to.apply_direction(gd).normalize();
                worst.0 = worst.0.max(dist(o, want_o) / want_o.length().max(1.0));
                worst.1 = worst.1.max(dist(d, want_d));
            }
        }
    }
    assert!(
        worst.0 < 1e-5 && worst.1 < 1e-5,
        "worst origin / direction error {worst:?}"
    );
}

#[test]
fn captures_give_the_generating_cameras_rays() {
    for layout in [CaptureLayout::ObjectCentred, CaptureLayout::ForwardFacing] {
        for (format, enc) in [
            (SceneFormat::Colmap, Encoding::Binary),
            (SceneFormat::Colmap, Encoding::Text),
            (SceneFormat::Transforms, Encoding::Binary),
        ] {
            let (dir, synth) = capture(format, layout, enc);
            let scene = load(dir.path());
            assert_eq!(scene.format, format);
            assert_eq!(
                scene.forward_facing,
                layout == CaptureLayout::ForwardFacing,
                "{format} {layout:?}"
            );
            assert_rays_equal_generating_cameras(&scene, &synth);
            // Every 8th view held out, starting with the first.
            assert_eq!(scene.split(Split::Test), &[0, 8]);
            assert_eq!(scene.split(Split::Train).len(), 7);
            let report = check_scene(&scene);
            assert!(report.all_ok(), "{format} {layout:?}: {:?}", report.checks);
        }
    }
}

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
fn colmap_binary_and_text_read_as_the_same_scene() {
    let (a, _) = capture(
        SceneFormat::Colmap,
        CaptureLayout::ObjectCentred,
        Encoding::Binary,
    );
    let (b, _) = capture(
        SceneFormat::Colmap,
        CaptureLayout::ObjectCentred,
        Encoding::Text,
    );
    let (sa, sb) = (load(a.path()), load(b.path()));
    for (va, vb) in sa.views.iter().zip(&sb.views) {
        assert_eq!(va.camera, vb.camera);
        assert_eq!(va.image, vb.image);
    }
    assert_eq!(sa.to_scene, sb.to_scene);
    assert_eq!((sa.near, sa.far, sa.bounds), (sb.near, sb.far, sb.bounds));
}

#[test]
fn transforms_frames_are_listed_by_file_name_whatever_their_order() {
    // Exporters write frames in registration order; the scene (and its hold-out) must not
    // depend on it.
    let (d, _) = capture(
        SceneFormat::Transforms,
        CaptureLayout::ObjectCentred,
        Encoding::Binary,
    );
    let before = load(d.path());
    let json = d.path().join("transforms.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    v["frames"].as_array_mut().unwrap().reverse();
    std::fs::write(&json, v.to_string()).unwrap();
    let after = load(d.path());
    for (a, b) in before.views.iter().zip(&after.views) {
        assert_eq!(a.path, b.path);
        assert_eq!(a.camera, b.camera);
    }
    assert_eq!(before.split(Split::Test), after.split(Split::Test));
}

#[test]
fn photos_a_transforms_json_names_but_lacks_are_left_out_and_said() {
    // Public captures are shared without some of their photos: train on those present, say
    // how many are missing, and refuse only when too few remain.
    let (d, _) = capture(
        SceneFormat::Transforms,
        CaptureLayout::ObjectCentred,
        Encoding::Binary,
    );
    let json = d.path().join("transforms.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let frames = v["frames"].as_array_mut().unwrap();
    let named = frames.len();
    frames[0]["file_path"] = "images/nowhere.png".into();
    frames[3]["file_path"] = "images/lost".into();
    std::fs::write(&json, v.to_string()).unwrap();
    let scene = load(d.path());
    assert_eq!(scene.views.len(), named - 2);
    assert_eq!(scene.notes.len(), 1, "{:?}", scene.notes);
    let note = &scene.notes[0];
    assert!(
        note.contains(&format!("2 of the {named} photos"))
            && note.contains("nowhere.png")
            && note.contains(&format!("training on the {} present", named - 2)),
        "{note}"
    );
    // Every photo but one missing: too few to train on, an error naming a missing one.
    let frames = v["frames"].as_array_mut().unwrap();
    for f in frames.iter_mut().skip(2) {
        f["file_path"] = "images/nowhere.png".into();
    }
    std::fs::write(&json, v.to_string()).unwrap();
    let e = load_err(d.path());
    assert_names(&e, "nowhere.png");
    assert_names(&e, "at least 3");
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
fn photos_of_different_sizes_and_orientations_keep_their_own() {
    // Phones mix portrait and landscape, COLMAP's undistorter writes a size per photo: every
    // view keeps its own size and intrinsics, and its rays are those of the photo it was cut
    // from.
    let (d, _) = capture(
        SceneFormat::Transforms,
        CaptureLayout::ObjectCentred,
        Encoding::Binary,
    );
    let whole = load(d.path());
    let cropped = synthetic::portrait_every_other(d.path()).unwrap();
    let scene = load(d.path());
    assert_eq!(scene.views.len(), whole.views.len());
    let (w, h) = whole.resolution();
    let cw = h * 3 / 4;
    let x0 = (w - cw) / 2;
    for i in 0..scene.views.len() {
        let (v, orig) = (&scene.views[i], &whole.views[i]);
        if !cropped.contains(&i) {
            assert_eq!(v.camera, orig.camera, "view {i}");
            continue;
        }
        assert_eq!((v.camera.width, v.camera.height), (cw, h), "view {i}");
        for y in (0..h).step_by(3) {
            for x in (0..cw).step_by(3) {
                let (o, dir) = v.camera.pixel_ray(x, y);
                let (oo, od) = orig.camera.pixel_ray(x + x0, y);
                assert!(
                    dist(o, oo) < 1e-5 && dist(dir, od) < 1e-5,
                    "view {i} ({x}, {y})"
                );
                assert_eq!(v.image.rgb(x, y), orig.image.rgb(x + x0, y));
            }
        }
    }
    assert_eq!(scene.smallest_resolution(), (cw, h));
    assert_eq!(scene.notes.len(), 1, "{:?}", scene.notes);
    let note = &scene.notes[0];
    assert!(
        note.contains("2 sizes") && note.contains(&format!("{w}×{h}")) && note.contains("portrait"),
        "{note}"
    );
    // Patches drawn from any view fit it; the contact sheet keeps each photo's shape.
    let mut patches = PatchSampler::new(8, 2, 7);
    for _ in 0..20 {
        patches.sample(&scene, Split::Train).unwrap();
    }
    let sheet = contact_sheet(&scene, 9, 40);
    assert_eq!(
        sheet.height,
        3 * (40 * h / cw) + 4 * 4,
        "3 rows as tall as a portrait"
    );
    let report = check_scene(&scene);
    assert!(report.all_ok(), "{:?}", report.checks);
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

/// pycolmap 4.2.1's model of fern's 20 photos (tests/fixtures/fern_colmap): for every
/// observation, the ray our camera gives through the observed pixel passes the observed 3D
/// point within COLMAP's reprojection error, and projecting the point lands on the pixel. This
/// checks the pose convention (world-to-camera quaternion, OpenCV axes), the pixel-centre
/// convention and the lens against COLMAP's own output, not against our writer.
#[test]
fn a_real_colmap_model_agrees_with_its_own_observations() {
    let model = read_model(&ins_tests::fixture("fern_colmap/sparse/0")).unwrap();
    assert_eq!(model.images.len(), 20);
    let points: std::collections::HashMap<u64, Vec3> = model
        .points
        .iter()
        .map(|p| {
            (
                p.id,
                Vec3::new(p.xyz[0] as f32, p.xyz[1] as f32, p.xyz[2] as f32),
            )
        })
        .collect();
    let (mut ray_px, mut proj_px) = (Vec::new(), Vec::new());
    for img in &model.images {
        let cam = &model.cameras[&img.camera_id];
        let ([fx, fy, cx, cy], lens) = cam.intrinsics();
        let c2w = image_pose(img).unwrap().map(|r| r.map(|v| v as f32));
        let camera = Camera::new(
            cam.width, cam.height, fx as f32, fy as f32, cx as f32, cy as f32, c2w,
        )
        .with_distortion(lens);
        for &(xy, id) in &img.points2d {
            let Some(&p) = u64::try_from(id).ok().and_then(|id| points.get(&id)) else {
                continue;
            };
            let (o, d) = camera.ray(xy[0] as f32, xy[1] as f32);
            let to_p = (p - o).normalize();
            ray_px.push(d.cross(to_p).length() * fx as f32);
            let q = camera.project(p).expect("observed points are in front");
            proj_px.push(((q[0] as f64 - xy[0]).hypot(q[1] as f64 - xy[1])) as f32);
        }
    }
    let median = |v: &mut Vec<f32>| {
        v.sort_by(f32::total_cmp);
        (v[v.len() / 2], v[v.len() * 9 / 10])
    };
    let (ray_med, ray_p90) = median(&mut ray_px);
    let (proj_med, proj_p90) = median(&mut proj_px);
    assert!(ray_px.len() > 5000, "{} observations", ray_px.len());
    eprintln!(
        "fern COLMAP model, {} observations: ray off its point by {ray_med:.3} px (median), \
         {ray_p90:.3} px (90 %); projection {proj_med:.3} px / {proj_p90:.3} px",
        ray_px.len()
    );
    // pycolmap reported a mean reprojection error of 0.70 px.
    assert!(
        ray_med < 1.0 && ray_p90 < 2.0,
        "ray: median {ray_med} px, 90 % {ray_p90} px"
    );
    assert!(
        proj_med < 1.0 && proj_p90 < 2.0,
        "projection: median {proj_med} px, 90 % {proj_p90} px"
    );
    // A convention error is far off: the same check with the y axis not flipped fails.
    let img = &model.images[0];
    let cam = &model.cameras[&img.camera_id];
    let ([fx, fy, cx, cy], _) = cam.intrinsics();
    let wrong = ins_scene::camera::flip_yz(&image_pose(img).unwrap().map(|r| r.map(|v| v as f32)));
    let camera = Camera::new(
        cam.width, cam.height, fx as f32, fy as f32, cx as f32, cy as f32, wrong,
    );
    let off = img
        .points2d
        .iter()
        .filter_map(|&(xy, id)| {
            let p = points.get(&u64::try_from(id).ok()?)?;
            let q = camera.project(*p)?;
            Some(((q[0] as f64 - xy[0]).hypot(q[1] as f64 - xy[1])) as f32)
        })
        .fold(f32::INFINITY, f32::min);
    assert!(
        off > 5.0 || !off.is_finite(),
        "flipped axes still reproject within {off} px"
    );
}

#[test]
fn bad_colmap_inputs_are_errors_naming_the_file() {
    let (d, _) = capture(
        SceneFormat::Colmap,
        CaptureLayout::ObjectCentred,
        Encoding::Text,
    );
    let sparse = d.path().join("sparse/0");
    // Truncated, unsupported model, a photo named but absent, a broken rotation.
    let cams = sparse.join("cameras.txt");
    let good_cams = std::fs::read_to_string(&cams).unwrap();
    std::fs::write(&cams, good_cams.replace("OPENCV", "FOV")).unwrap();
    let e = load_err(d.path());
    assert_names(&e, "cameras.txt");
    assert_names(&e, "FOV is not supported");
    std::fs::write(&cams, &good_cams).unwrap();

    let imgs = sparse.join("images.txt");
    let good_imgs = std::fs::read_to_string(&imgs).unwrap();
    std::fs::remove_file(d.path().join("images/frame_003.png")).unwrap();
    assert_names(&load_err(d.path()), "frame_003.png");
    std::fs::write(&imgs, good_imgs.replace("frame_003.png", "frame_004.png")).unwrap();
    // A quaternion that is not unit: not a rotation.
    let mut lines: Vec<String> = good_imgs.lines().map(String::from).collect();
    let first = lines.iter().position(|l| !l.starts_with('#')).unwrap();
    let mut tok: Vec<String> = lines[first].split(' ').map(String::from).collect();
    tok[1] = "3.0".into();
    lines[first] = tok.join(" ");
    std::fs::write(
        &imgs,
        lines.join("\n").replace("frame_003.png", "frame_004.png"),
    )
    .unwrap();
    let e = load_err(d.path());
    assert_names(&e, "images.txt");
    assert_names(&e, "not a rotation");

    // Binary: a truncated file.
    let (d, _) = capture(
        SceneFormat::Colmap,
        CaptureLayout::ObjectCentred,
        Encoding::Binary,
    );
    let pts = d.path().join("sparse/0/points3D.bin");
    let b = std::fs::read(&pts).unwrap();
    std::fs::write(&pts, &b[..b.len() / 2]).unwrap();
    assert_names(&load_err(d.path()), "points3D.bin");
    // No sparse model at all: not a scene folder, with the way out named.
    std::fs::remove_dir_all(d.path().join("sparse")).unwrap();
    assert_names(&load_err(d.path()), "data sfm");
}

#[test]
fn bad_transforms_inputs_are_errors_naming_the_file() {
    let (d, _) = capture(
        SceneFormat::Transforms,
        CaptureLayout::ObjectCentred,
        Encoding::Binary,
    );
    let json = d.path().join("transforms.json");
    let good = std::fs::read_to_string(&json).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&good).unwrap();
    // A scaled (not rigid) matrix.
    for c in 0..3 {
        let x = v["frames"][2]["transform_matrix"][0][c].as_f64().unwrap();
        v["frames"][2]["transform_matrix"][0][c] = (2.0 * x).into();
    }
    std::fs::write(&json, v.to_string()).unwrap();
    let e = load_err(d.path());
    assert_names(&e, "transforms.json");
    assert_names(&e, "frame 2");
    assert_names(&e, "not rigid");
    // NaN cannot be written in JSON; a string where a number belongs is the same mistake.
    let mut v: serde_json::Value = serde_json::from_str(&good).unwrap();
    v["fl_x"] = "NaN".into();
    std::fs::write(&json, v.to_string()).unwrap();
    assert_names(&load_err(d.path()), "fl_x");
    let mut v: serde_json::Value = serde_json::from_str(&good).unwrap();
    v["camera_model"] = "EQUIRECTANGULAR".into();
    std::fs::write(&json, v.to_string()).unwrap();
    assert_names(&load_err(d.path()), "EQUIRECTANGULAR is not supported");
    std::fs::write(&json, &good[..good.len() / 2]).unwrap();
    assert_names(&load_err(d.path()), "transforms.json");
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
fn masked_captures_are_placed_in_the_unit_sphere_from_their_visual_hull() {
    use ins_scene::data::unit_sphere::{SPHERE_MARGIN, UNMASKED_CAMERA_DISTANCE, into_unit_sphere};
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
        assert!(sphere.from_masks);
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
        // Without masks: centred where the cameras look, the cameras DTU's distance away.
        let (bare, sphere) = into_unit_sphere(scene, false).unwrap();
        assert!(!sphere.from_masks);
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
