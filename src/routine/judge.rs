//! The routine's judgement of what it measured: whether a square's headings are plausible
//! (the compass's sign convention against the commanded turns), the test built from a pair of
//! squares and its Cramér–Rao bound, convergence between rounds, and the gyro warning.

use super::*;

/// Robot time of motion `motion` (1..=8, legs odd) of a square at the speed limits (s).
pub(super) fn motion_time_s(cfg: &RoutineConfig, motion: usize) -> f64 {
    if motion % 2 == 1 {
        cfg.side_m / cfg.max_speed_m_s
    } else {
        std::f64::consts::FRAC_PI_2 / cfg.max_rate_rad_s
    }
}

/// Robot time of a square's eight motions at the speed limits (s).
pub(super) fn square_motion_time_s(cfg: &RoutineConfig) -> f64 {
    (1..=8).map(|k| motion_time_s(cfg, k)).sum()
}

/// What a gyro's scale error does to the estimate, for a heading that is or may be integrated
/// from a gyro whose scale was not given.
pub fn gyro_warning(kind: HeadingKind, scale_error: Option<f64>) -> Option<String> {
    if scale_error.is_some() {
        return None;
    }
    let what = "E_b (the wheelbase) carries the gyro's scale error one to one: a gyro 1 % fast \
                writes a wheelbase 1 % off, and no square can tell; measure it with `odocal spin` \
                and give it with --gyro-scale-error";
    match kind {
        HeadingKind::Gyro => Some(format!("the heading is integrated from a gyro: {what}")),
        HeadingKind::Unknown => Some(format!(
            "the heading sensor's kind is unknown (--heading-kind): if it is integrated from a \
             gyro (an IMU without magnetometer), {what}"
        )),
        HeadingKind::Magnetic | HeadingKind::Reference => None,
    }
}

/// A square starts within this of the first square's heading (rad; 0.5°), or the robot turns
/// back to it ([`RoutineConfig::realign`]).
pub const REALIGN_WITHIN_RAD: f64 = 0.5 * std::f64::consts::PI / 180.0;

/// A correction that changes the heading error of a square by less than this (deg) is not
/// worth a write: it is below what a user can see or a compass can tell.
pub const VISIBLE_DEG: f64 = 0.1;

/// Whether a round's estimate ends the calibration, and why: its correction is within two of
/// its standard errors of no correction (nothing significant to apply), or it would change
/// the heading error of a square by less than [`VISIBLE_DEG`], or (when the user set one) it
/// is within the tolerance. A significant, visible correction is applied whatever its size.
/// Without run-to-run standard errors (one run per direction) the Cramér–Rao bound stands in.
pub fn convergence(
    cfg: &RoutineConfig,
    chosen: &Estimate,
    cramer_rao_std: Option<[f64; 2]>,
    wheelbase_m: f64,
) -> Option<String> {
    let (db, dd) = (chosen.e_b - 1.0, chosen.e_d - 1.0);
    if let Some(t) = cfg.tolerance {
        if db.abs() < t && dd.abs() < t {
            return Some(format!(
                "|E_b − 1| and |E_d − 1| are within the tolerance ±{t}"
            ));
        }
    }
    let sigma = match (chosen.e_b_std_err, chosen.e_d_std_err, cramer_rao_std) {
        (Some(b), Some(d), _) => Some((b, d)),
        (_, _, Some([b, d])) => Some((b, d)),
        _ => None,
    };
    if let Some((sb, sd)) = sigma {
        if db.abs() <= 2.0 * sb && dd.abs() <= 2.0 * sd {
            return Some(format!(
                "the correction is not significant (E_b − 1 = {db:+.5} ± {sb:.5}, E_d − 1 = \
                 {dd:+.5} ± {sd:.5}: within two standard errors)"
            ));
        }
    }
    let (cw, ccw) = crate::calibration::exact::predicted_heading_errors(
        &chosen.correction,
        cfg.side_m,
        wheelbase_m,
    );
    let gain_deg = cw.abs().max(ccw.abs()).to_degrees();
    (gain_deg < VISIBLE_DEG).then(|| {
        format!(
            "the correction would change a square's heading error by {gain_deg:.3}° at most, \
             below the {VISIBLE_DEG}° that can be seen"
        )
    })
}

/// Whether written parameters clearly helped ("never worse"): `Err` with the numbers when the
/// rounds diverged (the last round's estimate is no nearer 1 than the first's,
/// `round_distance` being `|E_b − 1| + |E_d − 1|` per round) or when the verification's mean
/// |heading error| is not below the first round's by two of its standard errors (the two
/// means' standard errors combined; an error of a run set with fewer than two runs counts its
/// spread as 0).
pub fn judge(
    before_deg: &[(Direction, f64)],
    after_deg: &[(Direction, f64)],
    round_distance: &[f64],
) -> Result<(), String> {
    if let (Some(first), Some(last)) = (round_distance.first(), round_distance.last()) {
        if round_distance.len() >= 2 && last >= first {
            return Err(format!(
                "the rounds diverged: |E_b − 1| + |E_d − 1| went from {first:.5} to {last:.5} \
                 over {} rounds",
                round_distance.len()
            ));
        }
    }
    // Per direction: a robot off by 50° one way and 10° the other is not a scatter of 40°.
    let stats = |v: &[(Direction, f64)]| {
        let mut parts = Vec::new();
        for d in [Direction::Cw, Direction::Ccw] {
            let x: Vec<f64> = v.iter().filter(|r| r.0 == d).map(|r| r.1).collect();
            if x.is_empty() {
                continue;
            }
            let n = x.len() as f64;
            let mean = x.iter().sum::<f64>() / n;
            let var = if x.len() > 1 {
                x.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (n - 1.0)
            } else {
                0.0
            };
            parts.push((mean, var / n));
        }
        let k = parts.len().max(1) as f64;
        (
            parts.iter().map(|p| p.0).sum::<f64>() / k,
            parts.iter().map(|p| p.1).sum::<f64>().sqrt() / k,
        )
    };
    let ((b, sb), (a, sa)) = (stats(before_deg), stats(after_deg));
    let margin = 2.0 * sb.hypot(sa);
    if a.is_nan() || b.is_nan() || a >= b - margin {
        return Err(format!(
            "mean |heading error| {b:.3}° before, {a:.3}° after (± {:.3}° at 2σ): no clear \
             improvement; the original parameters were restored",
            margin
        ));
    }
    Ok(())
}

pub(super) fn check_plausible(
    rec: &SquareRecord,
    run: &RunReport,
    params: &WheelParams,
    ui: &mut dyn RoutineUi,
) -> Result<(), RoutineError> {
    use std::f64::consts::{FRAC_PI_2, PI};
    let sign = rec.command.direction.turn_sign();
    let expected = sign * 2.0 * PI;
    // Reversed means at least half the square's turn the other way: a stream that saw little
    // of the square (lost or late samples) turns near zero, which is no evidence either way.
    let opposite = |turn: f64| turn * sign < -PI;
    // Too few samples to tell a turn's sign (a stream that barely started) are no evidence,
    // nor are headings so far apart that the robot may have turned a quarter between two:
    // their differences cannot be unwrapped.
    let track = rec.recording().track(params.wheelbase_m);
    let turns = track.turns();
    let widest_gap_s = track
        .readings
        .windows(2)
        .map(|w| w[1].0 - w[0].0)
        .fold(0.0, f64::max);
    let unwrappable = widest_gap_s * rec.command.max_rate_rad_s < FRAC_PI_2;
    let odometry_turn = (track.points.len() > 8).then_some(turns.odometry_rad);
    let compass_turn = turns
        .heading_rad
        .filter(|_| track.readings.len() > 8 && unwrappable);
    // The wheels must turn the robot the way the square was commanded; the opposite sign
    // means the encoders or motor channels are swapped or reversed.
    if let Some(turn) = odometry_turn.filter(|&t| opposite(t)) {
        return Err(RoutineError::Implausible(format!(
            "the drive's odometry turned {:.0}° during a {} square that should turn {:.0}°: \
             left and right wheels (or encoder directions) are swapped",
            turn.to_degrees(),
            rec.command.direction,
            expected.to_degrees()
        )));
    }
    match compass_turn {
        // The heading must turn about ±360° the way the square was commanded; the opposite
        // sign means the sensor reports clockwise-positive azimuth.
        Some(turn) if opposite(turn) => {
            return Err(RoutineError::Implausible(format!(
                "the heading turned {:.0}° during a {} square that should turn {:.0}°: the \
                 heading sensor reports clockwise-positive (negate it) or is mounted upside \
                 down",
                turn.to_degrees(),
                rec.command.direction,
                expected.to_degrees()
            )));
        }
        Some(_) => {}
        None if track.readings.len() > 8 => ui.event(&RoutineEvent::Warning(format!(
            "the heading stream has gaps of up to {widest_gap_s:.2} s: the heading sensor's \
             sign convention cannot be checked on this square"
        ))),
        None => ui.event(&RoutineEvent::Warning(
            "no heading stream: the heading sensor's sign convention cannot be checked".into(),
        )),
    }
    for w in &run.warnings {
        ui.event(&RoutineEvent::Warning(w.clone()));
    }
    Ok(())
}

/// The square test of `runs`; each run's heading error at rest carries the variance the
/// heading noise gives it (`heading_noise_rad` per reading, `heading_samples` averaged at each
/// end), the floor under its stated standard error ([`planning`]).
pub(super) fn square_test(
    cfg: &RoutineConfig,
    params: &WheelParams,
    runs: &[RunReport],
    heading_noise_rad: f64,
) -> SquareTest {
    let noise = (heading_noise_rad > 0.0)
        .then(|| heading_error_sigma(heading_noise_rad, cfg.heading_samples).powi(2));
    SquareTest::from_runs(
        cfg.side_m,
        params.wheelbase_m,
        runs.iter().map(|r| {
            let mut m = r.measurement();
            m.noise_variance_rad2 = noise;
            (r.direction, m)
        }),
    )
}

/// The Cramér–Rao bound's standard errors for `runs` per direction.
pub(super) fn cramer_rao_std(
    cfg: &RoutineConfig,
    e: &Estimate,
    heading_noise_rad: f64,
    wheelbase_m: f64,
    runs: usize,
) -> Option<[f64; 2]> {
    let design = TestDesign {
        side_m: cfg.side_m,
        wheelbase_m,
        runs_cw: runs,
        runs_ccw: runs,
        heading_error_sigma_rad: heading_error_sigma(heading_noise_rad, cfg.heading_samples),
    };
    cramer_rao_bound(e.e_b, e.e_d, cfg.split_convention(), &design)
        .ok()
        .map(|c| [c[(0, 0)].sqrt(), c[(1, 1)].sqrt()])
}

#[cfg(test)]
mod judge_tests {
    use super::judge;
    use crate::kinematics::Direction;

    fn cw(v: &[f64]) -> Vec<(Direction, f64)> {
        v.iter().map(|&x| (Direction::Cw, x)).collect()
    }

    #[test]
    fn only_a_clear_improvement_that_converges_passes() {
        // 5° → 0.1°, rounds converging: better.
        assert_eq!(
            judge(&cw(&[5.0, 5.2, 4.9]), &cw(&[0.1, 0.12]), &[0.03, 0.0005]),
            Ok(())
        );
        // The rounds oscillate (the last no nearer than the first): refused, with the numbers.
        let e = judge(&cw(&[37.7, 37.8]), &cw(&[38.6, 38.5]), &[0.5, 0.2, 0.5]).unwrap_err();
        assert!(e.contains("diverged") && e.contains("0.50000"), "{e}");
        // Worse after than before.
        let e = judge(&cw(&[1.0, 1.1]), &cw(&[1.3, 1.2]), &[0.02]).unwrap_err();
        assert!(e.contains("1.050° before, 1.250° after"), "{e}");
        // Better, but within the scatter: not clearly better.
        assert!(judge(&cw(&[0.30, 0.10, 0.50]), &cw(&[0.25, 0.05, 0.45]), &[0.001]).is_err());
        // A robot 58° off one way and 3° the other, each repeatable, brought to 0.1°: better
        // (pooled, the two directions would look like a scatter of 30°).
        let both = |a: f64, b: f64| {
            vec![
                (Direction::Cw, a),
                (Direction::Cw, a + 0.1),
                (Direction::Ccw, b),
                (Direction::Ccw, b - 0.1),
            ]
        };
        assert_eq!(
            judge(&both(58.0, 3.0), &both(0.1, 0.15), &[0.06, 0.0001]),
            Ok(())
        );
    }
}

#[cfg(test)]
mod convergence_tests {
    use super::convergence;
    use crate::calibration::{Estimate, Method};
    use crate::kinematics::{Correction, SplitConvention};
    use crate::routine::config::RoutineConfig;

    fn estimate(e_b: f64, e_d: f64, se: (f64, f64)) -> Estimate {
        let correction = Correction {
            left_diameter_scale: 1.0,
            right_diameter_scale: e_d,
            wheelbase_scale: e_b,
        };
        Estimate::of(
            Method::Exact,
            correction,
            Some(se),
            &SplitConvention::LeftNominal,
        )
    }

    #[test]
    fn a_significant_visible_correction_is_applied_however_small() {
        // The round 2: E_d 1.000976 ± 0.00003 on 4 m squares, thirty standard errors
        // from 1 and 0.2° a square: applied, although below the old fixed 0.001.
        let cfg = RoutineConfig::default();
        let e = estimate(1.0, 1.000976, (0.00003, 0.00003));
        assert_eq!(convergence(&cfg, &e, None, 0.39), None);
        // The user's explicit tolerance still ends it.
        let loose = RoutineConfig {
            tolerance: Some(0.001),
            ..RoutineConfig::default()
        };
        let why = convergence(&loose, &e, None, 0.39).unwrap();
        assert!(why.contains("tolerance"), "{why}");
    }

    #[test]
    fn a_correction_within_two_standard_errors_ends_the_rounds() {
        let cfg = RoutineConfig::default();
        let e = estimate(1.003, 0.998, (0.002, 0.0015));
        let why = convergence(&cfg, &e, None, 0.39).unwrap();
        assert!(why.contains("not significant"), "{why}");
        // Without run-to-run errors the Cramér–Rao bound stands in.
        let mut bare = e.clone();
        bare.e_b_std_err = None;
        bare.e_d_std_err = None;
        assert!(convergence(&cfg, &bare, Some([0.002, 0.0015]), 0.39).is_some());
        assert_eq!(convergence(&cfg, &bare, Some([0.0001, 0.0001]), 0.39), None);
    }

    #[test]
    fn a_significant_correction_too_small_to_see_ends_the_rounds() {
        // 20 ppm on E_b, precisely measured: significant, but it changes a 4 m square's
        // heading error by far less than 0.1°.
        let cfg = RoutineConfig::default();
        let e = estimate(1.00002, 1.0, (0.000001, 0.000001));
        let why = convergence(&cfg, &e, None, 0.39).unwrap();
        assert!(why.contains("below the 0.1°"), "{why}");
    }
}
