//! How far stylization moved a surface: two renders of one camera compared pixel by pixel on
//! the depth of the surface each pixel sees.

/// The agreement of a stylized render's surface with the pretrained one's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthAgreement {
    /// Median relative depth difference over the pixels on the surface in both.
    pub median_rel_error: f64,
    /// Fraction of pixels where both see the surface or neither does.
    pub agreement: f64,
    /// How many pixels see the surface in both.
    pub both: usize,
}

impl DepthAgreement {
    /// Compares `student`'s depth with `teacher`'s, pixel by pixel (`None`: no surface).
    pub fn of(student: &[Option<f32>], teacher: &[Option<f32>]) -> Self {
        let mut errors = Vec::new();
        let mut agree = 0usize;
        for (s, t) in student.iter().zip(teacher) {
            if s.is_some() == t.is_some() {
                agree += 1;
            }
            if let (Some(s), Some(t)) = (s, t) {
                errors.push(((s - t).abs() / t.abs().max(1e-6)) as f64);
            }
        }
        errors.sort_by(f64::total_cmp);
        Self {
            median_rel_error: errors.get(errors.len() / 2).copied().unwrap_or(0.0),
            agreement: agree as f64 / student.len().max(1) as f64,
            both: errors.len(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_agreement_on_every_pixel_and_error_where_both_see_a_surface() {
        let a = [Some(1.0), Some(2.0), None, None, Some(4.0)];
        let b = [Some(1.0), Some(1.0), None, Some(3.0), Some(5.0)];
        let d = DepthAgreement::of(&a, &b);
        // Errors 0, 1, 0.2 → median 0.2; four of five pixels agree on the surface.
        assert_eq!(d.both, 3);
        assert!((d.median_rel_error - 0.2).abs() < 1e-7, "{d:?}");
        assert!((d.agreement - 0.8).abs() < 1e-12);
    }
}
