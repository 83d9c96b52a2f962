//! The metrics log: one JSON object per line, appended as training goes.

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::Path;

use anyhow::{Context, Result};

/// Appends JSON lines to `metrics.jsonl`.
pub struct MetricsLog {
    out: BufWriter<File>,
}

impl MetricsLog {
    /// Opens (appending) the log at `path`.
    pub fn open(path: &Path) -> Result<Self> {
        let f = OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .with_context(|| format!("opening {}", path.display()))?;
        Ok(Self {
            out: BufWriter::new(f),
        })
    }

    /// Writes one record and flushes, so that a killed run keeps what it logged.
    pub fn write(&mut self, record: &serde_json::Value) -> Result<()> {
        writeln!(self.out, "{record}")?;
        self.out.flush()?;
        Ok(())
    }
}
