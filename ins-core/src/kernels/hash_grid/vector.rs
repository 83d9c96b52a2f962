//! Which vector loops the hash grid runs on this CPU: [`avx512`]'s 16 points at a time, else
//! [`avx2`]'s 8, else none (`super::kernel`'s scalar loops take every point). Each returns how
//! many points it took; all give the scalar loops' bits.

use super::kernel::Layout;
use super::{avx2, avx512};

pub use super::avx512::columns;

/// Whether a vector loop runs for a grid of `features` a level.
pub fn usable(features: usize) -> bool {
    avx512::usable(features) || avx2::usable(features)
}

/// See [`avx512::encode_level`].
pub fn encode_level(
    layout: &Layout,
    l: usize,
    table: &[f32],
    columns: &[f32],
    dst: &mut [f32],
) -> usize {
    let f = layout.features;
    if avx512::usable(f) {
        avx512::encode_level(layout, l, table, columns, dst)
    } else if avx2::usable(f) {
        avx2::encode_level(layout, l, table, columns, dst)
    } else {
        0
    }
}

/// See [`avx512::scatter_level`].
pub fn scatter_level(
    layout: &Layout,
    l: usize,
    columns: &[f32],
    grad_level: &[f32],
    grad: &mut [f32],
) -> usize {
    let f = layout.features;
    if avx512::usable(f) {
        avx512::scatter_level(layout, l, columns, grad_level, grad)
    } else if avx2::usable(f) {
        avx2::scatter_level(layout, l, columns, grad_level, grad)
    } else {
        0
    }
}

/// See [`avx512::jacobian_points`].
pub fn jacobian_points(layout: &Layout, table: &[f32], columns: &[f32], jac: &mut [f32]) -> usize {
    let f = layout.features;
    if avx512::usable(f) {
        avx512::jacobian_points(layout, table, columns, jac)
    } else if avx2::usable(f) {
        avx2::jacobian_points(layout, table, columns, jac)
    } else {
        0
    }
}

/// See [`avx512::jacobian_scatter_level`].
pub fn jacobian_scatter_level(
    layout: &Layout,
    l: usize,
    columns: &[f32],
    grad_jac: &[f32],
    grad: &mut [f32],
) -> usize {
    let f = layout.features;
    if avx512::usable(f) {
        avx512::jacobian_scatter_level(layout, l, columns, grad_jac, grad)
    } else if avx2::usable(f) {
        avx2::jacobian_scatter_level(layout, l, columns, grad_jac, grad)
    } else {
        0
    }
}

#[cfg(test)]
mod tests;
