//! Distance from a query to the nearest of a fixed set of points, through a uniform grid of
//! buckets searched in growing shells. Written here rather than taken from a k-d tree crate:
//! surface distances query points that lie on a surface at a known spacing, where a grid of
//! that spacing answers in a few buckets, and it costs the build nothing.

use std::collections::HashMap;

use glam::Vec3;

/// Points bucketed by a cubic grid of side `cell`.
#[derive(Debug, Clone)]
pub struct NearestPoints {
    points: Vec<Vec3>,
    cell: f32,
    /// Each occupied cell's range in `order`.
    buckets: HashMap<[i32; 3], (u32, u32)>,
    /// Indices into `points`, grouped by cell.
    order: Vec<u32>,
}

impl NearestPoints {
    /// Buckets `points` into cells of side `cell` (about their spacing answers fastest).
    pub fn new(points: Vec<Vec3>, cell: f32) -> Self {
        assert!(cell > 0.0 && cell.is_finite(), "cell size {cell}");
        let key = |p: Vec3| -> [i32; 3] { (p / cell).floor().as_ivec3().to_array() };
        let mut keyed: Vec<([i32; 3], u32)> = points
            .iter()
            .enumerate()
            .map(|(i, &p)| (key(p), i as u32))
            .collect();
        keyed.sort_unstable();
        let mut buckets = HashMap::new();
        let mut start = 0usize;
        while start < keyed.len() {
            let k = keyed[start].0;
            let end = start + keyed[start..].iter().take_while(|e| e.0 == k).count();
            buckets.insert(k, (start as u32, (end - start) as u32));
            start = end;
        }
        let order = keyed.into_iter().map(|(_, i)| i).collect();
        Self {
            points,
            cell,
            buckets,
            order,
        }
    }

    /// How many points are held.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether no point is held.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The distance from `q` to the nearest point, if one lies within `max_distance`.
    pub fn nearest_within(&self, q: Vec3, max_distance: f32) -> Option<f32> {
        let c = (q / self.cell).floor().as_ivec3();
        // Every point outside the shells searched so far is at least `r · cell` away from q.
        let shells = (max_distance / self.cell).ceil() as i32 + 1;
        let mut best = f32::INFINITY;
        for r in 0..=shells {
            for dz in -r..=r {
                for dy in -r..=r {
                    // On the shell's inner rows only its two x ends are new.
                    let on_face = dz.abs() == r || dy.abs() == r;
                    let step = if on_face || r == 0 {
                        1
                    } else {
                        (2 * r) as usize
                    };
                    for dx in (-r..=r).step_by(step.max(1)) {
                        let k = [c.x + dx, c.y + dy, c.z + dz];
                        if let Some(&(start, len)) = self.buckets.get(&k) {
                            for &i in &self.order[start as usize..(start + len) as usize] {
                                best = best.min(self.points[i as usize].distance_squared(q));
                            }
                        }
                    }
                }
            }
            let reach = r as f32 * self.cell;
            if best <= reach * reach {
                break;
            }
        }
        let d = best.sqrt();
        (d <= max_distance).then_some(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::SmallRng;
    use rand::{Rng, SeedableRng};

    fn brute(points: &[Vec3], q: Vec3) -> f32 {
        points
            .iter()
            .map(|p| p.distance(q))
            .fold(f32::INFINITY, f32::min)
    }

    #[test]
    fn matches_a_brute_force_search() {
        let mut rng = SmallRng::seed_from_u64(3);
        let mut v = || Vec3::new(rng.random(), rng.random(), rng.random()) * 2.0 - 1.0;
        let points: Vec<Vec3> = (0..2000).map(|_| v()).collect();
        let queries: Vec<Vec3> = (0..300).map(|_| v() * 1.5).collect();
        for cell in [0.02f32, 0.1, 0.7] {
            let grid = NearestPoints::new(points.clone(), cell);
            for &q in &queries {
                let want = brute(&points, q);
                for cap in [0.05f32, 0.2, 3.0] {
                    let got = grid.nearest_within(q, cap);
                    if want <= cap {
                        let d = got.unwrap_or_else(|| panic!("{q} cell {cell} cap {cap}"));
                        assert!((d - want).abs() < 1e-6, "{d} against {want}");
                    } else {
                        assert_eq!(got, None, "{q}: {want} beyond {cap}");
                    }
                }
            }
        }
    }

    #[test]
    fn an_empty_set_has_nothing_near() {
        let grid = NearestPoints::new(Vec::new(), 0.1);
        assert!(grid.is_empty());
        assert_eq!(grid.nearest_within(Vec3::ZERO, 10.0), None);
    }
}
