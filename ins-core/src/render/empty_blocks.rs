//! The occupancy bits packed by blocks of 8³ cells, for marching: a block's bits fill one
//! cache line, and a block with none set is crossed in one jump.

use rayon::prelude::*;

use ins_scene::geometry::Vec3;

use super::occupancy::OccupancyGrid;

/// Cells per side of a block: 8³ bits are one 64-byte cache line.
const SIZE: usize = 8;

/// A block's bits: byte `(z % 8)·8 + y % 8`, bit `x % 8`.
#[derive(Clone, Copy)]
#[repr(align(64))]
struct Line([u8; SIZE * SIZE]);

/// The grid's occupancy bits by blocks of 8³ cells (instant-ngp's coarser grid levels do the
/// same), for marching. A ray's lookups within a block read one cache line, where the grid's
/// byte per cell (x fastest) put a ray's consecutive cells up to `resolution²` bytes apart: at
/// 128³ (2 MB) half a march's time went to those cache misses. Derived from the bits on every
/// march (one pass over the grid) so it can never go stale.
pub(crate) struct Blocks {
    /// Blocks per axis.
    per_axis: usize,
    /// Cells per axis.
    resolution: usize,
    lines: Vec<Line>,
    /// Whether each block holds an occupied cell.
    occupied: Vec<bool>,
    min: Vec3,
    cell: Vec3,
}

/// Eight cells' bytes (0 or 1) as the bits of one byte, cell `i` at bit `i`: the multiplier
/// moves byte `i`'s low bit to bit `56 + i` and no two of its products overlap.
#[inline]
fn pack(cells: &[bool]) -> u8 {
    match <[bool; 8]>::try_from(cells) {
        Ok(eight) => {
            let v = u64::from_le_bytes(eight.map(u8::from));
            (v.wrapping_mul(0x0102_0408_1020_4080) >> 56) as u8
        }
        Err(_) => cells
            .iter()
            .enumerate()
            .fold(0, |byte, (i, &o)| byte | (u8::from(o) << i)),
    }
}

impl Blocks {
    pub(crate) fn of(grid: &OccupancyGrid) -> Self {
        let r = grid.resolution as usize;
        let per_axis = r.div_ceil(SIZE);
        // One z-slab of blocks per task: each packs its own cells.
        let lines: Vec<Line> = (0..per_axis)
            .into_par_iter()
            .flat_map_iter(|bz| {
                let mut slab = vec![Line([0; SIZE * SIZE]); per_axis * per_axis];
                for z in bz * SIZE..((bz + 1) * SIZE).min(r) {
                    for y in 0..r {
                        let row = &grid.occupied[(z * r + y) * r..(z * r + y + 1) * r];
                        for (bx, cells) in row.chunks(SIZE).enumerate() {
                            slab[(y / SIZE) * per_axis + bx].0[(z % SIZE) * SIZE + y % SIZE] =
                                pack(cells);
                        }
                    }
                }
                slab
            })
            .collect();
        let occupied = lines
            .iter()
            .map(|line| line.0.iter().any(|&b| b != 0))
            .collect();
        Self {
            per_axis,
            resolution: r,
            lines,
            occupied,
            min: Vec3::from(grid.min),
            cell: grid.cell_size(),
        }
    }

    #[inline]
    fn block(&self, c: [usize; 3]) -> usize {
        let [x, y, z] = c.map(|v| v / SIZE);
        (z * self.per_axis + y) * self.per_axis + x
    }

    /// Whether the cell at coordinates `c` is occupied (the grid's bit).
    #[inline]
    pub(crate) fn cell(&self, c: [usize; 3]) -> bool {
        let byte = self.lines[self.block(c)].0[(c[2] % SIZE) * SIZE + c[1] % SIZE];
        (byte >> (c[0] % SIZE)) & 1 != 0
    }

    /// Whether the block of the cell at coordinates `c` holds an occupied cell.
    #[inline]
    pub(crate) fn occupied_at(&self, c: [usize; 3]) -> bool {
        self.occupied[self.block(c)]
    }

    /// Where the ray `o + t·d` leaves the block of the cell at coordinates `c` (which it is in).
    pub(crate) fn exit_at(&self, c: [usize; 3], o: Vec3, d: Vec3) -> f32 {
        let b = Vec3::from(c.map(|v| (v / SIZE) as f32));
        let lo = self.min + b * SIZE as f32 * self.cell;
        let hi = self.min
            + (b * SIZE as f32 + SIZE as f32).min(Vec3::splat(self.resolution as f32)) * self.cell;
        let plane = |lo: f32, hi: f32, o: f32, d: f32| {
            if d > 0.0 {
                (hi - o) / d
            } else if d < 0.0 {
                (lo - o) / d
            } else {
                f32::INFINITY
            }
        };
        plane(lo.x, hi.x, o.x, d.x)
            .min(plane(lo.y, hi.y, o.y, d.y))
            .min(plane(lo.z, hi.z, o.z, d.z))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packed_bits_are_the_grids_bits_at_every_cell() {
        // 21 cells a side: partial blocks at the far end of every axis.
        let mut g = OccupancyGrid::new(21, Vec3::splat(-1.0), Vec3::splat(1.0), 0.05);
        let r = 21;
        for (i, o) in g.occupied.iter_mut().enumerate() {
            *o = (i * 7919) % 13 < 4 && i / (r * r) < 16;
        }
        let blocks = Blocks::of(&g);
        for i in 0..r * r * r {
            let c = [i % r, i / r % r, i / (r * r)];
            assert_eq!(blocks.cell(c), g.occupied[i], "cell {c:?}");
            if i % 97 == 0 {
                let block_any = (0..r * r * r).any(|j| {
                    let d = [j % r, j / r % r, j / (r * r)];
                    g.occupied[j] && (0..3).all(|a| d[a] / SIZE == c[a] / SIZE)
                });
                assert_eq!(blocks.occupied_at(c), block_any, "block of {c:?}");
            }
        }
        // The last z-slab of blocks (z 16..21) has no cell set; the one before has.
        assert!(!blocks.occupied_at([0, 0, 20]));
        assert!(blocks.occupied_at([0, 0, 15]));
    }
}
