//! An occupancy grid (instant-ngp): a cube of cells over the scene's box, each holding a decayed
//! running maximum of the field's density and one bit "worth sampling". Marching a ray skips
//! cells whose bit is off, so empty space costs nothing.
//!
//! The grid is refreshed from the model every few steps ([`OccupancyGrid::update`]): a random
//! point in each chosen cell is evaluated, `density ← max(decay · density, new)`, and a cell is
//! occupied when `density · step > min(threshold, mean)` (nerfacc's rule), so a sample whose
//! cell has recorded a density above the threshold is never culled.

use burn::prelude::Tensor;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use ins_scene::geometry::{Contraction, Vec3};

/// A density grid with occupancy bits.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct OccupancyGrid {
    /// Cells per axis.
    pub resolution: u32,
    /// Box minimum corner.
    pub min: [f32; 3],
    /// Box maximum corner.
    pub max: [f32; 3],
    /// Running maximum of the density per cell (x fastest, then y, then z).
    pub density: Vec<f32>,
    /// Occupancy bit per cell.
    pub occupied: Vec<bool>,
    /// Ray-marching step (distance between samples along a unit ray).
    pub step: f32,
    /// Occupancy threshold on `density · step` (an opacity of about 1 %).
    pub threshold: f32,
    /// Decay of the running maximum per update.
    pub decay: f32,
    /// Unbounded scenes: the grid covers contracted space (`min`/`max` are the contracted
    /// cube), marching steps lengthen with distance so contracted samples stay evenly spaced,
    /// and [`OccupancyGrid::field_point`] gives the coordinates the field is queried at.
    #[serde(default)]
    pub contraction: Option<Contraction>,
}

impl OccupancyGrid {
    /// A grid over `[min, max]` with every cell occupied (so the first steps sample everywhere),
    /// marching with `step`.
    pub fn new(resolution: u32, min: Vec3, max: Vec3, step: f32) -> Self {
        let n = (resolution as usize).pow(3);
        Self {
            resolution,
            min: min.to_array(),
            max: max.to_array(),
            density: vec![f32::MAX / 2.0; n],
            occupied: vec![true; n],
            step,
            threshold: 0.01,
            decay: 0.95,
            contraction: None,
        }
    }

    /// A grid over the contracted cube of `contraction`, whose field lives in contracted
    /// coordinates.
    pub fn contracted(resolution: u32, contraction: Contraction) -> Self {
        let e = Vec3::splat(contraction.extent());
        let mut g = Self::new(resolution, -e, e, Self::default_step(resolution, -e, e));
        g.contraction = Some(contraction);
        g
    }

    /// Where the field is evaluated for the scene point `p`: `p` itself, or its contraction.
    pub fn field_point(&self, p: Vec3) -> Vec3 {
        match &self.contraction {
            Some(c) => c.apply(p),
            None => p,
        }
    }

    /// [`OccupancyGrid::field_point`] of each row of `points [N, 3]`, on the device.
    pub fn field_points(&self, points: Tensor<2>) -> Tensor<2> {
        let Some(c) = self.contraction else {
            return points;
        };
        // Outside the cube of half side `radius`, p · (2 − r/n) · r/n with n = max |p_i|.
        let n = points.clone().abs().max_dim(1);
        let inside = n.clone().lower_equal_elem(c.radius);
        let q = n.recip() * c.radius;
        let scale = (q.clone().neg() + 2.0) * q;
        points * scale.mask_fill(inside, 1.0)
    }

    /// A step of half a cell along the box's longest side: fine enough that no cell is
    /// skipped between samples.
    pub fn default_step(resolution: u32, min: Vec3, max: Vec3) -> f32 {
        (max - min).max_element() / resolution as f32 * 0.5
    }

    pub(crate) fn cell_size(&self) -> Vec3 {
        (Vec3::from(self.max) - Vec3::from(self.min)) / self.resolution as f32
    }

    /// The cell containing `p`, if inside the box.
    pub fn cell_of(&self, p: Vec3) -> Option<usize> {
        let [x, y, z] = self.cell_coords(p, Vec3::from(self.min), self.cells_per_unit())?;
        let r = self.resolution as usize;
        Some(x + y * r + z * r * r)
    }

    /// Cells per unit of length along each axis (a multiplication per point, not a division).
    pub(crate) fn cells_per_unit(&self) -> Vec3 {
        self.resolution as f32 / (Vec3::from(self.max) - Vec3::from(self.min))
    }

    /// The cell containing `p` as coordinates along each axis, if inside the box; `min` and
    /// `per_unit` ([`Self::cells_per_unit`]) are passed in so a march computes them once.
    #[inline]
    pub(crate) fn cell_coords(&self, p: Vec3, min: Vec3, per_unit: Vec3) -> Option<[usize; 3]> {
        let rel = (p - min) * per_unit;
        if rel.cmplt(Vec3::ZERO).any() || rel.cmpge(Vec3::splat(self.resolution as f32)).any() {
            return None;
        }
        Some([rel.x as usize, rel.y as usize, rel.z as usize])
    }

    /// Whether `p` lies in an occupied cell.
    pub fn is_occupied(&self, p: Vec3) -> bool {
        self.cell_of(p).is_some_and(|c| self.occupied[c])
    }

    /// The box of the occupied cells in the grid's coordinates (contracted ones for unbounded
    /// scenes), `None` when none is occupied.
    pub fn occupied_bounds(&self) -> Option<(Vec3, Vec3)> {
        let r = self.resolution as usize;
        let cell = self.cell_size();
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for (i, _) in self.occupied.iter().enumerate().filter(|(_, o)| **o) {
            let c = Vec3::new((i % r) as f32, ((i / r) % r) as f32, (i / (r * r)) as f32);
            lo = lo.min(c);
            hi = hi.max(c + Vec3::ONE);
        }
        lo.x.is_finite().then(|| {
            (
                Vec3::from(self.min) + lo * cell,
                Vec3::from(self.min) + hi * cell,
            )
        })
    }

    /// Fraction of occupied cells.
    pub fn occupancy(&self) -> f32 {
        self.occupied.iter().filter(|&&o| o).count() as f32 / self.occupied.len().max(1) as f32
    }

    /// Refreshes the grid: evaluates `density_at` (positions `[n·3]` → densities `[n]`) at a
    /// random point of `cells` chosen cells (every cell when `cells` covers the grid; else half
    /// uniformly, half among occupied ones), decays and updates the running maxima and bits.
    pub fn update(&mut self, cells: usize, seed: u64, density_at: impl FnMut(&[f32]) -> Vec<f32>) {
        self.refresh(cells, seed, true, density_at);
    }

    /// Evaluates every cell afresh and keeps only what the field holds now: no running maximum.
    /// Why: while a field takes shape its first steps fill space with fog, and a running
    /// maximum decaying by 0.95 a refresh remembers a ten-times-threshold fog for 45 refreshes;
    /// on a room capture (unbounded, 1000 steps) the grid kept 222 samples a ray until step
    /// 680, long after the field had cleared (docs/measurements.md).
    pub fn rebuild(&mut self, seed: u64, density_at: impl FnMut(&[f32]) -> Vec<f32>) {
        self.refresh(usize::MAX, seed, false, density_at);
    }

    fn refresh(
        &mut self,
        cells: usize,
        seed: u64,
        keep_max: bool,
        mut density_at: impl FnMut(&[f32]) -> Vec<f32>,
    ) {
        let total = self.density.len();
        let mut rng = SmallRng::seed_from_u64(seed);
        let chosen: Vec<usize> = if cells >= total {
            (0..total).collect()
        } else {
            let occupied: Vec<usize> = (0..total).filter(|&c| self.occupied[c]).collect();
            (0..cells)
                .map(|i| {
                    if i % 2 == 1 && !occupied.is_empty() {
                        occupied[rng.random_range(0..occupied.len())]
                    } else {
                        rng.random_range(0..total)
                    }
                })
                .collect()
        };
        let r = self.resolution as usize;
        let size = self.cell_size();
        let min = Vec3::from(self.min);
        let mut points = Vec::with_capacity(chosen.len() * 3);
        for &c in &chosen {
            let idx = Vec3::new((c % r) as f32, ((c / r) % r) as f32, (c / (r * r)) as f32);
            let jitter = Vec3::new(rng.random(), rng.random(), rng.random());
            points.extend((min + (idx + jitter) * size).to_array());
        }
        let new = density_at(&points);
        // Decay everything once, then raise the evaluated cells (a cell chosen twice keeps its
        // larger value).
        for d in &mut self.density {
            *d = if *d >= f32::MAX / 4.0 || !keep_max {
                0.0
            } else {
                *d * self.decay
            };
        }
        for (&c, &v) in chosen.iter().zip(&new) {
            let v = if v.is_finite() { v.max(0.0) } else { 0.0 };
            self.density[c] = self.density[c].max(v);
        }
        let mean = self
            .density
            .iter()
            .map(|&d| (d * self.step) as f64)
            .sum::<f64>()
            / total as f64;
        let threshold = self.threshold.min(mean as f32);
        for (o, &d) in self.occupied.iter_mut().zip(&self.density) {
            *o = d * self.step > threshold;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ins_scene::rays::Rays;

    /// Density 10 inside the cube `[0.2, 0.5]³` (aligned with cells of a 10³ grid over
    /// `[0, 1]³`), 0 elsewhere.
    fn cube_density(points: &[f32]) -> Vec<f32> {
        points
            .chunks_exact(3)
            .map(|p| {
                let inside = p.iter().all(|&v| (0.2..0.5).contains(&v));
                if inside { 10.0 } else { 0.0 }
            })
            .collect()
    }

    fn grid() -> OccupancyGrid {
        let mut g = OccupancyGrid::new(10, Vec3::ZERO, Vec3::ONE, 0.01);
        g.update(usize::MAX, 1, cube_density);
        g
    }

    #[test]
    fn a_full_update_marks_exactly_the_dense_cells() {
        let g = grid();
        assert_eq!(g.occupied.iter().filter(|&&o| o).count(), 27);
        assert!(g.is_occupied(Vec3::splat(0.35)));
        assert!(!g.is_occupied(Vec3::splat(0.75)));
        // The dense cube [0.2, 0.5)³ fills cells 2..5 of 10 along each axis.
        let (lo, hi) = g.occupied_bounds().unwrap();
        assert!((lo - Vec3::splat(0.2)).abs().max_element() < 1e-6, "{lo}");
        assert!((hi - Vec3::splat(0.5)).abs().max_element() < 1e-6, "{hi}");
        let mut empty = OccupancyGrid::new(4, Vec3::ZERO, Vec3::ONE, 0.1);
        empty.occupied.fill(false);
        assert!(empty.occupied_bounds().is_none());
    }

    #[test]
    fn marching_never_culls_a_sample_with_density_above_the_threshold() {
        let g = grid();
        let mut rays = Rays::default();
        let mut rng = SmallRng::seed_from_u64(9);
        for _ in 0..300 {
            let o = Vec3::new(rng.random(), rng.random(), -1.0);
            let target = Vec3::new(rng.random(), rng.random(), rng.random());
            rays.push(o, (target - o).normalize(), 0.0, 4.0);
        }
        let kept = g.march(&rays, 10_000, Some(2));
        // Every point of a dense ray segment is kept: compare with marching an all-occupied
        // grid and keeping samples whose true density is positive.
        let mut all = g.clone();
        all.occupied.fill(true);
        let every = all.march(&rays, 10_000, Some(2));
        let dense: Vec<(u32, f32)> = every
            .ray
            .iter()
            .zip(&every.t)
            .filter(|&(&r, &t)| {
                let p = rays.point(r as usize, t);
                cube_density(&p.to_array())[0] > 0.0
            })
            .map(|(&r, &t)| (r, t))
            .collect();
        assert!(!dense.is_empty());
        let kept_set: Vec<(u32, f32)> = kept
            .ray
            .iter()
            .copied()
            .zip(kept.t.iter().copied())
            .collect();
        for s in &dense {
            assert!(kept_set.contains(s), "dense sample {s:?} was culled");
        }
        // And empty space costs nothing: far fewer samples than marching everything.
        assert!(
            kept.len() * 3 < every.len(),
            "{} of {}",
            kept.len(),
            every.len()
        );
    }

    /// Every step tested, none skipped: what [`OccupancyGrid::march`] must equal.
    fn march_every_step(g: &OccupancyGrid, rays: &Rays, max: usize, seed: u64) -> Vec<Vec<f32>> {
        let (lo, hi) = (Vec3::from(g.min), Vec3::from(g.max));
        let bounds = ins_scene::geometry::Bounds::Aabb { min: lo, max: hi };
        (0..rays.len())
            .map(|i| {
                let (o, d) = (rays.origins[i], rays.directions[i]);
                let Some((b0, b1)) = bounds.intersect(o, d) else {
                    return Vec::new();
                };
                let (t0, t1, dt) = (
                    rays.near[i].max(b0),
                    rays.far[i].min(b1),
                    g.step / d.length(),
                );
                let offset =
                    SmallRng::seed_from_u64(seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
                        .random::<f32>();
                (0..)
                    .map(|k| t0 + (offset + k as f32) * dt)
                    .take_while(|&t| t < t1)
                    .filter(|&t| g.is_occupied(o + d * t))
                    .take(max)
                    .collect()
            })
            .collect()
    }

    #[test]
    fn crossing_empty_blocks_in_one_jump_keeps_every_sample() {
        let mut rng = SmallRng::seed_from_u64(4);
        // 37 cells a side: blocks of 8 with a partial one at the far end.
        let mut g = OccupancyGrid::new(
            37,
            Vec3::new(-1.0, -0.5, -2.0),
            Vec3::new(1.0, 1.5, 0.5),
            0.02,
        );
        let mut rays = Rays::default();
        for i in 0..400 {
            let o = Vec3::new(rng.random(), rng.random(), rng.random()) * 6.0 - 3.0;
            let target = Vec3::new(rng.random(), rng.random(), rng.random()) - 0.5;
            let mut d = target - o;
            // Some rays along an axis (zero components), some not of unit length (NDC).
            if i % 7 == 0 {
                d = Vec3::new(0.0, 0.0, d.z);
            } else if i % 5 == 0 {
                d *= 0.37;
            } else {
                d = d.normalize();
            }
            rays.push(o, d, 0.0, 20.0);
        }
        // Empty, a few isolated cells, a ball, the faces of every other block (where a jump
        // one step too far would land past a sample), and full.
        let n = g.occupied.len();
        for round in 0..5 {
            for (c, o) in g.occupied.iter_mut().enumerate() {
                let r = 37;
                let p = Vec3::new((c % r) as f32, (c / r % r) as f32, (c / (r * r)) as f32);
                *o = match round {
                    0 => false,
                    1 => c % 997 == 5,
                    2 => (p - Vec3::splat(20.0)).length() < 9.0,
                    3 => [p.x, p.y, p.z]
                        .iter()
                        .any(|&v| v as usize % 16 == 8 || v as usize % 16 == 15),
                    _ => true,
                };
            }
            let marched = g.march(&rays, 40, Some(round));
            let every = march_every_step(&g, &rays, 40, round);
            let per_ray: Vec<Vec<f32>> = marched
                .offsets
                .windows(2)
                .map(|w| marched.t[w[0] as usize..w[1] as usize].to_vec())
                .collect();
            assert_eq!(per_ray, every, "occupancy pattern {round} of {n} cells");
            if round > 0 {
                assert!(!marched.is_empty(), "pattern {round} meets no ray");
            }
        }
    }

    #[test]
    fn a_rebuild_forgets_the_fog_a_running_maximum_keeps() {
        let fog = |points: &[f32]| vec![5.0; points.len() / 3];
        let (mut kept, mut rebuilt) = (grid(), grid());
        kept.update(usize::MAX, 2, fog);
        rebuilt.update(usize::MAX, 2, fog);
        assert!(kept.occupied.iter().all(|&o| o), "fog fills the grid");
        kept.update(usize::MAX, 3, cube_density);
        rebuilt.rebuild(3, cube_density);
        // The running maximum still holds the fog (5 · 0.95 · 0.01 > 0.01)...
        assert!(kept.is_occupied(Vec3::splat(0.75)));
        // ...the rebuild holds the cube alone.
        assert_eq!(rebuilt.occupied.iter().filter(|&&o| o).count(), 27);
        assert!(rebuilt.is_occupied(Vec3::splat(0.35)));
    }

    #[test]
    fn decay_forgets_density_that_moved_away() {
        let mut g = grid();
        let moved = |points: &[f32]| -> Vec<f32> {
            let shifted: Vec<f32> = points.iter().map(|v| v - 0.4).collect();
            cube_density(&shifted)
        };
        for s in 0..100 {
            g.update(usize::MAX, 10 + s, moved);
        }
        assert!(
            !g.is_occupied(Vec3::splat(0.35)),
            "the old cube is still occupied"
        );
        assert!(
            g.is_occupied(Vec3::splat(0.75)),
            "the new cube is not occupied"
        );
        assert_eq!(g.occupied.iter().filter(|&&o| o).count(), 27);
    }

    #[test]
    fn field_points_on_the_device_are_the_hosts() {
        let device = burn::prelude::Device::flex();
        let g = OccupancyGrid::contracted(8, Contraction { radius: 1.5 });
        let mut rng = SmallRng::seed_from_u64(3);
        // Inside the cube, on its face, beyond it, and far away.
        let mut points = vec![
            Vec3::ZERO,
            Vec3::new(1.5, -0.2, 0.3),
            Vec3::new(-40.0, 2.0, 1.0),
        ];
        points.extend(
            (0..50).map(|_| (Vec3::new(rng.random(), rng.random(), rng.random()) - 0.5) * 8.0),
        );
        let flat: Vec<f32> = points.iter().flat_map(|p| p.to_array()).collect();
        let t = Tensor::<1>::from_floats(flat.as_slice(), &device).reshape([points.len(), 3]);
        let got = g.field_points(t).into_data().try_to_vec::<f32>().unwrap();
        for (p, q) in points.iter().zip(got.chunks_exact(3)) {
            let want = g.field_point(*p);
            assert!(
                (want - Vec3::new(q[0], q[1], q[2])).abs().max_element() < 1e-5,
                "{p}: {want} vs {q:?}"
            );
        }
        // A grid over a box evaluates the field at the points themselves.
        let plain = OccupancyGrid::new(4, Vec3::ZERO, Vec3::ONE, 0.1);
        let t = Tensor::<1>::from_floats(flat.as_slice(), &device).reshape([points.len(), 3]);
        assert_eq!(
            plain
                .field_points(t)
                .into_data()
                .try_to_vec::<f32>()
                .unwrap(),
            flat
        );
    }

    #[test]
    fn contracted_grids_march_to_the_far_background_in_lengthening_steps() {
        let c = Contraction { radius: 2.0 };
        let g = OccupancyGrid::contracted(32, c);
        let mut rays = Rays::default();
        rays.push(Vec3::new(0.5, 0.0, 0.0), Vec3::X, 0.0, 2000.0);
        let m = g.march(&rays, usize::MAX, None);
        // Inside the radius, the grid's step; beyond, steps that keep the contracted spacing.
        assert!((m.delta[0] - g.step).abs() < 1e-6);
        let last = m.len() - 1;
        assert!(
            m.t[last] > 500.0,
            "the march reaches the far background: {}",
            m.t[last]
        );
        assert!(m.delta[last] > 100.0 * g.step);
        // Samples stay evenly spaced in contracted space, and there are few of them.
        for w in m.t.windows(2).skip(5) {
            let (a, b) = (
                c.apply(Vec3::X * (0.5 + w[0])).x,
                c.apply(Vec3::X * (0.5 + w[1])).x,
            );
            assert!((b - a) < 2.0 * g.step, "contracted gap {}", b - a);
        }
        assert!(m.len() < 200, "{} samples", m.len());
        assert!(
            m.t.iter()
                .all(|&t| g.field_point(Vec3::X * (0.5 + t)).x < c.extent())
        );
    }
}
