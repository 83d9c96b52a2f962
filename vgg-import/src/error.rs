//! Everything that can go wrong reading VGG weights, each naming the file.

use std::path::PathBuf;

/// A VGG import error.
#[derive(Debug, thiserror::Error)]
pub enum VggError {
    /// The file does not exist.
    #[error(
        "VGG weights not found at {path}. Run `ins-cli vgg fetch` to download the default VGG-16, or pass --onnx FILE"
    )]
    Missing {
        /// The path.
        path: PathBuf,
    },
    /// The file is not a readable ONNX model.
    #[error("{path} is not a readable ONNX model: {reason}")]
    NotOnnx {
        /// The path.
        path: PathBuf,
        /// What the parser said.
        reason: String,
    },
    /// Fewer than 10 convolutions.
    #[error(
        "{path} has {found} convolutions; a VGG-16 feature extractor needs the first 10 (up to relu4_3)"
    )]
    TooFewConvolutions {
        /// The path.
        path: PathBuf,
        /// How many were found.
        found: usize,
    },
    /// A convolution's weights have the wrong shape.
    #[error("{path}: convolution {index} ({name}) has {what} {found:?}, expected {expected:?}")]
    WrongShape {
        /// The path.
        path: PathBuf,
        /// 1-based convolution index in graph order.
        index: usize,
        /// ONNX node name.
        name: String,
        /// "weight shape", "bias shape", "kernel", ...
        what: String,
        /// What the file holds.
        found: Vec<usize>,
        /// What VGG-16 needs.
        expected: Vec<usize>,
    },
    /// A convolution's weights are not constant (not stored in the file).
    #[error("{path}: convolution {index} ({name}) has no constant {what}")]
    NoWeights {
        /// The path.
        path: PathBuf,
        /// 1-based convolution index.
        index: usize,
        /// ONNX node name.
        name: String,
        /// "weight" or "bias".
        what: String,
    },
    /// The graph is not laid out like VGG-16 (pools in the wrong places, ...).
    #[error("{path} is not a VGG-16 graph: {reason}")]
    NotVgg {
        /// The path.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The default weights could not be fetched.
    #[error("fetching the default VGG-16 weights failed: {0}")]
    Fetch(String),
    /// The converted-weights cache is unreadable (it is rebuilt on the next run).
    #[error("{path}: {reason}")]
    Cache {
        /// The cache file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// An I/O error on a named file.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
}
