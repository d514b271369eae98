//! Motion helpers for the calibration routine: drive one open-loop square and measure its final
//! heading error at rest, with a guard that stops the base if anything goes wrong.

use super::{Client, HalError, LinkError, TelemetrySample};
use crate::kinematics::{wrap_angle, Direction};
use crate::protocol::message::{MotionMode, MotionState};
use serde::Serialize;
use std::f64::consts::FRAC_PI_2;
use std::time::Duration;
use tokio::time::Instant;

/// Sends STOP when dropped unless [`MotionGuard::disarm`] was called: an error, a panic or a
/// cancelled future (Ctrl-C) while the robot moves stops the base.
pub struct MotionGuard {
    client: Client,
    armed: bool,
}

impl MotionGuard {
    /// Arms a guard on `client`.
    pub fn new(client: &Client) -> Self {
        MotionGuard {
            client: client.clone(),
            armed: true,
        }
    }

    /// The motion finished normally: do not stop on drop.
    pub fn disarm(mut self) {
        self.armed = false;
    }
}

impl Drop for MotionGuard {
    fn drop(&mut self) {
        if self.armed {
            self.client.emergency_stop();
        }
    }
}

/// How to drive a square. Speeds are limits the device must not exceed.
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
    /// Heading samples averaged at rest before and after.
    pub heading_samples: usize,
    /// Pause between motions and before reading the heading, for the base to settle.
    pub settle: Duration,
}

/// One square as measured through the link.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SquareRecord {
    /// The command.
    pub command: SquareCommand,
    /// Mean heading at rest before (rad).
    pub heading_before_rad: f64,
    /// Mean heading at rest after (rad).
    pub heading_after_rad: f64,
    /// Final-minus-start heading error (rad, wrapped).
    pub heading_error_rad: f64,
    /// Telemetry received while driving.
    pub trace: Vec<TelemetrySample>,
}

/// The circular mean of `n` heading readings (rad); `n` at least 1.
pub async fn mean_heading(client: &Client, n: usize) -> Result<f64, HalError> {
    let (mut s, mut c) = (0.0, 0.0);
    for _ in 0..n.max(1) {
        let h = client.read_heading().await?;
        if !h.valid {
            return Err(LinkError::Protocol("heading reported invalid".into()).into());
        }
        s += h.heading_rad.sin();
        c += h.heading_rad.cos();
    }
    Ok(wrap_angle(s.atan2(c)))
}

/// Polls the status until `completed` motions are done and the base is idle, failing if that
/// takes longer than `limit`.
pub async fn wait_until_done(
    client: &Client,
    motion_id: u16,
    completed: u32,
    limit: Duration,
) -> Result<(), HalError> {
    let start = Instant::now();
    loop {
        let s = client.status().await?;
        if s.motion_state == MotionState::Idle
            && s.completed_motions.wrapping_sub(completed) < u32::MAX / 2
        {
            return Ok(());
        }
        if s.watchdog_state == crate::protocol::message::WatchdogState::Tripped {
            return Err(LinkError::Protocol("the device watchdog stopped the base".into()).into());
        }
        if start.elapsed() > limit {
            return Err(LinkError::MotionTimeout {
                motion_id,
                after: limit,
            }
            .into());
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

/// **Moves the robot**: drives one open-loop square (four legs and four ±90° turns, one motion
/// at a time) and measures its final heading error at rest.
pub async fn run_square(client: &Client, cmd: &SquareCommand) -> Result<SquareRecord, HalError> {
    run_square_with_progress(client, cmd, |_| {}).await
}

/// [`run_square`], calling `on_motion(k)` after motion `k` of 8 (1-based) has finished.
pub async fn run_square_with_progress(
    client: &Client,
    cmd: &SquareCommand,
    mut on_motion: impl FnMut(usize),
) -> Result<SquareRecord, HalError> {
    let mut events = client.subscribe();
    if cmd.settle > Duration::ZERO {
        tokio::time::sleep(cmd.settle).await;
    }
    let before = mean_heading(client, cmd.heading_samples).await?;
    let guard = MotionGuard::new(client);
    let mut completed = client.status().await?.completed_motions;
    let turn = cmd.direction.turn_sign() * FRAC_PI_2;
    let mut done = 0;
    for _ in 0..4 {
        for leg in [true, false] {
            let (accepted, expected_s) = if leg {
                (
                    client
                        .move_straight(cmd.side_m, cmd.max_speed_m_s, MotionMode::Queue)
                        .await?,
                    cmd.side_m / cmd.max_speed_m_s,
                )
            } else {
                (
                    client
                        .turn_in_place(turn, cmd.max_rate_rad_s, MotionMode::Queue)
                        .await?,
                    FRAC_PI_2 / cmd.max_rate_rad_s,
                )
            };
            completed = completed.wrapping_add(1);
            // Real hardware ramps and the mock may run slower than real time: allow 3× + 2 s.
            let limit = Duration::from_secs_f64(3.0 * expected_s + 2.0);
            wait_until_done(client, accepted.motion_id, completed, limit).await?;
            done += 1;
            on_motion(done);
        }
    }
    guard.disarm();
    if cmd.settle > Duration::ZERO {
        tokio::time::sleep(cmd.settle).await;
    }
    let after = mean_heading(client, cmd.heading_samples).await?;
    let mut trace = Vec::new();
    while let Ok(s) = events.try_recv() {
        trace.push(s);
    }
    Ok(SquareRecord {
        command: *cmd,
        heading_before_rad: before,
        heading_after_rad: after,
        heading_error_rad: wrap_angle(after - before),
        trace,
    })
}
