//! A gyro's scale error: what it does to the estimate, how a spin test measures it, and its
//! removal from a square test.
//!
//! A heading integrated from a gyro reads `(1 + s)` times every true turn. Every method here
//! compares the heading's turn with the odometry's, and a square turns ±2π, so `s` shows as a
//! turn error of `2π·s` per square — exactly what a wheelbase error does: `E_b` carries `s` one
//! to one (a 1 % scale error writes a wheelbase 1 % off), and nothing in the squares can tell
//! the two apart. It has to be measured against something else:
//!
//! - a **spin test**: the robot turns `N` full turns in place and the user says how far past
//!   (or short of) its start mark on the floor it stopped, `δ`; the true turn is `N·2π + δ`
//!   and `s = gyro turn / true turn − 1` ([`scale_from_spin`]);
//! - a **reference** that sees the same turn (a compass over whole turns, where its deviation
//!   cancels): `s = gyro turn / reference turn − 1`.
//!
//! With `s` known, each heading change is divided by `1 + s` before estimating
//! ([`remove_scale`]). Sign conventions are the crate's: counter-clockwise positive.

use super::legs::LegMeasurement;
use super::{ideal_odometry, CalibrationError, RunMeasurement, SquareTest};
use crate::kinematics::{wrap_angle, Direction};
use std::f64::consts::TAU;

/// The gyro's scale error from a spin test: the heading read at rest before and after
/// (rad, wrapped), the signed number of full turns commanded (`+` counter-clockwise), and how
/// far past the start mark the robot stopped (rad, in the direction of the turn; negative
/// when short of it).
pub fn scale_from_spin(
    heading_before_rad: f64,
    heading_after_rad: f64,
    turns: f64,
    past_mark_rad: f64,
) -> Result<f64, CalibrationError> {
    if !(turns.is_finite() && turns.abs() >= 1.0 && past_mark_rad.is_finite()) {
        return Err(CalibrationError::Unsupported(format!(
            "a spin test needs at least one full turn and a finite angle to the mark (got \
             {turns} turns, {past_mark_rad} rad)"
        )));
    }
    let sign = turns.signum();
    let true_turn = turns * TAU + sign * past_mark_rad;
    // The gyro's turn: the commanded whole turns and what the wrapped readings add; a scale
    // error beyond ±π over the spin would wrap (over 10 turns, 5 %) and is refused below.
    let gyro_turn = turns * TAU
        + sign * past_mark_rad
        + wrap_angle(heading_after_rad - heading_before_rad - sign * past_mark_rad);
    let s = gyro_turn / true_turn - 1.0;
    if !(s.is_finite() && s.abs() < 0.1) {
        return Err(CalibrationError::Unsupported(format!(
            "a gyro scale error of {:.1} % is not a gyro's (check the mark and the count of \
             turns)",
            100.0 * s
        )));
    }
    Ok(s)
}

/// A heading error against the odometry's turn `turn_rad`, with the gyro's scale error `s`
/// taken out of the heading's change: the heading turned `θ + T` by the gyro, so truly
/// `(θ + T)/(1 + s)`. The heading's change need not be unwrapped (a square's at-rest readings
/// are a full turn apart): `θ` is wrapped and `T` carries the whole turns.
pub fn unscaled_error(error_rad: f64, turn_rad: f64, s: f64) -> f64 {
    (error_rad + turn_rad) / (1.0 + s) - turn_rad
}

/// Checks that `s` is a gyro's scale error (finite, under 10 %).
pub fn check_scale(s: f64) -> Result<(), CalibrationError> {
    if s.is_finite() && s.abs() < 0.1 {
        Ok(())
    } else {
        Err(CalibrationError::Unsupported(format!(
            "a gyro scale error of {s} is not a gyro's"
        )))
    }
}

/// One run with the gyro's scale error `s` taken out of its heading changes: the whole run's
/// ([`unscaled_error`] against the odometry's turn, the commanded one without it) and each
/// leg's along it.
pub fn remove_scale_from_run(run: &mut RunMeasurement, direction: Direction, side_m: f64, s: f64) {
    let t = run
        .odometry
        .unwrap_or_else(|| ideal_odometry(direction, side_m))
        .turn_rad;
    run.heading_error_rad = wrap_angle(unscaled_error(run.heading_error_rad, t, s));
    if let Some(legs) = &mut run.legs {
        remove_scale_from_legs(legs, s);
    }
}

/// The legs of one run with the gyro's scale error `s` taken out of their headings.
pub fn remove_scale_from_legs(legs: &mut LegMeasurement, s: f64) {
    for leg in &mut legs.legs {
        leg.error_rad = unscaled_error(leg.error_rad, leg.odometry.turn_rad, s);
    }
}

/// The test with the gyro's scale error `s` taken out of every heading change
/// ([`remove_scale_from_run`]).
pub fn remove_scale(test: &SquareTest, s: f64) -> Result<SquareTest, CalibrationError> {
    check_scale(s)?;
    let mut out = test.clone();
    for (runs, direction) in [(&mut out.cw, Direction::Cw), (&mut out.ccw, Direction::Ccw)] {
        for r in runs.iter_mut() {
            remove_scale_from_run(r, direction, test.side_m, s);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::exact::predicted_heading_errors;
    use crate::calibration::{estimate, Method, RunMeasurement};
    use crate::kinematics::{Correction, SplitConvention};

    #[test]
    fn a_spin_test_reads_the_scale_and_removing_it_gives_the_robot_back() {
        // Three turns counter-clockwise with a gyro 1 % fast; the robot stopped 2° past.
        let s = 0.01;
        let past = 2f64.to_radians();
        let true_turn = 3.0 * TAU + past;
        let before = 0.4;
        let after = wrap_angle(before + (1.0 + s) * true_turn);
        let got = scale_from_spin(before, after, 3.0, past).unwrap();
        assert!((got - s).abs() < 1e-12, "{got}");
        // Clockwise, short of the mark.
        let true_turn = -(2.0 * TAU - past);
        let after = wrap_angle(before + (1.0 + s) * true_turn);
        let got = scale_from_spin(before, after, -2.0, -past).unwrap();
        assert!((got - s).abs() < 1e-12, "{got}");
        assert!(scale_from_spin(0.0, 0.0, 0.5, 0.0).is_err());

        // Squares seen by that gyro: E_b is off by the scale until it is removed.
        let truth = Correction {
            left_diameter_scale: 1.0,
            right_diameter_scale: 0.992,
            wheelbase_scale: 0.976,
        };
        let (side, b) = (2.0, 0.39);
        let (cw, ccw) = predicted_heading_errors(&truth, side, b);
        let seen = |theta: f64, t: f64| RunMeasurement::heading((theta + t) * (1.0 + s) - t);
        let test = SquareTest {
            side_m: side,
            wheelbase_m: b,
            cw: vec![seen(cw, -TAU); 2],
            ccw: vec![seen(ccw, TAU); 2],
        };
        let raw = estimate(Method::Exact, &test, SplitConvention::LeftNominal).unwrap();
        assert!((raw.e_b / 0.976 - 1.0).abs() > 0.005, "{raw:?}");
        let fixed = estimate(
            Method::Exact,
            &remove_scale(&test, s).unwrap(),
            SplitConvention::LeftNominal,
        )
        .unwrap();
        assert!((fixed.e_b / 0.976 - 1.0).abs() < 1e-9, "{fixed:?}");
        assert!((fixed.e_d / 0.992 - 1.0).abs() < 1e-9, "{fixed:?}");
    }
}
