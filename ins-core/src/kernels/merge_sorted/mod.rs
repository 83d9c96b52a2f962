//! Two sets of ray samples, each sorted along its rays, merged by one kernel on the GPU
//! backends, which have no sort (Burn's `sort` there reads the tensor back, sorts on the host
//! and uploads it). A unit per ray walks both sets once, as a merge sort's last step does:
//! `Ka + Kb` steps a ray, where counting each value's place compared every `a` with every `b`
//! (`Ka·Kb`, about twenty launches and an `[R, Ka, Kb]` intermediate).
//!
//! - [`cube`]: the kernel.
//! - [`op`]: a Burn op under autodiff and Fusion (no gradient: the merged samples are where
//!   to sample).

pub mod cube;
pub mod op;
