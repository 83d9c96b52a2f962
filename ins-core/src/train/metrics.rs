//! The metrics log: one JSON object per line, appended as training goes.

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use super::error::TrainError;

/// Appends JSON lines to `metrics.jsonl`.
pub struct MetricsLog {
    path: PathBuf,
    out: BufWriter<File>,
}

impl MetricsLog {
    /// Starts the log at `path` afresh with the records of `history` (a resumed run's log
    /// mirrors its checkpoint, so no step appears twice).
    pub fn rewrite(path: &Path, history: &[serde_json::Value]) -> Result<Self, TrainError> {
        let mut text = String::new();
        for rec in history {
            text.push_str(&rec.to_string());
            text.push('\n');
        }
        ins_io::write_atomic(path, text.as_bytes())?;
        let f = OpenOptions::new()
            .append(true)
            .open(path)
            .map_err(|e| TrainError::io(path, e))?;
        Ok(Self {
            path: path.to_path_buf(),
            out: BufWriter::new(f),
        })
    }

    /// Writes one record and flushes, so that a killed run keeps what it logged.
    pub fn write(&mut self, record: &serde_json::Value) -> Result<(), TrainError> {
        writeln!(self.out, "{record}")
            .and_then(|()| self.out.flush())
            .map_err(|e| TrainError::io(&self.path, e))
    }
}
