//! The merge as a CubeCL kernel, one unit a ray: at each place the smaller of the two sets'
//! next values, `a`'s on a tie (so equal values keep their columns' order, as a stable sort of
//! the joined row `[a, b]` does), and its column in that joined row.

use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use crate::kernels::cube_launch::{assert_f32, empty_like, grid};

/// Ray `r`'s merged row (`out[0, r, ..]`) and each place's column in `[a, b]`
/// (`out[1, r, ..]`, as f32: exact below 2²⁴ columns).
#[cube(launch)]
fn merge_kernel(
    a: &[f32],
    b: &[f32],
    out: &mut [f32],
    #[comptime] width_a: usize,
    #[comptime] width_b: usize,
) {
    let rays = a.len() / width_a;
    if ABSOLUTE_POS >= rays {
        terminate!();
    }
    let r = ABSOLUTE_POS;
    let width = width_a + width_b;
    let (row, plane) = (r * width, rays * width);
    let mut i = 0usize;
    let mut j = 0usize;
    for c in 0..width {
        let mut from_a = false;
        if i < width_a {
            from_a = true;
            if j < width_b {
                from_a = a[r * width_a + i] <= b[r * width_b + j];
            }
        }
        if from_a {
            out[row + c] = a[r * width_a + i];
            out[plane + row + c] = f32::cast_from(i);
            i += 1;
        } else {
            out[row + c] = b[r * width_b + j];
            out[plane + row + c] = f32::cast_from(width_a + j);
            j += 1;
        }
    }
}

/// `[2, R, Ka + Kb]`: the rows of `a [R, Ka]` and `b [R, Kb]` (each sorted ascending) merged,
/// and each place's column in `[a, b]`. Needs `Ka, Kb ≥ 1`.
pub fn merge(a: CubeTensor, b: CubeTensor) -> CubeTensor {
    let [rays, width_a] = [a.meta.shape()[0], a.meta.shape()[1]];
    let width_b = b.meta.shape()[1];
    assert!(
        width_a > 0 && width_b > 0,
        "merging rows needs two non-empty sets"
    );
    assert_f32("merging rows", &[(&a, "first set"), (&b, "second set")]);
    let out = empty_like(&a, [2, rays, width_a + width_b]);
    if rays == 0 {
        return out;
    }
    let (count, dim) = grid(&a, rays);
    merge_kernel::launch(
        &a.client.clone(),
        count,
        dim,
        into_contiguous(a).into_buffer_arg(),
        into_contiguous(b).into_buffer_arg(),
        out.clone().into_buffer_arg(),
        width_a,
        width_b,
    );
    out
}
