//! The samples a march through an occupancy grid keeps, ray by ray, and the renders' ways of
//! cutting them short (in rounds, until a ray is opaque).

/// Samples produced by marching rays through a grid: only those in occupied cells.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MarchedSamples {
    /// Ray of each sample.
    pub ray: Vec<u32>,
    /// Distance along the ray.
    pub t: Vec<f32>,
    /// Length of ray the sample stands for.
    pub delta: Vec<f32>,
    /// First sample of each ray, plus one past the end (`rays + 1` entries).
    pub offsets: Vec<u32>,
}

impl MarchedSamples {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    /// The most samples any ray got.
    pub fn max_per_ray(&self) -> usize {
        self.offsets
            .windows(2)
            .map(|w| (w[1] - w[0]) as usize)
            .max()
            .unwrap_or(0)
    }

    /// The next round of samples along the rays still open: up to `round` more of each ray
    /// from its `cursor` (an index into `self`, moved past them), skipping the rays whose
    /// `transmittance` fell below `min_transmittance` and those with no samples left. Returns
    /// their indices into `self`, ray by ray. Renders that stop rays once opaque evaluate
    /// rounds of growing length, so that few samples behind a surface are ever evaluated.
    pub fn next_round(
        &self,
        cursor: &mut [usize],
        transmittance: &[f32],
        min_transmittance: f32,
        round: usize,
    ) -> Vec<usize> {
        let mut index = Vec::new();
        for (ray, at) in cursor.iter_mut().enumerate() {
            let end = self.offsets[ray + 1] as usize;
            if transmittance[ray] < min_transmittance || *at >= end {
                continue;
            }
            let stop = at.saturating_add(round).min(end);
            index.extend(*at..stop);
            *at = stop;
        }
        index
    }

    /// Each ray's samples up to where it turns opaque under `density` (one value a sample,
    /// in order): a sample is kept while the transmittance in front of it is at least
    /// `min_transmittance`, so what the dropped ones could add to a pixel is below that. Also
    /// returns the kept samples' indices into `self`. Why: with the density frozen
    /// (stylization), the samples behind a surface cost the colour network's work and show
    /// nothing.
    pub fn until_opaque(&self, density: &[f32], min_transmittance: f32) -> (Self, Vec<u32>) {
        let mut kept = Self {
            offsets: Vec::with_capacity(self.offsets.len()),
            ..Default::default()
        };
        let mut index = Vec::new();
        kept.offsets.push(0);
        for w in self.offsets.windows(2) {
            let mut transmittance = 1f32;
            for k in w[0] as usize..w[1] as usize {
                if transmittance < min_transmittance {
                    break;
                }
                kept.ray.push(self.ray[k]);
                kept.t.push(self.t[k]);
                kept.delta.push(self.delta[k]);
                index.push(k as u32);
                transmittance *= (-density[k].max(0.0) * self.delta[k]).exp();
            }
            kept.offsets.push(kept.t.len() as u32);
        }
        (kept, index)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_behind_an_opaque_point_are_dropped() {
        // Two rays of four samples: the first turns opaque at its second sample, the second
        // stays clear.
        let m = MarchedSamples {
            ray: vec![0, 0, 0, 0, 1, 1, 1, 1],
            t: vec![0.1, 0.2, 0.3, 0.4, 0.1, 0.2, 0.3, 0.4],
            delta: vec![0.1; 8],
            offsets: vec![0, 4, 8],
        };
        let density = [0.5, 200.0, 200.0, 200.0, 0.5, 0.5, 0.5, 0.5];
        let (kept, index) = m.until_opaque(&density, 1e-4);
        assert_eq!(index, vec![0, 1, 4, 5, 6, 7]);
        assert_eq!(kept.offsets, vec![0, 2, 6]);
        assert_eq!(kept.ray, vec![0, 0, 1, 1, 1, 1]);
        assert_eq!(kept.t, vec![0.1, 0.2, 0.1, 0.2, 0.3, 0.4]);
        // What the dropped samples could add is below the threshold.
        let behind: f32 = (-(0.5f32 + 200.0) * 0.1).exp();
        assert!(behind < 1e-4);
        // With no threshold every sample stays.
        assert_eq!(m.until_opaque(&density, 0.0).0, m);
    }
}
