//! A ray march's samples on the device, and what a render builds from them there: the points
//! the field is evaluated at and the padded `[rays, width]` layout they are composited in.
//!
//! Why on the device: the host built the padded layout itself, three `rays × width` arrays
//! (about 660,000 entries each for a NeRF step of 4,600 rays), and uploaded them with the
//! points, about 11 MB a step, where the samples themselves are three numbers each and the
//! layout follows from where each ray's samples start. On the CUDA stand-in that host work
//! was a third of a grid NeRF step's host time (issue 48, docs/measurements.md).

use burn::prelude::*;

use super::marched_samples::MarchedSamples;
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

/// The `[rays, width]` layout a render composites in: a ray's samples in its row, in order.
pub struct PaddedLayout {
    /// Index of each cell's sample, `rows` (one past the samples) where the row has ended,
    /// `[rays · width]`.
    pub index: Tensor<1, Int>,
    /// Distance of each cell; where the row has ended, its last sample's (the ray's `near`
    /// if it has none), so the depth of empty columns stays meaningful. `[rays, width]`.
    pub t: Tensor<2>,
    /// Length of each cell's sample, 0 where the row has ended. `[rays, width]`.
    pub delta: Tensor<2>,
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

    /// The padded layout `width` columns wide (at least the most samples of a ray), the rays'
    /// `near` distances `[R]` standing in for the depth of rays with no sample.
    pub fn padded(&self, near: &[f32], width: usize) -> PaddedLayout {
        let device = self.t.device();
        let rays = near.len();
        debug_assert_eq!(self.offsets.dims()[0], rays + 1);
        let start = self.offsets.clone().slice(0..rays).unsqueeze_dim::<2>(1);
        let end = self
            .offsets
            .clone()
            .slice(1..rays + 1)
            .unsqueeze_dim::<2>(1);
        let column = Tensor::<1, Int>::arange(0..width as i64, &device).unsqueeze_dim::<2>(0);
        // The sample each cell would hold, and whether its row still has one.
        let k = (start.clone() + column).expand([rays, width]);
        let end = end.expand([rays, width]);
        let inside = k.clone().lower(end.clone());
        let index = k
            .clone()
            .mask_fill(inside.clone().bool_not(), self.rows() as i64)
            .reshape([rays * width]);
        // Past a row's end, its last sample; rows with none read sample 0, then take `near`.
        let last = k
            .min_pair(end.clone() - 1)
            .clamp_min(0)
            .reshape([rays * width]);
        let empty = end.equal(start.expand([rays, width]));
        let near = Tensor::<1>::from_floats(near, &device)
            .unsqueeze_dim::<2>(1)
            .expand([rays, width]);
        let t = self
            .t
            .clone()
            .select(0, last.clone())
            .reshape([rays, width])
            .mask_where(empty, near);
        let delta = self
            .delta
            .clone()
            .select(0, last)
            .reshape([rays, width])
            .mask_fill(inside.bool_not(), 0.0);
        PaddedLayout { index, t, delta }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The layout as the host built it before: what [`DeviceSamples::padded`] must equal.
    fn host_layout(
        m: &MarchedSamples,
        rows: usize,
        near: &[f32],
        width: usize,
    ) -> (Vec<i64>, Vec<f32>, Vec<f32>) {
        let r = near.len();
        let mut index = vec![rows as i64; r * width];
        let mut t_pad = vec![0f32; r * width];
        let mut delta_pad = vec![0f32; r * width];
        for ray in 0..r {
            let (a, b) = (m.offsets[ray] as usize, m.offsets[ray + 1] as usize);
            for (j, k) in (a..b).enumerate() {
                index[ray * width + j] = k as i64;
                t_pad[ray * width + j] = m.t[k];
                delta_pad[ray * width + j] = m.delta[k];
            }
            let last = if b > a { m.t[b - 1] } else { near[ray] };
            for j in (b - a)..width {
                t_pad[ray * width + j] = last;
            }
        }
        (index, t_pad, delta_pad)
    }

    #[test]
    fn the_padded_layout_is_the_one_the_host_built() {
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
        let near = [0.25, 0.5, 0.75, 1.25, 1.5];
        let (rows, width) = (11, 7);
        let s = DeviceSamples::upload(&m, rows, &device);
        assert_eq!(s.rows(), rows);
        let got = s.padded(&near, width);
        let (index, t, delta) = host_layout(&m, rows, &near, width);
        assert_eq!(
            got.index
                .into_data()
                .convert::<i64>()
                .try_to_vec::<i64>()
                .unwrap(),
            index
        );
        assert_eq!(got.t.into_data().try_to_vec::<f32>().unwrap(), t);
        assert_eq!(got.delta.into_data().try_to_vec::<f32>().unwrap(), delta);
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
