//! What `ins-cli stylize` checks before any stage: what the photos folder holds, the files a
//! scene folder's fingerprint reads, and the free disk space a run needs.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use ins_scene::data::SceneFormat;
use ins_scene::data::images::list_images;

/// Fewest photos worth posing and training on: below this structure from motion rarely
/// registers enough of them, and a held-out view or two leaves too few to learn from.
pub const MIN_PHOTOS: usize = 8;

/// Free disk space a run needs: two runs' checkpoints (tens of MB each), the posed photos'
/// copies and the frames of the video and report, with room to spare.
pub const MIN_FREE_BYTES: u64 = 1 << 30;

/// What the photos folder holds.
pub enum Photos {
    /// Plain photos, to pose.
    Plain(Vec<PathBuf>),
    /// A scene folder of a known format.
    Scene(SceneFormat),
}

/// What `dir` holds: a scene folder of a known format, or plain photos (at least
/// [`MIN_PHOTOS`]); anything else is an error saying what was expected.
pub fn what_photos(dir: &Path) -> Result<Photos> {
    if !dir.is_dir() {
        bail!("--photos {}: not a folder", dir.display());
    }
    if let Ok(format) = ins_scene::data::detect_format(dir) {
        return Ok(Photos::Scene(format));
    }
    let files = list_images(dir)?;
    if files.len() < MIN_PHOTOS {
        bail!(
            "--photos {}: {} photos; a scene needs at least {MIN_PHOTOS} overlapping ones \
             (30–100 is typical, each spot seen from several), or a scene folder (COLMAP \
             workspace, transforms.json, Blender, LLFF, DTU)",
            dir.display(),
            files.len()
        );
    }
    Ok(Photos::Plain(files))
}

/// Every file under a scene folder, in a fixed order (what its fingerprint reads), but those of
/// the output folder `out` where it lies inside the scene's.
pub fn scene_files(dir: &Path, out: &Path) -> Result<Vec<PathBuf>> {
    let out = std::path::absolute(out).unwrap_or_else(|_| out.to_path_buf());
    let mut files = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).with_context(|| format!("reading {}", d.display()))? {
            let p = e?.path();
            if std::path::absolute(&p).is_ok_and(|p| p.starts_with(&out)) {
                continue;
            }
            if p.is_dir() {
                stack.push(p);
            } else {
                files.push(p);
            }
        }
    }
    files.sort();
    Ok(files)
}

/// Refuses to start when the output's disk has less than [`MIN_FREE_BYTES`] free.
pub fn check_free_space(out: &Path) -> Result<()> {
    let mut probe = out.to_path_buf();
    while !probe.exists() {
        match probe.parent() {
            Some(p) if !p.as_os_str().is_empty() => probe = p.to_path_buf(),
            _ => {
                probe = PathBuf::from(".");
                break;
            }
        }
    }
    let c = std::ffi::CString::new(probe.as_os_str().as_encoded_bytes())?;
    let mut s: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `c` is a NUL-terminated path and `s` a writable statvfs.
    if unsafe { libc::statvfs(c.as_ptr(), &mut s) } != 0 {
        return Ok(()); // a filesystem that cannot say: the writes will tell
    }
    let free = s.f_bavail as u64 * s.f_frsize as u64;
    if free < MIN_FREE_BYTES {
        bail!(
            "{}: only {:.0} MB free on its disk; a run needs about {:.0} MB (checkpoints, the \
             posed photos, frames): free some space or choose another --out",
            out.display(),
            free as f64 / 1e6,
            MIN_FREE_BYTES as f64 / 1e6
        );
    }
    Ok(())
}
