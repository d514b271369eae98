//! One open-loop square over the seam: four legs and four ±90° turns, each a separate motion,
//! the heading averaged at rest before and after, and the wheel travel and heading streamed
//! while it drives.

use super::heading::{at_rest, NoisePool};
use super::RoutineError;
use crate::base::{Base, HeadingSample, MotionGuard, SampleStream, TravelSample};
use crate::calibration::recording::{Clocks, Recording};
use crate::kinematics::{wrap_angle, Direction, Displacement};
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
    /// The drive's odometry over the square (its turn and distance), when every motion
    /// reported what it saw.
    pub odometry: Option<Displacement>,
    /// Wheel travel streamed while driving (empty when the drive cannot stream).
    pub travel: Vec<TravelSample>,
    /// Headings streamed while driving (empty when the source cannot stream).
    pub headings: Vec<HeadingSample>,
    /// How the two streams' clocks relate ([`Base::clocks`]).
    pub clocks: Clocks,
    /// The spread of the readings at rest before and after, pooled.
    pub rest_noise: NoisePool,
}

impl SquareRecord {
    /// The streams as a [`Recording`].
    pub fn recording(&self) -> Recording {
        Recording {
            travel: self.travel.clone(),
            headings: self.headings.clone(),
            clocks: self.clocks,
            poses: Vec::new(),
        }
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
    let before = at_rest(base.heading.as_ref(), cmd.heading_samples).await?;
    let mut travel = base.drive.travel(cmd.stream_period).await?;
    let mut headings = base.heading.stream(cmd.stream_period).await?;
    let guard = MotionGuard::new(&base.drive);
    let turn = cmd.direction.turn_sign() * FRAC_PI_2;
    let mut done = 0;
    // Σ of the drive's reported turns while every motion reported one.
    let mut achieved: Option<Displacement> = Some(Displacement::default());
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
            (Some(sum), Some(a), Some(b)) => Some(sum.plus(&a).plus(&b)),
            _ => None,
        };
    }
    guard.disarm();
    if !cmd.settle.is_zero() {
        tokio::time::sleep(cmd.settle).await;
    }
    let after = at_rest(base.heading.as_ref(), cmd.heading_samples).await?;
    // Streams are forwarded by tasks of their own: let them hand over what they hold.
    for _ in 0..8 {
        tokio::task::yield_now().await;
    }
    Ok(SquareRecord {
        command: *cmd,
        heading_before_rad: before.mean_rad,
        heading_after_rad: after.mean_rad,
        heading_error_rad: wrap_angle(
            after.mean_rad - before.mean_rad - achieved.map_or(0.0, |a| a.turn_rad - 4.0 * turn),
        ),
        odometry: achieved,
        travel: drain(&mut travel),
        headings: drain(&mut headings),
        clocks: base.clocks(),
        rest_noise: before.noise.plus(after.noise),
    })
}
