//! Evaluation that needs geometry: warping frames between cameras by known depth, and the view
//! consistency of a frame sequence built on it.

pub mod consistency;
pub mod warp;
