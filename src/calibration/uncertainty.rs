//! How precisely heading errors can determine `E_b` and `E_d`: the Cramér–Rao bound.
//!
//! Each run's heading error is modelled as the exact prediction
//! ([`exact::predicted_heading_errors`]) plus independent Gaussian noise of standard deviation
//! `σ_run`. With a compass read once at rest before and once after a run, `σ_run = √2·σ_compass`
//! ([`heading_error_sigma`]). The Fisher information of `n_cw` and `n_ccw` runs is
//! `Hᵀ·diag(n_cw, n_ccw)·H/σ_run²` with `H = ∂(θ_cw, θ_ccw)/∂(E_b, E_d)`; its inverse bounds the
//! covariance of any unbiased estimator. The exact method attains it to first order.

use super::{exact, CalibrationError};
use crate::kinematics::SplitConvention;
use nalgebra::{Matrix2, Vector2};

/// Standard deviation of one run's final-minus-start heading error when each end is the mean
/// of `samples_per_read` compass readings of standard deviation `compass_sigma_rad`.
pub fn heading_error_sigma(compass_sigma_rad: f64, samples_per_read: usize) -> f64 {
    compass_sigma_rad * (2.0 / samples_per_read.max(1) as f64).sqrt()
}

/// The layout and noise of a square test, as the bound needs them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TestDesign {
    /// Square side (m).
    pub side_m: f64,
    /// Wheelbase configured during the test (m).
    pub wheelbase_m: f64,
    /// Clockwise runs.
    pub runs_cw: usize,
    /// Counter-clockwise runs.
    pub runs_ccw: usize,
    /// Standard deviation of one run's heading error (rad), see [`heading_error_sigma`].
    pub heading_error_sigma_rad: f64,
}

/// The Cramér–Rao covariance bound for `(E_b, E_d)` at the given truth.
///
/// Only the two heading-determined conventions have a bound here: under a measured scale `E_b`
/// also depends on the distance measurement, whose noise this model does not include.
pub fn cramer_rao_bound(
    e_b: f64,
    e_d: f64,
    convention: SplitConvention,
    design: &TestDesign,
) -> Result<Matrix2<f64>, CalibrationError> {
    let TestDesign {
        side_m,
        wheelbase_m,
        runs_cw,
        runs_ccw,
        heading_error_sigma_rad,
    } = *design;
    if let SplitConvention::MeasuredScale { .. } = convention {
        return Err(CalibrationError::Unsupported(
            "Cramér–Rao bound under a measured scale (distance noise is not modelled)".into(),
        ));
    }
    if !(heading_error_sigma_rad.is_finite() && heading_error_sigma_rad > 0.0) {
        return Err(CalibrationError::Unsupported(format!(
            "a bound needs heading noise > 0, got {heading_error_sigma_rad}"
        )));
    }
    if runs_cw == 0 || runs_ccw == 0 {
        return Err(CalibrationError::Unsupported(
            "a bound needs runs in both directions".into(),
        ));
    }
    let predict = |p: Vector2<f64>| -> Result<Vector2<f64>, CalibrationError> {
        let c = convention.split(p[0], p[1], wheelbase_m)?;
        let (cw, ccw) = exact::predicted_heading_errors(&c, side_m, wheelbase_m);
        Ok(Vector2::new(cw, ccw))
    };
    let p0 = Vector2::new(e_b, e_d);
    let mut h = Matrix2::zeros();
    for k in 0..2 {
        let step = 1e-6 * p0[k].abs().max(1.0);
        let mut plus = p0;
        let mut minus = p0;
        plus[k] += step;
        minus[k] -= step;
        let d = (predict(plus)? - predict(minus)?) / (2.0 * step);
        h.set_column(k, &d);
    }
    let w = Matrix2::from_diagonal(&Vector2::new(runs_cw as f64, runs_ccw as f64))
        / heading_error_sigma_rad.powi(2);
    let fisher = h.transpose() * w * h;
    fisher.try_inverse().ok_or_else(|| {
        CalibrationError::Unsupported("Fisher information is singular at this point".into())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bound_shrinks_with_runs_and_grows_with_noise() {
        let design = |n, s| TestDesign {
            side_m: 4.0,
            wheelbase_m: 0.39,
            runs_cw: n,
            runs_ccw: n,
            heading_error_sigma_rad: s,
        };
        let b = |n, s| {
            cramer_rao_bound(0.976, 0.992, SplitConvention::LeftNominal, &design(n, s)).unwrap()
        };
        let one = b(1, 0.01);
        let four = b(4, 0.01);
        assert!((one[(0, 0)] / four[(0, 0)] - 4.0).abs() < 1e-6);
        let noisy = b(1, 0.02);
        assert!((noisy[(1, 1)] / one[(1, 1)] - 4.0).abs() < 1e-6);
        assert!(cramer_rao_bound(
            1.0,
            1.0,
            SplitConvention::MeasuredScale {
                commanded_m: 1.0,
                measured_m: 1.0
            },
            &design(1, 0.01)
        )
        .is_err());
    }
}
