//! Blocks of occupancy-grid cells with nothing occupied, which a march crosses in one jump.

use rayon::prelude::*;

use ins_scene::geometry::Vec3;

use super::occupancy::OccupancyGrid;

/// Cells per side of a [`Blocks`] block.
const BLOCK: usize = 8;

/// Which blocks of 8³ cells hold an occupied cell, for marching across empty space a block at
/// a time (instant-ngp's coarser grid levels do the same). Derived from the bits on every march
/// (a pass over the grid, under a millisecond at 128³) so it can never go stale.
pub(crate) struct Blocks {
    /// Blocks per axis.
    per_axis: usize,
    /// Cells per axis.
    resolution: usize,
    occupied: Vec<bool>,
    min: Vec3,
    cell: Vec3,
}

impl Blocks {
    pub(crate) fn of(grid: &OccupancyGrid) -> Self {
        let r = grid.resolution as usize;
        let per_axis = r.div_ceil(BLOCK);
        // One z-slab of blocks per task: each scans its own cells.
        let occupied = (0..per_axis)
            .into_par_iter()
            .flat_map_iter(|bz| {
                let mut slab = vec![false; per_axis * per_axis];
                for z in bz * BLOCK..((bz + 1) * BLOCK).min(r) {
                    for y in 0..r {
                        let row = &grid.occupied[(z * r + y) * r..(z * r + y + 1) * r];
                        for (x, _) in row.iter().enumerate().filter(|(_, o)| **o) {
                            slab[(y / BLOCK) * per_axis + x / BLOCK] = true;
                        }
                    }
                }
                slab
            })
            .collect();
        Self {
            per_axis,
            resolution: r,
            occupied,
            min: Vec3::from(grid.min),
            cell: grid.cell_size(),
        }
    }

    /// The block of cell `c`, as block coordinates.
    fn block(&self, c: usize) -> [usize; 3] {
        let r = self.resolution;
        [(c % r) / BLOCK, (c / r % r) / BLOCK, (c / (r * r)) / BLOCK]
    }

    /// Whether the block of cell `c` holds an occupied cell.
    pub(crate) fn occupied(&self, c: usize) -> bool {
        let [x, y, z] = self.block(c);
        self.occupied[(z * self.per_axis + y) * self.per_axis + x]
    }

    /// Where the ray `o + t·d` leaves the block of cell `c` (which it is in).
    pub(crate) fn exit(&self, c: usize, o: Vec3, d: Vec3) -> f32 {
        let b = Vec3::from(self.block(c).map(|v| v as f32));
        let lo = self.min + b * BLOCK as f32 * self.cell;
        let hi = self.min
            + (b * BLOCK as f32 + BLOCK as f32).min(Vec3::splat(self.resolution as f32))
                * self.cell;
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
