//! NNFM's match on the CPU, a few positions at a time: for each position of a render, the
//! painting feature with the largest cosine to it, among those within a radius of the photo's
//! best cosine at the same position (a guided match; every feature when unguided).
//!
//! Why by hand: as tensor ops the guided match builds `[N, M]` matrices (N positions, M painting
//! features; 4096 × 7396 at relu1_2 of a 64² patch, 121 MB each): both similarity matrices, the
//! photo's allowed set, their sum, each written and read again by the next op. Here a block of
//! 32 positions takes both similarity rows (two products by `gemm`) while they sit in the cache
//! and keeps only the winner's index. With `bf16` the products round their operands to bf16
//! (`VDPBF16PS`, twice the multiply-adds of f32's FMA; the features come out of bf16
//! convolutions already): matches whose cosines tie within that rounding may pick another of
//! the tied features.

use rayon::prelude::*;

use crate::kernels::dense_bf16::columns as bf16_columns;
use crate::kernels::flex::product_on;

/// Positions per block: two `[32, M]` similarity blocks stay within a core's cache for
/// paintings of up to ~4000 positions and spill gracefully above.
const BLOCK: usize = 32;

/// Unit feature columns on the host: `values` row-major `[channels, positions]`.
#[derive(Clone, Copy, Debug)]
pub struct Columns<'a> {
    /// The values, channel by channel.
    pub values: &'a [f32],
    /// Channels (rows).
    pub channels: usize,
    /// Positions (columns).
    pub positions: usize,
}

impl<'a> Columns<'a> {
    /// `values` as `channels × positions`.
    pub fn new(values: &'a [f32], channels: usize, positions: usize) -> Self {
        Self {
            values,
            channels,
            positions,
        }
    }

    fn check(&self, what: &str) {
        assert_eq!(
            self.values.len(),
            self.channels * self.positions,
            "{what}: {} values for {}×{}",
            self.values.len(),
            self.channels,
            self.positions
        );
    }
}

/// For each position of `render`, the index of its match among the `painting`'s columns: the
/// largest cosine to the render's feature among the painting features whose cosine to the
/// `photo`'s feature at that position is within `radius` of the photo's best (all of them when
/// `photo` is `None`). The first of equal ones wins, as `argmax` picks. `bf16`: the cosines
/// from bf16 operands (see the module), where [`bf16_columns`] can run.
pub fn guided_nearest(
    render: Columns,
    photo: Option<(Columns, f32)>,
    painting: Columns,
    bf16: bool,
) -> Vec<u32> {
    render.check("render");
    painting.check("painting");
    let (c, n, m) = (render.channels, render.positions, painting.positions);
    assert_eq!(painting.channels, c, "painting channels");
    if let Some((p, _)) = &photo {
        p.check("photo");
        assert_eq!((p.channels, p.positions), (c, n), "photo columns");
    }
    let mut out = vec![0u32; n];
    if m == 0 {
        return out;
    }
    // The bf16 operands, packed once for every block.
    let packed = (bf16 && bf16_columns::available()).then(|| {
        let left = |cols: &Columns| bf16_columns::Columns::new(cols.values, [c, n]);
        let right = bf16_columns::Right::new(painting.values, [c, m]);
        (left(&render), photo.as_ref().map(|(p, _)| left(p)), right)
    });
    out.par_chunks_mut(BLOCK).enumerate().for_each_init(
        || (vec![0f32; BLOCK * m], vec![0f32; BLOCK * m]),
        |(sim_r, sim_p), (b, idx)| {
            let (first, rows) = (b * BLOCK, idx.len());
            // sim[i, j] = Σ_k columns[k, first + i] · painting[k, j]: the block of
            // positions read through strides (position i is column `first + i`).
            let similarity = |cols: &Columns, dst: &mut [f32]| {
                // SAFETY: the operands address `rows × c` and `c × m` elements inside
                // their slices (checked above); `dst` holds `rows × m`.
                unsafe {
                    product_on(
                        gemm::Parallelism::None,
                        [rows, c, m],
                        dst.as_mut_ptr(),
                        false,
                        1.0,
                        (cols.values.as_ptr().add(first), [1, n as isize]),
                        (painting.values.as_ptr(), [m as isize, 1]),
                    )
                }
            };
            match &packed {
                Some((render, photo, painting)) => {
                    painting.block(render, first, rows, sim_r);
                    if let Some(p) = photo {
                        painting.block(p, first, rows, sim_p);
                    }
                }
                None => {
                    similarity(&render, sim_r);
                    if let Some((p, _)) = &photo {
                        similarity(p, sim_p);
                    }
                }
            }
            for (i, slot) in idx.iter_mut().enumerate() {
                let r = &sim_r[i * m..(i + 1) * m];
                *slot = match &photo {
                    None => first_max(r, |_| true),
                    Some((_, radius)) => {
                        let p = &sim_p[i * m..(i + 1) * m];
                        let best = p.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                        // The same test, in the same order, as the tensor form's
                        // `(sim − best) + radius ≥ 0`.
                        first_max(r, |j| (p[j] - best) + radius >= 0.0)
                    }
                };
            }
        },
    );
    out
}

/// The index of the first largest of `values` among those `allowed`.
fn first_max(values: &[f32], allowed: impl Fn(usize) -> bool) -> u32 {
    let mut best = (0usize, f32::NEG_INFINITY);
    for (j, &v) in values.iter().enumerate() {
        if v > best.1 && allowed(j) {
            best = (j, v);
        }
    }
    best.0 as u32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::feature_match::unit_columns;
    use crate::loss::style::{candidates, nearest_columns, nearest_columns_among};
    use burn::prelude::*;
    use burn::tensor::Distribution;

    fn host(t: &Tensor<2>) -> Vec<f32> {
        t.clone().into_data().try_to_vec::<f32>().unwrap()
    }

    /// The painting column each position matched, by its values: `[C, N]` → index per column.
    fn indices_of(matched: &[f32], painting: &[f32], c: usize, n: usize, m: usize) -> Vec<u32> {
        (0..n)
            .map(|i| {
                (0..m)
                    .find(|&j| (0..c).all(|k| matched[k * n + i] == painting[k * m + j]))
                    .expect("a painting column") as u32
            })
            .collect()
    }

    /// Against the tensor form (similarity matrices, the photo's allowed set, `argmax`), on
    /// positions past two blocks and a partial one, guided at three radii and unguided.
    #[test]
    fn the_blocks_match_as_the_tensor_form_does() {
        let d = Device::flex();
        d.seed(5);
        let (c, n, m) = (24, 77, 150);
        let unit = |cols| unit_columns(Tensor::<2>::random([c, cols], Distribution::Default, &d));
        let (render, photo, painting) = (unit(n), unit(n), unit(m));
        let (r, p, s) = (host(&render), host(&photo), host(&painting));
        let cols = |values, positions| Columns::new(values, c, positions);
        let plain = guided_nearest(cols(&r, n), None, cols(&s, m), false);
        let want = nearest_columns(render.clone(), painting.clone());
        assert_eq!(plain, indices_of(&host(&want), &s, c, n, m));
        for radius in [0.0, 0.05, 0.3] {
            let got = guided_nearest(cols(&r, n), Some((cols(&p, n), radius)), cols(&s, m), false);
            let bias = candidates(photo.clone(), painting.clone(), radius);
            let want = nearest_columns_among(render.clone(), painting.clone(), bias);
            assert_eq!(
                got,
                indices_of(&host(&want), &s, c, n, m),
                "radius {radius}"
            );
        }
    }

    /// In bf16 each match is as near as the best one to within the operands' rounding, and
    /// under a guide it stays in the photo's allowed set to within that rounding too; most
    /// matches are the f32 ones.
    #[test]
    fn bf16_matches_are_the_best_to_within_rounding() {
        if !bf16_columns::available() {
            eprintln!("no AVX-512 BF16 here: nothing runs in bf16");
            return;
        }
        let d = Device::flex();
        d.seed(9);
        let (c, n, m) = (64, 77, 300);
        let unit = |cols| unit_columns(Tensor::<2>::random([c, cols], Distribution::Default, &d));
        let (r, p, s) = (host(&unit(n)), host(&unit(n)), host(&unit(m)));
        let cols = |values, positions| Columns::new(values, c, positions);
        let cos = |x: &[f32], i: usize, j: usize| {
            (0..c).map(|k| x[k * n + i] * s[k * m + j]).sum::<f32>()
        };
        for radius in [None, Some(0.05), Some(0.3)] {
            let guide = radius.map(|radius| (cols(&p, n), radius));
            let exact = guided_nearest(cols(&r, n), guide, cols(&s, m), false);
            let got = guided_nearest(cols(&r, n), guide, cols(&s, m), true);
            let same = exact.iter().zip(&got).filter(|(a, b)| a == b).count();
            assert!(
                same * 10 >= n * 9,
                "{radius:?}: {same} of {n} matches the same"
            );
            for i in 0..n {
                let (want, had) = (exact[i] as usize, got[i] as usize);
                let gap = cos(&r, i, want) - cos(&r, i, had);
                assert!(gap <= 0.01, "{radius:?}: position {i} {gap} below the best");
                if let Some(radius) = radius {
                    let best = (0..m).map(|j| cos(&p, i, j)).fold(f32::MIN, f32::max);
                    let margin = cos(&p, i, had) - best + radius;
                    assert!(
                        margin >= -0.01,
                        "{radius}: position {i} outside the guide by {margin}"
                    );
                }
            }
        }
    }

    #[test]
    fn the_first_of_equal_matches_wins_and_only_allowed_ones_count() {
        assert_eq!(first_max(&[0.1, 0.5, 0.5, 0.2], |_| true), 1);
        assert_eq!(first_max(&[0.1, 0.5, 0.5, 0.2], |j| j != 1), 2);
        assert_eq!(first_max(&[0.9, 0.5, 0.4], |j| j == 2), 2);
    }
}
