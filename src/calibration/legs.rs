//! The leg-aware heading method ("legs"): the exact inversion ([`super::exact`]) applied to the
//! heading measured **along the legs** instead of at rest before and after the run.
//!
//! Recorded runs of real robots often pick up a heading offset of a few degrees before the
//! first corner (start transient, wheels settling) that the paper's model has no term for; a
//! method that reads the heading at rest before the run counts it in full. Here the heading
//! error — the heading sensor's turn minus the odometry's turn, which also removes what the
//! robot did not execute as commanded — is taken between the **middle of the first leg** and
//! the **middle of the last**: each as the mean over the leg, which under a constant curvature
//! is its value at mid-leg. Between those instants the robot makes three turns and three whole
//! legs' worth of straight driving, so under the square model (see `exact`: the final error is
//! four identical turn terms and four identical leg terms) the partial error is exactly ¾ of
//! the final one: `θ = (4/3)·θ_legs`, then `G = 1 − (θ_cw − θ_ccw)/(4π)`,
//! `c = (θ_cw + θ_ccw)·b/(16L)` as in `exact`. A heading offset the sensor picks up before the
//! first leg is under way, or after the last, does not enter (one picked up during the first
//! leg enters in part: the leg's mean includes it for the part of the leg after it).
//!
//! Legs and turns are found from the data ([`classify`]): an interval is at rest, straight or a
//! turn by the odometry's own travel and turn over it, never by assumed timing.

use super::{CalibrationError, SquareTest};

/// What the robot did over one sample interval, by its odometry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Below 5 mm/s and 0.02 rad/s.
    Rest,
    /// Mostly forward travel.
    Straight,
    /// Mostly rotation in place.
    Turn,
}

/// Classifies an interval of `dt` seconds in which the odometry moved `ds` forward (m) and
/// turned `dth` (rad), on a wheelbase of `b` (m): a turn when the wheels' rotation part
/// (`dth·b/2`) exceeds their common part.
pub fn classify(ds: f64, dth: f64, dt: f64, b: f64) -> Phase {
    let dt = dt.max(1e-6);
    if ds.abs() / dt < 0.005 && dth.abs() / dt < 0.02 {
        Phase::Rest
    } else if (0.5 * dth * b).abs() > ds.abs() {
        Phase::Turn
    } else {
        Phase::Straight
    }
}

/// One sample of a run: time (s), odometry travel and turn since the previous sample (m, rad),
/// and the heading error now: heading sensor minus odometry heading (rad, unwrapped).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LegSample {
    /// Time (s).
    pub t: f64,
    /// Forward travel since the previous sample (m).
    pub ds: f64,
    /// Turn since the previous sample (rad).
    pub dth: f64,
    /// Heading sensor minus odometry heading (rad, unwrapped).
    pub error_rad: f64,
}

/// Legs shorter than this (m) are not legs (a nudge, a correction).
const MIN_LEG_M: f64 = 0.05;

/// The heading error between the middle of the first and the last of exactly four legs, or
/// `None` when the run does not have four legs.
pub fn leg_heading_error(samples: &[LegSample], wheelbase_m: f64) -> Option<f64> {
    // Legs as index ranges of samples, rests inside a leg ignored.
    let mut legs: Vec<(Vec<usize>, f64)> = Vec::new();
    let mut current: Option<(Vec<usize>, f64)> = None;
    for i in 1..samples.len() {
        let s = &samples[i];
        match classify(s.ds, s.dth, s.t - samples[i - 1].t, wheelbase_m) {
            Phase::Straight => {
                let leg = current.get_or_insert_with(|| (vec![i - 1], 0.0));
                leg.0.push(i);
                leg.1 += s.ds;
            }
            Phase::Turn => {
                if let Some(leg) = current.take() {
                    legs.push(leg);
                }
            }
            Phase::Rest => {}
        }
    }
    legs.extend(current);
    legs.retain(|(_, len)| len.abs() > MIN_LEG_M);
    if legs.len() != 4 {
        return None;
    }
    let mean =
        |idx: &[usize]| idx.iter().map(|&i| samples[i].error_rad).sum::<f64>() / idx.len() as f64;
    Some(mean(&legs[3].0) - mean(&legs[0].0))
}

/// The test whose final heading errors the legs imply: `(4/3)·θ_legs` per run.
pub fn equivalent_test(test: &SquareTest) -> Result<SquareTest, CalibrationError> {
    let map =
        |runs: &[super::RunMeasurement]| -> Result<Vec<super::RunMeasurement>, CalibrationError> {
            runs.iter()
                .map(|r| {
                    r.leg_heading_error_rad
                        .map(|legs| super::RunMeasurement {
                            heading_error_rad: 4.0 / 3.0 * legs,
                            ..*r
                        })
                        .ok_or(CalibrationError::MissingLegHeadings)
                })
                .collect()
        };
    Ok(SquareTest {
        cw: map(&test.cw)?,
        ccw: map(&test.ccw)?,
        ..test.clone()
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::exact::predicted_heading_errors;
    use crate::kinematics::{SplitConvention, WheelParams};

    /// A square driven with the exact model; the heading sensor picks up an offset of `offset`
    /// rad as the robot starts (after the reading at rest, before the first leg is under way).
    fn run(
        truth: &WheelParams,
        cfg: &WheelParams,
        side: f64,
        ccw: bool,
        offset: f64,
    ) -> Vec<LegSample> {
        let mut out = vec![LegSample {
            t: 0.0,
            ds: 0.0,
            dth: 0.0,
            error_rad: offset,
        }];
        let (mut t, mut true_turn, mut odo_turn) = (0.0, 0.0, 0.0);
        let turn = if ccw { 1.0 } else { -1.0 } * std::f64::consts::FRAC_PI_2;
        let b = cfg.wheelbase_m;
        for _ in 0..4 {
            for (l, r, n) in [(side, side, 200), (-0.5 * turn * b, 0.5 * turn * b, 100)] {
                for _ in 0..n {
                    // What the odometry believes, and what the true wheels did with those counts.
                    let (sl, sr) = (l / f64::from(n), r / f64::from(n));
                    let tl = sl * truth.left_m_per_count() / cfg.left_m_per_count();
                    let tr = sr * truth.right_m_per_count() / cfg.right_m_per_count();
                    true_turn += (tr - tl) / truth.wheelbase_m;
                    let dth = (sr - sl) / b;
                    odo_turn += dth;
                    t += 0.01;
                    out.push(LegSample {
                        t,
                        ds: 0.5 * (sl + sr),
                        dth,
                        error_rad: true_turn - odo_turn + offset,
                    });
                }
            }
        }
        out
    }

    #[test]
    fn legs_give_three_quarters_of_the_final_error_and_ignore_a_start_transient() {
        let cfg = WheelParams::nominal(0.15, 0.39, 4096.0);
        let truth =
            WheelParams::from_ratios(&cfg, 0.976, 0.992, &SplitConvention::LeftNominal).unwrap();
        let c = crate::kinematics::Correction {
            left_diameter_scale: 1.0,
            right_diameter_scale: 0.992,
            wheelbase_scale: 0.976,
        };
        let (cw_pred, ccw_pred) = predicted_heading_errors(&c, 2.0, 0.39);
        for (ccw, pred) in [(false, cw_pred), (true, ccw_pred)] {
            let samples = run(&truth, &cfg, 2.0, ccw, 0.03);
            // At rest before (error 0) and after, the 0.03 rad transient counts in full…
            let at_rest = samples.last().unwrap().error_rad;
            assert!((at_rest - pred - 0.03).abs() < 1e-9, "{at_rest} vs {pred}");
            // …along the legs it does not, and ¾ of the model's error remains, to rounding.
            let legs = leg_heading_error(&samples, 0.39).unwrap();
            assert!(
                (4.0 / 3.0 * legs - pred).abs() < 1e-9,
                "{ccw}: {legs} vs {pred}"
            );
        }
    }
}
