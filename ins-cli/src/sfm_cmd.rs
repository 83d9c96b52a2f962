//! `ins-cli data sfm`: poses for a folder of plain photos, by COLMAP's structure from motion
//! (feature extraction, exhaustive matching, incremental mapping) through `pycolmap`, which is
//! installed into a virtual environment in the cache folder on first use, the way `vgg fetch`
//! uses pip. The result is a COLMAP workspace `train nerf --scene` reads.
//!
//! Why pycolmap and not a Rust SfM: COLMAP is the reference every capture tool uses; a
//! reimplementation would be slower and less robust, and pip ships it prebuilt for CPUs.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use anyhow::{Context, Result, bail};

/// The script run inside the environment.
const SCRIPT: &str = include_str!("sfm.py");
/// The pycolmap release the script is written against (its option names change between
/// majors).
pub const PYCOLMAP: &str = "pycolmap==4.2.1";

/// Options of `data sfm`.
#[derive(clap::Args, Debug)]
pub struct SfmArgs {
    /// Folder of photos (PNG or JPEG) of one scene.
    #[arg(long)]
    pub images: PathBuf,
    /// Workspace to write (`images/`, `sparse/0/`); created.
    #[arg(long)]
    pub out: PathBuf,
    /// COLMAP camera model shared by the photos (SIMPLE_RADIAL, OPENCV, PINHOLE, …).
    #[arg(long, default_value = "SIMPLE_RADIAL")]
    pub camera_model: String,
    /// Cache folder holding the Python environment (default: $INS_CACHE_DIR, else
    /// ~/.cache/ins-rs).
    #[arg(long)]
    pub cache: Option<PathBuf>,
}

/// Runs structure from motion and reports how many photos were registered.
pub fn run(args: SfmArgs) -> Result<()> {
    let s = structure_from_motion(
        &args.images,
        &args.out,
        &args.camera_model,
        args.cache.as_deref(),
    )?;
    println!(
        "registered {} of {} photos, {} points, mean reprojection error {:.2} px, in {:.0} s",
        s.registered, s.photos, s.summary["points"], s.reprojection_error, s.seconds
    );
    if let Some(cam) = s.summary["cameras"].get(0) {
        println!(
            "camera   {} {}×{} {}",
            cam["model"].as_str().unwrap_or("?"),
            cam["width"],
            cam["height"],
            cam["params"]
        );
    }
    if !s.unregistered.is_empty() {
        println!(
            "not registered (left out of the scene): {}",
            serde_json::to_string(&s.unregistered)?
        );
    }
    if s.registered * 2 < s.photos {
        eprintln!("warning: {FEW_REGISTERED}");
    }
    println!(
        "wrote {} (check it with `ins-cli data check {}`)",
        args.out.display(),
        args.out.display()
    );
    Ok(())
}

/// What to say when fewer than half the photos were registered.
pub const FEW_REGISTERED: &str = "fewer than half of the photos were registered; take photos \
     with more overlap (each spot seen from 3+ photos) and less motion blur";

/// What structure from motion made of a folder of photos.
pub struct Sfm {
    /// Photos in the folder.
    pub photos: usize,
    /// Photos it posed.
    pub registered: usize,
    /// Names of the photos it could not pose.
    pub unregistered: Vec<String>,
    /// Mean reprojection error in pixels.
    pub reprojection_error: f64,
    /// Seconds it took.
    pub seconds: f64,
    /// The script's whole summary (points, cameras).
    pub summary: serde_json::Value,
}

/// Poses the photos in `images` into the COLMAP workspace `out` (created), COLMAP's stages'
/// own messages on stderr. Refuses a folder with fewer than 3 photos and a workspace that
/// already holds a model.
pub fn structure_from_motion(
    images: &Path,
    out: &Path,
    camera_model: &str,
    cache: Option<&Path>,
) -> Result<Sfm> {
    if !images.is_dir() {
        bail!("{}: not a folder of photos", images.display());
    }
    let photos = ins_scene::data::images::list_images(images)?;
    if photos.len() < 3 {
        bail!(
            "{}: {} photos; structure from motion needs at least 3 overlapping ones (20–100 is typical)",
            images.display(),
            photos.len()
        );
    }
    if out.join("sparse/0").exists() {
        bail!(
            "{}: already holds a sparse model (sparse/0); choose another --out or remove it",
            out.display()
        );
    }
    let python = environment(&vgg_import::source::cache_dir(cache))?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let script = out.join(".ins-sfm.py");
    std::fs::write(&script, SCRIPT).with_context(|| format!("writing {}", script.display()))?;
    let t = Instant::now();
    let mut child = Command::new(&python)
        .arg(&script)
        .args(["--images".as_ref(), images.as_os_str()])
        .args(["--out".as_ref(), out.as_os_str()])
        .args(["--camera-model", camera_model])
        // COLMAP's own log is thousands of INFO lines; warnings and errors still show.
        .env("GLOG_minloglevel", "1")
        .stdout(Stdio::piped())
        .spawn()
        .with_context(|| format!("running {}", python.display()))?;
    let mut summary = None;
    if let Some(stdout) = child.stdout.take() {
        for line in BufReader::new(stdout).lines() {
            let line = line?;
            match line.strip_prefix("SUMMARY ") {
                Some(json) => summary = serde_json::from_str::<serde_json::Value>(json).ok(),
                None => eprintln!("{line}"),
            }
        }
    }
    let status = child.wait()?;
    let _ = std::fs::remove_file(&script);
    if !status.success() {
        bail!(
            "structure from motion on {} failed ({status}); see the messages above",
            images.display()
        );
    }
    let s = summary.context("the SfM script ended without its summary")?;
    Ok(Sfm {
        photos: s["photos"].as_u64().unwrap_or(0) as usize,
        registered: s["registered"].as_u64().unwrap_or(0) as usize,
        unregistered: s["unregistered"]
            .as_array()
            .map(|l| {
                l.iter()
                    .filter_map(|v| v.as_str().map(str::to_string))
                    .collect()
            })
            .unwrap_or_default(),
        reprojection_error: s["reprojection_error_px"].as_f64().unwrap_or(f64::NAN),
        seconds: t.elapsed().as_secs_f64(),
        summary: s,
    })
}

/// The environment's Python, creating the environment and installing pycolmap on first use.
fn environment(cache: &Path) -> Result<PathBuf> {
    let venv = cache.join("pycolmap-venv");
    let python = venv.join("bin/python");
    let ready = venv.join(".ins-ready");
    if ready.is_file() && python.is_file() {
        return Ok(python);
    }
    let system = std::env::var("PYTHON").unwrap_or_else(|_| "python3".into());
    eprintln!(
        "installing {PYCOLMAP} into {} (first use only; about 100 MB)",
        venv.display()
    );
    let ok = |c: &mut Command, what: &str| -> Result<()> {
        let st = c
            .status()
            .with_context(|| format!("{what}: could not start"))?;
        if !st.success() {
            bail!("{what} failed ({st})");
        }
        Ok(())
    };
    ok(
        Command::new(&system).args(["-m", "venv"]).arg(&venv),
        &format!(
            "`{system} -m venv {}` (install python3-venv)",
            venv.display()
        ),
    )?;
    ok(
        Command::new(&python).args([
            "-m",
            "pip",
            "install",
            "--disable-pip-version-check",
            "-q",
            PYCOLMAP,
        ]),
        &format!("`pip install {PYCOLMAP}` (needs network access to PyPI)"),
    )?;
    std::fs::write(&ready, PYCOLMAP).with_context(|| format!("writing {}", ready.display()))?;
    Ok(python)
}
