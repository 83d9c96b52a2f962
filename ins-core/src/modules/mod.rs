//! The three INS modules and the building blocks they share.
//!
//! - [`sim::Sim`]: style code (and optionally encoded position) → style features.
//! - [`cim`]: coordinates → content features ([`cim::SirenCim`], [`cim::FourierCim`], or your own
//!   [`cim::ContentModule`]).
//! - [`am::Amalgamation`]: content features + style features → output, starting as identity.
//! - [`ins::Ins`]: the three composed, the library API for custom INRs.
//! - [`field::Field`]: radiance fields for 3D (hash-grid or NeRF-MLP geometry, view-dependent
//!   colour); [`radiance_am::RadianceAm`] fuses them with style features.
//! - [`sdf::SdfNet`]: signed distance networks for surfaces (IDR MLP or hash grid), with exact
//!   forward-mode normals.
//! - [`hash_grid::HashGrid`]: the multiresolution hash encoding of the fast 3D content modules.

pub mod am;
pub mod cim;
pub mod color_head;
pub mod encoding;
pub mod field;
pub mod grid_field;
pub mod hash_grid;
pub mod ins;
pub mod mlp;
pub mod mlp_field;
pub mod radiance_am;
pub mod sdf;
pub mod sh;
pub mod sim;
pub mod sine;
pub mod style_position;
pub mod surface_color;
