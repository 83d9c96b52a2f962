//! The command line's tests, one module per command or subject, built as one program: each
//! file used to be its own program, compiled and linked on its own. They run `ins-cli` as a
//! user does (Cargo builds it for them); `scripts/test.sh` runs each module in a process of
//! its own, in the lane its backend needs (wgpu on lavapipe, or the CPU).

mod common;

mod capture_cli;
mod cli;
mod idr_cli;
mod kill_resume;
mod nerf_cli;
mod report_cli;
mod run_folder;
mod stylize2d_cli;
mod stylize_cli;
mod viewer_cli;
mod wgpu_cli;
