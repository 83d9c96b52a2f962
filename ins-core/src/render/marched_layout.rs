//! A ray march's samples on the device, and what a render builds from them there: the points
//! the field is evaluated at and where each ray's samples lie for compositing.
//!
//! Why on the device: the host built a padded `[rays, width]` layout itself, three arrays of
//! about 660,000 entries each for a NeRF step of 4,600 rays, and uploaded them with the points,
//! about 11 MB a step, where the samples themselves are three numbers each. On the CUDA
//! stand-in that host work was a third of a grid NeRF step's host time (issue 48,
//! docs/measurements.md). Since then the renders composite each ray's run of samples without
//! any padded layout (`volume::composite_ragged`).

use burn::prelude::*;

use super::marched_samples::MarchedSamples;
use super::volume::RaySpans;
use crate::shape_buckets::pad_rows;

/// The samples of a [`MarchedSamples`], uploaded once: each sample's ray, distance and length,
/// padded to `rows` by repeating the first sample (the bucketed sizes of GPUs), and where each
/// ray's samples start.
pub struct DeviceSamples {
    /// Ray of each sample, `[rows]`.
    pub ray: Tensor<1, Int>,
    /// Distance along its ray, `[rows]`.
    pub t: Tensor<1>,
    /// Length of ray it stands for, `[rows]`.
    pub delta: Tensor<1>,
    /// First sample of each ray and one past the last, `[rays + 1]`.
    offsets: Tensor<1, Int>,
}

impl DeviceSamples {
    /// Uploads `m` (at least one sample), padded to `rows ≥ m.len()`.
    pub fn upload(m: &MarchedSamples, rows: usize, device: &Device) -> Self {
        assert!(
            !m.is_empty() && rows >= m.len(),
            "{} samples into {rows} rows",
            m.len()
        );
        let mut ray: Vec<i64> = m.ray.iter().map(|&i| i64::from(i)).collect();
        pad_rows(&mut ray, 1, rows);
        let padded = |v: &[f32]| {
            let mut v = v.to_vec();
            pad_rows(&mut v, 1, rows);
            Tensor::<1>::from_floats(v.as_slice(), device)
        };
        let offsets: Vec<i64> = m.offsets.iter().map(|&o| i64::from(o)).collect();
        let n_offsets = offsets.len();
        Self {
            ray: Tensor::from_data(TensorData::new(ray, [rows]), device),
            t: padded(&m.t),
            delta: padded(&m.delta),
            offsets: Tensor::from_data(TensorData::new(offsets, [n_offsets]), device),
        }
    }

    /// Where each ray's samples are, for [`composite_ragged`](super::volume::composite_ragged).
    pub fn spans(&self) -> RaySpans {
        RaySpans {
            t: self.t.clone(),
            delta: self.delta.clone(),
            offsets: self.offsets.clone().float(),
        }
    }

    /// Rows, padding included.
    pub fn rows(&self) -> usize {
        self.ray.dims()[0]
    }

    /// The point of each sample, `origins[ray] + t · directions[ray]`, `[rows, 3]`, from the
    /// rays' `origins` and `directions` `[R, 3]`.
    pub fn points(&self, origins: Tensor<2>, directions: Tensor<2>) -> Tensor<2> {
        let t = self.t.clone().unsqueeze_dim::<2>(1);
        origins.select(0, self.ray.clone()) + directions.select(0, self.ray.clone()) * t
    }

    /// The row of `per_ray [R, ...]` of each sample's ray, `[rows, ...]`.
    pub fn per_sample<const D: usize>(&self, per_ray: Tensor<D>) -> Tensor<D> {
        per_ray.select(0, self.ray.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spans_points_and_per_ray_rows_are_the_samples() {
        let device = Device::flex();
        // Five rays: the first and the fourth without samples, the third the widest.
        let counts = [0usize, 2, 5, 0, 1];
        let mut m = MarchedSamples {
            offsets: vec![0],
            ..Default::default()
        };
        for (ray, &c) in counts.iter().enumerate() {
            for j in 0..c {
                m.ray.push(ray as u32);
                m.t.push(1.0 + ray as f32 + 0.1 * j as f32);
                m.delta.push(0.01 * (j + 1) as f32);
            }
            m.offsets.push(m.t.len() as u32);
        }
        let rows = 11;
        let s = DeviceSamples::upload(&m, rows, &device);
        assert_eq!(s.rows(), rows);
        let spans = s.spans();
        let host = |t: Tensor<1>| t.into_data().try_to_vec::<f32>().unwrap();
        let offsets: Vec<f32> = m.offsets.iter().map(|&o| o as f32).collect();
        assert_eq!(host(spans.offsets), offsets);
        // The padding repeats the first sample; no ray's span reaches it.
        let padded = |v: &[f32]| [v, &vec![v[0]; rows - v.len()]].concat();
        assert_eq!(host(spans.t), padded(&m.t));
        assert_eq!(host(spans.delta), padded(&m.delta));
        // Each sample's point and a per-ray value, padding repeating the first sample.
        let o = Tensor::<2>::from_floats([[0.0, 0.0, 0.0]; 5], &device)
            + Tensor::<1>::from_floats([0.0, 1.0, 2.0, 3.0, 4.0], &device).unsqueeze_dim(1);
        let d = Tensor::<2>::from_floats([[1.0, 0.0, -1.0]; 5], &device);
        let p = s
            .points(o.clone(), d)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        let mut want = Vec::new();
        let firsts = std::iter::repeat_n(0, rows - m.len());
        for k in (0..m.len()).chain(firsts) {
            let (ray, t) = (m.ray[k] as f32, m.t[k]);
            want.extend([ray + t, ray, ray - t]);
        }
        assert_eq!(p, want);
        let per = s.per_sample(o).into_data().try_to_vec::<f32>().unwrap();
        assert_eq!(per.len(), rows * 3);
        assert_eq!(per[..3], [1.0, 1.0, 1.0]);
        assert_eq!(per[rows * 3 - 3..], [1.0, 1.0, 1.0]);
    }
}
