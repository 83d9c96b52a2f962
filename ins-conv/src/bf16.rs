//! BF16 values and the tile layouts both BF16 engines read (AMX, AVX-512 BF16): the left matrix as 16×32 tiles of rows, the right
//! matrix in the VNNI layout (pairs of consecutive `k` side by side), both zero-padded to whole
//! tiles.

use rayon::prelude::*;

/// f32 → bf16 with round-to-nearest-even (NaN stays NaN).
#[inline]
pub fn to_bf16(x: f32) -> u16 {
    // Branch-free, so loops of it vectorize.
    let bits = x.to_bits();
    let rounded = bits.wrapping_add(0x7FFF + ((bits >> 16) & 1)) >> 16;
    let quiet_nan = (bits >> 16) | 0x40;
    (if x.is_nan() { quiet_nan } else { rounded }) as u16
}

/// bf16 → f32 (exact).
#[inline]
pub fn from_bf16(x: u16) -> f32 {
    f32::from_bits((x as u32) << 16)
}

/// Rows and columns of one tile: 16 rows of 64 bytes (32 bf16 or 16 f32).
pub const TILE: usize = 16;
/// `k` per tile: 32 bf16 values per 64-byte row.
pub const TILE_K: usize = 32;

/// `x` rounded up to a multiple of `m`.
pub fn round_up(x: usize, m: usize) -> usize {
    x.div_ceil(m) * m
}

/// A row-major `[m, k]` f32 matrix as bf16 tiles: `[m/16][k/32][16][32]`, with `m` padded to a
/// multiple of 32 (the kernel's two row tiles) and `k` to a multiple of 32.
pub struct PackedLeft {
    /// Padded rows.
    pub m: usize,
    /// Padded depth.
    pub k: usize,
    /// The tiles.
    pub data: Vec<u16>,
}

impl PackedLeft {
    /// Packs `a` (`[m, k]`, row-major).
    pub fn new(a: &[f32], m: usize, k: usize) -> Self {
        let (mp, kp) = (round_up(m, 2 * TILE), round_up(k, TILE_K));
        let mut data = vec![0u16; mp * kp];
        // One row block of 16 per job.
        data.par_chunks_mut(kp * TILE)
            .enumerate()
            .for_each(|(mb, block)| {
                for rr in 0..TILE.min(m.saturating_sub(mb * TILE)) {
                    let r = mb * TILE + rr;
                    for (kb, src) in a[r * k..(r + 1) * k].chunks(TILE_K).enumerate() {
                        let dst = &mut block[(kb * TILE + rr) * TILE_K..][..src.len()];
                        dst.iter_mut().zip(src).for_each(|(d, &v)| *d = to_bf16(v));
                    }
                }
            });
        Self { m: mp, k: kp, data }
    }

    /// The tiles of row block `mb` (16 rows), one per 32 of `k`.
    pub fn row_block(&self, mb: usize) -> &[u16] {
        let len = (self.k / TILE_K) * TILE * TILE_K;
        &self.data[mb * len..(mb + 1) * len]
    }
}

/// Packs a row-major `[k, n]` f32 matrix into VNNI tiles `[n_pad/16][k_pad/32][16 pairs][16][2]`
/// in `out` (resized), with `n` padded to `n_pad` and `k` to a multiple of 32.
pub fn pack_right(b: &[f32], k: usize, n: usize, n_pad: usize, out: &mut Vec<u16>) {
    let kp = round_up(k, TILE_K);
    let kblocks = kp / TILE_K;
    out.clear();
    out.resize(kp * n_pad, 0);
    for kr in (0..k).step_by(2) {
        let (kb, pair) = (kr / TILE_K, (kr % TILE_K) / 2);
        let row0 = &b[kr * n..(kr + 1) * n];
        let row1 = (kr + 1 < k).then(|| &b[(kr + 1) * n..(kr + 2) * n]);
        for nb in 0..n.div_ceil(TILE) {
            let tile = &mut out[((nb * kblocks + kb) * TILE + pair) * TILE * 2..][..TILE * 2];
            for j in 0..TILE.min(n - nb * TILE) {
                let col = nb * TILE + j;
                tile[2 * j] = to_bf16(row0[col]);
                tile[2 * j + 1] = row1.map_or(0, |r| to_bf16(r[col]));
            }
        }
    }
}

/// The operands of one 32×32 output block, for either BF16 engine: rows `a[0]` (16) and `a[1]`
/// (16) of the left matrix times columns `b[0]` (16) and `b[1]` (16) of the right one, each a
/// run of `kblocks` tiles as laid out above; `init[i]` (16×16, row-major) starts both column
/// halves of row half `i` (the bias, broadcast along a row).
pub struct Block32<'a> {
    /// Two runs of left tiles (16 rows each).
    pub a: [&'a [u16]; 2],
    /// Two runs of right VNNI tiles (16 columns each).
    pub b: [&'a [u16]; 2],
    /// Tiles per run (`k / 32`).
    pub kblocks: usize,
    /// Starting values of the two row halves.
    pub init: [&'a [f32; 256]; 2],
}

impl Block32<'_> {
    /// Panics unless every run holds `kblocks` whole tiles.
    pub fn check(&self) {
        for s in self.a.iter().chain(self.b.iter()) {
            assert!(s.len() >= self.kblocks * TILE * TILE_K, "short tile run");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bf16_rounds_to_nearest_even_and_keeps_nan() {
        assert_eq!(from_bf16(to_bf16(1.0)), 1.0);
        // 1 + 2^-8 is halfway between two bf16 values: ties go to the even one (1.0).
        assert_eq!(from_bf16(to_bf16(1.0 + 2f32.powi(-8))), 1.0);
        assert_eq!(
            from_bf16(to_bf16(1.0 + 3.0 * 2f32.powi(-8))),
            1.0 + 2f32.powi(-6)
        );
        assert!(from_bf16(to_bf16(f32::NAN)).is_nan());
        for x in [0.1f32, -3.7, 1e-20, 6.5e4] {
            assert!((from_bf16(to_bf16(x)) - x).abs() <= x.abs() * 2f32.powi(-8));
        }
    }
}
