//! How far a reconstructed surface lies from a reference one, the way DTU's benchmark and
//! NeuS's evaluation score meshes: points drawn evenly over the mesh, each one's distance to
//! the nearest reference point (accuracy) and each reference point's to the nearest mesh point
//! (completeness), each a mean over the distances under a cap (beyond it a point is counted
//! as an outlier, not averaged), their mean the Chamfer distance; and the shares within a
//! threshold (precision, recall, their F-score, as Tanks and Temples reports).

use glam::Vec3;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use serde::Serialize;

use super::nearest_points::NearestPoints;
use super::triangle_mesh::Mesh;

/// `n` points drawn uniformly by area over `mesh`'s triangles (seeded, so a score repeats).
/// Empty for a mesh without area.
pub fn sample_surface(mesh: &Mesh, n: usize, seed: u64) -> Vec<Vec3> {
    let corners = |t: &[u32; 3]| t.map(|i| Vec3::from_array(mesh.vertices[i as usize]));
    let mut cumulative = Vec::with_capacity(mesh.triangles.len());
    let mut total = 0.0f64;
    for t in &mesh.triangles {
        let [a, b, c] = corners(t);
        total += 0.5 * (b - a).cross(c - a).length() as f64;
        cumulative.push(total);
    }
    if total <= 0.0 || n == 0 {
        return Vec::new();
    }
    let mut rng = SmallRng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let u: f64 = rng.random::<f64>() * total;
            let i = cumulative
                .partition_point(|&c| c < u)
                .min(cumulative.len() - 1);
            let [a, b, c] = corners(&mesh.triangles[i]);
            // Uniform over the triangle: fold the unit square's upper half onto the lower.
            let (mut s, mut t): (f32, f32) = (rng.random(), rng.random());
            if s + t > 1.0 {
                (s, t) = (1.0 - s, 1.0 - t);
            }
            a + (b - a) * s + (c - a) * t
        })
        .collect()
}

/// The scores of a surface against a reference, in the units of the points given.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SurfaceDistance {
    /// Mean distance from the surface's points to the reference, over those within the cap.
    pub accuracy: f64,
    /// Mean distance from the reference's points to the surface, over those within the cap.
    pub completeness: f64,
    /// The mean of the two (DTU's "overall").
    pub chamfer: f64,
    /// Share of the surface's points within the threshold of the reference.
    pub precision: f64,
    /// Share of the reference's points within the threshold of the surface.
    pub recall: f64,
    /// Harmonic mean of precision and recall.
    pub fscore: f64,
    /// Share of the surface's points beyond the cap (floaters, parts the reference lacks).
    pub surface_outliers: f64,
    /// Share of the reference's points beyond the cap (parts the surface misses).
    pub reference_outliers: f64,
    /// The distance beyond which a point is an outlier.
    pub max_distance: f64,
    /// The distance precision and recall count within.
    pub threshold: f64,
}

/// The distances of each of `from` to the nearest of `to`, `None` beyond `max_distance`.
fn distances(from: &[Vec3], to: &NearestPoints, max_distance: f32) -> Vec<Option<f32>> {
    from.par_iter()
        .map(|&p| to.nearest_within(p, max_distance))
        .collect()
}

/// (mean within the cap, share within `threshold`, share beyond the cap).
fn summarize(d: &[Option<f32>], threshold: f32) -> (f64, f64, f64) {
    let n = d.len().max(1) as f64;
    let kept: Vec<f64> = d.iter().flatten().map(|&x| x as f64).collect();
    let mean = if kept.is_empty() {
        f64::NAN
    } else {
        kept.iter().sum::<f64>() / kept.len() as f64
    };
    let within = d.iter().flatten().filter(|&&x| x <= threshold).count() as f64;
    (mean, within / n, (d.len() - kept.len()) as f64 / n)
}

/// Scores the points `surface` (drawn over a mesh by [`sample_surface`]) against the points
/// `reference`. Both should be dense against `threshold`; `spacing` (about the reference's
/// point spacing) sizes the search grids.
pub fn surface_distance(
    surface: &[Vec3],
    reference: &[Vec3],
    max_distance: f32,
    threshold: f32,
    spacing: f32,
) -> SurfaceDistance {
    let cell = spacing.max(max_distance / 64.0).max(f32::MIN_POSITIVE);
    let to_reference = NearestPoints::new(reference.to_vec(), cell);
    let to_surface = NearestPoints::new(surface.to_vec(), cell);
    let (accuracy, precision, surface_outliers) =
        summarize(&distances(surface, &to_reference, max_distance), threshold);
    let (completeness, recall, reference_outliers) =
        summarize(&distances(reference, &to_surface, max_distance), threshold);
    let fscore = if precision + recall > 0.0 {
        2.0 * precision * recall / (precision + recall)
    } else {
        0.0
    };
    SurfaceDistance {
        accuracy,
        completeness,
        chamfer: 0.5 * (accuracy + completeness),
        precision,
        recall,
        fscore,
        surface_outliers,
        reference_outliers,
        max_distance: max_distance as f64,
        threshold: threshold as f64,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit square in the plane z = `z`, as two triangles.
    fn square(z: f32) -> Mesh {
        Mesh {
            vertices: vec![[0.0, 0.0, z], [1.0, 0.0, z], [1.0, 1.0, z], [0.0, 1.0, z]],
            normals: vec![[0.0, 0.0, 1.0]; 4],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        }
    }

    fn grid_points(z: f32, n: usize) -> Vec<Vec3> {
        (0..n)
            .flat_map(|i| {
                (0..n).map(move |j| {
                    Vec3::new(i as f32 / (n - 1) as f32, j as f32 / (n - 1) as f32, z)
                })
            })
            .collect()
    }

    #[test]
    fn samples_cover_the_mesh_evenly() {
        // A 1×1 square and a 1×3 one: three quarters of the points on the larger.
        let mut mesh = square(0.0);
        mesh.vertices.extend([
            [0.0, 0.0, 1.0],
            [3.0, 0.0, 1.0],
            [3.0, 1.0, 1.0],
            [0.0, 1.0, 1.0],
        ]);
        mesh.normals.extend([[0.0, 0.0, 1.0]; 4]);
        mesh.triangles.extend([[4, 5, 6], [4, 6, 7]]);
        let points = sample_surface(&mesh, 8000, 1);
        assert_eq!(points.len(), 8000);
        let upper = points.iter().filter(|p| p.z > 0.5).count() as f64 / 8000.0;
        assert!((upper - 0.75).abs() < 0.02, "{upper}");
        assert!(
            points
                .iter()
                .all(|p| p.x >= 0.0 && p.y >= 0.0 && p.y <= 1.0 && p.x <= 3.0)
        );
        assert!(sample_surface(&Mesh::default(), 10, 1).is_empty());
    }

    #[test]
    fn a_shifted_surface_scores_its_shift() {
        let reference = grid_points(0.0, 101);
        let same = surface_distance(
            &sample_surface(&square(0.0), 20000, 2),
            &reference,
            0.2,
            0.02,
            0.01,
        );
        // Off the reference's grid by at most half its 0.01 spacing.
        assert!(same.chamfer < 0.005 && same.fscore > 0.999, "{same:?}");
        let shifted = surface_distance(
            &sample_surface(&square(0.05), 20000, 2),
            &reference,
            0.2,
            0.02,
            0.01,
        );
        assert!((shifted.accuracy - 0.05).abs() < 0.002, "{shifted:?}");
        assert!((shifted.completeness - 0.05).abs() < 0.002, "{shifted:?}");
        assert_eq!(shifted.fscore, 0.0);
        // Beyond the cap, everything is an outlier and nothing is averaged.
        let far = surface_distance(
            &sample_surface(&square(0.5), 1000, 2),
            &reference,
            0.2,
            0.02,
            0.01,
        );
        assert_eq!((far.surface_outliers, far.reference_outliers), (1.0, 1.0));
        assert!(far.chamfer.is_nan());
    }

    #[test]
    fn a_missing_half_costs_completeness_not_accuracy() {
        let reference = grid_points(0.0, 101);
        let half = Mesh {
            vertices: vec![
                [0.0, 0.0, 0.0],
                [0.5, 0.0, 0.0],
                [0.5, 1.0, 0.0],
                [0.0, 1.0, 0.0],
            ],
            ..square(0.0)
        };
        let d = surface_distance(
            &sample_surface(&half, 20000, 3),
            &reference,
            1.0,
            0.02,
            0.01,
        );
        assert!(d.accuracy < 0.005, "{d:?}");
        // The missing half's points lie 0 to 0.5 from the mesh: 0.125 on average over all.
        assert!((d.completeness - 0.127).abs() < 0.01, "{d:?}");
        assert!(
            (d.recall - 0.52).abs() < 0.02 && d.precision > 0.999,
            "{d:?}"
        );
    }
}
