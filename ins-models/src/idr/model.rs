//! IDR + INS: an SDF network (the CIM: IDR's MLP or a hash grid), IDR's rendering network,
//! and, once stylization starts, a SIM (style code + encoded position → style features) and an
//! AM that fuses them into the SDF features the rendering network sees.

use burn::prelude::*;
use ins_core::modules::color_head::{ColorHeadConfig, DirEncoding};
use ins_core::modules::field::{Field, Geometry};
use ins_core::modules::grid_field::GridGeometryConfig;
use ins_core::modules::hash_grid::HashGridConfig;
use ins_core::modules::radiance_am::FeatureBlend;
use ins_core::modules::sdf::{SdfGridConfig, SdfMlpConfig, SdfNet};
use ins_core::modules::sim::Sim;
use ins_core::modules::style_position::{StylePosition, StylePositionConfig, positional_sim};
use ins_core::modules::surface_color::{SurfaceColor, SurfaceColorConfig};
use ins_core::render::sdf_volume::Sharpness;
use ins_core::train::{GroupSpec, Optimizable};
use serde::{Deserialize, Serialize};

/// Which SDF network a run uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum SdfKind {
    /// Hash grid + small MLPs (fast on a CPU).
    #[default]
    Grid,
    /// IDR's 8×512 MLP (the paper's).
    Mlp,
}

impl std::str::FromStr for SdfKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "grid" => Ok(Self::Grid),
            "mlp" | "idr" => Ok(Self::Mlp),
            _ => Err(format!("unknown --sdf {s:?} (expected grid or mlp)")),
        }
    }
}

impl std::fmt::Display for SdfKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Grid => "grid",
            Self::Mlp => "mlp",
        })
    }
}

/// How pretraining renders the SDF.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum SdfRenderer {
    /// IDR: sphere-trace the first surface point, colour there, masks through the closest
    /// approach (runs from before the volume renderer).
    #[default]
    Surface,
    /// NeuS: the SDF as a volume with a learnable sharpness, every sample along the ray
    /// coloured and weighted.
    Volume,
}

impl std::str::FromStr for SdfRenderer {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "surface" | "idr" => Ok(Self::Surface),
            "volume" | "neus" => Ok(Self::Volume),
            _ => Err(format!(
                "unknown --renderer {s:?} (expected volume or surface)"
            )),
        }
    }
}

impl std::fmt::Display for SdfRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Surface => "surface",
            Self::Volume => "volume",
        })
    }
}

/// SIM and feature AM.
#[derive(Module, Debug)]
pub struct SurfaceStylizer {
    /// Style code (+ encoded position) → style features.
    pub sim: Sim,
    /// Fuses them into the SDF features (γ starts at 1: identity).
    pub am: FeatureBlend,
    /// The SIM's view of a position (octaves, and a texture grid where configured).
    pub position: StylePosition,
}

/// The model of an IDR run.
#[derive(Module, Debug)]
pub struct IdrModel {
    /// Signed distance and features.
    pub sdf: SdfNet,
    /// Surface colour.
    pub color: SurfaceColor,
    /// SIM + AM (stylization runs only).
    pub stylizer: Option<SurfaceStylizer>,
    /// The volume renderer's sharpness (runs pretrained as a volume only).
    pub sharpness: Option<Sharpness>,
    /// What lies beyond the unit sphere (volume runs without masks only): a radiance field
    /// over contracted space, composited behind the SDF.
    pub background: Option<Field>,
}

impl Optimizable for IdrModel {
    /// The surface and its colour, then the stylizer's parts: the SIM, its texture grid where it
    /// has one, the AM's layers and its blend (each its own group).
    fn groups(&self) -> Vec<GroupSpec> {
        let mut groups = vec![
            GroupSpec::new("sdf", &["sdf"]),
            GroupSpec::new("color", &["color"]),
        ];
        if self.sharpness.is_some() {
            groups.push(GroupSpec::new("sharpness", &["sharpness"]));
        }
        if self.background.is_some() {
            groups.push(GroupSpec::new("background", &["background"]));
        }
        if let Some(s) = &self.stylizer {
            groups.push(GroupSpec::new("sim", &["stylizer.sim"]));
            if s.position.grid.is_some() {
                groups.push(GroupSpec::new("texture", &["stylizer.position"]));
            }
            groups.push(GroupSpec::new("am", &["stylizer.am.layers"]));
            groups.push(GroupSpec::new("blend", &["stylizer.am.gamma"]));
        }
        groups
    }
}

/// The volume renderer's starting sharpness, `s = exp(10 · 0.3) ≈ 20` (NeuS, instant-nsr-pl):
/// a band about a tenth of the unit sphere wide, which the surface narrows as it settles.
const INITIAL_VARIANCE: f32 = 0.3;

/// Sizes of an IDR model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct IdrArch {
    /// SDF network.
    pub sdf: SdfKind,
    /// Radius of the initial sphere.
    pub radius: f64,
    /// `grid`: finest hash-encoding resolution.
    pub grid_max_resolution: u32,
    /// `grid`: log2 of the hash encoding's entries per level.
    #[serde(default = "default_grid_table")]
    pub grid_table: u32,
    /// Hidden width of the colour network (`grid`; the `mlp` SDF keeps IDR's).
    pub color_width: usize,
    /// Finest resolution of the colour network's appearance grid (0: none).
    #[serde(default)]
    pub color_grid: u32,
    /// How pretraining renders the SDF (a volume adds the learnable sharpness).
    #[serde(default)]
    pub renderer: SdfRenderer,
    /// Whether a radiance field beyond the unit sphere shows behind the SDF (NeRF++): what
    /// photos without masks need, the room behind the object having to live somewhere.
    #[serde(default)]
    pub background: bool,
}

/// The SDF grid's table before it could be chosen (run folders without `grid_table`).
pub const DEFAULT_GRID_TABLE: u32 = 17;

fn default_grid_table() -> u32 {
    DEFAULT_GRID_TABLE
}

impl IdrArch {
    /// A small volume-rendered grid SDF for unit tests (a 64 finest level, 16 wide colour, no
    /// appearance grid, no background field); tests change what they need with `..`.
    #[cfg(test)]
    pub(crate) fn small_volume() -> Self {
        IdrArch {
            sdf: SdfKind::Grid,
            radius: 0.5,
            grid_max_resolution: 64,
            grid_table: DEFAULT_GRID_TABLE,
            color_width: 16,
            color_grid: 0,
            renderer: SdfRenderer::Volume,
            background: false,
        }
    }

    /// The `grid` SDF's hash encoding.
    fn hash_grid(&self) -> HashGridConfig {
        HashGridConfig::new()
            .with_log2_table(self.grid_table)
            .with_base_resolution(16)
            .with_max_resolution(self.grid_max_resolution)
    }

    /// The colour network's appearance grid, when there is one. Its table is larger than the
    /// SDF's (2^19 entries a hashed level, 12.2 M parameters): texture needs the capacity, and a
    /// collision there blurs a colour rather than bending the surface.
    fn color_hash_grid(&self) -> Option<HashGridConfig> {
        (self.color_grid > 0).then(|| {
            HashGridConfig::new()
                .with_log2_table(19)
                .with_base_resolution(16)
                .with_max_resolution(self.color_grid)
        })
    }

    /// Checks the hash encodings against what the hash grid supports.
    pub fn validate(&self) -> Result<(), String> {
        if let Some(grid) = self.color_hash_grid() {
            grid.validate()
                .map_err(|e| format!("--color-grid {}: {e}", self.color_grid))?;
        }
        match self.sdf {
            SdfKind::Grid => self.hash_grid().validate().map_err(|e| {
                format!(
                    "--grid-max-resolution {} --grid-table {}: {e}",
                    self.grid_max_resolution, self.grid_table
                )
            }),
            SdfKind::Mlp => Ok(()),
        }
    }
}

/// The field beyond the unit sphere: a hash grid over the contracted shell (radii 1 to 2, in
/// the box of side 4) with instant-ngp's density network and a view-dependent colour head. A
/// panorama at a few hundred cells across is what photos of a room at 400 px resolve.
fn background_field(device: &Device) -> Field {
    let geometry = GridGeometryConfig::new(
        HashGridConfig::new()
            .with_log2_table(16)
            .with_max_resolution(256),
    )
    .init([-2.0, -2.0, -2.0, 2.0, 2.0, 2.0], device);
    let color = ColorHeadConfig::new(geometry.d_features(), DirEncoding::SphericalHarmonics)
        .with_d_hidden(64)
        .with_depth(2)
        .init(device);
    Field {
        geometry: Geometry::Grid(geometry),
        color,
    }
}

impl IdrModel {
    /// A fresh model: the SDF starts as a sphere of radius `arch.radius` inside the unit sphere.
    pub fn new(arch: &IdrArch, device: &Device) -> Self {
        let (sdf, color) = match arch.sdf {
            SdfKind::Mlp => {
                let s = SdfMlpConfig::new().with_radius(arch.radius).init(device);
                let net = SdfNet::Mlp(s);
                let c = SurfaceColorConfig::new(net.d_features())
                    .with_grid(arch.color_hash_grid())
                    .init(device);
                (net, c)
            }
            SdfKind::Grid => {
                let net = SdfNet::Grid(
                    SdfGridConfig::new(arch.hash_grid())
                        .with_radius(arch.radius)
                        .init(1.0, device),
                );
                // One octave of view direction: with the grid's sharper features, more octaves let
                // the colour fit each training view on its own and miss the views between them.
                // The direction reflected about the normal instead (Ref-NeRF's) fitted scan37's
                // metal worse, 20.73 dB held out against 21.40 (docs/measurements.md).
                let c = SurfaceColorConfig::new(net.d_features())
                    .with_grid(arch.color_hash_grid())
                    .with_d_hidden(arch.color_width)
                    .with_depth(2)
                    .with_dir_freqs(1)
                    .init(device);
                (net, c)
            }
        };
        Self {
            sdf,
            color,
            stylizer: None,
            sharpness: (arch.renderer == SdfRenderer::Volume)
                .then(|| Sharpness::new(INITIAL_VARIANCE, device)),
            background: arch.background.then(|| background_field(device)),
        }
    }

    /// Adds a fresh SIM and AM (identity) for `n_styles` styles, the SIM seeing positions
    /// through `position`; the AM blends the appearance grid's features too where
    /// `blend_grid` (and there is a grid): they hold the photos' finest texture, which would
    /// otherwise reach the colour as pretrained (scan37: texture transfer 0.72 / 0.92 over two
    /// seeds without, docs/measurements.md).
    pub fn with_stylizer(
        mut self,
        n_styles: usize,
        width: usize,
        position: &StylePositionConfig,
        blend_grid: bool,
        device: &Device,
    ) -> Self {
        let (position, sim) = positional_sim(n_styles, width, position, device);
        let grid = if blend_grid { self.color.d_grid() } else { 0 };
        let am = FeatureBlend::new(self.sdf.d_features() + grid, width, width, 2, device);
        self.stylizer = Some(SurfaceStylizer { sim, am, position });
        self
    }

    /// Number of styles (0 without a stylizer).
    pub fn n_styles(&self) -> usize {
        self.stylizer.as_ref().map_or(0, |s| s.sim.n_styles())
    }

    /// Colour at surface points `x [N, 3]` with normals `n [N, 3]`, seen along unit `dirs`,
    /// with SDF features `f [N, F]`, under each style code of `codes [S, n_styles]`: `[S, N, 3]`.
    pub fn shade(
        &self,
        x: Tensor<2>,
        n: Tensor<2>,
        dirs: Tensor<2>,
        f: Tensor<2>,
        codes: Option<Tensor<2>>,
    ) -> Tensor<3> {
        let [count, _] = x.dims();
        let (Some(st), Some(codes)) = (&self.stylizer, codes) else {
            return self.color.forward(x, n, dirs, f).reshape([1, count, 3]);
        };
        let s = codes.dims()[0];
        let rep = |t: Tensor<2>| -> Tensor<2> {
            let w = t.dims()[1];
            if s == 1 {
                t
            } else {
                t.unsqueeze_dim::<3>(0)
                    .expand([s, count, w])
                    .reshape([s * count, w])
            }
        };
        let pos = st.position.encode(x.clone());
        let style = st.sim.forward_per_style(codes, pos);
        // An AM wider than the SDF's features blends the appearance grid's with them.
        let d_am = st.am.layers.last().map_or(0, |l| l.weight.dims()[1]);
        if d_am > f.dims()[1]
            && let Some(g) = self.color.grid_features(x.clone())
        {
            let fg = st.am.forward(rep(Tensor::cat(vec![f, g], 1)), style);
            return self
                .color
                .forward_blended(rep(x), rep(n), rep(dirs), fg)
                .reshape([s, count, 3]);
        }
        let f = st.am.forward(rep(f), style);
        self.color
            .forward(rep(x), rep(n), rep(dirs), f)
            .reshape([s, count, 3])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    /// A fresh stylizer's AM is the identity (γ = 1), whether or not it blends the appearance
    /// grid: stylization starts from the base's colours; blending widens the AM by the grid.
    #[test]
    fn a_fresh_stylizer_blending_the_grid_renders_the_base_colours() {
        let device = Device::flex();
        device.seed(2);
        let arch = IdrArch {
            grid_max_resolution: 32,
            color_width: 8,
            color_grid: 64,
            ..IdrArch::small_volume()
        };
        let base = IdrModel::new(&arch, &device);
        let n = 6;
        let random =
            |w: usize| Tensor::<2>::random([n, w], Distribution::Uniform(-0.5, 0.5), &device);
        let (x, normals, dirs) = (random(3), random(3), random(3));
        let f = random(base.sdf.d_features());
        let plain = base.shade(x.clone(), normals.clone(), dirs.clone(), f.clone(), None);
        for blend_grid in [false, true] {
            let styled =
                base.clone()
                    .with_stylizer(2, 16, &StylePositionConfig::new(), blend_grid, &device);
            let am = &styled.stylizer.as_ref().unwrap().am;
            let widened = if blend_grid { base.color.d_grid() } else { 0 };
            assert_eq!(
                am.layers.last().unwrap().weight.dims()[1],
                base.sdf.d_features() + widened
            );
            let codes = Tensor::<2>::from_floats([[1.0, 0.0]], &device);
            let rgb = styled.shade(
                x.clone(),
                normals.clone(),
                dirs.clone(),
                f.clone(),
                Some(codes),
            );
            let diff = (rgb - plain.clone()).abs().max().into_scalar::<f32>();
            assert!(diff < 1e-5, "blend_grid {blend_grid}: {diff}");
        }
    }
}
