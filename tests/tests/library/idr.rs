//! IDR + INS end to end on a small synthetic DTU scene: the surface pretrains to a silhouette
//! IoU on held-out views through either renderer (sphere tracing, or the SDF as a volume), the differentiable surface point carries the implicit-function
//! gradient, stylization changes the colours and not the silhouette, and a mesh comes out.

use burn::prelude::*;
use ins_core::imaging::RgbImage;
use ins_models::consistency::PaintingFeatures;
use ins_models::idr::eval::evaluate_views;
use ins_models::idr::mesh::extract_mesh;
use ins_models::idr::model::SdfRenderer;
use ins_models::idr::{Idr, IdrRun, IdrRunConfig};
use ins_models::run::train;
use ins_scene::data::synthetic::{SynthOptions, write_dtu};
use ins_tests::{quiet_options, real_vgg, save_image};

fn stripes(size: usize) -> RgbImage {
    let mut data = Vec::with_capacity(size * size * 3);
    for v in 0..size {
        for u in 0..size {
            data.extend(if ((u + 2 * v) / 5) % 2 == 0 {
                [0.95, 0.8, 0.1]
            } else {
                [0.1, 0.1, 0.5]
            });
        }
    }
    RgbImage {
        width: size,
        height: size,
        data,
    }
}

/// The 48-pixel synthetic DTU scene in `dir/scene` and a small grid SDF's settings on it.
fn small_scene(dir: &std::path::Path) -> IdrRunConfig {
    let scene = dir.join("scene");
    // 24 views, 18 of them for training: with 16 (12 for training) the held-out PSNR inside the
    // mask sat 0.1 to 0.4 dB above the bar below and moved by as much with any change to the
    // tracer; 24 views give 15.8 dB at the same number of steps, clear of it.
    write_dtu(
        &scene,
        &SynthOptions {
            size: 48,
            views: 24,
        },
    )
    .unwrap();
    small_scene_config(scene)
}

/// A small grid SDF's settings on the synthetic scene in `scene`.
fn small_scene_config(scene: std::path::PathBuf) -> IdrRunConfig {
    let mut cfg = IdrRunConfig {
        holdout: 4,
        eval_every: Some(0),
        // The defaults (grid 512, colour width 128) are tuned on scan37 at 400×300; on this
        // 48-pixel scene they reach only 12.9 dB held-out (13.2 with width 64), where the
        // finer 1024 grid with the 64-wide colour network (the earlier defaults) reaches 15.0 dB.
        grid_max_resolution: 1024,
        color_width: 64,
        // The volume's appearance grid (2047 cells across) holds texture finer than a 400×300
        // capture's pixels; this scene has none finer than the SDF's grid.
        color_grid: Some(0),
        ..Default::default()
    };
    cfg.source.scene = Some(scene);
    cfg.source.downscale = 1;
    cfg
}

/// `scene` written as a DTU scene of `size` pixels and 24 views in `dir/scene`, and a volume
/// run's settings on it (`rays` a step, `steps` steps).
fn volume_scene_config(
    scene: ins_scene::data::synthetic::AnalyticScene,
    dir: &std::path::Path,
    size: u32,
    rays: usize,
    steps: usize,
) -> IdrRunConfig {
    let path = dir.join("scene");
    ins_scene::data::synthetic::write_dtu_of(scene, &path, &SynthOptions { size, views: 24 })
        .unwrap();
    let mut cfg = small_scene_config(path);
    cfg.renderer = SdfRenderer::Volume;
    cfg.rays = rays;
    cfg.schedule.steps = steps;
    cfg
}

/// Pretrains `cfg` into `run_dir` and renders its held-out views, scored against the scene's
/// masks.
fn train_and_evaluate(
    cfg: &IdrRunConfig,
    run_dir: &std::path::Path,
    device: &Device,
) -> (IdrRun, Vec<ins_models::idr::eval::SurfaceEval>) {
    let out = train::<Idr>(cfg, None, device, quiet_options(run_dir)).unwrap();
    assert!(out.finished);
    let run = IdrRun::load(run_dir, device).unwrap();
    let views = run.scene().split(ins_scene::data::Split::Val).to_vec();
    assert!(!views.is_empty());
    let evals = evaluate_views(
        &run.model.valid(),
        run.scene(),
        &views,
        None,
        &run.config.view_options(),
        device,
    )
    .unwrap();
    (run, evals)
}

/// Pretrains `cfg` into `run_dir`, then scores its held-out views: asserts a silhouette IoU
/// above 0.9 and a PSNR inside the masks 3 dB above the best constant colour's.
fn pretrain_and_score(
    cfg: &IdrRunConfig,
    run_dir: &std::path::Path,
    device: &Device,
) -> (IdrRun, Vec<ins_models::idr::eval::SurfaceEval>) {
    let (run, evals) = train_and_evaluate(cfg, run_dir, device);
    let iou = evals.iter().map(|e| e.iou).sum::<f64>() / evals.len() as f64;
    let psnr = evals.iter().map(|e| e.psnr_mask).sum::<f64>() / evals.len() as f64;
    // The reference: the best constant colour inside the masks of the same views (what a colour
    // network that learned nothing but the mean would score).
    let photos: Vec<(&[f32], Vec<bool>)> = evals
        .iter()
        .map(|e| (e.photo.as_slice(), e.mask.clone()))
        .collect();
    let psnr_constant = ins_tests::constant_colour_psnr(&photos);
    eprintln!(
        "{:?} renderer: held-out IoU {iou:.3}, PSNR in mask {psnr:.2} dB (constant colour: {psnr_constant:.2} dB)",
        cfg.renderer
    );
    assert!(iou > 0.9, "held-out silhouette IoU {iou:.3}");
    assert!(
        psnr > psnr_constant + 3.0,
        "held-out PSNR inside the mask {psnr:.2} dB is not clearly above a constant colour's {psnr_constant:.2} dB"
    );
    (run, evals)
}

/// The notched block's hollow corner is seen against the block from every camera, so masks
/// cannot carve it; a volume-rendered SDF carves it from the photos' colours. At 128 pixels
/// after 1200 steps the SDF is positive (empty) at all six points probed inside the notch
/// (+0.07 to +0.20 where the truth is +0.15 to +0.30); the surface renderer after as many
/// steps of 1024 rays left the deep half filled (three probes at −0.04 to −0.15), and at 64
/// pixels (checker squares of 3 pixels) the volume's did too. The smoothness term keeps the
/// checkers out of the surface: the mesh's normals 22° from the truth on average at weight
/// 0.5, 35° without it (docs/measurements.md). With half the rays inside the masks (the
/// default since the thirtieth session): probes +0.03 to +0.13, normals 20.9°, the mesh
/// 0.041 from the truth, held out IoU 0.976 and 17.31 dB (135 s alone). Scored as `eval mesh`
/// scores it against the true surface the cameras see: 0.876 of the truth within 0.03 of the
/// mesh and a Chamfer distance of 0.018, where the block with its notch filled has 0.722 and
/// 0.034 (the notch is 28 % of what the cameras see).
#[test]
fn volume_rendered_sdf_carves_a_corner_masks_cannot() {
    use ins_models::mesh_score::{MeshScoreOptions, score_mesh};
    use ins_models::run::MeshOptions;
    use ins_scene::data::synthetic::{AnalyticScene, Object, Shape, Texture};
    use ins_scene::geometry::Vec3;
    let device = Device::flex();
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = volume_scene_config(AnalyticScene::notched_block(), dir.path(), 128, 256, 1200);
    // The smoothness term at 0.5, five times the default: the normals' figure below then
    // stands clear of the run without it (22° against 35°; the default's 0.1 gave 27°).
    cfg.curvature_weight = Some(0.5);
    let run_dir = dir.path().join("volume");
    let (run, _) = pretrain_and_score(&cfg, &run_dir, &device);
    // The learnable sharpness rose from its start (s ≈ 20) as the surface settled: the
    // colour now comes from a band narrower than the one it began with.
    let s = run
        .model
        .sharpness
        .as_ref()
        .expect("a volume run has a sharpness")
        .value();
    assert!(s > 25.0, "sharpness {s}");

    let truth = AnalyticScene::notched_block();
    let [lo, hi] = AnalyticScene::NOTCH;
    let inside_notch: Vec<Vec3> = [0.3f32, 0.5, 0.7]
        .into_iter()
        .flat_map(|f| {
            [0.3f32, 0.6].map(|h| {
                Vec3::new(
                    lo[0] + f * (hi[0] - lo[0]),
                    lo[1] + f * (hi[1] - lo[1]),
                    lo[2] + h * (hi[2] - lo[2]),
                )
            })
        })
        .collect();
    // Inside each wall and the slab: an SDF positive everywhere would pass the notch alone.
    let inside_block = [
        Vec3::new(0.2, -0.3, -0.1),
        Vec3::new(-0.3, 0.2, -0.1),
        Vec3::new(0.2, 0.2, -0.45),
    ];
    let sdf = |points: &[Vec3]| {
        let flat: Vec<f32> = points.iter().flat_map(|p| p.to_array()).collect();
        ins_models::idr::render::sdf_at(&run.model.sdf, &flat, &device)
    };
    let (notch, block) = (sdf(&inside_notch), sdf(&inside_block));
    eprintln!("SDF inside the notch {notch:?}, inside the block {block:?}");
    assert!(
        notch.iter().all(|&d| d > 0.0),
        "the notch is filled: SDF {notch:?} at {inside_notch:?}"
    );
    assert!(
        block.iter().all(|&d| d < 0.0),
        "the block is hollow: {block:?}"
    );

    let (mesh, _) = extract_mesh(&run.model.valid(), 96, None, &device).unwrap();
    let mean = mesh
        .vertices
        .iter()
        .map(|v| truth.foreground_distance(Vec3::from_array(*v)).abs())
        .sum::<f32>()
        / mesh.vertices.len() as f32;
    eprintln!("the mesh's mean distance to the true surface: {mean:.4}");
    let e = 1e-3;
    let angle = mesh
        .vertices
        .iter()
        .zip(&mesh.normals)
        .map(|(v, n)| {
            let p = Vec3::from_array(*v);
            let d = |o: Vec3| truth.foreground_distance(p + o) - truth.foreground_distance(p - o);
            let t = Vec3::new(d(Vec3::X * e), d(Vec3::Y * e), d(Vec3::Z * e)).normalize_or_zero();
            Vec3::from_array(*n)
                .dot(t)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        })
        .sum::<f32>()
        / mesh.vertices.len() as f32;
    eprintln!("the mesh's normals {angle:.2} degrees from the true surface's on average");
    assert!(
        angle < 28.0,
        "the mesh's normals {angle:.1}° from the truth on average"
    );
    assert!(mean < 0.06, "mesh {mean} from the true surface on average");

    // The mesh against the true surface the cameras see (the `reference.ply` written beside
    // the photos, in the world frame at 30 times the scene's), as `eval mesh` scores it, and
    // the same block with its notch filled (what a visual hull would give) scored alike: within
    // 0.3 (scene units) of the truth a point is averaged, within 0.03 it is a match.
    let reference = dir
        .path()
        .join("scene")
        .join(ins_scene::data::synthetic::REFERENCE_SURFACE);
    let world = 30.0;
    let options = MeshScoreOptions {
        mesh: MeshOptions {
            resolution: 96,
            level: None,
        },
        samples: 50_000,
        max_distance: Some(0.3 * world),
        threshold: Some(0.03 * world),
    };
    let carved = score_mesh(&run_dir, &reference, &options, &device)
        .unwrap()
        .distance;
    let to_scene = run.scene().to_scene;
    let truth_points: Vec<Vec3> = ins_scene::data::ply_points::read_ply_points(&reference)
        .unwrap()
        .iter()
        .map(|p| to_scene.apply_point(p.as_vec3()))
        .collect();
    let filled_block = AnalyticScene {
        objects: vec![Object {
            shape: Shape::Box {
                min: Vec3::new(-0.5, -0.5, -0.55),
                max: Vec3::new(0.5, 0.5, 0.15),
            },
            texture: Texture::Solid(Vec3::ONE),
            foreground: true,
        }],
        ..truth.clone()
    };
    let cameras: Vec<_> = run.scene().views.iter().map(|v| v.camera.clone()).collect();
    let filled = filled_block.seen_by(&filled_block.foreground_surface(0.01), &cameras);
    let hull = ins_core::mesh::surface_distance(&filled, &truth_points, 0.3, 0.03, 0.01);
    eprintln!("against the true surface (world units): the mesh {carved:?}");
    eprintln!("the notch filled (scene units): {hull:?}");
    assert!(
        carved.recall > hull.recall + 0.08 && carved.chamfer / world < hull.chamfer,
        "the mesh matches the true surface no better than the filled block: {carved:?} against {hull:?}"
    );
}

/// Without masks, the room behind the objects has to live somewhere: the volume renderer's
/// field beyond the unit sphere (NeRF++) takes it, so the SDF builds nothing in front of the
/// cameras. Objects inside a painted dome, trained on the photos alone and scored against the
/// masks it never saw: the surface stays on the objects (no floaters), the central sphere is
/// whole, and the dome is learnt where it shows. The two small objects at the sphere's side
/// are lost in the first 200 steps (carved with the starting sphere, never regrown; at 96
/// pixels: IoU 0.76 without masks, 0.98 with), which is why the test does not ask for them.
/// With the background's learning rate at a tenth, the dome was painted on a shell around the
/// objects instead (IoU 0.36): what this test fails on.
#[test]
fn without_masks_the_room_goes_beyond_the_unit_sphere() {
    use ins_scene::data::synthetic::AnalyticScene;
    let device = Device::flex();
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = volume_scene_config(AnalyticScene::domed(), dir.path(), 64, 256, 800);
    cfg.no_mask = true;
    let (run, evals) = train_and_evaluate(&cfg, &dir.path().join("no_mask"), &device);
    assert!(!run.masked());
    assert!(
        run.model.background.is_some(),
        "a run without masks has a background field"
    );
    let truth = AnalyticScene::domed();
    let (mut opaque, mut opaque_outside, mut sphere, mut sphere_opaque) = (0, 0, 0, 0);
    let (mut se_outside, mut outside) = (0f64, 0usize);
    for e in &evals {
        let objects = truth.render(&run.scene().views[e.view].camera).object;
        for i in 0..e.mask.len() {
            let hit = e.render.hit[i];
            opaque += hit as usize;
            opaque_outside += (hit && !e.mask[i]) as usize;
            if objects[i] == Some(0) {
                sphere += 1;
                sphere_opaque += hit as usize;
            }
            if !e.mask[i] {
                outside += 1;
                se_outside += (0..3)
                    .map(|c| (e.render.rgb[i * 3 + c].clamp(0.0, 1.0) - e.photo[i * 3 + c]) as f64)
                    .map(|d| d * d)
                    .sum::<f64>();
            }
        }
    }
    let floaters = opaque_outside as f64 / opaque.max(1) as f64;
    let sphere_kept = sphere_opaque as f64 / sphere.max(1) as f64;
    let psnr_outside = ins_core::loss::psnr(se_outside / (3 * outside.max(1)) as f64);
    let background: Vec<(&[f32], Vec<bool>)> = evals
        .iter()
        .map(|e| (e.photo.as_slice(), e.mask.iter().map(|m| !m).collect()))
        .collect();
    let psnr_constant = ins_tests::constant_colour_psnr(&background);
    eprintln!(
        "without masks: {:.1}% of the opaque pixels outside the masks, {:.1}% of the central \
         sphere opaque, PSNR outside the masks {psnr_outside:.2} dB (a constant colour: \
         {psnr_constant:.2} dB), IoU {:.3}",
        floaters * 100.0,
        sphere_kept * 100.0,
        evals.iter().map(|e| e.iou).sum::<f64>() / evals.len() as f64
    );
    assert!(
        floaters < 0.03,
        "{:.1}% of the surface's pixels lie outside the masks",
        floaters * 100.0
    );
    assert!(
        sphere_kept > 0.95,
        "{:.1}% of the central sphere is opaque",
        sphere_kept * 100.0
    );
    assert!(
        psnr_outside > psnr_constant + 6.0,
        "the background is not learnt: {psnr_outside:.2} dB outside the masks, {psnr_constant:.2} for a constant colour"
    );
}

#[test]
fn grid_surface_pretrains_stylizes_and_meshes() {
    let device = Device::flex();
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = small_scene(dir.path());
    cfg.renderer = SdfRenderer::Surface;
    cfg.rays = 1024;
    cfg.schedule.steps = 400;
    cfg.schedule.checkpoint_every = 200;
    let run_dir = dir.path().join("surface");
    let (run, evals) = pretrain_and_score(&cfg, &run_dir, &device);
    let views: Vec<usize> = evals.iter().map(|e| e.view).collect();
    let opts = run.config.view_options();

    // Stylize with two paintings: the surface is frozen by default, so the silhouette is the
    // same; colours move.
    let style = save_image(dir.path(), "stripes.png", &stripes(64));
    let second = save_image(dir.path(), "blotches.png", &ins_tests::blotches(64));
    let st_dir = dir.path().join("stylized");
    let mut st = cfg.clone();
    st.source.scene = None;
    st.source.from = Some(run_dir.clone());
    st.schedule.steps = 40;
    st.style.styles = vec![style, second];
    st.style.patch = 24;
    st.style.stride = 1;
    st.style.style_size = 64;
    let vgg = real_vgg(&device);
    train::<Idr>(&st, Some(vgg.clone()), &device, quiet_options(&st_dir)).unwrap();
    let srun = IdrRun::load(&st_dir, &device).unwrap();
    let code = srun.code(None, &device).unwrap();
    let after = evaluate_views(
        &srun.model.valid(),
        &srun.scene(),
        &views,
        code,
        &opts,
        &device,
    )
    .unwrap();
    for (a, b) in after.iter().zip(&evals) {
        assert_eq!(
            a.render.hit, b.render.hit,
            "the silhouette changed although the SDF is frozen"
        );
    }
    // Nearer each painting on the surface (nearest-neighbour feature distances, as `eval
    // consistency` measures texture: a Gram distance also falls when the object just darkens).
    let paintings = [stripes(64), ins_tests::blotches(64)]
        .map(|p| PaintingFeatures::new(&vgg, &p, 64, &device));
    let d = |img: &RgbImage, mask: &[bool]| {
        ins_tests::painting_distance(&vgg, &paintings[0], img, mask, &device)
    };
    let mut closer = 0;
    for (a, b) in after.iter().zip(&evals) {
        let (d0, d1) = (
            d(&b.render.image(), &b.render.hit),
            d(&a.render.image(), &a.render.hit),
        );
        eprintln!(
            "view {}: distance to the painting on the surface {d0:.4} → {d1:.4}",
            b.view
        );
        closer += (d1 < d0) as usize;
    }
    assert_eq!(
        closer,
        evals.len(),
        "stylizing did not bring every held-out view closer to the painting"
    );

    // Along the mix from the stripes to the blotches, a held-out view leaves the one painting
    // and nears the other, step by step.
    let (mut to_first, mut to_second) = (Vec::new(), Vec::new());
    let view = &evals[0];
    let stylized = srun.model.valid();
    for t in ins_tests::MIX_STEPS {
        let code = srun.code(Some(&[1.0 - t, t]), &device).unwrap();
        let r = ins_models::idr::eval::render_camera(
            &stylized,
            srun.scene(),
            &srun.scene().views[view.view].camera,
            code,
            &opts,
            &device,
        )
        .unwrap();
        let img = r.image();
        let d = |p| ins_tests::painting_distance(&vgg, p, &img, &r.hit, &device);
        to_first.push(d(&paintings[0]));
        to_second.push(d(&paintings[1]));
    }
    eprintln!("along the mix: to the stripes {to_first:?}, to the blotches {to_second:?}");
    ins_tests::assert_monotone(&to_first, true, 0.15, "the distance to the stripes");
    ins_tests::assert_monotone(&to_second, false, 0.15, "the distance to the blotches");

    // A mesh of the reconstructed surface, coloured; closed and of a plausible size.
    let (mesh, colors) = extract_mesh(&run.model.valid(), 64, None, &device).unwrap();
    assert!(mesh.triangles.len() > 100);
    assert_eq!(colors.len(), mesh.vertices.len());
    assert!(mesh.volume() > 0.01, "volume {}", mesh.volume());
}
