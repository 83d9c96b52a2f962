//! No panics on any input: every loader runs over thousands of seeded mutations (byte flips,
//! truncations, insertions, duplicated runs) of real-format files, and each must end in `Ok` or
//! an error that names the file. No panic, no hang (each input within a time bound, watched by
//! a second thread), and no single allocation above a stated cap, however the headers lie.
//!
//! Its own test binary: it installs a counting global allocator.

use std::alloc::{GlobalAlloc, Layout, System};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use burn::prelude::*;
use ins_core::train::checkpoint::{CheckpointStore, load_module_bytes};
use ins_scene::data::synthetic::{SynthOptions, write_blender, write_dtu, write_llff};
use ins_scene::data::{LoadOptions, Scene};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

/// The largest single allocation any loader may make, whatever a file claims: 512 MiB.
const ALLOC_CAP: usize = 512 << 20;
/// Mutated inputs per loader.
const MUTANTS: usize = 2000;
/// Time bound per input.
const PER_INPUT: Duration = Duration::from_secs(3);

struct Counting;
static LARGEST: AtomicUsize = AtomicUsize::new(0);
static TRACK: AtomicBool = AtomicBool::new(false);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if TRACK.load(Ordering::Relaxed) {
            LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if TRACK.load(Ordering::Relaxed) {
            LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        }
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if TRACK.load(Ordering::Relaxed) {
            LARGEST.fetch_max(new_size, Ordering::Relaxed);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// One seeded mutation of `original`.
fn mutate(original: &[u8], rng: &mut SmallRng) -> Vec<u8> {
    let mut b = original.to_vec();
    let rounds = rng.random_range(1..=4);
    for _ in 0..rounds {
        match rng.random_range(0..6) {
            // Flip random bytes.
            0 | 1 => {
                for _ in 0..rng.random_range(1..=8) {
                    if !b.is_empty() {
                        let i = rng.random_range(0..b.len());
                        b[i] ^= 1 << rng.random_range(0..8);
                    }
                }
            }
            // Set a byte to an extreme value (lying lengths and sizes).
            2 => {
                if !b.is_empty() {
                    let i = rng.random_range(0..b.len());
                    b[i] = [0x00, 0x7f, 0x80, 0xff][rng.random_range(0..4)];
                }
            }
            // Truncate.
            3 => {
                let n = rng.random_range(0..=b.len());
                b.truncate(n);
            }
            // Insert random bytes.
            4 => {
                let at = rng.random_range(0..=b.len());
                let n = rng.random_range(1..=16);
                let ins: Vec<u8> = (0..n).map(|_| rng.random()).collect();
                b.splice(at..at, ins);
            }
            // Duplicate a run of bytes.
            _ => {
                if b.len() > 2 {
                    let s = rng.random_range(0..b.len() - 1);
                    let e = rng.random_range(s + 1..=b.len().min(s + 64));
                    let run = b[s..e].to_vec();
                    let at = rng.random_range(0..=b.len());
                    b.splice(at..at, run);
                }
            }
        }
    }
    b
}

/// What happened to the mutants of one loader.
#[derive(Debug, Default)]
struct Tally {
    ok: usize,
    errors: usize,
    unnamed: Vec<String>,
    panics: Vec<String>,
    slow: Vec<String>,
    largest_alloc: usize,
}

static CURRENT: Mutex<String> = Mutex::new(String::new());
static PROGRESS: AtomicU64 = AtomicU64::new(0);

/// Runs `load` on `MUTANTS` mutations of `original` written to `target` (restored after).
/// An error must mention `name_in_error` (the file's name).
fn fuzz(
    label: &str,
    original: &[u8],
    target: &Path,
    name_in_error: &str,
    load: &dyn Fn(&Path) -> Result<(), String>,
) -> Tally {
    let mut rng = SmallRng::seed_from_u64(label.bytes().map(u64::from).sum());
    let mut t = Tally::default();
    for i in 0..MUTANTS {
        let bytes = mutate(original, &mut rng);
        std::fs::write(target, &bytes).unwrap();
        *CURRENT.lock().unwrap() = format!("{label} mutant {i}");
        PROGRESS.fetch_add(1, Ordering::Relaxed);
        LARGEST.store(0, Ordering::Relaxed);
        TRACK.store(true, Ordering::Relaxed);
        let start = Instant::now();
        let r = catch_unwind(AssertUnwindSafe(|| load(target)));
        TRACK.store(false, Ordering::Relaxed);
        let took = start.elapsed();
        t.largest_alloc = t.largest_alloc.max(LARGEST.load(Ordering::Relaxed));
        if took > PER_INPUT {
            t.slow.push(format!("mutant {i}: {took:?}"));
        }
        match r {
            Ok(Ok(())) => t.ok += 1,
            Ok(Err(msg)) => {
                t.errors += 1;
                if !msg.contains(name_in_error) {
                    t.unnamed.push(format!("mutant {i}: {msg}"));
                }
            }
            Err(p) => {
                let msg = p
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                t.panics.push(format!("mutant {i}: {msg}"));
            }
        }
    }
    std::fs::write(target, original).unwrap();
    t
}

fn check(label: &str, t: &Tally) {
    eprintln!(
        "{label}: {} ok, {} errors, {} panics, {} unnamed, {} slow, largest allocation {} KiB",
        t.ok,
        t.errors,
        t.panics.len(),
        t.unnamed.len(),
        t.slow.len(),
        t.largest_alloc >> 10
    );
    // The panic hook is silenced while fuzzing, so say what failed before asserting.
    for (what, list) in [
        ("panics", &t.panics),
        ("unnamed", &t.unnamed),
        ("slow", &t.slow),
    ] {
        for item in list.iter().take(5) {
            eprintln!("  {label} {what}: {item}");
        }
    }
    assert!(
        t.panics.is_empty(),
        "{label}: panics on {:?}",
        &t.panics[..t.panics.len().min(5)]
    );
    assert!(
        t.unnamed.is_empty(),
        "{label}: errors not naming the file: {:?}",
        &t.unnamed[..t.unnamed.len().min(5)]
    );
    assert!(t.slow.is_empty(), "{label}: slow inputs: {:?}", t.slow);
    assert!(
        t.largest_alloc <= ALLOC_CAP,
        "{label}: allocated {} bytes at once",
        t.largest_alloc
    );
    assert_eq!(t.ok + t.errors, MUTANTS);
}

/// Fails the test (instead of hanging CI) when an input makes no progress for a while.
fn watchdog() {
    static STARTED: AtomicBool = AtomicBool::new(false);
    if STARTED.swap(true, Ordering::SeqCst) {
        return;
    }
    std::thread::spawn(|| {
        let mut last = u64::MAX;
        loop {
            std::thread::sleep(Duration::from_secs(30));
            let now = PROGRESS.load(Ordering::Relaxed);
            if now == last {
                eprintln!("hang: no progress for 30 s on {}", CURRENT.lock().unwrap());
                std::process::exit(3);
            }
            last = now;
        }
    });
}

fn quiet_panics() {
    std::panic::set_hook(Box::new(|_| {}));
}

fn err<E: std::fmt::Display>(e: E) -> String {
    format!("{e:#}")
}

fn fixture(rel: &str) -> PathBuf {
    ins_tests::fixture(rel)
}

/// A loader's run over its mutants, with one more check: the original loads.
fn run(label: &str, original_path: &Path, name: &str, load: &dyn Fn(&Path) -> Result<(), String>) {
    watchdog();
    quiet_panics();
    load(original_path).unwrap_or_else(|e| panic!("{label}: the unmutated file fails: {e}"));
    let original = std::fs::read(original_path).unwrap();
    let t = fuzz(label, &original, original_path, name, load);
    check(label, &t);
}

#[test]
fn onnx_models() {
    let dir = tempfile::tempdir().unwrap();
    for f in ["tiny_nhwc.onnx", "tiny_nchw.onnx"] {
        let p = dir.path().join(f);
        std::fs::copy(fixture(&format!("vgg/{f}")), &p).unwrap();
        run(f, &p, f, &|p| {
            vgg_import::onnx::read_vgg_like_onnx(p, None)
                .map(|_| ())
                .map_err(err)
        });
    }
}

#[test]
fn png_and_jpeg_images() {
    let dir = tempfile::tempdir().unwrap();
    let img = ins_models::demo::demo_content(48);
    for name in ["photo.png", "photo.jpg"] {
        let p = dir.path().join(name);
        img.save(&p).unwrap();
        run(name, &p, name, &|p| {
            ins_scene::data::images::read_image(p)
                .map(|_| ())
                .map_err(err)
        });
    }
}

fn tiny() -> SynthOptions {
    SynthOptions { size: 16, views: 3 }
}

#[test]
fn blender_transforms() {
    let dir = tempfile::tempdir().unwrap();
    write_blender(dir.path(), &tiny()).unwrap();
    let p = dir.path().join("transforms_train.json");
    run("blender json", &p, "transforms_train.json", &|_| {
        Scene::load(dir.path(), &LoadOptions::default())
            .map(|_| ())
            .map_err(err)
    });
}

#[test]
fn llff_poses_bounds() {
    let dir = tempfile::tempdir().unwrap();
    write_llff(dir.path(), &tiny()).unwrap();
    let p = dir.path().join("poses_bounds.npy");
    run("llff npy", &p, "poses_bounds.npy", &|_| {
        Scene::load(dir.path(), &LoadOptions::default())
            .map(|_| ())
            .map_err(err)
    });
}

#[test]
fn dtu_cameras() {
    let dir = tempfile::tempdir().unwrap();
    write_dtu(dir.path(), &tiny()).unwrap();
    let p = dir.path().join("cameras.npz");
    run("dtu npz", &p, "cameras.npz", &|_| {
        Scene::load(dir.path(), &LoadOptions::default())
            .map(|_| ())
            .map_err(err)
    });
}

#[test]
fn colmap_models() {
    use ins_scene::data::colmap_model::Encoding;
    use ins_scene::data::synthetic::{CaptureLayout, write_colmap};
    for (enc, ext) in [(Encoding::Binary, "bin"), (Encoding::Text, "txt")] {
        let dir = tempfile::tempdir().unwrap();
        write_colmap(dir.path(), &tiny(), CaptureLayout::ObjectCentred, enc).unwrap();
        for stem in ["cameras", "images", "points3D"] {
            let name = format!("{stem}.{ext}");
            let p = dir.path().join("sparse/0").join(&name);
            run(&format!("colmap {name}"), &p, &name, &|_| {
                Scene::load(dir.path(), &LoadOptions::default())
                    .map(|_| ())
                    .map_err(err)
            });
        }
    }
}

#[test]
fn nerfstudio_transforms() {
    use ins_scene::data::synthetic::{CaptureLayout, write_transforms};
    let dir = tempfile::tempdir().unwrap();
    write_transforms(dir.path(), &tiny(), CaptureLayout::ObjectCentred).unwrap();
    for name in ["transforms.json", "sparse_pc.ply"] {
        let p = dir.path().join(name);
        run(&format!("transforms {name}"), &p, name, &|_| {
            Scene::load(dir.path(), &LoadOptions::default())
                .map(|_| ())
                .map_err(err)
        });
    }
}

#[test]
fn run_configs() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("config.json");
    let cfg = ins_tests::small_config("c.png".into(), vec!["s.png".into()], 32);
    std::fs::write(&p, serde_json::to_string_pretty(&cfg).unwrap()).unwrap();
    run("siren config", &p, "config.json", &|p| {
        ins_models::siren::SirenRunConfig::from_file(p)
            .map(|_| ())
            .map_err(err)
    });
}

#[test]
fn checkpoints() {
    use ins_core::train::checkpoint::{Checkpoint, module_bytes};
    let device = Device::flex();
    let dir = tempfile::tempdir().unwrap();
    let cfg = ins_tests::small_config("c.png".into(), vec!["s.png".into()], 32);
    let model = cfg.build_model(&device);
    let store = CheckpointStore::new(dir.path(), 2);
    let ckpt_dir = store
        .save(&Checkpoint {
            step: 3,
            model: module_bytes(&model).unwrap(),
            optim: Vec::new(),
            state: serde_json::json!({"step": 3, "seed": 0, "history": []}),
            task: None,
        })
        .unwrap();
    let load = |_: &Path| -> Result<(), String> {
        let c = CheckpointStore::load_dir(&ckpt_dir).map_err(err)?;
        let at = ckpt_dir.join("model.bpk");
        load_module_bytes(cfg.build_model(&device), c.model, &at)
            .map(|_| ())
            .map_err(err)
    };
    for file in ["model.bpk", "state.json"] {
        run(
            &format!("checkpoint {file}"),
            &ckpt_dir.join(file),
            file,
            &load,
        );
    }
}

#[test]
fn optimizer_state() {
    // A real Adam state: two fitting steps of a small SIREN run, checkpointed.
    let device = Device::flex();
    let dir = tempfile::tempdir().unwrap();
    let content = ins_tests::save_image(dir.path(), "c.png", &ins_models::demo::demo_content(16));
    let style = ins_tests::save_image(dir.path(), "s.png", &ins_models::demo::demo_style(16));
    let cfg = ins_tests::small_config(content, vec![style], 16);
    let run_dir = dir.path().join("run");
    let mut o = ins_tests::quiet_options(&run_dir);
    o.checkpoint_every = 2;
    o.stop_after = Some(2);
    ins_tests::train_siren(&cfg, ins_tests::real_vgg(&device), &device, o).unwrap();
    let ckpt_dir = CheckpointStore::new(run_dir.join("checkpoints"), 2)
        .latest_dir()
        .unwrap()
        .expect("a checkpoint after two steps");
    let p = ckpt_dir.join("optim.bpk");
    run("checkpoint optim.bpk", &p, "optim.bpk", &|p| {
        let bytes = std::fs::read(p).map_err(err)?;
        ins_core::train::trainer::restore_adam(bytes, p)
            .map(|_| ())
            .map_err(err)
    });
}
