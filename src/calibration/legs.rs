//! The leg-aware heading method ("legs"): the exact inversion ([`super::exact`]) applied to the
//! heading measured **along the legs** instead of at rest before and after the run.
//!
//! Recorded runs of real robots often pick up a heading offset of a few degrees before the
//! first corner (start transient, wheels settling) that the paper's model has no term for; a
//! method that reads the heading at rest before the run counts it in full. Here the heading
//! error — the heading sensor's turn minus the odometry's turn, which also removes what the
//! robot did not execute as commanded — is taken between the **middle of the first leg** and
//! the **middle of the last**: each as the mean over the leg, which under a constant curvature
//! is its value at mid-leg. The exact model holds for any stretch of driving
//! (`θ = (G − 1)·T + (2c/b)·D`, see [`super::exact`]), so the error between those instants is
//! inverted with the odometry's turn `T` and distance `D` between the same instants
//! ([`LegMeasurement`]): three turns and three sides as commanded (`θ = (4/3)·θ_legs` of the
//! final-error form), or what the odometry measured when a drive overshoots its turns. A
//! heading offset the sensor picks up before the first leg is under way, or after the last,
//! does not enter (one picked up during the first leg enters in part: the leg's mean includes
//! it for the part of the leg after it). Runs whose heading along the legs was not recorded (a
//! stream that lost their end) are left out.
//!
//! Legs and turns are found from the data ([`classify`]): an interval is at rest, straight or a
//! turn by the odometry's own travel and turn over it, never by assumed timing.

use super::{CalibrationError, SquareTest};
use crate::kinematics::{Direction, Displacement};
use serde::{Deserialize, Serialize};

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

/// Legs shorter than this (m) are not legs (a nudge, a correction).
pub const MIN_LEG_M: f64 = 0.05;
/// Turns smaller than this (rad) are not corners.
pub const MIN_TURN_RAD: f64 = 0.2;

/// A stretch of one kind of motion: the intervals of it (by index) and how far it went (m for
/// a leg, rad for a turn).
#[derive(Debug, Clone, PartialEq)]
pub struct Piece {
    /// [`Phase::Straight`] or [`Phase::Turn`].
    pub phase: Phase,
    /// The intervals that make it, in order (rests inside it not among them).
    pub intervals: Vec<usize>,
    /// Forward travel (a leg, m) or turn (a turn, rad).
    pub amount: f64,
}

/// Splits a run's intervals — each `(ds, dth, dt)`: forward travel (m), turn (rad) and length
/// (s) — into legs and turns, the one segmentation of the crate: consecutive intervals of one
/// kind make a piece, the other kind ends it, and a rest inside a piece (a pause) neither ends
/// nor adds to it. Legs of at most [`MIN_LEG_M`] and turns of at most [`MIN_TURN_RAD`] are
/// dropped (a nudge, a correction).
pub fn pieces(
    intervals: impl IntoIterator<Item = (f64, f64, f64)>,
    wheelbase_m: f64,
) -> Vec<Piece> {
    let mut out: Vec<Piece> = Vec::new();
    let mut current: Option<Piece> = None;
    for (i, (ds, dth, dt)) in intervals.into_iter().enumerate() {
        let phase = classify(ds, dth, dt, wheelbase_m);
        let amount = match phase {
            Phase::Rest => continue,
            Phase::Straight => ds,
            Phase::Turn => dth,
        };
        match &mut current {
            Some(p) if p.phase == phase => {
                p.intervals.push(i);
                p.amount += amount;
            }
            _ => {
                out.extend(current.replace(Piece {
                    phase,
                    intervals: vec![i],
                    amount,
                }));
            }
        }
    }
    out.extend(current);
    out.retain(|p| match p.phase {
        Phase::Straight => p.amount.abs() > MIN_LEG_M,
        _ => p.amount.abs() > MIN_TURN_RAD,
    });
    out
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

/// One leg as the heading along it measured: the mean of the heading error over the leg
/// (heading sensor minus odometry, rad) and the mean of the odometry's turn and distance from
/// the first sample of the run — under a constant curvature, both are their values at the
/// leg's middle.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct LegMean {
    /// Mean heading error over the leg (rad).
    pub error_rad: f64,
    /// Mean odometry over the leg, from the run's first sample.
    pub odometry: Displacement,
    /// Variance of `error_rad` from the heading's own noise along the leg (rad²): the scatter
    /// about the leg's straight-line trend, over the samples' effective number (lag-one
    /// correlation counted). `None` with fewer than four samples.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub variance_rad2: Option<f64>,
}

/// The variance of the mean of `y` (rad²) from its scatter about a straight line in `x`, with
/// the sample count reduced for lag-one correlation (`n·(1 − ρ)/(1 + ρ)`): a heading sensor
/// that filters or repeats its readings averages less than its sample count says. `None` with
/// fewer than four samples.
pub fn noise_variance_of_mean(x: &[f64], y: &[f64]) -> Option<f64> {
    let n = x.len().min(y.len());
    if n < 4 {
        return None;
    }
    let nf = n as f64;
    let (mx, my) = (x.iter().sum::<f64>() / nf, y.iter().sum::<f64>() / nf);
    let sxx: f64 = x.iter().map(|v| (v - mx).powi(2)).sum();
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    let r: Vec<f64> = x
        .iter()
        .zip(y)
        .map(|(a, b)| b - my - slope * (a - mx))
        .collect();
    let ss: f64 = r.iter().map(|v| v * v).sum();
    if !ss.is_finite() {
        return None;
    }
    if ss == 0.0 {
        return Some(0.0);
    }
    let rho = (r.windows(2).map(|w| w[0] * w[1]).sum::<f64>() / ss).clamp(0.0, 0.99);
    let n_eff = (nf * (1.0 - rho) / (1.0 + rho)).max(1.0);
    Some(ss / (nf - 2.0) / n_eff)
}

/// What the heading along the four legs measured.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct LegMeasurement {
    /// The four legs in the order driven.
    pub legs: [LegMean; 4],
}

impl LegMeasurement {
    /// The heading error and the odometry from the middle of leg `from` to the middle of leg
    /// `to` (0-based).
    pub fn between(&self, from: usize, to: usize) -> (f64, Displacement) {
        let (a, b) = (self.legs[from], self.legs[to]);
        (
            b.error_rad - a.error_rad,
            Displacement {
                distance_m: b.odometry.distance_m - a.odometry.distance_m,
                turn_rad: b.odometry.turn_rad - a.odometry.turn_rad,
            },
        )
    }

    /// The variance of [`LegMeasurement::between`]'s heading error from the noise along the
    /// two legs (rad²), when both legs have it.
    pub fn variance_between(&self, from: usize, to: usize) -> Option<f64> {
        Some(self.legs[from].variance_rad2? + self.legs[to].variance_rad2?)
    }

    /// The heading error from the middle of the first leg to the middle of the last (rad).
    pub fn heading_error_rad(&self) -> f64 {
        self.between(0, 3).0
    }

    /// The odometry between the same two instants (ideally ±3π/2 and three sides).
    pub fn odometry(&self) -> Displacement {
        self.between(0, 3).1
    }
}

/// The heading error between the middle of the first and the last of exactly four legs, or
/// `None` when the run does not have four legs.
pub fn leg_measurement(samples: &[LegSample], wheelbase_m: f64) -> Option<LegMeasurement> {
    // Legs as the samples that end their intervals, and the one before the first.
    let steps = samples
        .windows(2)
        .map(|w| (w[1].ds, w[1].dth, w[1].t - w[0].t));
    let legs: Vec<Vec<usize>> = pieces(steps, wheelbase_m)
        .into_iter()
        .filter(|p| p.phase == Phase::Straight)
        .map(|p| {
            let first = p.intervals.first().copied().unwrap_or(0);
            std::iter::once(first)
                .chain(p.intervals.iter().map(|i| i + 1))
                .collect()
        })
        .collect();
    if legs.len() != 4 {
        return None;
    }
    // The odometry from the first sample to each sample.
    let mut cumulative = Vec::with_capacity(samples.len());
    let mut sum = Displacement::default();
    for (i, s) in samples.iter().enumerate() {
        if i > 0 {
            sum = sum.plus(&Displacement {
                distance_m: s.ds,
                turn_rad: s.dth,
            });
        }
        cumulative.push(sum);
    }
    let mean = |idx: &[usize], f: &dyn Fn(usize) -> f64| {
        idx.iter().map(|&i| f(i)).sum::<f64>() / idx.len() as f64
    };
    let leg = |k: usize| {
        let idx = &legs[k];
        let x: Vec<f64> = idx.iter().map(|&i| cumulative[i].distance_m).collect();
        let y: Vec<f64> = idx.iter().map(|&i| samples[i].error_rad).collect();
        LegMean {
            error_rad: mean(idx, &|i| samples[i].error_rad),
            odometry: Displacement {
                distance_m: mean(idx, &|i| cumulative[i].distance_m),
                turn_rad: mean(idx, &|i| cumulative[i].turn_rad),
            },
            variance_rad2: noise_variance_of_mean(&x, &y),
        }
    };
    Some(LegMeasurement {
        legs: [leg(0), leg(1), leg(2), leg(3)],
    })
}

/// The test the legs make (of the runs that measured it): each run's heading error along the
/// legs, with the odometry between
/// the same two instants (three quarters of a square as commanded, unless measured). The exact
/// model holds for any stretch of driving, so [`super::exact`] inverts it unchanged; with the
/// commanded odometry this is the final-error test of `(4/3)·θ_legs` per run.
pub fn equivalent_test(test: &SquareTest) -> Result<SquareTest, CalibrationError> {
    let map = |runs: &[super::RunMeasurement],
               direction: Direction|
     -> Result<Vec<super::RunMeasurement>, CalibrationError> {
        let _ = direction;
        let kept: Vec<super::RunMeasurement> = runs
            .iter()
            .filter_map(|r| {
                r.legs.map(|l| super::RunMeasurement {
                    heading_error_rad: l.heading_error_rad(),
                    odometry: Some(l.odometry()),
                    noise_variance_rad2: l.variance_between(0, 3),
                    ..*r
                })
            })
            .collect();
        if kept.is_empty() {
            return Err(CalibrationError::MissingLegHeadings);
        }
        Ok(kept)
    };
    Ok(SquareTest {
        cw: map(&test.cw, Direction::Cw)?,
        ccw: map(&test.ccw, Direction::Ccw)?,
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
                    true_turn += Displacement::of_wheels(tl, tr, truth.wheelbase_m).turn_rad;
                    let dth = Displacement::of_wheels(sl, sr, b).turn_rad;
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
            let legs = leg_measurement(&samples, 0.39).unwrap().heading_error_rad();
            assert!(
                (4.0 / 3.0 * legs - pred).abs() < 1e-9,
                "{ccw}: {legs} vs {pred}"
            );
        }
    }
}
