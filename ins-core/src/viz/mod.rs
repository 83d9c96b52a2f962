//! Pictures for people: a tiny raster canvas with lines and text, and image grids.

pub mod canvas;
pub mod font;
