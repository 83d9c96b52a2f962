//! The layout of a run folder, in one place: its configuration, checkpoints, metrics, loss
//! curve and held-out pictures, and the lock that keeps two runs out of one folder.
//!
//! ```text
//! RUN/
//!   config.json        the resolved configuration (paths absolute)
//!   checkpoints/       atomic checkpoints, `latest` names the newest complete one
//!   metrics.jsonl      one line per logged step
//!   loss_curve.png     the loss terms over the run
//!   val/               pictures of held-out views, per evaluation and at the end
//!                      (`final.png`), and the final views' scores (`final.json`)
//!   run.lock           held (flock) by the process training into the folder
//! ```

use std::fs::{self, File, OpenOptions, TryLockError};
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};

use super::checkpoint::CheckpointStore;
use super::error::TrainError;

/// Checkpoints kept in a run folder: the newest and the one before it.
const KEEP_CHECKPOINTS: usize = 2;

/// A run folder.
#[derive(Debug, Clone)]
pub struct RunFolder {
    dir: PathBuf,
}

/// The lock of a run folder, held while a process trains into it (released when dropped or
/// when the process ends, however it ends).
#[derive(Debug)]
pub struct RunLock {
    _file: File,
}

impl RunFolder {
    /// The folder `dir` (which need not exist yet).
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// `config.json`.
    pub fn config(&self) -> PathBuf {
        self.dir.join("config.json")
    }

    /// The checkpoints.
    pub fn checkpoints(&self) -> CheckpointStore {
        CheckpointStore::new(self.dir.join("checkpoints"), KEEP_CHECKPOINTS)
    }

    /// `metrics.jsonl`.
    pub fn metrics(&self) -> PathBuf {
        self.dir.join("metrics.jsonl")
    }

    /// `loss_curve.png`.
    pub fn loss_curve(&self) -> PathBuf {
        self.dir.join("loss_curve.png")
    }

    /// `scene.json`: how the run's scene was read and framed (format, frame, the map from the
    /// capture's world to the scene frame, bounds), so renders can be placed back in the
    /// capture's coordinates.
    pub fn scene_frame(&self) -> PathBuf {
        self.dir.join("scene.json")
    }

    /// `val/`: pictures of held-out views.
    pub fn val_dir(&self) -> PathBuf {
        self.dir.join("val")
    }

    /// `val/final.png`: the held-out views at the end of the run.
    pub fn final_picture(&self) -> PathBuf {
        self.val_dir().join("final.png")
    }

    /// `val/final.json`: the scores of those views.
    pub fn final_scores(&self) -> PathBuf {
        self.val_dir().join("final.json")
    }

    /// Takes the folder's lock (creating the folder), or refuses with the pid of the process
    /// that holds it: two runs writing one folder would interleave their checkpoints.
    pub fn lock(&self) -> Result<RunLock, TrainError> {
        fs::create_dir_all(&self.dir).map_err(|e| TrainError::io(&self.dir, e))?;
        let path = self.dir.join("run.lock");
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|e| TrainError::io(&path, e))?;
        match file.try_lock() {
            Ok(()) => {
                let pid = std::process::id().to_string();
                file.set_len(0)
                    .and_then(|_| file.rewind())
                    .and_then(|_| file.write_all(pid.as_bytes()))
                    .map_err(|e| TrainError::io(&path, e))?;
                Ok(RunLock { _file: file })
            }
            Err(TryLockError::WouldBlock) => {
                let mut pid = String::new();
                let _ = file.read_to_string(&mut pid);
                Err(TrainError::RunInUse {
                    dir: self.dir.clone(),
                    pid: pid.trim().to_string(),
                })
            }
            Err(TryLockError::Error(e)) => Err(TrainError::io(&path, e)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_is_refused_with_the_holders_pid_until_the_first_is_released() {
        let dir = tempfile::tempdir().unwrap();
        let folder = RunFolder::new(dir.path().join("run"));
        let first = folder.lock().unwrap();
        let e = folder.lock().unwrap_err().to_string();
        assert!(e.contains(&std::process::id().to_string()), "{e}");
        assert!(e.contains("in use"), "{e}");
        drop(first);
        let _again = folder.lock().unwrap();
    }
}
