//! Small models and rays the NeRF unit tests share.

use burn::prelude::*;
use ins_core::modules::field::{CimKind, Geometry};
use ins_core::modules::style_position::StylePositionConfig;
use ins_scene::geometry::Vec3;
use ins_scene::rays::Rays;

use super::model::{NerfArch, NerfModel};
use super::render::RenderRays;

/// `k × k` rays from a camera at (0.3, −0.2, 2.5) through a square of the plane z = 0.
pub fn patch_rays(k: usize) -> RenderRays {
    let eye = Vec3::new(0.3, -0.2, 2.5);
    let mut rays = Rays::default();
    for j in 0..k {
        for i in 0..k {
            let target = Vec3::new(
                -0.6 + 1.2 * i as f32 / (k - 1) as f32,
                -0.6 + 1.2 * j as f32 / (k - 1) as f32,
                0.0,
            );
            rays.origins.push(eye);
            rays.directions.push((target - eye).normalize());
            rays.near.push(0.5);
            rays.far.push(4.5);
        }
    }
    RenderRays {
        view_dirs: rays.directions.clone(),
        rays,
    }
}

/// A small grid model over `[-1, 1]³` with a two-style stylizer, drawn from `seed` (under the
/// seeding lock, so tests running beside it cannot change it).
pub fn stylized_model(seed: u64, d: &Device) -> NerfModel {
    ins_core::train::seeding::seeded(d, seed, || {
        let arch = NerfArch {
            cim: CimKind::Grid,
            log2_table: 10,
            max_resolution: 32,
        };
        let position = StylePositionConfig::new()
            .with_grid_resolution(32)
            .with_grid_log2_table(10);
        NerfModel::new(&arch, [-1.0, -1.0, -1.0, 1.0, 1.0, 1.0], d)
            .with_stylizer(2, 16, &position, d)
    })
}

/// `model` made dense (about e³ times a fresh field, so rays turn opaque inside the box) with
/// its geometry and the AM's density branch frozen, as a stylization keeping the density has
/// them.
pub fn dense_kept_density(mut model: NerfModel) -> NerfModel {
    model.field.geometry = match model.field.geometry {
        Geometry::Grid(g) => Geometry::Grid(g.with_density_offset(-3.0)),
        other => other,
    }
    .no_grad();
    if let Some(st) = model.stylizer.as_mut() {
        st.am.density = st.am.density.clone().no_grad();
    }
    model
}
