//! Blocks of occupancy-grid cells with nothing occupied, which a march crosses in one jump.

use rayon::prelude::*;

use ins_scene::geometry::Vec3;

use super::occupancy::OccupancyGrid;

/// Which blocks of `size`³ cells hold an occupied cell, for marching across empty space a block
/// at a time (instant-ngp's coarser grid levels do the same). Derived from the bits on every
/// march (a pass over the grid, under a millisecond at 128³) so it can never go stale.
pub(crate) struct Blocks {
    /// Cells per side of a block.
    size: usize,
    /// Blocks per axis.
    per_axis: usize,
    /// Cells per axis.
    resolution: usize,
    occupied: Vec<bool>,
    min: Vec3,
    cell: Vec3,
}

impl Blocks {
    pub(crate) fn of(grid: &OccupancyGrid, size: usize) -> Self {
        let r = grid.resolution as usize;
        let per_axis = r.div_ceil(size);
        // One z-slab of blocks per task: each scans its own cells.
        let occupied = (0..per_axis)
            .into_par_iter()
            .flat_map_iter(|bz| {
                let mut slab = vec![false; per_axis * per_axis];
                for z in bz * size..((bz + 1) * size).min(r) {
                    for y in 0..r {
                        let row = &grid.occupied[(z * r + y) * r..(z * r + y + 1) * r];
                        for (bx, cells) in row.chunks(size).enumerate() {
                            // Bytes compared a vector at a time, not a branch a cell.
                            if cells.iter().fold(false, |any, &o| any | o) {
                                slab[(y / size) * per_axis + bx] = true;
                            }
                        }
                    }
                }
                slab
            })
            .collect();
        Self {
            size,
            per_axis,
            resolution: r,
            occupied,
            min: Vec3::from(grid.min),
            cell: grid.cell_size(),
        }
    }

    /// Whether the block of the cell at coordinates `c` holds an occupied cell.
    #[inline]
    pub(crate) fn occupied_at(&self, c: [usize; 3]) -> bool {
        let [x, y, z] = c.map(|v| v / self.size);
        self.occupied[(z * self.per_axis + y) * self.per_axis + x]
    }

    /// Where the ray `o + t·d` leaves the block of the cell at coordinates `c` (which it is in).
    pub(crate) fn exit_at(&self, c: [usize; 3], o: Vec3, d: Vec3) -> f32 {
        let b = Vec3::from(c.map(|v| (v / self.size) as f32));
        let lo = self.min + b * self.size as f32 * self.cell;
        let hi = self.min
            + (b * self.size as f32 + self.size as f32).min(Vec3::splat(self.resolution as f32))
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
