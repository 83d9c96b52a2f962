//! The view-dependent colour head of a radiance field: features and an encoded view direction
//! → RGB in [0, 1].

use burn::prelude::*;
use serde::{Deserialize, Serialize};

use super::encoding::FourierEncoding;
use super::mlp::RgbMlp;
use super::sh::{spherical_harmonics, spherical_harmonics_host};

/// How the view direction enters the colour head.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DirEncoding {
    /// Spherical harmonics up to degree 3 (16 values; instant-ngp).
    SphericalHarmonics,
    /// NeRF's positional encoding with this many octaves (3·(1+2n) values; NeRF uses 4).
    Fourier(usize),
}

impl DirEncoding {
    /// Width of the encoding.
    pub fn d_out(&self) -> usize {
        match self {
            Self::SphericalHarmonics => 16,
            Self::Fourier(n) => FourierEncoding::new(*n).d_out(3),
        }
    }

    /// `dirs [N, 3]` (unit) → `[N, d_out]`.
    pub fn encode(&self, dirs: Tensor<2>) -> Tensor<2> {
        match self {
            Self::SphericalHarmonics => spherical_harmonics(dirs),
            Self::Fourier(n) => FourierEncoding::new(*n).encode(dirs),
        }
    }

    /// The same on the host, for directions that are data (no gradient): `dirs` is `N·3`,
    /// the result `N·d_out`. Computing it here spares the device dozens of tiny ops per step.
    pub fn encode_host(&self, dirs: &[f32]) -> Vec<f32> {
        let d_out = self.d_out();
        let mut out = Vec::with_capacity(dirs.len() / 3 * d_out);
        for d in dirs.chunks_exact(3) {
            match self {
                Self::SphericalHarmonics => {
                    out.extend(spherical_harmonics_host([d[0], d[1], d[2]]))
                }
                Self::Fourier(n) => {
                    out.extend_from_slice(d);
                    for k in 0..*n {
                        let f = (1u64 << k) as f32;
                        out.extend(d.iter().map(|v| (v * f).sin()));
                        out.extend(d.iter().map(|v| (v * f).cos()));
                    }
                }
            }
        }
        out
    }
}

/// Configuration of a [`ColorHead`].
#[derive(Config, Debug)]
pub struct ColorHeadConfig {
    /// Width of the incoming features.
    pub d_features: usize,
    /// View-direction encoding.
    pub dirs: DirEncoding,
    /// Hidden width.
    #[config(default = 64)]
    pub d_hidden: usize,
    /// Hidden layers (ReLU), before the linear RGB layer.
    #[config(default = 2)]
    pub depth: usize,
}

/// `[features, enc(dir)]` → ReLU layers → sigmoid RGB.
#[derive(Module, Debug)]
pub struct ColorHead {
    /// Hidden ReLU layers and the linear RGB layer.
    pub mlp: RgbMlp,
    /// View-direction encoding.
    #[module(skip)]
    pub dirs: DirEncoding,
}

impl ColorHeadConfig {
    /// Builds the head.
    pub fn init(&self, device: &Device) -> ColorHead {
        let d_in = self.d_features + self.dirs.d_out();
        ColorHead {
            mlp: RgbMlp::new(d_in, self.d_hidden, self.depth, device),
            dirs: self.dirs,
        }
    }
}

impl ColorHead {
    /// Encoded view directions `[N, d_out]` of unit directions `dirs` (`N·3`, host data).
    pub fn encode_dirs(&self, dirs: &[f32], device: &Device) -> Tensor<2> {
        let n = dirs.len() / 3;
        Tensor::<1>::from_floats(self.dirs.encode_host(dirs).as_slice(), device)
            .reshape([n, self.dirs.d_out()])
    }

    /// `features [N, F]`, encoded view directions `[N, d_out]` (see
    /// [`ColorHead::encode_dirs`] or [`DirEncoding::encode`]) → RGB `[N, 3]`.
    pub fn forward(&self, features: Tensor<2>, encoded_dirs: Tensor<2>) -> Tensor<2> {
        self.mlp
            .forward(Tensor::cat(vec![features, encoded_dirs], 1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn host_fourier_encoding_matches_the_tensor_one() {
        let d = Device::flex();
        let v = [0.36f32, -0.48, 0.8];
        let enc = DirEncoding::Fourier(4);
        let t = enc
            .encode(Tensor::<2>::from_floats([v], &d))
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        let h = enc.encode_host(&v);
        assert_eq!(t.len(), h.len());
        for (a, b) in t.iter().zip(&h) {
            assert!((a - b).abs() < 1e-6);
        }
    }
}
