//! The spin test over the seam: full turns in place, the heading read at rest before and after,
//! for the user to compare with a mark on the floor ([`crate::calibration::gyro`]).

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
