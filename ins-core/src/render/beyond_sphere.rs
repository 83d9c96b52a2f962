//! What lies beyond the unit sphere (NeRF++'s background): a radiance field over space outside
//! the sphere, seen through mip-NeRF 360's contraction `p ↦ (2 − 1/|p|) p/|p|` (the shell
//! between radii 1 and 2 holds everything out to infinity), sampled evenly in inverse distance
//! from where each ray leaves the sphere and composited to full opacity. An SDF trained on
//! photos without masks needs it: without a place for the room behind the object, the colour
//! loss builds that room inside the sphere, in front of the cameras.

use burn::prelude::*;

use super::samplers::stratified;
use super::volume::weights;
use crate::modules::field::Field;

/// A spacing long enough that the last sample of a ray is opaque whatever its density: the
/// background has nothing behind it.
const LAST_SPACING: f32 = 1e4;

/// Inverse distance of the farthest sample over the nearest's (its samples stop short of
/// infinity, where the contraction's radius 2 is).
const FAR_FRACTION: f32 = 1e-3;

/// Points `p [N, 3]` outside the unit sphere contracted into the shell of radii 1 to 2 (those
/// inside, which samples here never are, kept as they are).
pub fn contract(p: Tensor<2>) -> Tensor<2> {
    let [n, _] = p.dims();
    let r = p.clone().square().sum_dim(1).sqrt().clamp_min(1.0); // [N, 1]
    let scale = r.clone().recip().neg().add_scalar(2.0) / r;
    p * scale.expand([n, 3])
}

/// Colour `[R, 3]` of what lies beyond the unit sphere along rays `origins`, unit `dirs`
/// (`[R, 3]`), each from distance `start [R]` on (where it leaves the sphere, or its origin
/// for a ray that misses it): `samples` positions stratified in inverse distance (jittered by
/// `seed`, at bin centres without), the field's density over the contracted spacings, the
/// last sample opaque.
pub fn render_beyond_unit_sphere(
    field: &Field,
    origins: Tensor<2>,
    dirs: Tensor<2>,
    start: Tensor<1>,
    samples: usize,
    seed: Option<u64>,
) -> Tensor<2> {
    let [r, _] = origins.dims();
    let n = samples.max(2);
    let device = origins.device();
    // Stratified fractions of each ray's stretch, increasing along each row.
    let u = stratified(
        Tensor::zeros([r], &device),
        Tensor::ones([r], &device),
        n,
        seed,
    );
    // Inverse distance from 1/start down to FAR_FRACTION/start.
    let inv_start = start.clamp_min(1e-3).recip().reshape([r, 1]).expand([r, n]);
    let inv = inv_start * u.mul_scalar(FAR_FRACTION - 1.0).add_scalar(1.0);
    let t = inv.recip();
    let o = origins.reshape([r, 1, 3]).expand([r, n, 3]);
    let d = dirs.clone().reshape([r, 1, 3]).expand([r, n, 3]);
    let p = (o + d * t.reshape([r, n, 1]).expand([r, n, 3])).reshape([r * n, 3]);
    let c = contract(p).reshape([r, n, 3]);
    let gaps = (c.clone().slice([0..r, 1..n, 0..3]) - c.clone().slice([0..r, 0..n - 1, 0..3]))
        .square()
        .sum_dim(2)
        .sqrt()
        .reshape([r, n - 1]);
    let delta = Tensor::cat(vec![gaps, Tensor::full([r, 1], LAST_SPACING, &device)], 1);
    let v: Tensor<2> = dirs
        .reshape([r, 1, 3])
        .expand([r, n, 3])
        .reshape([r * n, 3]);
    let encoded = field.color.dirs.encode(v);
    let (sigma, rgb) = field.forward(c.reshape([r * n, 3]), encoded);
    let w = weights(sigma.reshape([r, n]), delta);
    // The weights sum to 1 up to rounding; dividing makes the background exactly opaque.
    let total = w.clone().sum_dim(1).clamp_min(1e-6);
    let colour: Tensor<2> = (w.unsqueeze_dim::<3>(2) * rgb.reshape([r, n, 3]))
        .sum_dim(1)
        .reshape([r, 3]);
    colour / total.expand([r, 3])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::modules::color_head::{ColorHeadConfig, DirEncoding};
    use crate::modules::field::Geometry;
    use crate::modules::grid_field::GridGeometryConfig;
    use crate::modules::hash_grid::HashGridConfig;

    fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap()
    }

    #[test]
    fn contraction_keeps_the_sphere_and_squeezes_infinity_into_radius_two() {
        let d = Device::flex();
        let p = Tensor::<2>::from_floats([[0.0, 0.0, 1.0], [3.0, 0.0, 4.0], [0.0, -1e6, 0.0]], &d);
        let c = values(contract(p));
        assert!((c[2] - 1.0).abs() < 1e-6);
        // |p| = 5 → radius 2 − 1/5 = 1.8 along (0.6, 0, 0.8).
        assert!((c[3] - 1.08).abs() < 1e-5 && (c[5] - 1.44).abs() < 1e-5);
        assert!((c[7] + 2.0).abs() < 1e-5);
    }

    #[test]
    fn the_background_is_opaque_and_shows_the_fields_colour() {
        let d = Device::flex();
        d.seed(3);
        let geometry = GridGeometryConfig::new(
            HashGridConfig::new()
                .with_log2_table(12)
                .with_max_resolution(32),
        )
        .init([-2.0, -2.0, -2.0, 2.0, 2.0, 2.0], &d);
        let color =
            ColorHeadConfig::new(geometry.d_features(), DirEncoding::SphericalHarmonics).init(&d);
        let field = Field {
            geometry: Geometry::Grid(geometry),
            color,
        };
        let origins = Tensor::<2>::from_floats([[0.0, 0.0, 3.0], [0.0, 2.0, 3.0]], &d);
        let dirs = Tensor::<2>::from_floats([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]], &d);
        // The first ray leaves the unit sphere at t = 4; the second misses it.
        let start = Tensor::<1>::from_floats([4.0, 0.0], &d);
        let rgb = values(render_beyond_unit_sphere(
            &field,
            origins.clone(),
            dirs.clone(),
            start.clone(),
            16,
            None,
        ));
        assert_eq!(rgb.len(), 6);
        assert!(rgb.iter().all(|&c| c > 0.0 && c < 1.0), "{rgb:?}");
        // Jittered samples move the colour of a smooth fresh field only a little.
        let jittered = values(render_beyond_unit_sphere(
            &field,
            origins,
            dirs,
            start,
            16,
            Some(7),
        ));
        let worst = rgb
            .iter()
            .zip(&jittered)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 0.05, "{worst}");
    }
}
