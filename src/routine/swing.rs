//! The compass swing over the seam: full turns in place each way, the wheel travel and the
//! heading streamed, and the deviation curve fitted ([`crate::calibration::swing`]).

use super::RoutineError;
use crate::base::{Base, MotionGuard, SampleStream};
use crate::calibration::recording::Recording;
use crate::calibration::swing::{fit, SwingFit, SwingPoint};
use std::f64::consts::TAU;
use std::time::Duration;

/// How to swing. Rates are limits the drive must not exceed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SwingCommand {
    /// Full turns each way (counter-clockwise first, then clockwise).
    pub turns_per_direction: u32,
    /// Turn-rate limit (rad/s): slow, so that a compass that filters or lags keeps up.
    pub rate_rad_s: f64,
    /// The wheelbase the drive's odometry uses (m).
    pub wheelbase_m: f64,
    /// Requested period of the streams.
    pub stream_period: Duration,
}

/// Slowest sensible default swing rate (rad/s): a turn in about 12.6 s.
pub const SWING_RATE_RAD_S: f64 = 0.5;

/// Why a base cannot swing, or `None` when it can: both streams are needed.
async fn streams(
    base: &Base,
    period: Duration,
) -> Result<
    Result<
        (
            SampleStream<crate::base::TravelSample>,
            SampleStream<crate::base::HeadingSample>,
        ),
        String,
    >,
    RoutineError,
> {
    let travel = base.drive.travel(period).await?;
    let headings = base.heading.stream(period).await?;
    Ok(match (travel, headings) {
        (Some(t), Some(h)) => Ok((t, h)),
        (None, _) => Err("the drive does not stream its wheel travel".into()),
        (_, None) => Err("the heading source does not stream".into()),
    })
}

fn drain<T>(rx: &mut SampleStream<T>) -> Vec<T> {
    let mut out = Vec::new();
    while let Ok(v) = rx.try_recv() {
        out.push(v);
    }
    out
}

/// **Moves the robot**: turns in place `turns_per_direction` full turns counter-clockwise,
/// then as many clockwise (one motion per turn), and fits the compass's deviation from the
/// readings. `Ok(Err(reason))` when this base cannot swing or the readings do not make a fit
/// (the caller goes on without one); any error or a dropped future stops the base.
pub async fn run_swing(
    base: &Base,
    cmd: &SwingCommand,
) -> Result<Result<SwingFit, String>, RoutineError> {
    let mut turns = Vec::new();
    for sign in [1.0, -1.0] {
        let (mut travel, mut headings) = match streams(base, cmd.stream_period).await? {
            Ok(s) => s,
            Err(why) => return Ok(Err(why)),
        };
        let guard = MotionGuard::new(&base.drive);
        for _ in 0..cmd.turns_per_direction {
            base.drive.turn_in_place(sign * TAU, cmd.rate_rad_s).await?;
        }
        guard.disarm();
        // Streams are forwarded by tasks of their own: let them hand over what they hold.
        for _ in 0..8 {
            tokio::task::yield_now().await;
        }
        let recording = Recording {
            travel: drain(&mut travel),
            headings: drain(&mut headings),
            clocks: base.clocks(),
        };
        let track = recording.track(cmd.wheelbase_m);
        if !track.alignment.comparable {
            return Ok(Err(
                "the heading's clock and the wheels' cannot be compared (separate devices whose \
                 stamps disagree)"
                    .into(),
            ));
        }
        turns.push(
            track
                .points
                .iter()
                .filter_map(|p| {
                    p.heading_rad.map(|h| SwingPoint {
                        odometry_turn_rad: p.odometry_turn_rad,
                        heading_rad: h,
                    })
                })
                .collect::<Vec<_>>(),
        );
    }
    Ok(fit(&turns).map_err(|e| e.to_string()))
}
