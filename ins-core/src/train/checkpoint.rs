//! Atomic checkpoints: a run killed at any moment resumes from the last complete one.
//!
//! A checkpoint is a folder `step-SSSSSSSS-KKK/` (model record, optimizer state, trainer state,
//! the task's own state) written under a temporary name, every file synced, then renamed into
//! place and the parent synced. Only then is the `latest` file that names it replaced (itself
//! written atomically), and only then are older folders pruned. Folder names are never reused,
//! so `latest` always names a complete folder.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::Duration;

use burn::module::Module;
use burn::store::ModuleRecord;
use burn::tensor::Bytes;

use super::error::TrainError;

/// What a checkpoint holds.
pub struct Checkpoint {
    /// Steps completed.
    pub step: usize,
    /// The model's burnpack record.
    pub model: Vec<u8>,
    /// The optimizer state.
    pub optim: Vec<u8>,
    /// Trainer state (step, seed, metrics history).
    pub state: serde_json::Value,
    /// The task's own state (e.g. an occupancy grid), if it has one.
    pub task: Option<Vec<u8>>,
}

/// The checkpoint folder of a run.
#[derive(Debug, Clone)]
pub struct CheckpointStore {
    dir: PathBuf,
    keep: usize,
}

/// Serializes a module's parameters.
pub fn module_bytes<M: Module>(model: &M) -> Result<Vec<u8>, TrainError> {
    let bytes = model
        .clone()
        .into_record()
        .into_bytes()
        .map_err(|e| TrainError::checkpoint("model", format!("serializing the model: {e}")))?;
    Ok(bytes.to_vec())
}

/// Loads parameters written by [`module_bytes`] into `model` (same architecture), naming
/// `origin` in the error.
pub fn load_module_bytes<M: Module>(
    model: M,
    bytes: Vec<u8>,
    origin: &Path,
) -> Result<M, TrainError> {
    let record = crate::contain::contain(|| ModuleRecord::from_bytes(Bytes::from_bytes_vec(bytes)))
        .map_err(|e| TrainError::checkpoint(origin, format!("damaged model record: {e}")))?
        .map_err(|e| TrainError::checkpoint(origin, format!("not a model record: {e}")))?;
    crate::contain::contain(|| model.try_load_record(record))
        .map_err(|e| TrainError::checkpoint(origin, format!("damaged model record: {e}")))?
        .map_err(|e| {
            TrainError::checkpoint(
                origin,
                format!("the saved model does not fit this configuration: {e}"),
            )
        })
}

const MODEL: &str = "model.bpk";
const OPTIM: &str = "optim.bpk";
const STATE: &str = "state.json";
const TASK: &str = "task.bin";

/// Test and debugging aid: `INS_FAULT_CHECKPOINT_DELAY_MS` pauses each checkpoint write
/// halfway (after the model file, before the folder is published), so a test can kill the
/// process while a checkpoint is being written.
fn fault_delay() {
    if let Some(ms) = std::env::var("INS_FAULT_CHECKPOINT_DELAY_MS")
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
    {
        std::thread::sleep(Duration::from_millis(ms));
    }
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

    fn latest_file(&self) -> PathBuf {
        self.dir.join("latest")
    }

    /// Names of complete checkpoint folders, oldest first.
    fn complete(&self) -> Vec<String> {
        let Ok(entries) = fs::read_dir(&self.dir) else {
            return Vec::new();
        };
        let mut names: Vec<String> = entries
            .filter_map(|e| e.ok())
            .filter_map(|e| e.file_name().into_string().ok())
            .filter(|n| n.starts_with("step-"))
            .collect();
        names.sort();
        names
    }

    /// The model record inside the checkpoint folder `dir` (for messages naming it).
    pub fn model_file(dir: &Path) -> PathBuf {
        dir.join(MODEL)
    }

    /// The task's state inside the checkpoint folder `dir`.
    pub fn task_file(dir: &Path) -> PathBuf {
        dir.join(TASK)
    }

    /// Writes a checkpoint atomically, points `latest` at it, then prunes old ones. A write that
    /// fails (a full disk, a file-size limit) removes what it had written and leaves the
    /// previous checkpoint, and `latest`, as they were.
    pub fn save(&self, ckpt: &Checkpoint) -> Result<PathBuf, TrainError> {
        fs::create_dir_all(&self.dir).map_err(|e| TrainError::io(&self.dir, e))?;
        let existing = self.complete();
        let prefix = format!("step-{:08}-", ckpt.step);
        let k = (0..)
            .find(|k| !existing.contains(&format!("{prefix}{k:03}")))
            .unwrap_or(0);
        let name = format!("{prefix}{k:03}");
        let final_dir = self.dir.join(&name);
        let tmp = ins_io::temp_path_beside(&final_dir);
        let written = self.write_folder(ckpt, &tmp).and_then(|()| {
            ins_io::publish_dir(&tmp, &final_dir)?;
            ins_io::write_atomic(&self.latest_file(), name.as_bytes())
        });
        if let Err(source) = written {
            fs::remove_dir_all(&tmp).ok();
            return Err(TrainError::CheckpointWrite {
                step: ckpt.step,
                source,
                last_good: self.latest_path(),
            });
        }
        self.prune(&name);
        Ok(final_dir)
    }

    /// The checkpoint's files, synced, in the folder `tmp`.
    fn write_folder(&self, ckpt: &Checkpoint, tmp: &Path) -> Result<(), ins_io::IoError> {
        fs::create_dir_all(tmp).map_err(|source| ins_io::IoError {
            path: tmp.to_path_buf(),
            source,
        })?;
        ins_io::write_synced(&tmp.join(MODEL), &ckpt.model)?;
        fault_delay();
        ins_io::write_synced(&tmp.join(OPTIM), &ckpt.optim)?;
        let state = serde_json::to_vec_pretty(&ckpt.state).map_err(|e| ins_io::IoError {
            path: tmp.join(STATE),
            source: std::io::Error::other(e),
        })?;
        ins_io::write_synced(&tmp.join(STATE), &state)?;
        if let Some(task) = &ckpt.task {
            ins_io::write_synced(&tmp.join(TASK), task)?;
        }
        Ok(())
    }

    /// Removes all but the newest `keep` complete checkpoints (never the one `latest` names)
    /// and the leftovers of writers that were killed.
    fn prune(&self, newest: &str) {
        let complete = self.complete();
        let cut = complete.len().saturating_sub(self.keep);
        for n in complete.iter().take(cut) {
            if n != newest {
                fs::remove_dir_all(self.dir.join(n)).ok();
            }
        }
        if let Ok(entries) = fs::read_dir(&self.dir) {
            for e in entries.filter_map(|e| e.ok()) {
                let n = e.file_name().to_string_lossy().to_string();
                if n.starts_with(".step-") || n.starts_with(".latest.tmp") {
                    let p = e.path();
                    if p.is_dir() {
                        fs::remove_dir_all(&p).ok();
                    } else {
                        fs::remove_file(&p).ok();
                    }
                }
            }
        }
    }

    /// The folder `latest` names, if any.
    pub fn latest_dir(&self) -> Result<Option<PathBuf>, TrainError> {
        let latest = self.latest_file();
        if !latest.exists() {
            return Ok(None);
        }
        let name = read_limited(&latest, 256)?;
        let name = String::from_utf8(name)
            .map_err(|_| TrainError::checkpoint(&latest, "not a checkpoint name"))?;
        let name = name.trim();
        if !name.starts_with("step-") || name.contains(['/', '\\']) {
            return Err(TrainError::checkpoint(
                &latest,
                format!("names {name:?}, which is not a checkpoint folder"),
            ));
        }
        let dir = self.dir.join(name);
        if !dir.is_dir() {
            return Err(TrainError::checkpoint(
                &latest,
                format!("names {}, which does not exist", dir.display()),
            ));
        }
        Ok(Some(dir))
    }

    /// The newest complete checkpoint, if any.
    pub fn load_latest(&self) -> Result<Option<Checkpoint>, TrainError> {
        let Some(dir) = self.latest_dir()? else {
            return Ok(None);
        };
        Self::load_dir(&dir).map(Some)
    }

    /// Reads the checkpoint in folder `dir`.
    pub fn load_dir(dir: &Path) -> Result<Checkpoint, TrainError> {
        let read = |name: &str| -> Result<Vec<u8>, TrainError> {
            let p = dir.join(name);
            fs::read(&p).map_err(|e| TrainError::io(&p, e))
        };
        let model = read(MODEL)?;
        let optim = read(OPTIM)?;
        let state_path = dir.join(STATE);
        let state: serde_json::Value = serde_json::from_slice(&read(STATE)?).map_err(|e| {
            TrainError::checkpoint(&state_path, format!("malformed trainer state: {e}"))
        })?;
        let step = state
            .get("step")
            .and_then(|s| s.as_u64())
            .ok_or_else(|| TrainError::checkpoint(&state_path, "no step"))?
            as usize;
        let task_path = dir.join(TASK);
        let task = if task_path.exists() {
            Some(read(TASK)?)
        } else {
            None
        };
        Ok(Checkpoint {
            step,
            model,
            optim,
            state,
            task,
        })
    }

    /// Whether a checkpoint was ever published here (a run folder that holds a run).
    pub fn is_started(&self) -> bool {
        self.latest_file().exists()
    }

    /// Path of the newest checkpoint's folder, for messages; `None` when there is none.
    pub fn latest_path(&self) -> Option<PathBuf> {
        self.latest_dir().ok().flatten()
    }
}

/// Reads at most `cap` bytes of a small file (a lying or huge file is an error, not an
/// allocation).
fn read_limited(path: &Path, cap: u64) -> Result<Vec<u8>, TrainError> {
    use std::io::Read;
    let f = fs::File::open(path).map_err(|e| TrainError::io(path, e))?;
    let mut buf = Vec::new();
    f.take(cap + 1)
        .read_to_end(&mut buf)
        .map_err(|e| TrainError::io(path, e))?;
    if buf.len() as u64 > cap {
        return Err(TrainError::checkpoint(
            path,
            "too large for a checkpoint name",
        ));
    }
    Ok(buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ckpt(step: usize) -> Checkpoint {
        Checkpoint {
            step,
            model: vec![1, 2, 3],
            optim: vec![4],
            state: serde_json::json!({ "step": step }),
            task: Some(vec![9]),
        }
    }

    #[test]
    fn saving_the_same_step_twice_never_leaves_latest_dangling() {
        let dir = tempfile::tempdir().unwrap();
        let store = CheckpointStore::new(dir.path(), 2);
        let a = store.save(&ckpt(5)).unwrap();
        let b = store.save(&ckpt(5)).unwrap();
        assert_ne!(a, b);
        assert_eq!(store.latest_dir().unwrap().unwrap(), b);
        let c = store.load_latest().unwrap().unwrap();
        assert_eq!((c.step, c.task), (5, Some(vec![9])));
    }

    #[test]
    fn pruning_keeps_the_newest_and_removes_leftovers() {
        let dir = tempfile::tempdir().unwrap();
        let store = CheckpointStore::new(dir.path(), 2);
        fs::create_dir_all(dir.path().join(".step-00000001-000.tmp-1-0")).unwrap();
        for s in [1, 2, 3, 4] {
            store.save(&ckpt(s)).unwrap();
        }
        let mut names: Vec<String> = fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        names.sort();
        assert_eq!(names, ["latest", "step-00000003-000", "step-00000004-000"]);
    }

    #[test]
    fn a_latest_file_naming_garbage_is_an_error_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let store = CheckpointStore::new(dir.path(), 2);
        fs::write(dir.path().join("latest"), "../../etc").unwrap();
        let e = store.load_latest().err().unwrap().to_string();
        assert!(
            e.contains("latest") && e.contains("not a checkpoint folder"),
            "{e}"
        );
    }
}
