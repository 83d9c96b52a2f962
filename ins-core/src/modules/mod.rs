//! The three INS modules and the building blocks they share.
//!
//! - [`sim::Sim`]: style code (and optionally encoded position) → style features.
//! - [`cim`]: coordinates → content features ([`cim::SirenCim`], [`cim::FourierCim`], or your own
//!   [`cim::ContentModule`]).
//! - [`am::Amalgamation`]: content features + style features → output, starting as identity.
//! - [`ins::Ins`]: the three composed, the library API for custom INRs.

pub mod am;
pub mod cim;
pub mod encoding;
pub mod ins;
pub mod mlp;
pub mod sim;
pub mod sine;
