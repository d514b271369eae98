//! Legs matched by azimuth ("matched-legs"): the exact model ([`super::exact`]) on pairs of
//! legs that point the same way in both directions, so that a compass's deviation — any
//! function of the azimuth — cancels, and so does a start transient (as in [`super::legs`]).
//!
//! A clockwise square's legs point `ψ₀, ψ₀ − 90°, ψ₀ − 180°, ψ₀ − 270°`; a counter-clockwise
//! square's `ψ₀, ψ₀ + 90°, ψ₀ + 180°, ψ₀ + 270°` — the same four azimuths. With `θᵢⱼ` the heading
//! error from the middle of leg `i` to the middle of leg `j` (sensor minus odometry) and a
//! deviation `d(ψ)` in every reading:
//!
//! - legs 1→3: both directions go from `ψ₀` to `ψ₀ + 180°`, so `θ₁₃,cw − θ₁₃,ccw` holds
//!   `d(ψ₀+180°) − d(ψ₀)` twice, once with each sign: it cancels, and the difference, over
//!   `T₁₃ = ∓π`, is the turn term `G − 1` alone;
//! - legs 2→4: clockwise goes from `ψ₀ − 90°` to `ψ₀ + 90°`, counter-clockwise the other way,
//!   so `θ₂₄,cw + θ₂₄,ccw` holds `d(ψ₀+90°) − d(ψ₀−90°)` with both signs: it cancels, and the
//!   sum, over `D₂₄ = 2L`, is the leg term `2c/b` alone.
//!
//! With measured odometry each pair is the 2 × 2 solve of `θ = (G − 1)·T + (2c/b)·D`; `G`
//! comes from legs 1→3 and `c` from legs 2→4. The cancellation is exact when both directions
//! start at the same azimuth; squares that start a few degrees apart leave `d′·Δψ₀`, as the
//! methods at rest do. Each pair uses two turns and two sides of the square (`legs` uses
//! three), which costs about a fifth more noise for immunity to the compass.

use super::exact::{ratios_of, turn_and_leg_terms};
use super::{CalibrationError, Estimate, Method, RunMeasurement, SquareTest};
use crate::kinematics::{Displacement, SplitConvention};
use nalgebra::{SMatrix, SVector};

/// One run's pairs: `[θ₁₃, θ₂₄]`, their odometry, and their variances from the heading's
/// noise along the legs.
struct Pairs {
    theta: [f64; 2],
    odometry: [Displacement; 2],
    variance: Option<[f64; 2]>,
}

/// The pairs of one run.
fn pairs(r: &RunMeasurement) -> Option<Pairs> {
    let l = r.legs?;
    let (t13, o13) = l.between(0, 2);
    let (t24, o24) = l.between(1, 3);
    Some(Pairs {
        theta: [t13, t24],
        odometry: [o13, o24],
        variance: l
            .variance_between(0, 2)
            .zip(l.variance_between(1, 3))
            .map(|(a, b)| [a, b]),
    })
}

/// The means over one direction's runs that have legs: `[θ₁₃, θ₂₄]`, their odometry, each
/// run's `[θ₁₃, θ₂₄]` for the scatter, and the means' variances from the noise along the legs
/// when every run states them.
struct DirectionMeans {
    theta: [f64; 2],
    odometry: [Displacement; 2],
    rows: Vec<[f64; 2]>,
    noise: Option<[f64; 2]>,
}

fn means(runs: &[RunMeasurement]) -> Result<DirectionMeans, CalibrationError> {
    let rows: Vec<Pairs> = runs.iter().filter_map(pairs).collect();
    if rows.is_empty() {
        return Err(CalibrationError::MissingLegHeadings);
    }
    let n = rows.len() as f64;
    let noise = rows
        .iter()
        .map(|r| r.variance)
        .collect::<Option<Vec<[f64; 2]>>>()
        .map(|v| {
            let sum = |k: usize| v.iter().map(|x| x[k]).sum::<f64>() / (n * n);
            [sum(0), sum(1)]
        });
    let mut m = DirectionMeans {
        theta: [0.0; 2],
        odometry: [Displacement::default(); 2],
        rows: rows.iter().map(|r| r.theta).collect(),
        noise,
    };
    for Pairs {
        theta,
        odometry: odo,
        ..
    } in &rows
    {
        for k in 0..2 {
            m.theta[k] += theta[k] / n;
            m.odometry[k].distance_m += odo[k].distance_m / n;
            m.odometry[k].turn_rad += odo[k].turn_rad / n;
        }
    }
    Ok(m)
}

/// `(E_b, E_d)` from the four means `[θ₁₃,cw, θ₂₄,cw, θ₁₃,ccw, θ₂₄,ccw]`.
fn ratios(
    theta: &SVector<f64, 4>,
    cw: &DirectionMeans,
    ccw: &DirectionMeans,
    wheelbase_m: f64,
    convention: &SplitConvention,
) -> Result<(f64, f64), CalibrationError> {
    let undetermined = || CalibrationError::NotPhysical {
        method: Method::MatchedLegs,
        reason: "the two directions' odometry between the legs does not tell the turn and leg \
                 terms apart"
            .into(),
    };
    let (g13, _) = turn_and_leg_terms((theta[0], cw.odometry[0]), (theta[2], ccw.odometry[0]))
        .ok_or_else(undetermined)?;
    let (_, k24) = turn_and_leg_terms((theta[1], cw.odometry[1]), (theta[3], ccw.odometry[1]))
        .ok_or_else(undetermined)?;
    let (g, c) = (1.0 + g13, 0.5 * k24 * wheelbase_m);
    ratios_of(g - c, g + c, Method::MatchedLegs, convention)
}

/// The estimate, with standard errors from the run-to-run scatter of `[θ₁₃, θ₂₄]` when each
/// direction has at least two runs with legs, floored by the heading's noise along the legs
/// (as [`super::estimate`] does; delta method, numerical Jacobian).
pub fn estimate(
    test: &SquareTest,
    convention: SplitConvention,
) -> Result<Estimate, CalibrationError> {
    test.validate()?;
    let (cw, ccw) = (means(&test.cw)?, means(&test.ccw)?);
    let theta = SVector::<f64, 4>::new(cw.theta[0], cw.theta[1], ccw.theta[0], ccw.theta[1]);
    let b = test.wheelbase_m;
    let (e_b, e_d) = ratios(&theta, &cw, &ccw, b, &convention)?;
    if !(e_b.is_finite() && e_b > 0.0 && e_d.is_finite() && e_d > 0.0) {
        return Err(CalibrationError::NotPhysical {
            method: Method::MatchedLegs,
            reason: format!("estimate E_b = {e_b}, E_d = {e_d} is not a robot"),
        });
    }
    let correction = convention.split(e_b, e_d, b)?;
    // Each direction's covariance: the scatter of its runs (two or more), with the noise along
    // the legs as a floor under the variances (see `super::standard_errors`).
    // With `noise_only`, the noise along the legs alone (one run in a direction: no scatter).
    let covariance = |noise_only: bool| -> Option<SMatrix<f64, 4, 4>> {
        let mut cov = SMatrix::<f64, 4, 4>::zeros();
        for (offset, d) in [(0, &cw), (2, &ccw)] {
            let n = d.rows.len() as f64;
            if noise_only {
                let v = d.noise?;
                for k in 0..2 {
                    cov[(offset + k, offset + k)] = v[k];
                }
                continue;
            }
            if d.rows.len() >= 2 {
                for i in 0..2 {
                    for j in 0..2 {
                        let s: f64 = d
                            .rows
                            .iter()
                            .map(|r| (r[i] - d.theta[i]) * (r[j] - d.theta[j]))
                            .sum();
                        cov[(offset + i, offset + j)] = s / (n - 1.0) / n;
                    }
                }
            } else {
                return None;
            }
            if let Some(v) = d.noise {
                for k in 0..2 {
                    cov[(offset + k, offset + k)] = cov[(offset + k, offset + k)].max(v[k]);
                }
            }
        }
        Some(cov)
    };
    let propagate = |cov: SMatrix<f64, 4, 4>| {
        let mut jac = SMatrix::<f64, 2, 4>::zeros();
        for k in 0..4 {
            let h = 1e-7 * theta[k].abs().max(1.0);
            let (mut plus, mut minus) = (theta, theta);
            plus[k] += h;
            minus[k] -= h;
            let p = ratios(&plus, &cw, &ccw, b, &convention).ok()?;
            let m = ratios(&minus, &cw, &ccw, b, &convention).ok()?;
            // E_b as the split writes it, so a measured scale's rescaling is in the error.
            let split = |r: (f64, f64)| convention.split(r.0, r.1, b).ok();
            let (p, m) = (split(p)?, split(m)?);
            jac[(0, k)] = (p.e_b() - m.e_b()) / (2.0 * h);
            jac[(1, k)] = (p.e_d() - m.e_d()) / (2.0 * h);
        }
        let out = jac * cov * jac.transpose();
        Some((out[(0, 0)].max(0.0).sqrt(), out[(1, 1)].max(0.0).sqrt()))
    };
    let std_err = covariance(false).and_then(propagate);
    // The noise alone stands in only where there is no scatter to measure.
    let noise = std_err
        .is_none()
        .then(|| covariance(true).and_then(propagate))
        .flatten();
    Ok(
        Estimate::of(Method::MatchedLegs, correction, std_err, &convention)
            .with_noise_std_err(noise),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::legs::{LegMean, LegMeasurement};
    use crate::kinematics::{Correction, Direction};
    use crate::sim::sensor::Deviation;
    use std::f64::consts::FRAC_PI_2;

    /// The four legs of a square driven as commanded by a robot with `u_L`, `u_R`, seen by a
    /// compass with deviation `dev`, starting at azimuth `psi0`; `drift`: whether the robot's
    /// own heading error moves the azimuths the compass sees (it does; without it the
    /// cancellation is exact).
    fn run(
        direction: Direction,
        correction: &Correction,
        side: f64,
        b: f64,
        dev: &Deviation,
        psi0: f64,
        drift: bool,
    ) -> RunMeasurement {
        let u_l = correction.left_diameter_scale / correction.wheelbase_scale;
        let u_r = correction.right_diameter_scale / correction.wheelbase_scale;
        let (g, c) = (0.5 * (u_l + u_r), 0.5 * (u_r - u_l));
        let turn = direction.turn_sign() * FRAC_PI_2;
        let mut legs = [LegMean::default(); 4];
        for (k, leg) in legs.iter_mut().enumerate() {
            let kf = k as f64;
            // From the middle of leg 1: k turns and k sides.
            let (t, d) = (kf * turn, kf * side);
            let truth_turn = (g - 1.0) * t + 2.0 * c / b * d;
            let azimuth = psi0 + t + if drift { truth_turn } else { 0.0 };
            leg.error_rad = truth_turn + dev.at(azimuth);
            leg.odometry = Displacement {
                distance_m: d,
                turn_rad: t,
            };
        }
        RunMeasurement {
            legs: Some(LegMeasurement { legs }),
            ..RunMeasurement::default()
        }
    }

    #[test]
    fn any_deviation_cancels_and_the_robot_is_recovered() {
        let truth = Correction {
            left_diameter_scale: 1.0,
            right_diameter_scale: 0.992,
            wheelbase_scale: 0.976,
        };
        let (side, b) = (2.0, 0.39);
        for (dev, psi0) in [
            ("0,0,0,0", 0.3),
            ("2.2,0,0,0.7", 0.0),
            ("-1.5,2.5,0.8,-1.1", 2.0),
            ("3,0,-3,0", -1.2),
        ] {
            let dev: Deviation = dev.parse().unwrap();
            let test = |drift: bool| SquareTest {
                side_m: side,
                wheelbase_m: b,
                cw: vec![run(Direction::Cw, &truth, side, b, &dev, psi0, drift); 2],
                ccw: vec![run(Direction::Ccw, &truth, side, b, &dev, psi0, drift); 2],
            };
            let error = |e: &Estimate| (e.e_b - 0.976).abs() + (e.e_d - 0.992).abs();
            // Legs that point the same way: the deviation cancels exactly.
            let e = estimate(&test(false), SplitConvention::LeftNominal).unwrap();
            assert!(error(&e) < 1e-12, "{dev:?}: {e:?}");
            // The robot's own error turns the azimuths by a few degrees (here up to 4°) and
            // leaves `d′·Δψ` — with a 3° second harmonic up to 0.15 % — far below what the leg
            // method between legs 1 and 4 keeps; a compass swing removes most of `d` first.
            let e = estimate(&test(true), SplitConvention::LeftNominal).unwrap();
            let legs = crate::calibration::estimate(
                Method::Legs,
                &test(true),
                SplitConvention::LeftNominal,
            )
            .unwrap();
            assert!(error(&e) < 2e-3, "{dev:?}: {e:?}");
            if !dev.is_zero() {
                assert!(
                    error(&legs) > 3.0 * error(&e),
                    "{dev:?}: legs {legs:?}, {e:?}"
                );
            }
        }
    }
}
