//! Pixel rays, strided patches, random batches, camera paths and plain images.

use super::*;

#[test]
fn view_rays_agree_with_pixel_rays() {
    let (dir, _) = write(SceneFormat::Dtu, 16, 1);
    let scene = load(dir.path());
    let all = scene.view_rays(0).unwrap();
    assert_eq!(all.len(), 16 * 12);
    let some = scene.pixel_rays(0, &[(0, 0), (15, 11), (7, 3)]).unwrap();
    for (k, (x, y)) in [(0usize, 0usize), (15, 11), (7, 3)].into_iter().enumerate() {
        let i = y * 16 + x;
        assert_eq!(all.origins[i], some.origins[k]);
        assert_eq!(all.directions[i], some.directions[k]);
        assert_eq!((all.near[i], all.far[i]), (some.near[k], some.far[k]));
    }
    assert!(scene.pixel_rays(0, &[(16, 0)]).is_err());
    assert!(scene.view_rays(1).is_err());
}

#[test]
fn strided_patches_span_k_times_s_and_skip_background() {
    let (dir, _) = write(SceneFormat::Blender, 48, 3);
    let scene = load(dir.path());
    let (k, s) = (4u32, 3u32);
    let mut sampler = PatchSampler::new(k, s, 7);
    assert_eq!(sampler.span(), 12);
    let mut redrawn = 0;
    for _ in 0..200 {
        let p = sampler.sample(&scene, Split::Train).unwrap();
        assert!(scene.train.contains(&p.view));
        assert_eq!(p.batch.len(), 16);
        let xs: Vec<u32> = p.batch.pixels.iter().map(|q| q.x).collect();
        let ys: Vec<u32> = p.batch.pixels.iter().map(|q| q.y).collect();
        // Row major, stride s, spanning K·s pixels from the window origin.
        for j in 0..k {
            for i in 0..k {
                let q = p.batch.pixels[(j * k + i) as usize];
                assert_eq!((q.x, q.y), (p.x0 + i * s, p.y0 + j * s));
            }
        }
        let (x_min, x_max) = (*xs.iter().min().unwrap(), *xs.iter().max().unwrap());
        let (y_min, y_max) = (*ys.iter().min().unwrap(), *ys.iter().max().unwrap());
        assert_eq!(x_max - x_min + s, k * s);
        assert_eq!(y_max - y_min + s, k * s);
        assert!(p.x0 + k * s <= 48 && p.y0 + k * s <= 48);
        assert!(
            p.batch.mask.iter().any(|&m| m >= 0.5),
            "an all-background patch was returned"
        );
        // Rays and colours are those of the pixels.
        let pix: Vec<(u32, u32)> = p.batch.pixels.iter().map(|q| (q.x, q.y)).collect();
        let rays = scene.pixel_rays(p.view, &pix).unwrap();
        assert_eq!(rays.directions, p.batch.rays.directions);
        assert_eq!(
            p.batch.rgb[5],
            scene.views[p.view].image.rgb(pix[5].0, pix[5].1)
        );
        redrawn += p.redraws;
    }
    assert!(
        redrawn > 0,
        "with a small object, some random windows are all background and must be redrawn"
    );
    // A window larger than the image is an error, not a panic.
    assert!(
        PatchSampler::new(20, 3, 1)
            .sample(&scene, Split::Train)
            .is_err()
    );
    assert!(
        PatchSampler::new(2, 2, 1)
            .sample(&scene, Split::Test)
            .is_ok()
    );
}

#[test]
fn patches_can_be_required_to_lie_mostly_on_the_object() {
    let (dir, _) = write(SceneFormat::Blender, 48, 3);
    let scene = load(dir.path());
    let coverage = |p: &ins_scene::patches::Patch| {
        p.batch.mask.iter().filter(|&&m| m >= 0.5).count() as f32 / p.batch.len() as f32
    };
    let mut any = PatchSampler::new(4, 2, 3);
    let mut most = PatchSampler::new(4, 2, 3).with_min_coverage(0.9);
    let (mut plain_ok, mut ok) = (0, 0);
    for _ in 0..200 {
        plain_ok += (coverage(&any.sample(&scene, Split::Train).unwrap()) >= 0.9) as usize;
        let p = most.sample(&scene, Split::Train).unwrap();
        // Covered enough, or the best of all the redraws allowed.
        assert!(
            coverage(&p) >= 0.9 || p.redraws == most.max_redraws,
            "coverage {} after {} redraws",
            coverage(&p),
            p.redraws
        );
        ok += (coverage(&p) >= 0.9) as usize;
    }
    eprintln!("covered ≥ 90 %: {ok} of 200 (plain sampler: {plain_ok})");
    assert!(
        ok > 2 * plain_ok && ok > 150,
        "{ok} of 200 patches covered ≥ 90 % (plain sampler: {plain_ok})"
    );
    // Where no window is covered enough, the best of the draws comes back.
    let mut impossible = PatchSampler::new(20, 2, 1).with_min_coverage(1.01);
    let p = impossible.sample(&scene, Split::Train).unwrap();
    assert_eq!(p.redraws, impossible.max_redraws);
    assert!(coverage(&p) > 0.0);
}

#[test]
fn random_ray_batches_carry_pixel_targets() {
    let (dir, _) = write(SceneFormat::Llff, 24, 9);
    let scene = load(dir.path());
    let mut sampler = RaySampler::new(300, 3);
    let b = sampler.sample(&scene, Split::Train).unwrap();
    assert_eq!(b.len(), 300);
    for k in 0..b.len() {
        let p = b.pixels[k];
        assert!(scene.train.contains(&p.view));
        assert_eq!(b.rgb[k], scene.views[p.view].image.rgb(p.x, p.y));
        assert_eq!(b.mask[k], 1.0);
        assert_eq!(b.rays.near[k], scene.near);
    }
    // NDC: the ray starts on the near plane (z = −1) and its origin is on the near plane.
    let ndc = b.rays.to_ndc(24, 18, scene.views[0].camera.fx, 1.0);
    assert!(ndc.origins.iter().all(|o| (o[2] + 1.0).abs() < 1e-4));
    // Patches on a scene without masks are never redrawn.
    let p = PatchSampler::new(4, 2, 1)
        .sample(&scene, Split::Train)
        .unwrap();
    assert_eq!(p.redraws, 0);
}

#[test]
fn turntable_and_interpolation_paths() {
    let (dir, _) = write(SceneFormat::Blender, 16, 6);
    let scene = load(dir.path());
    let path = turntable_for_scene(&scene, 12).unwrap();
    assert_eq!(path.len(), 12);
    for cam in &path {
        assert!(
            (norm(cam.origin()) - 4.0).abs() < 1e-3,
            "radius {}",
            norm(cam.origin())
        );
        let to_centre = Vec3::ZERO - cam.origin();
        assert!(dot(cam.forward(), to_centre) / norm(to_centre) > 0.99999);
    }
    assert!(
        dist(path[0].origin(), path[6].origin()) > 5.0,
        "opposite sides of the circle"
    );
    let keys: Vec<Camera> = scene
        .views
        .iter()
        .take(3)
        .map(|v| v.camera.clone())
        .collect();
    let inter = interpolate(&keys, 5);
    assert_eq!(inter.len(), 11);
    assert_eq!(inter[0].c2w, keys[0].c2w);
    assert_eq!(inter[10].c2w, keys[2].c2w);
    for c in &inter {
        assert!(orthonormality_error(c.rotation()) < 1e-5);
    }
    let mid = &inter[5];
    assert!(dist(mid.origin(), keys[1].origin()) < 1e-4);
}

#[test]
fn a_partial_capture_is_shown_along_the_arc_its_cameras_saw() {
    // The synthetic DTU capture's cameras span 150° of azimuth; Blender's circle the object.
    let (dir, _) = write(SceneFormat::Dtu, 16, 8);
    let scene = load(dir.path());
    assert_eq!(default_kind(&scene), PathKind::Arc);
    let (start, span) = capture_arc(&scene).expect("a side unseen");
    assert!(
        span > 100f32.to_radians() && span < 180f32.to_radians(),
        "{span}"
    );
    let (orbit, _) = scene_orbit(&scene).unwrap();
    let (e1, e2) = plane_basis(orbit.up);
    let azimuth = |p: Vec3| {
        let v = p - orbit.center;
        // Measured from the arc's start, counter-clockwise, in [0, 2π).
        (v.dot(e2).atan2(v.dot(e1)) - start).rem_euclid(std::f32::consts::TAU)
    };
    // Every training camera lies on the arc, and so does every frame of the path.
    for &i in &scene.train {
        assert!(azimuth(scene.views[i].camera.origin()) <= span + 1e-4);
    }
    let path = path_for_scene(&scene, Some(PathKind::Arc), 24).unwrap();
    assert_eq!(path.len(), 24);
    let along: Vec<f32> = path.iter().map(|c| azimuth(c.origin())).collect();
    assert!(along.iter().all(|&a| a <= span + 1e-3), "{along:?}");
    assert!(
        along[0] < 1e-3 && (along[12] - span).abs() < 1e-3,
        "{along:?}"
    );
    let (blender, _) = write(SceneFormat::Blender, 16, 6);
    let blender = load(blender.path());
    assert_eq!(default_kind(&blender), PathKind::Turntable);
    assert_eq!(
        path_for_scene(&blender, Some(PathKind::Arc), 12).unwrap()[3].c2w,
        turntable_for_scene(&blender, 12).unwrap()[3].c2w,
        "cameras all around: the arc is the turntable"
    );
}

#[test]
fn plain_images_load_resize_and_give_a_grid() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("a.jpg");
    image::RgbImage::from_fn(40, 20, |x, _| image::Rgb([(x * 6) as u8, 100, 200]))
        .save(&p)
        .unwrap();
    let img = load_rgb(&p, None).unwrap();
    assert_eq!((img.width, img.height), (40, 20));
    let small = load_rgb(&p, Some((10, 5))).unwrap();
    assert_eq!((small.width, small.height, small.data.len()), (10, 5, 150));
    let grid = pixel_coordinates(4, 2);
    assert_eq!(grid.len(), 8);
    assert_eq!(grid[0], [-0.75, -0.5]);
    assert_eq!(grid[7], [0.75, 0.5]);
    let err = load_rgb(&dir.path().join("nope.png"), None)
        .unwrap_err()
        .to_string();
    assert!(err.contains("nope.png"), "{err}");
}
