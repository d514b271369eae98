//! The time offset beyond the fit's search, and whether one time offset holds over the whole
//! drive or the two streams' clocks run at different rates (a reference stamped by another computer whose clock is not synchronised
//! drifts by 10–100 ppm; over an hour that is a third of a second).
//!
//! At the solution, the offset is re-estimated on the first and on the last third of the
//! compared samples alone, the other parameters held: one Gauss–Newton step from the fitted
//! offset on each third's whitened residuals `z` and their derivative `j = ∂z/∂δ` (central
//! differences), `δ_k = δ̂ − Σ j z / Σ j²`, with variance `c / Σ j²` (`c` the covariance's
//! inflation for correlated residuals). Offsets that differ by more than [`DRIFT_SIGMAS`] of their
//! combined standard deviation, and by more than [`DRIFT_MIN_S`], are named with the rate they
//! imply: a single offset cannot hold, and the geometry absorbs what it leaves.
//!
//! Before the fit ([`delay_beyond_search`]), the reference's turn rate is cross-correlated with
//! the wheels' over ±[`COARSE_SEARCH_S`] ([`crate::calibration::time_offset`]'s estimator, on
//! the reference's stamps): a reference seconds late, more than twice the fit's
//! ±`max_time_offset_s`, is named with its delay and the flag that widens the search, instead
//! of being fitted at the wrong offset and judged unobserved (closer, the fit runs and warns of
//! an offset at its limit).

use super::problem::Problem;
use super::scales::Scales;
use super::Param;
use crate::calibration::pose_reference::{Geometry, PoseRecording};
use crate::calibration::time_offset::reference_delay;
use crate::calibration::CalibrationError;

/// How far the turn rates are cross-correlated before the fit (s).
pub(super) const COARSE_SEARCH_S: f64 = 10.0;
/// Least correlation of the turn rates at the delay found for it to be named.
const COARSE_CORRELATION: f64 = 0.7;

/// Refuses, with the delay and the flag, a reference whose turns follow the wheels' by more
/// than `max_offset_s` (the fit's search); `Ok` when they do not or the data cannot tell.
pub(super) fn delay_beyond_search(
    recording: &PoseRecording,
    nominal: Geometry,
    max_offset_s: f64,
) -> Result<(), CalibrationError> {
    // A limit of zero is the user's word that the streams are simultaneous.
    if !recording.has_yaw() || max_offset_s <= 0.0 {
        return Ok(());
    }
    let Some(found) = reference_delay(recording, nominal, COARSE_SEARCH_S) else {
        return Ok(());
    };
    // Up to twice the limit the fit runs and its offset at the limit is warned of (with the
    // flag); beyond that, the offset at the limit is no fit at all. A sample period's worth of
    // slack: the estimate is refined to a fraction of one.
    if found.correlation < COARSE_CORRELATION
        || found.offset_s.abs() <= 2.0 * max_offset_s + found.period_s
    {
        return Ok(());
    }
    Err(CalibrationError::DelayBeyondSearch {
        delay_s: found.offset_s,
        correlation: found.correlation,
        correlation_at_zero: found.correlation_at_zero,
        searched_s: max_offset_s,
    })
}

/// Standard deviations between the two thirds' offsets that name a drift.
pub(super) const DRIFT_SIGMAS: f64 = 4.0;
/// Smallest difference between the two thirds' offsets that is named (s).
pub(super) const DRIFT_MIN_S: f64 = 0.005;

/// The two thirds' offsets, when the drive tells them apart from the fitted one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct ClockDrift {
    /// Offset over the first third (s) and its standard deviation.
    pub(super) first: (f64, f64),
    /// Offset over the last third (s) and its standard deviation.
    pub(super) last: (f64, f64),
    /// Time between the thirds' middles (s).
    pub(super) span_s: f64,
}

impl ClockDrift {
    /// The rate of the reference's clock against the wheels' (parts per million, positive:
    /// the reference's stamps fall further behind).
    pub(super) fn ppm(&self) -> f64 {
        1e6 * (self.last.0 - self.first.0) / self.span_s
    }

    /// Whether the two offsets differ by more than the noise and the smallest named drift.
    pub(super) fn significant(&self) -> bool {
        let d = (self.last.0 - self.first.0).abs();
        let s = self.first.1.hypot(self.last.1);
        d > DRIFT_MIN_S && d > DRIFT_SIGMAS * s
    }

    /// The warning the fit gives.
    pub(super) fn warning(&self) -> String {
        format!(
            "the reference's delay goes from {:.0} ± {:.0} ms over the first third of the drive \
             to {:.0} ± {:.0} ms over the last (1σ): its clock runs {:+.0} ppm against the \
             wheels', so no single time offset holds and the geometry absorbs the rest; stamp \
             both streams with one clock (or split the drive into shorter recordings), then fit \
             again",
            1e3 * self.first.0,
            1e3 * self.first.1,
            1e3 * self.last.0,
            1e3 * self.last.1,
            self.ppm()
        )
    }
}

/// The offsets of the first and last thirds at the solution `p` (weights and scales of the
/// settled fit, the covariance inflated by `inflation`); `None` when the offset was not fitted
/// or a third does not observe it.
pub(super) fn clock_drift(
    problem: &Problem<'_>,
    p: &[f64; super::PARAMS],
    weights: &[f64],
    scales: Scales,
    inflation: f64,
) -> Option<ClockDrift> {
    if !problem.free.contains(&Param::TimeOffset) {
        return None;
    }
    let k = Param::TimeOffset.index();
    let h = 1e-4;
    let at = |delta: f64| {
        let mut q = *p;
        q[k] = delta;
        let r = problem.residuals_at(&q, weights, scales);
        problem.whiten(&r, weights, scales).0
    };
    let (z, plus, minus) = (at(p[k]), at(p[k] + h), at(p[k] - h));
    let dim = problem.dim;
    let n = problem.blocks();
    if n < 30 {
        return None;
    }
    let third = |range: std::ops::Range<usize>| -> Option<((f64, f64), f64)> {
        let (mut jj, mut jz, mut t) = (0.0, 0.0, 0.0);
        for b in range.clone() {
            if weights[b] <= 0.0 {
                continue;
            }
            for c in 0..dim {
                let i = b * dim + c;
                let j = (plus[i] - minus[i]) / (2.0 * h);
                jj += j * j;
                jz += j * z[i];
            }
            t += problem.block_time(b);
        }
        let kept = range.filter(|b| weights[*b] > 0.0).count();
        (jj > 0.0 && kept > 0).then(|| ((p[k] - jz / jj, (inflation / jj).sqrt()), t / kept as f64))
    };
    let (first, t1) = third(0..n / 3)?;
    let (last, t3) = third(n - n / 3..n)?;
    Some(ClockDrift {
        first,
        last,
        span_s: t3 - t1,
    })
}
