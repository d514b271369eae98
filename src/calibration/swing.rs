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

use super::CalibrationError;
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
    /// Readings used.
    pub points: usize,
}

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

/// Unwraps `h` in place (each step taken as the shortest way round).
fn unwrap(h: &mut [f64]) {
    for i in 1..h.len() {
        h[i] = h[i - 1] + wrap_angle(h[i] - h[i - 1]);
    }
}

/// Fits the deviation from the readings of each turn of a swing (one slice per turn in place,
/// in either direction).
pub fn fit(turns: &[Vec<SwingPoint>]) -> Result<SwingFit, CalibrationError> {
    let bad = |reason: String| CalibrationError::Unsupported(format!("compass swing: {reason}"));
    if turns.is_empty() {
        return Err(bad("no turns".into()));
    }
    // Per turn: φ from the turn's start, h unwrapped.
    let mut rows: Vec<(usize, f64, f64)> = Vec::new();
    let mut turned = Vec::with_capacity(turns.len());
    for (j, turn) in turns.iter().enumerate() {
        let usable: Vec<&SwingPoint> = turn
            .iter()
            .filter(|p| p.odometry_turn_rad.is_finite() && p.heading_rad.is_finite())
            .collect();
        let (Some(first), Some(last)) = (usable.first(), usable.last()) else {
            return Err(bad(format!("turn {} has no readings", j + 1)));
        };
        let span = last.odometry_turn_rad - first.odometry_turn_rad;
        if span.abs() < MIN_TURN_RAD {
            return Err(bad(format!(
                "turn {} covers {:.0}° of the {:.0}° a swing needs (whole turns separate the \
                 deviation from the turn's scale)",
                j + 1,
                span.abs().to_degrees(),
                MIN_TURN_RAD.to_degrees()
            )));
        }
        turned.push(span);
        let mut h: Vec<f64> = usable.iter().map(|p| p.heading_rad).collect();
        unwrap(&mut h);
        rows.extend(
            usable
                .iter()
                .zip(h)
                .map(|(p, h)| (j, p.odometry_turn_rad - first.odometry_turn_rad, h)),
        );
    }
    let (nt, n) = (turns.len(), rows.len());
    let p = nt + 5;
    if n < 4 * p {
        return Err(bad(format!(
            "{n} readings are too few to fit {p} unknowns (read the compass faster or turn \
             slower)"
        )));
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
            .map_err(|e| bad(format!("the fit failed: {e}")))?;
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
    let cov = normal
        .try_inverse()
        .ok_or_else(|| bad("the turns do not separate the deviation from the scale".into()))?
        * (sigma2 * inflation);
    let se = |k: usize| cov[(k, k)].max(0.0).sqrt();
    let deviation = Deviation([
        solution[nt + 1],
        solution[nt + 2],
        solution[nt + 3],
        solution[nt + 4],
    ]);
    if !(deviation.0.iter().all(|c| c.is_finite()) && solution[nt].is_finite()) {
        return Err(bad("the fit is not finite".into()));
    }
    Ok(SwingFit {
        deviation,
        deviation_std_err_rad: [se(nt + 1), se(nt + 2), se(nt + 3), se(nt + 4)],
        amplitude_rad: deviation.amplitude(),
        turn_scale: solution[nt],
        turn_scale_std_err: se(nt),
        offsets_rad: (0..nt).map(|j| wrap_angle(solution[j])).collect(),
        turned_rad: turned,
        residual_rms_rad: (rss / n as f64).sqrt(),
        points: n,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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
            let f = fit(&turns).unwrap();
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
        }
    }

    #[test]
    fn part_of_a_turn_is_refused_with_the_reason() {
        let d = Deviation::default();
        let err = fit(&[swing(&d, 0.0, 1.0, 0.5, 0.0)]).unwrap_err();
        assert!(err.to_string().contains("covers 180°"), "{err}");
        assert!(fit(&[]).is_err());
    }
}
