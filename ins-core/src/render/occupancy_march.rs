//! Marching rays through an [`OccupancyGrid`]: evenly spaced samples in its occupied cells,
//! empty blocks crossed in one jump.

use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

use ins_scene::geometry::Vec3;
use ins_scene::rays::Rays;

use super::empty_blocks::Blocks;
use super::marched_samples::MarchedSamples;
use super::occupancy::OccupancyGrid;

/// A chunk of rays' samples: where each ray's end, and every sample's `(t, delta)`.
type ChunkSamples = (Vec<u32>, Vec<(f32, f32)>);

impl OccupancyGrid {
    /// Marches every ray from its `near` to its `far` (clipped to the box) in steps of
    /// [`OccupancyGrid::step`] (divided by the ray direction's length, so non-unit NDC rays
    /// step evenly; lengthened by [`Contraction::step_scale`] in contracted grids), keeping at
    /// most `max_per_ray` samples in occupied cells. Each ray's first sample is offset by a
    /// uniform fraction of a step drawn from `seed` (`None`: half a step).
    ///
    /// [`Contraction::step_scale`]: ins_scene::geometry::Contraction::step_scale
    pub fn march(&self, rays: &Rays, max_per_ray: usize, seed: Option<u64>) -> MarchedSamples {
        let marcher = Marcher {
            grid: self,
            blocks: Blocks::of(self),
            bounds: ins_scene::geometry::Bounds::Aabb {
                min: Vec3::from(self.min),
                max: Vec3::from(self.max),
            },
            min: Vec3::from(self.min),
            per_unit: self.cells_per_unit(),
            max_per_ray,
            seed,
        };
        // Rays in chunks, each chunk's samples in one buffer (not one vector a ray).
        const CHUNK: usize = 64;
        let chunks: Vec<ChunkSamples> = (0..rays.len().div_ceil(CHUNK))
            .into_par_iter()
            .map(|chunk| {
                let rays_here = chunk * CHUNK..((chunk + 1) * CHUNK).min(rays.len());
                let mut ends = Vec::with_capacity(rays_here.len());
                let mut out = Vec::new();
                for i in rays_here {
                    marcher.ray(rays, i, &mut out);
                    ends.push(out.len() as u32);
                }
                (ends, out)
            })
            .collect();
        let total = chunks.iter().map(|(_, out)| out.len()).sum();
        let mut s = MarchedSamples {
            ray: Vec::with_capacity(total),
            t: Vec::with_capacity(total),
            delta: Vec::with_capacity(total),
            offsets: Vec::with_capacity(rays.len() + 1),
        };
        s.offsets.push(0);
        for (chunk, (ends, out)) in chunks.into_iter().enumerate() {
            let mut start = 0;
            for (j, end) in ends.into_iter().enumerate() {
                let ray = (chunk * CHUNK + j) as u32;
                for &(t, dt) in &out[start as usize..end as usize] {
                    s.ray.push(ray);
                    s.t.push(t);
                    s.delta.push(dt);
                }
                start = end;
                s.offsets.push(s.t.len() as u32);
            }
        }
        s
    }
}

/// One march's settings and what it derives from the grid once, for marching a ray at a time.
struct Marcher<'a> {
    grid: &'a OccupancyGrid,
    blocks: Blocks,
    bounds: ins_scene::geometry::Bounds,
    /// The grid's corner and [`OccupancyGrid::cells_per_unit`], computed once.
    min: Vec3,
    per_unit: Vec3,
    max_per_ray: usize,
    seed: Option<u64>,
}

impl Marcher<'_> {
    /// Appends ray `i`'s samples, `(t, delta)`, to `out`.
    fn ray(&self, rays: &Rays, i: usize, out: &mut Vec<(f32, f32)>) {
        let g = self.grid;
        let (o, d) = (rays.origins[i], rays.directions[i]);
        let len = d.length();
        if len <= 0.0 {
            return;
        }
        let (b0, b1) = match (&g.contraction, self.bounds.intersect(o, d)) {
            (Some(_), _) => (0.0, f32::INFINITY),
            (None, Some(b)) => b,
            (None, None) => return,
        };
        let t0 = rays.near[i].max(b0);
        let t1 = rays.far[i].min(b1);
        let dt = g.step / len;
        let offset = match self.seed {
            Some(s) => SmallRng::seed_from_u64(s ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
                .random::<f32>(),
            None => 0.5,
        };
        let limit = out.len().saturating_add(self.max_per_ray);
        match &g.contraction {
            None => {
                // Sample k sits at `t0 + (offset + k)·dt`; empty blocks are crossed in one jump.
                let mut k = 0usize;
                loop {
                    let t = t0 + (offset + k as f32) * dt;
                    if t >= t1 || out.len() >= limit {
                        break;
                    }
                    if let Some(c) = g.cell_coords(o + d * t, self.min, self.per_unit) {
                        if self.blocks.cell(c) {
                            out.push((t, dt));
                        } else if !self.blocks.occupied_at(c) {
                            let exit = self.blocks.exit_at(c, o, d);
                            // One step short of the exit, floor(v) − 1: every step skipped
                            // lies a cell inside the block, whatever the rounding. (For v ≥ 0
                            // the floor is the truncation `as` makes, which needs no call.)
                            let v = (exit - t0) / dt - offset;
                            if v >= 0.0 && v as usize > k + 2 {
                                k = v as usize - 1;
                                continue;
                            }
                        }
                    }
                    k += 1;
                }
            }
            Some(c) => {
                let mut t = t0 + offset * dt;
                while t < t1 && out.len() < limit {
                    let p = o + d * t;
                    let step = dt * c.step_scale(p);
                    let cell = g.cell_coords(c.apply(p), self.min, self.per_unit);
                    if cell.is_some_and(|cell| self.blocks.cell(cell)) {
                        out.push((t, step));
                    }
                    t += step;
                }
            }
        }
    }
}
