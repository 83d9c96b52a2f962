//! `aᵀ·b` for two matrices of feature columns (`[k, n]`, a feature a column), a block of `a`'s
//! columns at a time, in bf16: NNFM's cosines between a render's and a painting's unit VGG
//! features (`loss/guided_match.rs`), where the `gemm` crate's f32 products were a fifth of a
//! grid NeRF's stylizing step. The features themselves come out of bf16 convolutions.

pub use super::available;
use super::{pack_pairs, pack_panels, product_packed};

/// The left operand: `[k, n]`'s columns as bf16 pairs of consecutive rows, `n` wide.
pub struct Columns {
    packed: Vec<u32>,
    pairs: usize,
    n: usize,
}

impl Columns {
    /// `values` row-major `[k, n]`.
    ///
    /// # Panics
    /// Unless [`available`], or when `values` is not `k·n` long.
    pub fn new(values: &[f32], [k, n]: [usize; 2]) -> Self {
        assert!(available(), "bf16 column products need AVX-512 BF16");
        assert_eq!(values.len(), k * n, "{k}×{n} columns");
        Self {
            packed: pack_pairs(values, [k, n], n, n),
            pairs: k.div_ceil(2),
            n,
        }
    }
}

/// The right operand `[k, m]`, packed once for every block of a left one.
pub struct Right {
    packed: Vec<u32>,
    pairs: usize,
    m: usize,
    zeros: Vec<f32>,
}

impl Right {
    /// `values` row-major `[k, m]`.
    ///
    /// # Panics
    /// Unless [`available`], or when `values` is not `k·m` long.
    pub fn new(values: &[f32], [k, m]: [usize; 2]) -> Self {
        assert!(available(), "bf16 column products need AVX-512 BF16");
        assert_eq!(values.len(), k * m, "{k}×{m} columns");
        Self {
            packed: pack_panels(values, [k, m], m),
            pairs: k.div_ceil(2),
            m,
            zeros: vec![0.0; m],
        }
    }

    /// `dst [rows, m] = left[:, first..first + rows]ᵀ · self`, serially (callers run blocks
    /// in parallel), every value written.
    ///
    /// # Panics
    /// When the columns run past `left`'s, the operands' `k` differ, or `dst` is short.
    pub fn block(&self, left: &Columns, first: usize, rows: usize, dst: &mut [f32]) {
        assert!(
            rows > 0 && first + rows <= left.n,
            "columns {first}+{rows} of {}",
            left.n
        );
        assert_eq!(left.pairs, self.pairs, "the operands' k");
        assert!(
            dst.len() >= rows * self.m,
            "{} values for {rows}×{}",
            dst.len(),
            self.m
        );
        // SAFETY: `dst` holds `rows·m` values (checked); column `first + r`'s pair `p` is at
        // `packed[first + r + p·n]`, inside `packed` for `first + rows ≤ n`.
        unsafe {
            product_packed(
                &left.packed[first..],
                [1, left.n],
                [rows, self.pairs, self.m],
                &self.packed,
                &self.zeros,
                dst.as_mut_ptr(),
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ins_conv::bf16::{from_bf16, to_bf16};

    /// Each block equals the f64 product of the bf16-rounded operands within f32's rounding of
    /// the sum, on odd sizes: `k` odd (a pair padded), `m` past one 64-column panel and not a
    /// multiple of 16, blocks of 1, 5 and 13 columns anywhere in `a`.
    #[test]
    fn blocks_are_the_rounded_product() {
        if !available() {
            eprintln!("no AVX-512 BF16 here: nothing runs in bf16");
            return;
        }
        let (k, n, m) = (7, 40, 83);
        let value = |i: usize| ((i * 37 % 101) as f32 / 50.0 - 1.0) * 1.3;
        let a: Vec<f32> = (0..k * n).map(value).collect();
        let b: Vec<f32> = (0..k * m).map(|i| value(i + 17)).collect();
        let round = |x: f32| from_bf16(to_bf16(x)) as f64;
        let (left, right) = (Columns::new(&a, [k, n]), Right::new(&b, [k, m]));
        for (first, rows) in [(0, 1), (3, 5), (27, 13), (39, 1)] {
            let mut dst = vec![f32::NAN; rows * m];
            right.block(&left, first, rows, &mut dst);
            for r in 0..rows {
                for j in 0..m {
                    let want: f64 = (0..k)
                        .map(|p| round(a[p * n + first + r]) * round(b[p * m + j]))
                        .sum();
                    let got = dst[r * m + j] as f64;
                    assert!(
                        (got - want).abs() < 1e-5,
                        "[{r}, {j}] of block {first}: {got} vs {want}"
                    );
                }
            }
        }
    }
}
