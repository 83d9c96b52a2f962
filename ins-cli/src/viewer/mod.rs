//! The pictures `ins-cli view` serves.

pub mod source;
