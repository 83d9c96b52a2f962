//! The smoothness term's picks among flagged samples (`render::flagged_picks`) as one kernel
//! on the GPU backends. Given the running count of flagged entries, a unit per pick computes
//! its rank (one per stratum of the ranks) and finds the entry of that rank by a binary search
//! of the count: `log₂ N` reads a pick, where the ops it replaces scattered every flagged
//! entry into a rank → entry table (about fifteen launches and three `[N]` integer tensors).
//!
//! - [`cube`]: the kernel.
//! - [`op`]: a Burn op under autodiff and Fusion (no gradient: picks are indices).

pub mod cube;
pub mod op;
