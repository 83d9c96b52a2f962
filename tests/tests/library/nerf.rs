//! NeRF + INS end to end on a small analytic scene written by `data synth`: pretraining the grid
//! variant reaches a PSNR on held-out views, stylizing changes the colours towards a painting
//! while the depth stays that of the pretrained model, and the MLP variant trains.

use burn::prelude::*;
use ins_core::imaging::RgbImage;
use ins_core::modules::field::CimKind;
use ins_models::consistency::PaintingFeatures;
use ins_models::nerf::eval::{ViewRender, evaluate_views, render_camera};
use ins_models::nerf::{Nerf, NerfRun, NerfRunConfig};
use ins_models::run::scene::heldout_views;
use ins_models::run::train;
use ins_scene::data::synthetic::{SynthOptions, write_blender};
use ins_tests::{quiet_options, real_vgg, save_image};

/// A small grid configuration that trains in seconds.
fn tiny(scene: &std::path::Path) -> NerfRunConfig {
    let mut cfg = NerfRunConfig {
        target_samples: 1 << 14,
        log2_table: 14,
        max_resolution: 128,
        occupancy_resolution: 32,
        eval_every: 0,
        ..Default::default()
    };
    cfg.source.scene = Some(scene.to_path_buf());
    cfg.source.downscale = 1;
    cfg.schedule.steps = 600;
    cfg.schedule.checkpoint_every = 200;
    cfg
}

/// Diagonal stripes, a style unlike anything in the scene.
fn stripes(size: usize) -> RgbImage {
    let mut data = Vec::with_capacity(size * size * 3);
    for v in 0..size {
        for u in 0..size {
            data.extend(if ((u + v) / 4) % 2 == 0 {
                [0.9, 0.1, 0.1]
            } else {
                [0.1, 0.2, 0.9]
            });
        }
    }
    RgbImage {
        width: size,
        height: size,
        data,
    }
}

fn median_depth_error(a: &ViewRender, b: &ViewRender) -> f32 {
    let mut e: Vec<f32> = (0..a.opacity.len())
        .filter(|&i| a.opacity[i] > 0.5 && b.opacity[i] > 0.5)
        .map(|i| {
            let (da, db) = (a.depth[i] / a.opacity[i], b.depth[i] / b.opacity[i]);
            (da - db).abs() / db
        })
        .collect();
    assert!(e.len() > 50, "too few opaque pixels to compare depth");
    e.sort_by(f32::total_cmp);
    e[e.len() / 2]
}

#[test]
fn grid_nerf_pretrains_then_stylizes_keeping_its_depth() {
    let device = Device::flex();
    let dir = tempfile::tempdir().unwrap();
    let scene_dir = dir.path().join("scene");
    write_blender(
        &scene_dir,
        &SynthOptions {
            size: 48,
            views: 16,
        },
    )
    .unwrap();
    let run_dir = dir.path().join("pretrained");
    let cfg = tiny(&scene_dir);
    let out = train::<Nerf>(&cfg, None, &device, quiet_options(&run_dir)).unwrap();
    assert!(out.finished);
    assert!(run_dir.join("val/final.png").exists());
    let run = NerfRun::load(&run_dir, &device).unwrap();
    let views = heldout_views(&run.scene());
    let evals = evaluate_views(
        &run.model.valid(),
        &run.scene(),
        &views,
        run.sampling(),
        None,
        run.background(),
        &device,
    )
    .unwrap();
    let psnr = evals.iter().map(|e| e.psnr).sum::<f64>() / evals.len() as f64;
    // The reference: the best constant colour over the same views (what a field that learned
    // nothing but the mean colour would score).
    let photos: Vec<(&[f32], Vec<bool>)> = evals
        .iter()
        .map(|e| (e.photo.as_slice(), vec![true; e.photo.len() / 3]))
        .collect();
    let psnr_constant = ins_tests::constant_colour_psnr(&photos);
    eprintln!("held-out PSNR {psnr:.2} dB (constant colour: {psnr_constant:.2} dB)");
    assert!(
        psnr > psnr_constant + 8.0,
        "held-out PSNR after pretraining {psnr:.2} dB is not clearly above a constant colour's {psnr_constant:.2} dB"
    );
    let grid = run.grid().unwrap();
    assert!(
        grid.occupancy() < 0.5,
        "the occupancy grid did not prune: {}",
        grid.occupancy()
    );

    // Stylize with stripes and blotches (two styles: one-hot codes, mixes in between).
    let style = save_image(dir.path(), "stripes.png", &stripes(64));
    let second = save_image(dir.path(), "blotches.png", &ins_tests::blotches(64));
    let st_dir = dir.path().join("stylized");
    let mut st_cfg = cfg.clone();
    st_cfg.source.scene = None;
    st_cfg.source.from = Some(run_dir.clone());
    st_cfg.schedule.steps = 150;
    // At the default 1e-3, 150 steps leave the two styles nearly alike on this tiny scene.
    st_cfg.schedule.lr = 5e-3;
    st_cfg.schedule.checkpoint_every = 100;
    st_cfg.style.styles = vec![style, second];
    st_cfg.style.patch = 24;
    st_cfg.style.stride = 2;
    st_cfg.style.style_size = 64;
    let vgg = real_vgg(&device);
    train::<Nerf>(&st_cfg, Some(vgg.clone()), &device, quiet_options(&st_dir)).unwrap();
    let st = NerfRun::load(&st_dir, &device).unwrap();
    assert_eq!(st.model.n_styles(), 2);
    let view = &st.scene().views[views[0]].camera;
    let code = st.code(None, &device).unwrap();
    let before = render_camera(
        &run.model.valid(),
        &run.scene(),
        view,
        run.sampling(),
        None,
        run.background(),
        &device,
    )
    .unwrap();
    let stylized = st.model.valid();
    let render_stylized = |code| {
        render_camera(
            &stylized,
            st.scene(),
            view,
            st.sampling(),
            code,
            st.background(),
            &device,
        )
        .unwrap()
    };
    let after = render_stylized(code);
    // The object moved towards the painting (nearest-neighbour feature distances on the
    // pixels the pretrained model renders opaque, as `eval consistency` measures texture)...
    let paintings = [stripes(64), ins_tests::blotches(64)]
        .map(|p| PaintingFeatures::new(&vgg, &p, 64, &device));
    let opaque: Vec<bool> = before.opacity.iter().map(|&o| o > 0.5).collect();
    let d = |img: &RgbImage, p| ins_tests::painting_distance(&vgg, p, img, &opaque, &device);
    let (d0, d1) = (
        d(&before.image(), &paintings[0]),
        d(&after.image(), &paintings[0]),
    );
    eprintln!("distance to the painting on the object {d0:.4} → {d1:.4}");
    assert!(d1 < d0 - 0.02, "distance to the painting {d0} → {d1}");
    // ...and the geometry did not.
    let err = median_depth_error(&after, &before);
    eprintln!("median relative depth error after stylizing {err}");
    assert!(err < 0.02, "median relative depth error {err}");

    // From the one end of the mix to the other the render leaves the stripes and nears the
    // blotches (nearest-neighbour feature distances, as `eval consistency`
    // measures texture).
    let (mut to_first, mut to_second) = (Vec::new(), Vec::new());
    for t in ins_tests::MIX_STEPS {
        let code = st.code(Some(&[1.0 - t, t]), &device).unwrap();
        let img = render_stylized(code).image();
        to_first.push(d(&img, &paintings[0]));
        to_second.push(d(&img, &paintings[1]));
    }
    eprintln!("along the mix: to the stripes {to_first:?}, to the blotches {to_second:?}");
    // Asserted on the render's preference, its distance to the stripes less its distance to
    // the blotches, which rises as it leaves the one for the other. Either distance alone also
    // falls as a render gets painterly at all: in one run (a fresh clone, both tests of this
    // file at once) the blotch end was barely farther from the stripes than the stripe end
    // (0.4949 against 0.4870) while it neared the blotches by 0.112, a preference moved by
    // 0.120; here 0.35 and 0.26. A model that ignores its code moves 0. Only the ends are
    // asserted: between them this NeRF's mix is not reliably monotone (in one of three runs
    // the render at t = 0.5 was farther from both paintings than either end); the IDR test
    // holds the whole mix.
    let preference: Vec<f64> = to_first
        .iter()
        .zip(&to_second)
        .map(|(a, b)| a - b)
        .collect();
    ins_tests::assert_moved(
        &preference,
        true,
        "the distance to the stripes less the distance to the blotches",
    );

    // Deferred back-propagation through the trainer: the patch's 576 rays back-propagated in
    // chunks of 200, the density stylized too (so the geometry term goes through the chunks),
    // against the same run back-propagated directly (the same patches; the samples of chunks
    // after the first are jittered differently). At stylization's default rate: at the 5e-3
    // above, about one 80-step run in 32 (either way of back-propagating) had its colours
    // saturate to white within 20 steps and its style term stall there (the SIM's features
    // grow under Adam's first steps: mean |s| 0.12 → 8 by step 20), which says nothing of
    // the deferred gradient.
    let metrics = |chunk: usize| {
        let out_dir = dir.path().join(format!("chunk{chunk}"));
        let mut cfg = st_cfg.clone();
        cfg.style.styles.truncate(1);
        cfg.schedule.lr = 1e-3;
        cfg.schedule.steps = 80;
        cfg.backprop_chunk = chunk;
        cfg.stylize_density = true;
        let out = train::<Nerf>(&cfg, Some(vgg.clone()), &device, quiet_options(&out_dir));
        assert!(out.unwrap().finished);
        let log = std::fs::read_to_string(out_dir.join("metrics.jsonl")).unwrap();
        let records: Vec<serde_json::Value> = log
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .filter(|v: &serde_json::Value| v.get("style").is_some())
            .collect();
        // Logged every 10 steps: the first three records and the last three.
        assert!(records.len() >= 6, "{} records", records.len());
        let mean = |r: &[serde_json::Value], k: &str| {
            r.iter().map(|v| v[k].as_f64().unwrap()).sum::<f64>() / r.len() as f64
        };
        let last = &records[records.len() - 3..];
        (
            mean(&records[..3], "style"),
            mean(last, "style"),
            mean(last, "geometry"),
        )
    };
    let direct = metrics(4096);
    let deferred = metrics(200);
    eprintln!("style first → last, geometry: direct {direct:?}, deferred {deferred:?}");
    assert!(
        deferred.1 < deferred.0,
        "the style term did not fall: {deferred:?}"
    );
    assert!(
        (deferred.1 - direct.1).abs() < 0.03 * direct.1,
        "deferred {deferred:?} against direct {direct:?}"
    );
    assert!(deferred.2.is_finite() && deferred.2 > 0.0 && deferred.2 < 10.0 * direct.2 + 1e-6);
}

#[test]
fn mlp_nerf_trains_and_renders() {
    let device = Device::flex();
    let dir = tempfile::tempdir().unwrap();
    let scene_dir = dir.path().join("scene");
    write_blender(&scene_dir, &SynthOptions { size: 16, views: 4 }).unwrap();
    let run_dir = dir.path().join("mlp");
    let mut cfg = NerfRunConfig {
        cim: CimKind::Mlp,
        rays: 128,
        coarse_samples: 16,
        fine_samples: 16,
        ..tiny(&scene_dir)
    };
    cfg.schedule.steps = 30;
    cfg.schedule.lr = 5e-4;
    let out = train::<Nerf>(&cfg, None, &device, quiet_options(&run_dir)).unwrap();
    assert!(
        out.last["mse"] < out.last["mse_coarse"].max(0.2),
        "{:?}",
        out.last
    );
    let log = std::fs::read_to_string(run_dir.join("metrics.jsonl")).unwrap();
    let mse: Vec<f64> = log
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["mse"]
                .as_f64()
                .unwrap()
        })
        .collect();
    assert!(
        mse.last().unwrap() < mse.first().unwrap(),
        "MSE did not fall: {mse:?}"
    );
    let run = NerfRun::load(&run_dir, &device).unwrap();
    assert!(run.model.coarse.is_some());
    let r = render_camera(
        &run.model.valid(),
        &run.scene(),
        &run.scene().views[0].camera,
        run.sampling(),
        None,
        run.background(),
        &device,
    )
    .unwrap();
    assert_eq!(r.rgb.len(), 16 * 16 * 3);
}
