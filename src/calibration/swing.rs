//! A compass swing: the robot turns in place slowly, full turns each way, and the compass's
//! heading against the odometry's turn gives the compass's deviation curve.
//!
//! A compass on a robot reads `h = ψ + d(ψ)` for a true heading `ψ`, with the deviation
//! `d(ψ) = A₁·sin ψ + B₁·cos ψ + A₂·sin 2ψ + B₂·cos 2ψ` ([`Deviation`], marine practice's B–E).
//! Turning in place, the true heading is a straight line in the odometry's turn `φ`:
//! `ψ = a + s·φ`, where `s` (the true turn per odometry turn) carries the wheelbase error and,
//! for a gyro, its scale error. So each turn's readings are
//!
//! `h = a_j + s·φ + A₁·sin ψ + B₁·cos ψ + A₂·sin 2ψ + B₂·cos 2ψ`
//!
//! with an offset `a_j` per turn (where it started, and any lag of the readings, which shows as
//! an offset of opposite sign in the two directions) and one `s`. A scale error is linear in `φ`,
//! a deviation periodic, so over whole turns they separate: the fit is linear least squares in
//! `(a_j, s, A₁, B₁, A₂, B₂)`, with `ψ` taken from the fitted line (first from the readings
//! themselves; the difference is of the order of `d·d′`, a hundredth of a degree for 3°).
//!
//! Standard errors count the readings' lag-one correlation (a compass that filters repeats
//! itself) as [`super::legs::noise_variance_of_mean`] does. What is left after the fit (the
//! residual) is the compass's noise and whatever the four harmonics do not describe.
//!
//! The readings are unwrapped along the odometry's turn, not the shortest way from one reading
//! to the next: a link that loses readings leaves gaps, and across a gap of more than half a
//! turn the shortest way is the wrong one, which a fit turns into tens of degrees of deviation.
//! A fit is checked before it is returned ([`SwingError`] says why one is refused): every
//! turn's readings close enough together and every sector of the heading read in each
//! direction, a residual the compass's noise explains, the turns each way fitted alone agreeing
//! on the curve, and a curve and a scale of a plausible size. A refused fit is never applied.

use crate::kinematics::{wrap_angle, Deviation};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

/// One reading during a swing: the odometry's turn since the swing began (rad, not wrapped) and
/// the compass's heading (rad; wrapped or unwrapped, it is unwrapped here).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SwingPoint {
    /// The odometry's turn (rad, counter-clockwise positive, not wrapped).
    pub odometry_turn_rad: f64,
    /// The heading read (rad, counter-clockwise positive).
    pub heading_rad: f64,
}

/// Each turn of a swing must cover this much (rad; 95 % of a full turn) for the harmonics to
/// separate from the line.
pub const MIN_TURN_RAD: f64 = 0.95 * TAU;

/// A deviation larger than this (rad; 2°) is worth removing at its source.
pub const LARGE_DEVIATION_RAD: f64 = 2.0 * std::f64::consts::PI / 180.0;

/// The most odometry turn between two readings of one turn (rad; 120°): beyond it the curve
/// between them is guessed, not measured, and the odometry's turn (within
/// [`MAX_SCALE_ERROR`]) no longer certainly tells which way round the readings unwrap. Shorter
/// gaps (a host that stalled, a lossy link) are crossed along the odometry; the sectors they
/// leave thin are judged by [`MIN_PER_SECTOR`].
pub const MAX_GAP_RAD: f64 = TAU / 3.0;

/// Sectors of the heading whose readings are counted in each direction ([`MIN_PER_SECTOR`]).
pub const SECTORS: usize = 12;

/// Readings each sector needs in each direction.
pub const MIN_PER_SECTOR: usize = 3;

/// The largest deviation taken as measured (rad; 15°). A compass that deviates more needs its
/// own calibration first; and removing such a curve by fixed-point iteration
/// ([`Deviation::remove`]) no longer converges once its slope nears one.
pub const MAX_DEVIATION_RAD: f64 = 15.0 * std::f64::consts::PI / 180.0;

/// How far the true turn per odometry turn may be from one (20 %): further, the compass or the
/// odometry did not see the turn the robot made.
pub const MAX_SCALE_ERROR: f64 = 0.2;

/// The residual allowed beyond twice the compass's noise (rad; 0.25°): harmonics above the
/// second that the fit does not describe.
pub const RESIDUAL_MARGIN_RAD: f64 = 0.25 * std::f64::consts::PI / 180.0;

/// The residual allowed when the compass's noise is not known (rad; 1.5°).
pub const RESIDUAL_UNKNOWN_NOISE_RAD: f64 = 1.5 * std::f64::consts::PI / 180.0;

/// How far the curves of the turns each way may differ beyond five of their standard errors
/// (rad; 0.5°).
pub const AGREEMENT_MARGIN_RAD: f64 = 0.5 * std::f64::consts::PI / 180.0;

/// Why a swing gives no deviation curve. Every check names what it measured and what was
/// allowed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SwingError {
    /// No turns at all.
    #[error("no turns were recorded")]
    NoTurns,
    /// A turn has no usable readings.
    #[error("turn {turn} has no readings")]
    NoReadings {
        /// 1-based turn.
        turn: usize,
    },
    /// A turn covers less than [`MIN_TURN_RAD`].
    #[error(
        "turn {turn} covers {covered_deg:.0}° of the {needed_deg:.0}° a swing needs (whole \
         turns separate the deviation from the turn's scale)"
    )]
    TurnTooShort {
        /// 1-based turn.
        turn: usize,
        /// Its odometry turn (degrees).
        covered_deg: f64,
        /// What is needed (degrees).
        needed_deg: f64,
    },
    /// Only one direction was turned.
    #[error("every turn went {0}: a swing needs turns both ways to tell a lag from a deviation")]
    OneDirection(&'static str),
    /// Readings are missing over a stretch of a turn.
    #[error(
        "turn {turn} has no reading for {gap_deg:.0}° of its turn (at most {max_deg:.0}°): \
         readings were lost; check the link, or turn slower"
    )]
    Gap {
        /// 1-based turn.
        turn: usize,
        /// The longest stretch without a reading (degrees of odometry turn).
        gap_deg: f64,
        /// The longest allowed (degrees).
        max_deg: f64,
    },
    /// A sector of the heading has too few readings in one direction.
    #[error(
        "the headings {from_deg:.0}° to {to_deg:.0}° have {readings} reading(s) turning \
         {direction} (at least {needed}): read the compass faster or turn slower"
    )]
    Coverage {
        /// `"counter-clockwise"` or `"clockwise"`.
        direction: &'static str,
        /// The sector's start (degrees).
        from_deg: f64,
        /// The sector's end (degrees).
        to_deg: f64,
        /// Readings in it.
        readings: usize,
        /// Readings needed.
        needed: usize,
    },
    /// Too few readings for the unknowns.
    #[error(
        "{readings} readings are too few to fit {unknowns} unknowns (read the compass faster \
         or turn slower)"
    )]
    TooFewReadings {
        /// Readings.
        readings: usize,
        /// Unknowns.
        unknowns: usize,
    },
    /// The least-squares problem has no unique or finite solution.
    #[error("the fit failed: {0}")]
    Numerical(String),
    /// What the fit leaves is more than the compass's noise explains.
    #[error(
        "the fit leaves {residual_deg:.2}° RMS, more than the {limit_deg:.2}° the compass's \
         noise explains: the readings do not follow a deviation curve"
    )]
    Residual {
        /// Residual RMS (degrees).
        residual_deg: f64,
        /// Allowed (degrees).
        limit_deg: f64,
    },
    /// The turns each way, fitted alone, give different curves.
    #[error(
        "the turns counter-clockwise and clockwise give curves up to {difference_deg:.2}° apart \
         (at most {limit_deg:.2}°): the compass or the odometry did not see the same robot \
         both ways"
    )]
    Disagreement {
        /// The largest difference of the two curves over a turn (degrees).
        difference_deg: f64,
        /// Allowed (degrees).
        limit_deg: f64,
    },
    /// A deviation too large to be measured rather than an artefact.
    #[error(
        "a deviation of up to {amplitude_deg:.1}° (at most {max_deg:.0}° is taken as measured): \
         calibrate the compass itself (hard and soft iron) and mount it away from the motors, \
         then swing again"
    )]
    TooLarge {
        /// The curve's largest |d(ψ)| (degrees).
        amplitude_deg: f64,
        /// Allowed (degrees).
        max_deg: f64,
    },
    /// The compass turned a different amount from the odometry.
    #[error(
        "the compass turned {scale:.3} times the odometry's turn (at most {max_error:.0} % \
         off): the compass or the wheel travel did not follow the turn"
    )]
    Scale {
        /// True turn per odometry turn.
        scale: f64,
        /// Allowed error (%).
        max_error: f64,
    },
}

/// What a swing measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SwingFit {
    /// The deviation curve.
    pub deviation: Deviation,
    /// Standard errors of `[A₁, B₁, A₂, B₂]` (rad).
    pub deviation_std_err_rad: [f64; 4],
    /// The largest |d(ψ)| over a turn (rad).
    pub amplitude_rad: f64,
    /// The true turn per odometry turn in place, as the compass saw it (`s`).
    pub turn_scale: f64,
    /// Standard error of `turn_scale`.
    pub turn_scale_std_err: f64,
    /// Where each turn started (`a_j`, rad, wrapped).
    pub offsets_rad: Vec<f64>,
    /// Each turn's odometry turn (rad, signed).
    pub turned_rad: Vec<f64>,
    /// Root-mean-square of what the fit leaves (rad).
    pub residual_rms_rad: f64,
    /// The largest difference between the curves of the turns each way fitted alone (rad).
    #[serde(default)]
    pub direction_difference_rad: f64,
    /// Readings used.
    pub points: usize,
    /// The deviation each reading measured, `(ψ, h − a_j − s·φ)` (rad, ψ in [0, 2π)): the
    /// fitted curve's data, at most [`MEASURED_POINTS`] of them evenly through the readings,
    /// for a report to show the curve against. Empty in fits stored before it existed.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub measured: Vec<[f64; 2]>,
}

/// Most measured points a [`SwingFit`] keeps (a reading every degree or so of two turns each
/// way).
pub const MEASURED_POINTS: usize = 720;

impl SwingFit {
    /// Advice when the deviation is large enough to deal with at its source, else `None`.
    pub fn advice(&self) -> Option<String> {
        (self.amplitude_rad > LARGE_DEVIATION_RAD).then(|| {
            format!(
                "the compass deviates by up to {:.1}° with the heading: mount it away from the \
                 motors, the battery and steel, and run the compass's own (hard- and soft-iron) \
                 calibration; odocal removes the curve it measured, but a smaller one leaves \
                 less to remove",
                self.amplitude_rad.to_degrees()
            )
        })
    }
}

/// A turn's usable readings, their headings unwrapped along the odometry's turn: each step is
/// the odometry's step plus the compass's difference from it taken the shortest way, so that a
/// gap of any length during which the robot kept turning is crossed on the right turn (the
/// shortest way from reading to reading is wrong beyond half a turn). Returns
/// `(φ from the turn's first reading, h unwrapped)`.
fn unwrap_along(turn: &[&SwingPoint]) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::with_capacity(turn.len());
    let Some(first) = turn.first() else {
        return out;
    };
    let mut h = first.heading_rad;
    out.push((0.0, h));
    for w in turn.windows(2) {
        let dphi = w[1].odometry_turn_rad - w[0].odometry_turn_rad;
        h += dphi + wrap_angle(w[1].heading_rad - w[0].heading_rad - dphi);
        out.push((w[1].odometry_turn_rad - first.odometry_turn_rad, h));
    }
    out
}

/// One least-squares solution of the swing model over `rows` `(turn, φ, h)` of `nt` turns.
struct Solution {
    deviation: Deviation,
    std_err: [f64; 4],
    scale: f64,
    scale_std_err: f64,
    offsets: Vec<f64>,
    /// Each turn's start as fitted, not wrapped: the readings are unwrapped against it.
    offsets_unwrapped: Vec<f64>,
    residual_rms: f64,
}

fn solve(rows: &[(usize, f64, f64)], nt: usize) -> Result<Solution, SwingError> {
    let n = rows.len();
    let p = nt + 5;
    if n < 4 * p {
        return Err(SwingError::TooFewReadings {
            readings: n,
            unknowns: p,
        });
    }
    // ψ for the harmonics: the readings first, then the fitted line.
    let mut psi: Vec<f64> = rows.iter().map(|r| r.2).collect();
    let mut solution = DVector::<f64>::zeros(p);
    let mut design = DMatrix::<f64>::zeros(n, p);
    let y = DVector::from_iterator(n, rows.iter().map(|r| r.2));
    for _ in 0..2 {
        for (i, &(j, phi, _)) in rows.iter().enumerate() {
            let a = psi[i];
            design[(i, j)] = 1.0;
            design[(i, nt)] = phi;
            design[(i, nt + 1)] = a.sin();
            design[(i, nt + 2)] = a.cos();
            design[(i, nt + 3)] = (2.0 * a).sin();
            design[(i, nt + 4)] = (2.0 * a).cos();
        }
        solution = design
            .clone()
            .svd(true, true)
            .solve(&y, 1e-12)
            .map_err(|e| SwingError::Numerical(e.to_string()))?;
        for (i, &(j, phi, _)) in rows.iter().enumerate() {
            psi[i] = solution[j] + solution[nt] * phi;
        }
    }
    let residual = &y - &design * &solution;
    let rss = residual.norm_squared();
    let sigma2 = rss / (n - p) as f64;
    let rho = if rss > 0.0 {
        (residual
            .as_slice()
            .windows(2)
            .map(|w| w[0] * w[1])
            .sum::<f64>()
            / rss)
            .clamp(0.0, 0.99)
    } else {
        0.0
    };
    let inflation = (1.0 + rho) / (1.0 - rho);
    let normal = design.transpose() * &design;
    let cov = normal.try_inverse().ok_or_else(|| {
        SwingError::Numerical("the turns do not separate the deviation from the scale".into())
    })? * (sigma2 * inflation);
    let se = |k: usize| cov[(k, k)].max(0.0).sqrt();
    let deviation = Deviation([
        solution[nt + 1],
        solution[nt + 2],
        solution[nt + 3],
        solution[nt + 4],
    ]);
    if !(deviation.0.iter().all(|c| c.is_finite()) && solution[nt].is_finite()) {
        return Err(SwingError::Numerical("the fit is not finite".into()));
    }
    Ok(Solution {
        deviation,
        std_err: [se(nt + 1), se(nt + 2), se(nt + 3), se(nt + 4)],
        scale: solution[nt],
        scale_std_err: se(nt),
        offsets: (0..nt).map(|j| wrap_angle(solution[j])).collect(),
        offsets_unwrapped: (0..nt).map(|j| solution[j]).collect(),
        residual_rms: (rss / n as f64).sqrt(),
    })
}

/// Every `MEASURED_POINTS`-th reading's measured deviation at its fitted heading: the reading
/// less the fitted line of its turn (what is left is the curve plus the noise).
fn measured(rows: &[(usize, f64, f64)], s: &Solution) -> Vec<[f64; 2]> {
    let step = rows.len().div_ceil(MEASURED_POINTS).max(1);
    rows.iter()
        .step_by(step)
        .map(|&(j, phi, h)| {
            let line = s.offsets_unwrapped[j] + s.scale * phi;
            [line.rem_euclid(TAU), wrap_angle(h - line)]
        })
        .collect()
}

fn direction_name(counter_clockwise: bool) -> &'static str {
    if counter_clockwise {
        "counter-clockwise"
    } else {
        "clockwise"
    }
}

/// Fits the deviation from the readings of each turn of a swing (one slice per turn in place,
/// turns both ways), and checks the fit ([`SwingError`]). `noise_std_rad` is the compass's
/// noise per reading at rest, when known: the residual is judged against it.
pub fn fit(turns: &[Vec<SwingPoint>], noise_std_rad: Option<f64>) -> Result<SwingFit, SwingError> {
    if turns.is_empty() {
        return Err(SwingError::NoTurns);
    }
    // Per turn: φ from the turn's first reading, h unwrapped along the odometry.
    let mut rows: Vec<(usize, f64, f64)> = Vec::new();
    let mut turned = Vec::with_capacity(turns.len());
    for (j, turn) in turns.iter().enumerate() {
        let (span, usable) = usable_readings(j, turn)?;
        turned.push(span);
        rows.extend(
            unwrap_along(&usable)
                .into_iter()
                .map(|(phi, h)| (j, phi, h)),
        );
    }
    let ccw = |j: usize| turned[j] > 0.0;
    if (0..turns.len()).all(ccw) || !(0..turns.len()).any(ccw) {
        return Err(SwingError::OneDirection(direction_name(ccw(0))));
    }
    check_coverage(&rows, &turned)?;
    let nt = turns.len();
    let all = solve(&rows, nt)?;
    // The turns each way alone: the same compass on the same robot gives the same curve.
    let (left, right) = (
        solve_one_direction(&rows, &turned, true)?,
        solve_one_direction(&rows, &turned, false)?,
    );
    let difference = Deviation(std::array::from_fn(|k| {
        left.deviation.0[k] - right.deviation.0[k]
    }))
    .amplitude();
    let difference_std: f64 = (0..4)
        .map(|k| left.std_err[k].powi(2) + right.std_err[k].powi(2))
        .sum::<f64>()
        .sqrt();
    let amplitude = check_solution(&all, difference, difference_std, noise_std_rad)?;
    let measured = measured(&rows, &all);
    Ok(SwingFit {
        deviation: all.deviation,
        deviation_std_err_rad: all.std_err,
        amplitude_rad: amplitude,
        turn_scale: all.scale,
        turn_scale_std_err: all.scale_std_err,
        offsets_rad: all.offsets,
        turned_rad: turned,
        residual_rms_rad: all.residual_rms,
        direction_difference_rad: difference,
        points: rows.len(),
        measured,
    })
}

/// Turn `j`'s finite readings and its odometry turn, once it is long enough and has no gap.
fn usable_readings(j: usize, turn: &[SwingPoint]) -> Result<(f64, Vec<&SwingPoint>), SwingError> {
    let usable: Vec<&SwingPoint> = turn
        .iter()
        .filter(|p| p.odometry_turn_rad.is_finite() && p.heading_rad.is_finite())
        .collect();
    let (Some(first), Some(last)) = (usable.first(), usable.last()) else {
        return Err(SwingError::NoReadings { turn: j + 1 });
    };
    let span = last.odometry_turn_rad - first.odometry_turn_rad;
    if span.abs() < MIN_TURN_RAD {
        return Err(SwingError::TurnTooShort {
            turn: j + 1,
            covered_deg: span.abs().to_degrees(),
            needed_deg: MIN_TURN_RAD.to_degrees(),
        });
    }
    let gap = usable
        .windows(2)
        .map(|w| (w[1].odometry_turn_rad - w[0].odometry_turn_rad).abs())
        .fold(0.0, f64::max);
    if gap > MAX_GAP_RAD {
        return Err(SwingError::Gap {
            turn: j + 1,
            gap_deg: gap.to_degrees(),
            max_deg: MAX_GAP_RAD.to_degrees(),
        });
    }
    Ok((span, usable))
}

/// Checks every sector of the heading was read in each direction (`turned`: each turn's turn).
fn check_coverage(rows: &[(usize, f64, f64)], turned: &[f64]) -> Result<(), SwingError> {
    let ccw = |j: usize| turned[j] > 0.0;
    // Every sector of the heading read in each direction (the readings stand for ψ here: they
    // differ from it by the deviation, well inside a sector).
    for counter_clockwise in [true, false] {
        let mut count = [0usize; SECTORS];
        for &(_, _, h) in rows.iter().filter(|r| ccw(r.0) == counter_clockwise) {
            let k = (h.rem_euclid(TAU) / TAU * SECTORS as f64) as usize;
            count[k.min(SECTORS - 1)] += 1;
        }
        if let Some((k, &readings)) = count.iter().enumerate().find(|(_, c)| **c < MIN_PER_SECTOR) {
            let width = 360.0 / SECTORS as f64;
            return Err(SwingError::Coverage {
                direction: direction_name(counter_clockwise),
                from_deg: k as f64 * width,
                to_deg: (k + 1) as f64 * width,
                readings,
                needed: MIN_PER_SECTOR,
            });
        }
    }
    Ok(())
}

/// The fit of the turns in one direction alone, renumbered among themselves.
fn solve_one_direction(
    rows: &[(usize, f64, f64)],
    turned: &[f64],
    counter_clockwise: bool,
) -> Result<Solution, SwingError> {
    let ccw = |j: usize| turned[j] > 0.0;
    let nt = turned.len();
    // Turn j of the swing is turn local[j] of its direction.
    let mut local = vec![0; nt];
    let mut count = 0;
    for j in (0..nt).filter(|&j| ccw(j) == counter_clockwise) {
        local[j] = count;
        count += 1;
    }
    let rows: Vec<(usize, f64, f64)> = rows
        .iter()
        .filter(|r| ccw(r.0) == counter_clockwise)
        .map(|&(j, phi, h)| (local[j], phi, h))
        .collect();
    solve(&rows, count)
}

/// Checks the fit's residual, the directions' agreement and the sizes; returns the amplitude.
fn check_solution(
    all: &Solution,
    difference: f64,
    difference_std: f64,
    noise_std_rad: Option<f64>,
) -> Result<f64, SwingError> {
    let residual_limit = noise_std_rad
        .filter(|s| s.is_finite() && *s > 0.0)
        .map_or(RESIDUAL_UNKNOWN_NOISE_RAD, |s| {
            2.0 * s + RESIDUAL_MARGIN_RAD
        });
    if all.residual_rms > residual_limit {
        return Err(SwingError::Residual {
            residual_deg: all.residual_rms.to_degrees(),
            limit_deg: residual_limit.to_degrees(),
        });
    }
    let agreement_limit = 5.0 * difference_std + AGREEMENT_MARGIN_RAD;
    if difference > agreement_limit {
        return Err(SwingError::Disagreement {
            difference_deg: difference.to_degrees(),
            limit_deg: agreement_limit.to_degrees(),
        });
    }
    let amplitude = all.deviation.amplitude();
    if amplitude > MAX_DEVIATION_RAD {
        return Err(SwingError::TooLarge {
            amplitude_deg: amplitude.to_degrees(),
            max_deg: MAX_DEVIATION_RAD.to_degrees(),
        });
    }
    if (all.scale - 1.0).abs() > MAX_SCALE_ERROR {
        return Err(SwingError::Scale {
            scale: all.scale,
            max_error: 100.0 * MAX_SCALE_ERROR,
        });
    }
    Ok(amplitude)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The test compass's noise per reading (rad): the readings below scatter by up to 0.002.
    const NOISE: f64 = 0.0012;

    /// Readings of a compass with `dev` on a robot turning `turns` full turns from `start`,
    /// its true turn `scale` times the odometry's, with a little deterministic noise.
    fn swing(dev: &Deviation, start: f64, scale: f64, turns: f64, lag: f64) -> Vec<SwingPoint> {
        let n = 720;
        (0..=n)
            .map(|i| {
                let phi = turns * TAU * f64::from(i) / f64::from(n);
                // A reading that lags sees the robot a little behind.
                let psi = start + scale * (phi - lag * turns.signum());
                let noise = 0.002 * ((f64::from(i) * 12.9898).sin() * 43758.5453).fract();
                SwingPoint {
                    odometry_turn_rad: phi,
                    heading_rad: wrap_angle(psi + dev.at(psi) + noise),
                }
            })
            .collect()
    }

    #[test]
    fn the_deviation_and_the_scale_separate_over_whole_turns() {
        for (dev, start, scale) in [
            ("2.2,0,0,0.7", 0.3, 1.0246),
            ("-1.5,2.5,0.8,-1.1", 2.9, 0.99),
            ("0,0,0,0", -1.0, 1.0),
        ] {
            let d: Deviation = dev.parse().unwrap();
            let turns = vec![
                swing(&d, start, scale, 2.0, 0.01),
                swing(&d, start + 0.2, scale, -2.0, 0.01),
            ];
            let f = fit(&turns, Some(NOISE)).unwrap();
            for k in 0..4 {
                assert!(
                    (f.deviation.0[k] - d.0[k]).abs() < 2e-4,
                    "{dev}: {:?} vs {:?}",
                    f.deviation,
                    d
                );
                assert!(f.deviation_std_err_rad[k] < 1e-3, "{f:?}");
            }
            assert!((f.turn_scale - scale).abs() < 1e-4, "{dev}: {f:?}");
            assert!(f.residual_rms_rad < 0.003, "{f:?}");
            assert_eq!(f.advice().is_some(), d.amplitude() > LARGE_DEVIATION_RAD);
            assert!(f.direction_difference_rad < 5e-4, "{f:?}");
        }
    }

    #[test]
    fn part_of_a_turn_is_refused_with_the_reason() {
        let d = Deviation::default();
        let err = fit(&[swing(&d, 0.0, 1.0, 0.5, 0.0)], None).unwrap_err();
        assert!(err.to_string().contains("covers 180°"), "{err}");
        assert_eq!(fit(&[], None), Err(SwingError::NoTurns));
    }

    /// A deviation of the size marine practice calls common.
    fn typical() -> Deviation {
        "1.2,-0.8,0.5,0.3".parse().unwrap()
    }

    /// Two turns each way, as the routine swings.
    fn both_ways(d: &Deviation, scale: f64) -> Vec<Vec<SwingPoint>> {
        vec![
            swing(d, 0.4, scale, 2.0, 0.0),
            swing(d, 0.6, scale, -2.0, 0.0),
        ]
    }

    fn assert_recovers(f: &SwingFit, d: &Deviation) {
        for k in 0..4 {
            assert!(
                (f.deviation.0[k] - d.0[k]).abs() < 3e-4,
                "{:?} vs {:?}",
                f.deviation,
                d
            );
        }
    }

    #[test]
    fn a_gap_of_more_than_half_a_turn_is_unwrapped_along_the_odometry() {
        // 200° between two readings: the shortest way from one to the next is −160°.
        let a = SwingPoint {
            odometry_turn_rad: 0.0,
            heading_rad: 3.0,
        };
        let b = SwingPoint {
            odometry_turn_rad: 200f64.to_radians(),
            heading_rad: wrap_angle(3.0 + 200f64.to_radians() + 0.01),
        };
        let out = unwrap_along(&[&a, &b]);
        assert!(
            (out[1].1 - out[0].1 - 200f64.to_radians() - 0.01).abs() < 1e-12,
            "{out:?}"
        );
    }

    /// Headings handed over already unwrapped the wrong way round at some reading (a turn
    /// added from there on, as a shortest-way unwrap does across a long gap): the fit unwraps
    /// along the odometry and is unaffected.
    #[test]
    fn a_heading_unwrapped_the_wrong_way_upstream_gives_the_right_curve() {
        let d = typical();
        let mut turns = both_ways(&d, 1.02);
        for (i, p) in turns[0].iter_mut().enumerate().skip(300) {
            p.heading_rad += TAU * if i > 500 { 2.0 } else { 1.0 };
        }
        for p in turns[1].iter_mut().skip(100) {
            p.heading_rad -= TAU;
        }
        let f = fit(&turns, Some(NOISE)).unwrap();
        assert_recovers(&f, &d);
        assert!((f.turn_scale - 1.02).abs() < 1e-4, "{f:?}");
    }

    /// A lossy link: one reading in twenty lost at random and bursts of up to 30° of turn lost
    /// (one per turn and direction): the curve is the clean one's.
    #[test]
    fn readings_lost_in_bursts_leave_the_curve_as_it_is() {
        let d = typical();
        let clean = fit(&both_ways(&d, 1.0), Some(NOISE)).unwrap();
        let mut turns = both_ways(&d, 1.0);
        for (t, turn) in turns.iter_mut().enumerate() {
            let burst = 100 + 250 * t..130 + 250 * t;
            let kept: Vec<SwingPoint> = turn
                .iter()
                .enumerate()
                .filter(|(i, _)| {
                    let r = ((*i as f64 * 78.233).sin() * 43758.5453).fract().abs();
                    r > 0.05 && !burst.contains(i)
                })
                .map(|(_, p)| *p)
                .collect();
            *turn = kept;
        }
        let f = fit(&turns, Some(NOISE)).unwrap();
        assert!(
            f.points * 100 < clean.points * 95,
            "{} of {}",
            f.points,
            clean.points
        );
        assert_recovers(&f, &d);
    }

    #[test]
    fn a_gap_longer_than_a_third_of_a_turn_is_refused() {
        let d = typical();
        let mut turns = both_ways(&d, 1.0);
        // 720 readings over two turns: 1° each; 150 lost is 151° without a reading.
        turns[1].drain(400..550);
        match fit(&turns, Some(NOISE)) {
            Err(SwingError::Gap {
                turn: 2, gap_deg, ..
            }) => {
                assert!((gap_deg - 151.0).abs() < 0.5, "{gap_deg}")
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn sparse_readings_are_refused_for_their_coverage() {
        let d = typical();
        // One turn each way, a reading every 15°: two per 30° sector.
        let sparse = |turns: f64| -> Vec<SwingPoint> {
            swing(&d, 0.1, 1.0, turns, 0.0)
                .into_iter()
                .step_by(30)
                .collect()
        };
        let err = fit(&[sparse(1.0), sparse(-1.0)], None).unwrap_err();
        assert!(
            matches!(
                err,
                SwingError::Coverage {
                    readings: 2,
                    needed: 3,
                    ..
                }
            ),
            "{err}"
        );
        assert!(err.to_string().contains("read the compass faster"), "{err}");
    }

    #[test]
    fn turns_one_way_only_are_refused() {
        let d = typical();
        let turns = vec![swing(&d, 0.4, 1.0, 2.0, 0.0), swing(&d, 0.6, 1.0, 2.0, 0.0)];
        assert_eq!(
            fit(&turns, None),
            Err(SwingError::OneDirection("counter-clockwise"))
        );
    }

    /// Readings that scatter far more than the compass's noise at rest.
    #[test]
    fn a_residual_beyond_the_compass_noise_is_refused() {
        let d = typical();
        let mut turns = both_ways(&d, 1.0);
        for turn in &mut turns {
            for (i, p) in turn.iter_mut().enumerate() {
                p.heading_rad += 0.05 * ((i as f64 * 3.7).sin() * 9.1).sin();
            }
        }
        // The same readings pass when the compass is that noisy.
        assert!(fit(&turns, Some(0.04)).is_ok());
        match fit(&turns, Some(NOISE)) {
            Err(SwingError::Residual {
                residual_deg,
                limit_deg,
            }) => assert!(
                residual_deg > 1.5 && limit_deg < 0.4,
                "{residual_deg} {limit_deg}"
            ),
            other => panic!("{other:?}"),
        }
    }

    /// A curve one way and another the other way (an odometry or a compass that saw the turns
    /// differently): each way fits well alone, together they are refused.
    #[test]
    fn curves_that_differ_by_direction_are_refused() {
        let d = typical();
        let other: Deviation = "2.0,-0.8,-0.5,0.3".parse().unwrap();
        let turns = vec![
            swing(&d, 0.4, 1.0, 2.0, 0.0),
            swing(&other, 0.6, 1.0, -2.0, 0.0),
        ];
        match fit(&turns, None) {
            Err(SwingError::Disagreement {
                difference_deg,
                limit_deg,
            }) => {
                assert!(
                    difference_deg > 1.0 && limit_deg < 0.6,
                    "{difference_deg} {limit_deg}"
                )
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn an_implausible_curve_or_scale_is_refused() {
        let large: Deviation = "17,0,0,0".parse().unwrap();
        match fit(&both_ways(&large, 1.0), None) {
            Err(SwingError::TooLarge { amplitude_deg, .. }) => {
                assert!((amplitude_deg - 17.0).abs() < 0.1, "{amplitude_deg}")
            }
            other => panic!("{other:?}"),
        }
        match fit(&both_ways(&typical(), 1.3), None) {
            Err(SwingError::Scale { scale, .. }) => assert!((scale - 1.3).abs() < 1e-3),
            other => panic!("{other:?}"),
        }
    }
}
