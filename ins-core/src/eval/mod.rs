//! Evaluation of stylized renders: warping frames between cameras by known depth and the view
//! consistency of a frame sequence built on it; how far stylization moved the surface; how far an image's texture is from a
//! painting's on the object (nearest-neighbour feature distance) and how much of the way to a
//! reference a stylization went.

pub mod consistency;
pub mod depth;
pub mod feature_match;
pub mod warp;
