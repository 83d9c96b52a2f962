//! The NeRF task's state in a checkpoint (`task.bin`): the running samples-per-ray, the
//! occupancy grid, a boxed capture's learned background (its running sums) and the training
//! photos the view audit dropped, in a small binary layout checked on reading (a damaged file
//! is an error, never a huge allocation). States written before the audit (`INSNERF1`: the
//! background as an optional trailing section, no dropped photos) are still read.

use anyhow::{Result, bail, ensure};
use ins_core::render::occupancy::OccupancyGrid;

use super::background::LearnedBackground;

const MAGIC: &[u8; 8] = b"INSNERF2";
/// The layout before the view audit: the background trailing, nothing after it.
const MAGIC_V1: &[u8; 8] = b"INSNERF1";
/// Flags after the grid: which optional sections follow.
const HAS_BACKGROUND: u8 = 1;
const HAS_DROPPED_VIEWS: u8 = 2;
/// Most dropped views a state may list.
const MAX_DROPPED: u32 = 1 << 20;
/// Largest grid accepted: 512³ cells.
const MAX_RESOLUTION: u32 = 512;

/// What a checkpoint keeps of the task.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct NerfState {
    /// Running mean of fine samples per ray.
    pub samples_per_ray: f32,
    /// The occupancy grid (grid variant).
    pub grid: Option<OccupancyGrid>,
    /// The learned background (boxed captures).
    pub background: Option<LearnedBackground>,
    /// Training views the audit found wrongly posed ([`super::view_audit`]), in order.
    pub dropped_views: Vec<usize>,
}

impl crate::run::RunState for NerfState {
    fn decode(task_state: Option<&[u8]>, at: &std::path::Path) -> Result<Self> {
        use anyhow::Context as _;
        match task_state {
            Some(bytes) => decode(bytes).with_context(|| at.display().to_string()),
            None => Ok(NerfState::default()),
        }
    }
}

/// Encodes the task state.
pub fn encode(state: &NerfState) -> Vec<u8> {
    let (samples_per_ray, grid) = (state.samples_per_ray, state.grid.as_ref());
    let mut out = Vec::new();
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&samples_per_ray.to_le_bytes());
    match grid {
        None => out.push(0),
        Some(g) => {
            // Marker 1: a grid over a box; 2: a contracted grid, its radius following.
            match g.contraction {
                None => out.push(1),
                Some(c) => {
                    out.push(2);
                    out.extend_from_slice(&c.radius.to_le_bytes());
                }
            }
            out.extend_from_slice(&g.resolution.to_le_bytes());
            for v in g
                .min
                .iter()
                .chain(&g.max)
                .chain([&g.step, &g.threshold, &g.decay])
            {
                out.extend_from_slice(&v.to_le_bytes());
            }
            for d in &g.density {
                out.extend_from_slice(&d.to_le_bytes());
            }
            out.extend(g.occupied.iter().map(|&o| o as u8));
        }
    }
    let mut flags = 0;
    if state.background.is_some() {
        flags |= HAS_BACKGROUND;
    }
    if !state.dropped_views.is_empty() {
        flags |= HAS_DROPPED_VIEWS;
    }
    out.push(flags);
    if let Some(b) = &state.background {
        for v in b.num.iter().chain([&b.den]) {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    if !state.dropped_views.is_empty() {
        out.extend_from_slice(&(state.dropped_views.len() as u32).to_le_bytes());
        for &v in &state.dropped_views {
            out.extend_from_slice(&(v as u32).to_le_bytes());
        }
    }
    out
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8]> {
        ensure!(self.bytes.len() - self.at >= n, "truncated task state");
        let s = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    fn f32(&mut self) -> Result<f32> {
        Ok(f32::from_le_bytes(self.take(4)?.try_into()?))
    }
    fn u32(&mut self) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into()?))
    }
}

/// Decodes what [`encode`] wrote.
pub fn decode(bytes: &[u8]) -> Result<NerfState> {
    let mut r = Reader { bytes, at: 0 };
    let magic = r.take(8)?;
    let v1 = magic == MAGIC_V1;
    ensure!(v1 || magic == MAGIC, "not a NeRF task state");
    let spr = r.f32()?;
    let grid = match r.take(1)?[0] {
        0 => None,
        marker @ (1 | 2) => {
            let contraction = if marker == 2 {
                let radius = r.f32()?;
                ensure!(
                    radius.is_finite() && radius > 0.0,
                    "contraction radius {radius} is not positive"
                );
                Some(ins_scene::geometry::Contraction { radius })
            } else {
                None
            };
            let resolution = r.u32()?;
            ensure!(
                (1..=MAX_RESOLUTION).contains(&resolution),
                "occupancy grid resolution {resolution} is out of range"
            );
            let mut v = [0f32; 9];
            for x in &mut v {
                *x = r.f32()?;
            }
            let n = (resolution as usize).pow(3);
            let density = r
                .take(n * 4)?
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            let occupied = r.take(n)?.iter().map(|&b| b != 0).collect();
            Some(OccupancyGrid {
                resolution,
                min: [v[0], v[1], v[2]],
                max: [v[3], v[4], v[5]],
                density,
                occupied,
                step: v[6],
                threshold: v[7],
                decay: v[8],
                contraction,
            })
        }
        other => bail!("bad grid marker {other} in the task state"),
    };
    let flags = if v1 {
        if r.at < bytes.len() {
            HAS_BACKGROUND
        } else {
            0
        }
    } else {
        r.take(1)?[0]
    };
    ensure!(
        flags & !(HAS_BACKGROUND | HAS_DROPPED_VIEWS) == 0,
        "unknown sections {flags:#x} in the task state"
    );
    let background = if flags & HAS_BACKGROUND != 0 {
        let num = [r.f32()?, r.f32()?, r.f32()?];
        let den = r.f32()?;
        ensure!(
            num.iter().all(|v| v.is_finite()) && den.is_finite() && den >= 0.0,
            "the background's sums are not finite"
        );
        Some(LearnedBackground { num, den })
    } else {
        None
    };
    let mut dropped_views = Vec::new();
    if flags & HAS_DROPPED_VIEWS != 0 {
        let n = r.u32()?;
        ensure!(
            n <= MAX_DROPPED,
            "{n} dropped views in the task state is out of range"
        );
        for _ in 0..n {
            dropped_views.push(r.u32()? as usize);
        }
    }
    ensure!(r.at == bytes.len(), "trailing bytes after the task state");
    Ok(NerfState {
        samples_per_ray: spr,
        grid,
        background,
        dropped_views,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use ins_scene::geometry::Vec3;

    #[test]
    fn round_trip_and_damage_is_an_error() {
        let mut g = OccupancyGrid::new(4, Vec3::splat(-1.0), Vec3::ONE, 0.1);
        g.density[3] = 2.5;
        g.occupied[5] = false;
        let state = |spr: f32, grid: Option<&OccupancyGrid>| NerfState {
            samples_per_ray: spr,
            grid: grid.cloned(),
            background: None,
            dropped_views: Vec::new(),
        };
        let b = encode(&state(12.5, Some(&g)));
        let back = decode(&b).unwrap();
        assert_eq!(back, state(12.5, Some(&g)));
        assert!(decode(&b[..b.len() - 1]).is_err());
        let mut huge = b.clone();
        huge[13..17].copy_from_slice(&100_000u32.to_le_bytes());
        assert!(decode(&huge).is_err());
        assert_eq!(decode(&encode(&state(3.0, None))).unwrap().grid, None);
        // A contracted grid keeps its contraction, and a learned background its sums.
        let c = OccupancyGrid::contracted(4, ins_scene::geometry::Contraction { radius: 4.0 });
        let mut with_bg = state(1.0, Some(&c));
        with_bg.background = Some(LearnedBackground {
            num: [0.5, 1.0, 2.0],
            den: 2.5,
        });
        let bytes = encode(&with_bg);
        assert_eq!(decode(&bytes).unwrap(), with_bg);
        // Cut inside the background's sums, or a NaN in them: errors.
        assert!(decode(&bytes[..bytes.len() - 2]).is_err());
        let mut nan = bytes.clone();
        let at = nan.len() - 4;
        nan[at..].copy_from_slice(&f32::NAN.to_le_bytes());
        assert!(decode(&nan).is_err());
        // Dropped views, with or without a background; cut or unknown sections are errors.
        let mut dropped = with_bg.clone();
        dropped.dropped_views = vec![7, 2, 30];
        let bytes = encode(&dropped);
        assert_eq!(decode(&bytes).unwrap(), dropped);
        assert!(decode(&bytes[..bytes.len() - 1]).is_err());
        dropped.background = None;
        assert_eq!(decode(&encode(&dropped)).unwrap(), dropped);
        let mut unknown = encode(&state(3.0, None));
        let last = unknown.len() - 1;
        unknown[last] = 0x80;
        assert!(decode(&unknown).is_err());
    }

    #[test]
    fn states_written_before_the_audit_are_read() {
        // INSNERF1: the grid marker, then the background's 16 bytes when learned.
        let mut v1 = b"INSNERF1".to_vec();
        v1.extend_from_slice(&12.0f32.to_le_bytes());
        v1.push(0);
        assert_eq!(decode(&v1).unwrap().background, None);
        for v in [0.5f32, 1.0, 2.0, 2.5] {
            v1.extend_from_slice(&v.to_le_bytes());
        }
        let back = decode(&v1).unwrap();
        assert_eq!(
            back.background,
            Some(LearnedBackground {
                num: [0.5, 1.0, 2.0],
                den: 2.5
            })
        );
        assert!(back.dropped_views.is_empty());
    }
}
