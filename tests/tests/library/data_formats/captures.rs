//! Users' own captures: COLMAP workspaces (binary and text) and transforms.json, through a lens
//! with distortion, in a world frame of their own; and a real COLMAP model (pycolmap on fern's
//! photos) checked against COLMAP's own definition of a pixel: its observations of its points.

use ins_scene::data::colmap::image_pose;
use ins_scene::data::colmap_model::{Encoding, read_model};
use ins_scene::data::synthetic::{CaptureLayout, write_colmap, write_transforms};

use super::bad_inputs::{assert_names, load_err};
use super::*;

/// A synthetic capture (9 views, 40 px) of `layout` written as `format`.
pub(super) fn capture(
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
pub(super) fn assert_rays_equal_generating_cameras(scene: &Scene, synth: &SynthScene) {
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
