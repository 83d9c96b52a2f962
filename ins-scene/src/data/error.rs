//! Errors of the data layer. Every variant about a file names it, so a user with a broken
//! dataset learns which file to look at.

use std::path::{Path, PathBuf};

/// What went wrong while reading or writing a scene.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// A file or folder the format needs is not there.
    #[error("{}: missing: {what}", path.display())]
    Missing {
        /// The path that was looked for.
        path: PathBuf,
        /// What it should have held.
        what: String,
    },
    /// Reading or writing failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// JSON that does not parse or lacks a field.
    #[error("{}: malformed JSON: {msg}", path.display())]
    Json {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// An NPY or NPZ file that does not parse or holds the wrong shape or type.
    #[error("{}: malformed NPY/NPZ: {msg}", path.display())]
    Npy {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// An image that cannot be decoded or encoded.
    #[error("{}: cannot decode or encode image: {msg}", path.display())]
    Image {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// Files that parse but do not agree: counts that differ, mixed image sizes, a mask
    /// without its image, a degenerate camera.
    #[error("{}: {msg}", path.display())]
    Invalid {
        /// The file (or folder) at fault.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// A folder that is none of the known formats.
    #[error("{}: not a scene folder: {msg}", path.display())]
    UnknownFormat {
        /// The folder.
        path: PathBuf,
        /// What was found instead.
        msg: String,
    },
    /// A request the scene cannot satisfy (a view or pixel out of range, an empty split).
    #[error("{0}")]
    Request(String),
}

impl DataError {
    pub(crate) fn missing(path: &Path, what: impl Into<String>) -> Self {
        DataError::Missing {
            path: path.to_path_buf(),
            what: what.into(),
        }
    }

    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        if source.kind() == std::io::ErrorKind::NotFound {
            return DataError::missing(path, "file not found");
        }
        DataError::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    pub(crate) fn json(path: &Path, msg: impl Into<String>) -> Self {
        DataError::Json {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }

    pub(crate) fn npy(path: &Path, msg: impl Into<String>) -> Self {
        DataError::Npy {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }

    pub(crate) fn image(path: &Path, msg: impl Into<String>) -> Self {
        DataError::Image {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }

    pub(crate) fn invalid(path: &Path, msg: impl Into<String>) -> Self {
        DataError::Invalid {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }
}
