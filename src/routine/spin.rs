//! The spin test over the seam: full turns in place, the heading read at rest before and after,
//! for the user to compare with a mark on the floor ([`crate::calibration::gyro`]).

use super::config::ConfigError;
use super::heading::mean_heading;
use super::RoutineError;
use crate::base::{Base, MotionGuard};
use serde::Serialize;
use std::f64::consts::TAU;

/// What a spin measured.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SpinRecord {
    /// Full turns commanded (signed: `+` counter-clockwise).
    pub turns: i32,
    /// Mean heading at rest before (rad).
    pub heading_before_rad: f64,
    /// Mean heading at rest after (rad).
    pub heading_after_rad: f64,
    /// The drive's own odometry turn (rad), when it reported one.
    pub odometry_turn_rad: Option<f64>,
}

/// A spin as a user sets it (with the `cli` feature, `odocal spin`'s flags).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct SpinSettings {
    /// Full turns (negative: clockwise). More turns, a finer scale: 0.5° at the mark over 5
    /// turns is 0.03 %.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 5))]
    pub turns: i32,
    /// Turn-rate limit (rad/s).
    #[cfg_attr(
        feature = "cli",
        arg(long = "max-rate-rad-s", alias = "rate-rad-s", default_value_t = 0.5)
    )]
    pub rate_rad_s: f64,
    /// Readings averaged at rest before and after.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 10))]
    pub heading_samples: usize,
}

impl SpinSettings {
    /// Every setting in its range: 1–20 turns either way, a rate in (0, 3] rad/s, 1–100
    /// readings.
    pub fn check(&self) -> Result<(), ConfigError> {
        super::config::check_rate_limit(self.rate_rad_s)?;
        if !(1..=20).contains(&self.turns.unsigned_abs()) {
            let message = format!("--turns {}: must be 1..=20 either way", self.turns);
            return Err(ConfigError::new(message));
        }
        if !(1..=100).contains(&self.heading_samples) {
            let message = format!(
                "--heading-samples {}: must be 1..=100",
                self.heading_samples
            );
            return Err(ConfigError::new(message));
        }
        Ok(())
    }

    /// What is asked before the robot turns; without a reference compass, the user first
    /// marks the heading on the floor.
    pub fn question(&self, with_reference: bool) -> String {
        format!(
            "{}It will turn in place {} full turn(s) {} at up to {} rad/s.",
            if with_reference {
                ""
            } else {
                "Mark the robot's heading on the floor (a line along its side). "
            },
            self.turns.unsigned_abs(),
            if self.turns > 0 {
                "counter-clockwise"
            } else {
                "clockwise"
            },
            self.rate_rad_s
        )
    }
}

/// **Moves the robot**: turns in place `turns` full turns (one motion per turn; `+`
/// counter-clockwise) at up to `rate_rad_s`, the heading averaged over `heading_samples`
/// readings at rest before and after. Any error or a dropped future stops the base.
pub async fn run_spin(
    base: &Base,
    turns: i32,
    rate_rad_s: f64,
    heading_samples: usize,
) -> Result<SpinRecord, RoutineError> {
    let before = mean_heading(base.heading.as_ref(), heading_samples).await?;
    let guard = MotionGuard::new(&base.drive);
    let sign = f64::from(turns.signum());
    let mut odometry = Some(0.0);
    for _ in 0..turns.unsigned_abs() {
        let done = base.drive.turn_in_place(sign * TAU, rate_rad_s).await?;
        odometry = odometry.zip(done).map(|(sum, a)| sum + a.turn_rad);
    }
    guard.disarm();
    let after = mean_heading(base.heading.as_ref(), heading_samples).await?;
    Ok(SpinRecord {
        turns,
        heading_before_rad: before,
        heading_after_rad: after,
        odometry_turn_rad: odometry,
    })
}

/// A spin's result: where the robot stopped against its mark (or a reference compass), and
/// the gyro's scale error that follows.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SpinOutcome {
    /// What the spin measured.
    pub spin: SpinRecord,
    /// How far past the mark it stopped, in the direction it turned (deg; negative: short).
    pub past_mark_deg: f64,
    /// `reference` when a second compass said it, `mark` when the user did.
    pub past_mark_from: &'static str,
    /// The gyro's scale error (0.01: it reads 1 % more turn).
    pub gyro_scale_error: f64,
}

impl SpinOutcome {
    /// The outcome of `spin`, which stopped `past_mark_deg` past its mark (said by a
    /// reference compass when `from_reference`, else by the user).
    pub fn of(
        spin: SpinRecord,
        past_mark_deg: f64,
        from_reference: bool,
    ) -> Result<Self, crate::calibration::CalibrationError> {
        let gyro_scale_error = crate::calibration::gyro::scale_from_spin(
            spin.heading_before_rad,
            spin.heading_after_rad,
            f64::from(spin.turns),
            past_mark_deg.to_radians(),
        )?;
        Ok(SpinOutcome {
            spin,
            past_mark_deg,
            past_mark_from: if from_reference { "reference" } else { "mark" },
            gyro_scale_error,
        })
    }
}

/// The scale error in words, and the flag that removes it.
impl std::fmt::Display for SpinOutcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = self.gyro_scale_error;
        writeln!(
            f,
            "gyro scale error {:+.3} % (it reads {:.5} times every turn)\n\
             to remove it: calibrate --gyro-scale-error {s:.5}",
            100.0 * s,
            1.0 + s
        )
    }
}

#[cfg(test)]
mod settings_tests {
    use super::*;

    #[test]
    fn spin_settings_are_checked_and_the_outcome_carries_the_scale() {
        let ok = SpinSettings {
            turns: -5,
            rate_rad_s: 0.5,
            heading_samples: 10,
        };
        ok.check().unwrap();
        assert!(ok.question(false).contains("Mark the robot's heading"));
        assert!(ok
            .question(true)
            .starts_with("It will turn in place 5 full turn(s) clockwise"));
        for bad in [
            SpinSettings { turns: 0, ..ok },
            SpinSettings { turns: 21, ..ok },
            SpinSettings {
                rate_rad_s: 3.5,
                ..ok
            },
            SpinSettings {
                heading_samples: 0,
                ..ok
            },
        ] {
            assert!(bad.check().is_err(), "{bad:?}");
        }
        // Five turns counter-clockwise, the gyro 1° short at the end, the robot on its mark.
        let record = SpinRecord {
            turns: 5,
            heading_before_rad: 0.0,
            heading_after_rad: (-1.0f64).to_radians(),
            odometry_turn_rad: None,
        };
        let o = SpinOutcome::of(record, 0.0, false).unwrap();
        assert_eq!(o.past_mark_from, "mark");
        let expected = -1.0 / (5.0 * 360.0);
        assert!(
            (o.gyro_scale_error - expected).abs() < 1e-9,
            "{}",
            o.gyro_scale_error
        );
    }
}
