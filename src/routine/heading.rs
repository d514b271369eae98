//! Heading at rest: circular means of repeated readings and the noise of a sensor at rest.

use super::RoutineError;
use crate::base::{BaseError, HeadingSource};
use crate::kinematics::wrap_angle;

/// The circular mean of `angles` (rad), wrapped to (−π, π].
pub fn circular_mean(angles: &[f64]) -> f64 {
    let (s, c) = angles
        .iter()
        .fold((0.0, 0.0), |(s, c), a| (s + a.sin(), c + a.cos()));
    wrap_angle(s.atan2(c))
}

/// The sample standard deviation of `angles` about their circular mean (rad); 0 for fewer
/// than two.
pub fn circular_std(angles: &[f64]) -> f64 {
    if angles.len() < 2 {
        return 0.0;
    }
    let mean = circular_mean(angles);
    (angles
        .iter()
        .map(|h| wrap_angle(h - mean).powi(2))
        .sum::<f64>()
        / (angles.len() - 1) as f64)
        .sqrt()
}

/// `n` (at least 1) valid readings; an invalid one fails with its reason.
pub async fn readings(source: &dyn HeadingSource, n: usize) -> Result<Vec<f64>, RoutineError> {
    let mut out = Vec::with_capacity(n.max(1));
    for _ in 0..n.max(1) {
        let h = source.read().await?;
        if let crate::base::Validity::Invalid(reason) = h.validity {
            return Err(BaseError::HeadingInvalid { reason }.into());
        }
        out.push(h.heading_rad);
    }
    Ok(out)
}

/// The circular mean of `n` valid readings at rest (rad).
pub async fn mean_heading(source: &dyn HeadingSource, n: usize) -> Result<f64, RoutineError> {
    Ok(circular_mean(&readings(source, n).await?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn the_mean_of_headings_across_the_seam_stays_near_pi() {
        let m = circular_mean(&[PI - 0.01, -PI + 0.01, PI - 0.02, -PI + 0.02]);
        assert!((m.abs() - PI).abs() < 1e-12, "{m}");
        let s = circular_std(&[PI - 0.01, -PI + 0.01]);
        assert!((s - 0.01 * 2f64.sqrt()).abs() < 1e-12, "{s}");
    }
}
