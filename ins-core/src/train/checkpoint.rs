//! Atomic checkpoints: a run killed at any moment resumes from the last complete one.
//!
//! Each checkpoint is a directory `step-NNNNNNNN/` (model record, one optimizer state per
//! group, trainer state as JSON) written under a temporary name, synced, then renamed into
//! place; the `latest` file that names it is replaced the same way. A half-written checkpoint
//! is never named by `latest`, so it is never read.

use std::collections::BTreeMap;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::module::Module;
use burn::store::ModuleRecord;
use burn::tensor::Bytes;

/// What a checkpoint holds.
pub struct Checkpoint {
    /// Steps completed.
    pub step: usize,
    /// The model's burnpack record.
    pub model: Vec<u8>,
    /// Optimizer state per group.
    pub optim: BTreeMap<String, Vec<u8>>,
    /// Trainer state (loss history for the plot, run id, ...).
    pub state: serde_json::Value,
}

/// The checkpoint folder of a run.
#[derive(Debug, Clone)]
pub struct CheckpointStore {
    dir: PathBuf,
    keep: usize,
}

/// Serializes a module's parameters.
pub fn module_bytes<M: Module>(model: &M) -> Result<Vec<u8>> {
    let bytes = model
        .clone()
        .into_record()
        .into_bytes()
        .map_err(|e| anyhow::anyhow!("serializing the model: {e}"))?;
    Ok(bytes.to_vec())
}

/// Loads parameters written by [`module_bytes`] into `model` (same architecture), naming
/// `origin` in the error.
pub fn load_module_bytes<M: Module>(model: M, bytes: Vec<u8>, origin: &Path) -> Result<M> {
    let record = ModuleRecord::from_bytes(Bytes::from_bytes_vec(bytes))
        .map_err(|e| anyhow::anyhow!("{}: not a model record: {e}", origin.display()))?;
    model.try_load_record(record).map_err(|e| {
        anyhow::anyhow!(
            "{}: the saved model does not fit this configuration: {e}",
            origin.display()
        )
    })
}

/// Writes `bytes` to `path` atomically (temporary file, fsync, rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let tmp = dir.join(format!(
        ".{}.tmp-{}",
        path.file_name().and_then(|n| n.to_str()).unwrap_or("file"),
        std::process::id()
    ));
    {
        let mut f = fs::File::create(&tmp).with_context(|| format!("writing {}", tmp.display()))?;
        f.write_all(bytes)
            .with_context(|| format!("writing {}", tmp.display()))?;
        f.sync_all().ok();
    }
    fs::rename(&tmp, path).with_context(|| format!("renaming into {}", path.display()))?;
    Ok(())
}

impl CheckpointStore {
    /// Checkpoints under `dir`, keeping the newest `keep` (at least 1).
    pub fn new(dir: impl Into<PathBuf>, keep: usize) -> Self {
        Self {
            dir: dir.into(),
            keep: keep.max(1),
        }
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Writes a checkpoint atomically and prunes old ones.
    pub fn save(&self, ckpt: &Checkpoint) -> Result<PathBuf> {
        let name = format!("step-{:08}", ckpt.step);
        let final_dir = self.dir.join(&name);
        let tmp_dir = self.dir.join(format!(".{name}.tmp-{}", std::process::id()));
        if tmp_dir.exists() {
            fs::remove_dir_all(&tmp_dir).ok();
        }
        fs::create_dir_all(&tmp_dir).with_context(|| format!("creating {}", tmp_dir.display()))?;
        write_file(&tmp_dir.join("model.bpk"), &ckpt.model)?;
        for (group, bytes) in &ckpt.optim {
            write_file(&tmp_dir.join(format!("optim-{group}.bpk")), bytes)?;
        }
        write_file(
            &tmp_dir.join("state.json"),
            serde_json::to_string_pretty(&ckpt.state)?.as_bytes(),
        )?;
        if final_dir.exists() {
            fs::remove_dir_all(&final_dir).ok();
        }
        fs::rename(&tmp_dir, &final_dir)
            .with_context(|| format!("renaming into {}", final_dir.display()))?;
        write_atomic(&self.dir.join("latest"), name.as_bytes())?;
        self.prune(&name);
        Ok(final_dir)
    }

    fn prune(&self, newest: &str) {
        let Ok(entries) = fs::read_dir(&self.dir) else {
            return;
        };
        let mut names: Vec<String> = entries
            .filter_map(|e| e.ok())
            .filter_map(|e| e.file_name().into_string().ok())
            .filter(|n| n.starts_with("step-") || n.starts_with(".step-"))
            .collect();
        names.sort();
        let complete: Vec<&String> = names.iter().filter(|n| n.starts_with("step-")).collect();
        let cut = complete.len().saturating_sub(self.keep);
        for n in complete.iter().take(cut) {
            if n.as_str() != newest {
                fs::remove_dir_all(self.dir.join(n)).ok();
            }
        }
        // Leftovers of a killed writer.
        for n in names.iter().filter(|n| n.starts_with(".step-")) {
            fs::remove_dir_all(self.dir.join(n)).ok();
        }
    }

    /// The newest complete checkpoint, if any.
    pub fn load_latest(&self) -> Result<Option<Checkpoint>> {
        let latest = self.dir.join("latest");
        if !latest.exists() {
            return Ok(None);
        }
        let name =
            fs::read_to_string(&latest).with_context(|| format!("reading {}", latest.display()))?;
        let dir = self.dir.join(name.trim());
        if !dir.is_dir() {
            bail!(
                "{} names {}, which does not exist",
                latest.display(),
                dir.display()
            );
        }
        let model = read_file(&dir.join("model.bpk"))?;
        let mut optim = BTreeMap::new();
        for entry in fs::read_dir(&dir).with_context(|| format!("reading {}", dir.display()))? {
            let entry = entry?;
            let fname = entry.file_name().to_string_lossy().to_string();
            if let Some(group) = fname
                .strip_prefix("optim-")
                .and_then(|g| g.strip_suffix(".bpk"))
            {
                optim.insert(group.to_string(), read_file(&entry.path())?);
            }
        }
        let state_path = dir.join("state.json");
        let state: serde_json::Value = serde_json::from_slice(&read_file(&state_path)?)
            .with_context(|| format!("{}: malformed trainer state", state_path.display()))?;
        let step = state
            .get("step")
            .and_then(|s| s.as_u64())
            .with_context(|| format!("{}: no step", state_path.display()))?
            as usize;
        Ok(Some(Checkpoint {
            step,
            model,
            optim,
            state,
        }))
    }

    /// Path of the newest checkpoint's model record, if any.
    pub fn latest_model_path(&self) -> Option<PathBuf> {
        let name = fs::read_to_string(self.dir.join("latest")).ok()?;
        let p = self.dir.join(name.trim()).join("model.bpk");
        p.exists().then_some(p)
    }
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut f = fs::File::create(path).with_context(|| format!("writing {}", path.display()))?;
    f.write_all(bytes)
        .with_context(|| format!("writing {}", path.display()))?;
    f.sync_all().ok();
    Ok(())
}

fn read_file(path: &Path) -> Result<Vec<u8>> {
    fs::read(path).with_context(|| format!("reading {}", path.display()))
}
