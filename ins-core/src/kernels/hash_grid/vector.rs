//! Which vector loops the hash grid runs on this CPU: [`avx512`]'s 16 points at a time, else
//! [`avx2`]'s 8, else none (`super::kernel`'s scalar loops take every point). Each loop returns
//! how many points it took; all give the scalar loops' bits.

use super::kernel::Layout;
use super::{avx2, avx512};

pub use super::avx512::columns;

/// A loop over one level's points: the layout, the level, two slices in, the slice it writes.
pub type LevelLoop = fn(&Layout, usize, &[f32], &[f32], &mut [f32]) -> usize;

/// One instruction set's loops (see [`avx512`] for what each does).
pub struct Loops {
    /// The instruction set.
    pub name: &'static str,
    /// Points a call handles together.
    pub lanes: usize,
    /// Whether the CPU runs them for a grid of this many features a level.
    pub usable: fn(usize) -> bool,
    /// A level's lookup.
    pub encode_level: LevelLoop,
    /// A level's table gradient.
    pub scatter_level: LevelLoop,
    /// The spatial Jacobian's rows.
    pub jacobian_points: fn(&Layout, &[f32], &[f32], &mut [f32]) -> usize,
    /// A level's table gradient of the Jacobian.
    pub jacobian_scatter_level: LevelLoop,
}

/// Every vector path, widest first.
pub static PATHS: [Loops; 2] = [
    Loops {
        name: "AVX-512",
        lanes: avx512::LANES,
        usable: avx512::usable,
        encode_level: avx512::encode_level,
        scatter_level: avx512::scatter_level,
        jacobian_points: avx512::jacobian_points,
        jacobian_scatter_level: avx512::jacobian_scatter_level,
    },
    Loops {
        name: "AVX2",
        lanes: avx2::LANES,
        usable: avx2::usable,
        encode_level: avx2::encode_level,
        scatter_level: avx2::scatter_level,
        jacobian_points: avx2::jacobian_points,
        jacobian_scatter_level: avx2::jacobian_scatter_level,
    },
];

/// The widest loops this CPU runs for a grid of `features` a level, if any.
pub fn loops(features: usize) -> Option<&'static Loops> {
    PATHS.iter().find(|p| (p.usable)(features))
}

#[cfg(test)]
mod tests;
