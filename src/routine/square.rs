//! One open-loop square over the seam: four legs and four ±90° turns, each a separate motion,
//! the heading averaged at rest before and after, and the wheel travel and heading streamed
//! while it drives.

use super::heading::mean_heading;
use super::RoutineError;
use crate::base::{Base, HeadingSample, MotionGuard, SampleStream, TravelSample};
use crate::kinematics::{wrap_angle, Direction};
use serde::Serialize;
use std::f64::consts::FRAC_PI_2;
use std::time::Duration;

/// How to drive a square. Speeds are limits the drive must not exceed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SquareCommand {
    /// Side (m).
    pub side_m: f64,
    /// Direction.
    pub direction: Direction,
    /// Straight-leg speed limit (m/s).
    pub max_speed_m_s: f64,
    /// Turn-rate limit (rad/s).
    pub max_rate_rad_s: f64,
    /// Heading readings averaged at rest before and after.
    pub heading_samples: usize,
    /// Pause between the end of a motion and a heading reading, for the base to settle.
    pub settle: Duration,
    /// Requested period of the travel and heading streams.
    pub stream_period: Duration,
}

/// One square as measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SquareRecord {
    /// The command.
    pub command: SquareCommand,
    /// Mean heading at rest before (rad).
    pub heading_before_rad: f64,
    /// Mean heading at rest after (rad).
    pub heading_after_rad: f64,
    /// Heading error (rad, wrapped): the heading's change at rest minus the drive's own
    /// odometry turn (the commanded ±360° when the drive executes to its resolution), which
    /// removes what the drive did not execute as commanded.
    pub heading_error_rad: f64,
    /// The drive's odometry turn over the square, when it reported one (rad).
    pub odometry_turn_rad: Option<f64>,
    /// Wheel travel streamed while driving (empty when the drive cannot stream).
    pub travel: Vec<TravelSample>,
    /// Headings streamed while driving (empty when the source cannot stream).
    pub headings: Vec<HeadingSample>,
}

impl SquareRecord {
    /// The heading error along the legs ([`crate::calibration::legs`]) from the streamed wheel
    /// travel and headings, or `None` without both streams or without four legs.
    ///
    /// The two streams may run on different clocks (a drive and a separate IMU): both were
    /// started just before the first motion, so their first samples give a coarse alignment,
    /// refined by the turn-rate correlation of [`crate::calibration::time_offset`].
    pub fn leg_heading_error(&self, wheelbase_m: f64) -> Option<f64> {
        use crate::calibration::legs::{leg_heading_error, LegSample};
        use crate::calibration::time_offset::{estimate_time_offset, unwrapped_heading_at};
        let (h_times, h_values): (Vec<f64>, Vec<Option<f64>>) = self
            .headings
            .iter()
            .filter(|h| h.validity.is_valid() && h.heading_rad.is_finite())
            .map(|h| (h.time_s, Some(h.heading_rad)))
            .unzip();
        let (t_h0, t_d0) = (*h_times.first()?, self.travel.first()?.time_s);
        // Both clocks from their stream's first sample (see above).
        let h_times: Vec<f64> = h_times.iter().map(|t| t - t_h0).collect();
        let times: Vec<f64> = self.travel.iter().map(|t| t.time_s - t_d0).collect();
        let odo: Vec<f64> = self
            .travel
            .iter()
            .map(|t| (t.right_m - t.left_m) / wheelbase_m)
            .collect();
        let at = |offset_s: f64| -> Vec<Option<f64>> {
            let shifted: Vec<f64> = times.iter().map(|t| t + offset_s).collect();
            unwrapped_heading_at(&h_times, &h_values, &shifted)
        };
        let offset = estimate_time_offset(&times, &odo, &at(0.0), 1.0).map_or(0.0, |o| o.offset_s);
        let heading = at(offset);
        let mut samples = Vec::with_capacity(times.len());
        let mut odo_turn = 0.0;
        for ((t, tr), h) in times.iter().zip(&self.travel).zip(heading) {
            odo_turn += (tr.right_m - tr.left_m) / wheelbase_m;
            let Some(h) = h else { continue };
            samples.push(LegSample {
                t: *t,
                ds: 0.5 * (tr.left_m + tr.right_m),
                dth: (tr.right_m - tr.left_m) / wheelbase_m,
                error_rad: h - odo_turn,
            });
        }
        leg_heading_error(&samples, wheelbase_m)
    }
}

fn drain<T>(stream: &mut Option<SampleStream<T>>) -> Vec<T> {
    let mut out = Vec::new();
    if let Some(rx) = stream {
        while let Ok(v) = rx.try_recv() {
            out.push(v);
        }
    }
    out
}

/// **Moves the robot**: drives one open-loop square and measures its final heading error at
/// rest, calling `on_motion(k)` after motion `k` of 8 (1-based) has finished. Any error or a
/// dropped future stops the base ([`MotionGuard`]).
pub async fn run_square(
    base: &Base,
    cmd: &SquareCommand,
    mut on_motion: impl FnMut(usize),
) -> Result<SquareRecord, RoutineError> {
    if !cmd.settle.is_zero() {
        tokio::time::sleep(cmd.settle).await;
    }
    let before = mean_heading(base.heading.as_ref(), cmd.heading_samples).await?;
    let mut travel = base.drive.travel(cmd.stream_period).await?;
    let mut headings = base.heading.stream(cmd.stream_period).await?;
    let guard = MotionGuard::new(&base.drive);
    let turn = cmd.direction.turn_sign() * FRAC_PI_2;
    let mut done = 0;
    // Σ of the drive's reported turns while every motion reported one.
    let mut achieved: Option<f64> = Some(0.0);
    for _ in 0..4 {
        let leg = base
            .drive
            .move_straight(cmd.side_m, cmd.max_speed_m_s)
            .await?;
        done += 1;
        on_motion(done);
        let corner = base.drive.turn_in_place(turn, cmd.max_rate_rad_s).await?;
        done += 1;
        on_motion(done);
        achieved = match (achieved, leg, corner) {
            (Some(sum), Some(a), Some(b)) => Some(sum + a.turn_rad + b.turn_rad),
            _ => None,
        };
    }
    guard.disarm();
    if !cmd.settle.is_zero() {
        tokio::time::sleep(cmd.settle).await;
    }
    let after = mean_heading(base.heading.as_ref(), cmd.heading_samples).await?;
    // Streams are forwarded by tasks of their own: let them hand over what they hold.
    for _ in 0..8 {
        tokio::task::yield_now().await;
    }
    Ok(SquareRecord {
        command: *cmd,
        heading_before_rad: before,
        heading_after_rad: after,
        heading_error_rad: wrap_angle(after - before - achieved.map_or(0.0, |t| t - 4.0 * turn)),
        odometry_turn_rad: achieved,
        travel: drain(&mut travel),
        headings: drain(&mut headings),
    })
}
