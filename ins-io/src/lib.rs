//! Crash-safe file writes shared by every crate that persists something (checkpoints, run
//! configs, cached weights, pictures of a run).
//!
//! A write goes to a temporary name in the same folder, is flushed to disk (`fsync`), renamed
//! over the final name, and the folder itself is synced so the rename survives a power loss.
//! A process killed at any moment leaves either the old file or the new one, never half of one.

use std::fs::{self, File};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// An I/O failure with the path it concerns.
#[derive(Debug)]
pub struct IoError {
    /// The file or folder.
    pub path: PathBuf,
    /// What the OS said.
    pub source: io::Error,
}

impl std::fmt::Display for IoError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.source)
    }
}

impl std::error::Error for IoError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        Some(&self.source)
    }
}

fn at(path: &Path) -> impl FnOnce(io::Error) -> IoError + '_ {
    move |source| IoError {
        path: path.to_path_buf(),
        source,
    }
}

/// A temporary name beside `path`, unique to this process and call.
pub fn temp_path_beside(path: &Path) -> PathBuf {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("file");
    let dir = path.parent().unwrap_or(Path::new("."));
    dir.join(format!(".{name}.tmp-{}-{n}", std::process::id()))
}

/// Flushes a folder's entries (creations, renames) to disk. Folders cannot be opened for
/// syncing on every platform; there the call does nothing.
pub fn sync_dir(dir: &Path) -> Result<(), IoError> {
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    #[cfg(unix)]
    {
        File::open(dir)
            .and_then(|f| f.sync_all())
            .map_err(at(dir))?;
    }
    #[cfg(not(unix))]
    let _ = dir;
    Ok(())
}

/// Writes `bytes` to `path` and syncs it (not atomic by itself: for files inside a folder that
/// is itself renamed into place).
pub fn write_synced(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let mut f = File::create(path).map_err(at(path))?;
    f.write_all(bytes).map_err(at(path))?;
    f.sync_all().map_err(at(path))
}

/// Writes `bytes` to `path` atomically: temporary file, fsync, rename, fsync of the folder.
/// Creates the folder when missing.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    write_atomic_with(path, |tmp| write_synced(tmp, bytes))
}

/// Like [`write_atomic`], for writers that produce the file themselves (an image encoder, a
/// zip writer): `write` must create the file at the path it is given. The file is synced, then
/// renamed over `path`.
pub fn write_atomic_with<E>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), E>
where
    E: From<IoError>,
{
    let dir = path.parent().unwrap_or(Path::new("."));
    if !dir.as_os_str().is_empty() {
        fs::create_dir_all(dir).map_err(at(dir))?;
    }
    let tmp = temp_path_beside(path);
    let result = write(&tmp).and_then(|()| {
        File::open(&tmp)
            .and_then(|f| f.sync_all())
            .map_err(at(&tmp))?;
        fs::rename(&tmp, path).map_err(at(path))?;
        sync_dir(dir)?;
        Ok(())
    });
    if result.is_err() {
        fs::remove_file(&tmp).ok();
    }
    result
}

/// Renames a finished temporary folder into place and syncs the parent, so the folder appears
/// whole or not at all. `dest` must not exist.
pub fn publish_dir(tmp: &Path, dest: &Path) -> Result<(), IoError> {
    sync_dir(tmp)?;
    fs::rename(tmp, dest).map_err(at(dest))?;
    sync_dir(dest.parent().unwrap_or(Path::new(".")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_replaces_whole_files_and_leaves_no_temporaries() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("sub").join("a.txt");
        write_atomic(&p, b"first").unwrap();
        write_atomic(&p, b"second, longer").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"second, longer");
        let names: Vec<_> = fs::read_dir(p.parent().unwrap())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("a.txt")]);
    }

    #[test]
    fn a_failing_writer_leaves_the_old_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        write_atomic(&p, b"old").unwrap();
        let r: Result<(), IoError> = write_atomic_with(&p, |tmp| {
            fs::write(tmp, b"half").unwrap();
            Err(IoError {
                path: tmp.to_path_buf(),
                source: io::Error::other("disk full"),
            })
        });
        assert!(r.is_err());
        assert_eq!(fs::read(&p).unwrap(), b"old");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn published_folders_appear_whole() {
        let dir = tempfile::tempdir().unwrap();
        let tmp = dir.path().join(".x.tmp");
        fs::create_dir(&tmp).unwrap();
        write_synced(&tmp.join("f"), b"1").unwrap();
        let dest = dir.path().join("x");
        publish_dir(&tmp, &dest).unwrap();
        assert_eq!(fs::read(dest.join("f")).unwrap(), b"1");
        assert!(!tmp.exists());
    }
}
