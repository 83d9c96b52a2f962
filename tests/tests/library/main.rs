//! The workspace's integration tests, one module per subject, built as one program: each test
//! file used to be its own program, and every one of them compiled and linked its own copy of
//! the training code it instantiates (Burn's generic code included), minutes of a cold build.
//!
//! `scripts/test.sh` still runs each module in a process of its own (a job per module, in two
//! lanes), so a module's tests share the CPU and the wgpu device only with each other, as
//! before. Three programs stay apart: `cpu_fallback` (no libtest harness: it re-runs itself
//! under QEMU), `mutation` (it installs a counting global allocator) and `resume` (a resumed
//! run must match an uninterrupted one bit for bit, which holds only with no other test
//! sharing flex's thread pool, also under a plain `cargo test`).

mod backends;
mod data_formats;
mod hash_grid;
mod idr;
mod losses;
mod nerf;
mod siren;
mod stylize2d;
mod surface_points;
mod trainer;
mod vgg_import;
mod wgpu_render_ops;
mod wgpu_steps;
