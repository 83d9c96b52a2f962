//! NeRF + INS: a radiance field (the CIM: hash grid or NeRF MLP, with its colour head), an
//! optional coarse field for NeRF's hierarchical sampling, and, once stylization starts, a SIM
//! (style code + encoded position → style features) and an AM that fuses them into the
//! density and the features before the colour head.

use burn::prelude::*;
use ins_core::modules::color_head::{ColorHeadConfig, DirEncoding};
use ins_core::modules::field::{CimKind, Field, Geometry};
use ins_core::modules::grid_field::GridGeometryConfig;
use ins_core::modules::hash_grid::HashGridConfig;
use ins_core::modules::mlp_field::MlpGeometryConfig;
use ins_core::modules::radiance_am::{RadianceAm, RadianceAmConfig};
use ins_core::modules::sim::Sim;
use ins_core::modules::style_position::{StylePosition, StylePositionConfig, positional_sim};
use ins_core::train::{GroupSpec, Optimizable};

/// SIM and AM: what stylization adds to a pretrained field.
#[derive(Module, Debug)]
pub struct Stylizer {
    /// Style code (+ encoded position at layer 2) → style features.
    pub sim: Sim,
    /// Fuses style features into density and features.
    pub am: RadianceAm,
    /// The SIM's view of a position (octaves, and a texture grid where configured).
    pub position: StylePosition,
}

/// A NeRF's dense products in bf16 where the CPU has AVX-512 BF16 (and neither
/// `INS_DISABLE_BF16` nor `--precision f32` says otherwise), until the guard drops: its MLPs
/// are 64 wide, where bf16 products ran 1.5× as fast as f32 (`kernels::dense_bf16`). A
/// capture's pretraining and stylizing steps ran 15–25 % faster; the held-out PSNR over five
/// seeds and sizes moved by −0.05 dB on average (each pair within ±0.7 dB, as seeds differ),
/// the stylizing losses matched to four digits (docs/measurements.md).
fn products() -> ins_core::kernels::dense_bf16::Scope {
    ins_core::kernels::dense_bf16::scope(true)
}

/// The model of a NeRF run.
#[derive(Module, Debug)]
pub struct NerfModel {
    /// The content module and its colour head (the fine network of the MLP variant).
    pub field: Field,
    /// NeRF's coarse network (MLP variant only).
    pub coarse: Option<Field>,
    /// SIM + AM (stylization runs only).
    pub stylizer: Option<Stylizer>,
    /// The scene box `[min xyz, max xyz]` the field covers.
    #[module(skip)]
    pub aabb: [f32; 6],
}

/// Sizes of a NeRF model.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NerfArch {
    /// Content module.
    pub cim: CimKind,
    /// Hash grid (grid variant).
    pub log2_table: u32,
    /// Finest grid resolution (grid variant).
    pub max_resolution: u32,
}

fn field(arch: &NerfArch, aabb: [f32; 6], device: &Device) -> Field {
    match arch.cim {
        CimKind::Grid => {
            let g = GridGeometryConfig::new(
                HashGridConfig::new()
                    .with_log2_table(arch.log2_table)
                    .with_max_resolution(arch.max_resolution),
            )
            .init(aabb, device);
            let color = ColorHeadConfig::new(g.d_features(), DirEncoding::SphericalHarmonics)
                .with_d_hidden(64)
                .with_depth(2)
                .init(device);
            Field {
                geometry: Geometry::Grid(g),
                color,
            }
        }
        CimKind::Mlp => {
            let m = MlpGeometryConfig::new().init(device);
            let color = ColorHeadConfig::new(m.d_features(), DirEncoding::Fourier(4))
                .with_d_hidden(128)
                .with_depth(1)
                .init(device);
            Field {
                geometry: Geometry::Mlp(m),
                color,
            }
        }
    }
}

impl Optimizable for NerfModel {
    /// The field's geometry and colour, the coarse field of the MLP variant, then the stylizer's
    /// parts: the SIM, its texture grid where it has one, and the AM's density and colour
    /// branches (each its own group, so the density can be kept while the colour stylizes).
    fn groups(&self) -> Vec<GroupSpec> {
        let mut groups = vec![
            GroupSpec::new("geometry", &["field.geometry"]),
            GroupSpec::new("color", &["field.color"]),
        ];
        if self.coarse.is_some() {
            groups.push(GroupSpec::new("coarse", &["coarse"]));
        }
        if let Some(s) = &self.stylizer {
            groups.push(GroupSpec::new("sim", &["stylizer.sim"]));
            if s.position.grid.is_some() {
                groups.push(GroupSpec::new("texture", &["stylizer.position"]));
            }
            groups.push(GroupSpec::new("am_density", &["stylizer.am.density"]));
            groups.push(GroupSpec::new("am_color", &["stylizer.am.feature"]));
        }
        groups
    }
}

/// What the fine field gives at a set of points, for every style.
pub struct Evaluated {
    /// Activated density `[S, N]` (S = 1 without styles).
    pub density: Tensor<2>,
    /// Colour `[S, N, 3]`.
    pub rgb: Tensor<3>,
    /// Raw density after the AM `[S, N]` (the geometry loss compares it with a teacher's).
    pub raw: Tensor<2>,
}

impl NerfModel {
    /// A fresh model (no stylizer) for `arch` over the box `aabb`.
    pub fn new(arch: &NerfArch, aabb: [f32; 6], device: &Device) -> Self {
        Self {
            field: field(arch, aabb, device),
            coarse: (arch.cim == CimKind::Mlp).then(|| field(arch, aabb, device)),
            stylizer: None,
            aabb,
        }
    }

    /// Adds a fresh SIM and AM (AM = identity) for `n_styles` styles, the SIM seeing positions
    /// through `position`. The MLP variant follows the authors' sizes (AM feature branch of 4
    /// layers); the grid variant a 2-layer one.
    pub fn with_stylizer(
        mut self,
        n_styles: usize,
        sim_width: usize,
        position: &StylePositionConfig,
        device: &Device,
    ) -> Self {
        let (position, sim) = positional_sim(n_styles, sim_width, position, device);
        let feature_depth = if self.coarse.is_some() { 4 } else { 2 };
        let am = RadianceAmConfig::new(self.field.geometry.d_features(), sim_width)
            .with_d_hidden(sim_width)
            .with_feature_depth(feature_depth)
            .init(device);
        self.stylizer = Some(Stylizer { sim, am, position });
        self
    }

    /// Number of styles (0 without a stylizer).
    pub fn n_styles(&self) -> usize {
        self.stylizer.as_ref().map_or(0, |s| s.sim.n_styles())
    }

    /// Whether the density is the content module's alone: no stylizer, or the AM's density
    /// blend at λ = 1, which passes the content's through untouched (a stylization that kept
    /// the density). Renders then find where rays turn opaque before running the stylizer.
    pub fn density_is_geometry(&self) -> bool {
        self.stylizer
            .as_ref()
            .is_none_or(|st| st.am.density.lambda.val().into_scalar::<f32>() == 1.0)
    }

    /// Positions `[N, 3]` → `[-1, 1]³` over the scene box (the SIM's position input).
    fn unit_positions(&self, x: Tensor<2>) -> Tensor<2> {
        let a = self.aabb;
        let device = x.device();
        let c = Tensor::<1>::from_floats(
            [
                (a[0] + a[3]) / 2.0,
                (a[1] + a[4]) / 2.0,
                (a[2] + a[5]) / 2.0,
            ],
            &device,
        )
        .reshape([1, 3]);
        let s = Tensor::<1>::from_floats(
            [
                2.0 / (a[3] - a[0]),
                2.0 / (a[4] - a[1]),
                2.0 / (a[5] - a[2]),
            ],
            &device,
        )
        .reshape([1, 3]);
        (x - c) * s
    }

    /// Evaluates the fine field at `x [N, 3]` seen along directions encoded by the colour head
    /// (`ColorHead::encode_dirs`, `[N, d]`), under every style
    /// code of `codes [S, n_styles]` (or unstylized when `None` or without a stylizer). The
    /// content module runs once; only SIM, AM and colour run per style.
    pub fn evaluate(&self, x: Tensor<2>, dirs: Tensor<2>, codes: Option<Tensor<2>>) -> Evaluated {
        let geometry = self.geometry(x.clone());
        self.stylized(x, geometry, dirs, codes, false)
    }

    /// The content module's raw density `[N]` and features `[N, F]` at `x [N, 3]`.
    pub fn geometry(&self, x: Tensor<2>) -> (Tensor<1>, Tensor<2>) {
        let _products = products();
        self.field.geometry.forward(x)
    }

    /// [`Self::evaluate`] past the content module, for a field whose density is the content
    /// module's ([`Self::density_is_geometry`]: read first, to shade only where rays are
    /// still open): `raw [N]` and `features [N, F]` are the geometry's outputs at `x [N, 3]`.
    /// The AM's density branch is not run: its λ = 1 passes the content's density through
    /// untouched, and it was a seventh of a stylized sample's products.
    pub fn shade(
        &self,
        x: Tensor<2>,
        raw: Tensor<1>,
        features: Tensor<2>,
        dirs: Tensor<2>,
        codes: Option<Tensor<2>>,
    ) -> Evaluated {
        self.stylized(x, (raw, features), dirs, codes, true)
    }

    /// [`Self::evaluate`] from the geometry's outputs (raw density, features); `kept_density`:
    /// see [`Self::shade`].
    fn stylized(
        &self,
        x: Tensor<2>,
        (raw, features): (Tensor<1>, Tensor<2>),
        dirs: Tensor<2>,
        codes: Option<Tensor<2>>,
        kept_density: bool,
    ) -> Evaluated {
        let _products = products();
        let [n, _] = x.dims();
        let (Some(st), Some(codes)) = (&self.stylizer, codes) else {
            let density = self.field.geometry.activate(raw.clone());
            let rgb = self.field.color.forward(features, dirs);
            return Evaluated {
                density: density.reshape([1, n]),
                rgb: rgb.reshape([1, n, 3]),
                raw: raw.reshape([1, n]),
            };
        };
        let s = codes.dims()[0];
        let repeat2 = |t: Tensor<2>| -> Tensor<2> {
            let w = t.dims()[1];
            if s == 1 {
                t
            } else {
                t.unsqueeze_dim::<3>(0)
                    .expand([s, n, w])
                    .reshape([s * n, w])
            }
        };
        let pos = st.position.encode(self.unit_positions(x));
        let style = st.sim.forward_per_style(codes, pos);
        let raw_rep: Tensor<1> = repeat2(raw.reshape([n, 1])).reshape([s * n]);
        let (raw_s, feat_s) = if kept_density {
            (raw_rep, st.am.feature.forward(repeat2(features), style))
        } else {
            st.am.forward(raw_rep, repeat2(features), style)
        };
        let density = self.field.geometry.activate(raw_s.clone());
        let rgb = self.field.color.forward(feat_s, repeat2(dirs));
        Evaluated {
            density: density.reshape([s, n]),
            rgb: rgb.reshape([s, n, 3]),
            raw: raw_s.reshape([s, n]),
        }
    }
}
