//! The compass swing over the seam: full turns in place each way, the wheel travel and the
//! heading streamed, and the deviation curve fitted and checked ([`crate::calibration::swing`]).
//!
//! Each reading is paired with the odometry's turn at the reading's own time (the wheel travel
//! is cumulative, so a lost travel sample only coarsens it), not a heading interpolated at the
//! travel's times: across readings a lossy link lost, an interpolated heading is invented.

use super::config::ConfigError;
use super::RoutineError;
use crate::base::{Base, MotionGuard, SampleStream};
use crate::calibration::recording::{Recording, Track};
use crate::calibration::swing::{fit, SwingError, SwingFit, SwingPoint};
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
    /// The compass's noise per reading at rest (rad), when known: what the fit's residual is
    /// judged against.
    pub noise_std_rad: Option<f64>,
}

/// A swing as a user sets it (with the `cli` feature, `odocal swing`'s flags).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct SwingSettings {
    /// Full turns each way.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 2))]
    pub turns: u32,
    /// Turn-rate limit (rad/s): slow, so that a compass that filters keeps up.
    #[cfg_attr(feature = "cli", arg(long = "max-rate-rad-s", alias = "rate-rad-s", default_value_t = SWING_RATE_RAD_S))]
    pub rate_rad_s: f64,
}

impl SwingSettings {
    /// Both settings in their ranges: 1–10 turns, a rate in (0, 3] rad/s.
    pub fn check(&self) -> Result<(), ConfigError> {
        super::config::check_rate_limit(self.rate_rad_s)?;
        if !(1..=10).contains(&self.turns) {
            return Err(ConfigError::new(format!(
                "--turns {}: must be 1..=10",
                self.turns
            )));
        }
        Ok(())
    }

    /// What is asked before the robot turns.
    pub fn question(&self) -> String {
        format!(
            "The robot will turn in place {} full turn(s) each way at up to {} rad/s.",
            self.turns, self.rate_rad_s
        )
    }

    /// The swing of a robot whose odometry uses `wheelbase_m`, its streams at 50 Hz; its
    /// residual judged against a fixed allowance (the noise is not measured first).
    pub fn command(&self, wheelbase_m: f64) -> SwingCommand {
        SwingCommand {
            turns_per_direction: self.turns,
            rate_rad_s: self.rate_rad_s,
            wheelbase_m,
            stream_period: Duration::from_millis(20),
            noise_std_rad: None,
        }
    }
}

/// Why a swing gave no deviation curve.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NoSwing {
    /// This base cannot swing (a stream it lacks, clocks that cannot be compared).
    #[error("{0}")]
    Unsupported(String),
    /// The swing ran but its fit failed a check: never applied.
    #[error("{0}")]
    Refused(#[from] SwingError),
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
/// readings. `Ok(Err(reason))` when this base cannot swing or the fit is refused (the caller
/// goes on without one); any error or a dropped future stops the base.
pub async fn run_swing(
    base: &Base,
    cmd: &SwingCommand,
) -> Result<Result<SwingFit, NoSwing>, RoutineError> {
    let mut turns = Vec::new();
    for sign in [1.0, -1.0] {
        let (mut travel, mut headings) = match streams(base, cmd.stream_period).await? {
            Ok(s) => s,
            Err(why) => return Ok(Err(NoSwing::Unsupported(why))),
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
            poses: Vec::new(),
        };
        let track = recording.track(cmd.wheelbase_m);
        if !track.alignment.comparable {
            return Ok(Err(NoSwing::Unsupported(
                "the heading's clock and the wheels' cannot be compared (separate devices whose \
                 stamps disagree)"
                    .into(),
            )));
        }
        turns.push(points_at_readings(&track));
    }
    Ok(fit(&turns, cmd.noise_std_rad).map_err(NoSwing::from))
}

/// Every valid reading inside the travel's span, with the odometry's turn at its time
/// (interpolated between the travel samples around it).
fn points_at_readings(track: &Track) -> Vec<SwingPoint> {
    let p = &track.points;
    track
        .readings
        .iter()
        .filter_map(|&(t, h)| {
            let i = p.partition_point(|q| q.time_s <= t);
            if i == 0 {
                return None;
            }
            let a = &p[i - 1];
            let phi = match p.get(i) {
                Some(b) if b.time_s > a.time_s => {
                    let f = (t - a.time_s) / (b.time_s - a.time_s);
                    a.odometry_turn_rad + f * (b.odometry_turn_rad - a.odometry_turn_rad)
                }
                // Beyond the last travel sample: only a reading at its very time.
                None if a.time_s < t => return None,
                _ => a.odometry_turn_rad,
            };
            Some(SwingPoint {
                odometry_turn_rad: phi,
                heading_rad: h,
            })
        })
        .collect()
}

/// A swing's result as a person reads it: the curve fitted on top of what was `applied`
/// already (a flag, a profile's saved curve), the whole curve to keep, and where it was saved
/// (the profile and its backup), if it was.
#[derive(Debug, Clone, PartialEq)]
pub struct SwingOutcome {
    /// The fit of what was left in the readings.
    pub fit: SwingFit,
    /// The deviation already removed from the readings (rad).
    pub applied: crate::kinematics::Deviation,
    /// The profile it was saved in, and that profile's backup.
    pub saved: Option<(std::path::PathBuf, std::path::PathBuf)>,
}

impl SwingOutcome {
    /// The whole curve (applied and fitted), A1, B1, A2, B2 in degrees.
    pub fn total_deg(&self) -> [f64; 4] {
        std::array::from_fn(|k| (self.applied.0[k] + self.fit.deviation.0[k]).to_degrees())
    }

    /// The whole curve as `--compass-deviation-deg` takes it.
    pub fn flag(&self) -> String {
        self.total_deg().map(|c| format!("{c:.3}")).join(",")
    }

    /// As stdout's JSON.
    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "fit": self.fit,
            "already_removed_deg": self.applied.0.map(f64::to_degrees),
            "compass_deviation_deg": self.flag(),
            "advice": self.fit.advice(),
            "saved_to": self.saved.as_ref().map(|s| &s.0),
            "profile_backup": self.saved.as_ref().map(|s| &s.1),
        })
    }
}

/// The curve with each coefficient's ± (one standard error), how far it moves the heading,
/// what is left after the fit, and how to use or keep it.
impl std::fmt::Display for SwingOutcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let fit = &self.fit;
        let se = fit.deviation_std_err_rad.map(f64::to_degrees);
        let [a1, b1, a2, b2] = fit.deviation.0.map(f64::to_degrees);
        writeln!(
            f,
            "compass deviation d(ψ) = A1·sin ψ + B1·cos ψ + A2·sin 2ψ + B2·cos 2ψ\n  \
             A1 {a1:+.3}° ± {:.3}°  B1 {b1:+.3}° ± {:.3}°  A2 {a2:+.3}° ± {:.3}°  B2 {b2:+.3}° ± {:.3}°\n  \
             up to {:.2}° with the heading; {:.2}° left after the fit (noise and what four harmonics \
             do not describe); {} readings",
            se[0],
            se[1],
            se[2],
            se[3],
            fit.amplitude_rad.to_degrees(),
            fit.residual_rms_rad.to_degrees(),
            fit.points
        )?;
        if let Some(advice) = fit.advice() {
            writeln!(f, "advice: {advice}")?;
        }
        let flag = self.flag();
        if !self.applied.is_zero() {
            writeln!(
                f,
                "(on top of the deviation already removed: the whole curve is {flag} degrees)"
            )?;
        }
        match &self.saved {
            Some((path, backup)) => writeln!(
                f,
                "saved in {} ([heading]; the earlier file is {}): every command with this \
                 profile removes it",
                path.display(),
                backup.display()
            ),
            None => writeln!(
                f,
                "to remove it from every reading: --compass-deviation-deg {flag}, or --save it \
                 in the robot profile (calibrate also swings by itself unless --no-swing)"
            ),
        }
    }
}

#[cfg(test)]
mod settings_tests {
    use super::*;

    #[test]
    fn swing_settings_are_checked_and_make_the_command() {
        let s = SwingSettings {
            turns: 2,
            rate_rad_s: SWING_RATE_RAD_S,
        };
        s.check().unwrap();
        let c = s.command(0.39);
        assert_eq!((c.turns_per_direction, c.wheelbase_m), (2, 0.39));
        assert!(SwingSettings { turns: 11, ..s }.check().is_err());
        let e = SwingSettings {
            rate_rad_s: 0.0,
            ..s
        }
        .check()
        .unwrap_err();
        assert!(e.to_string().contains("--max-rate-rad-s"), "{e}");
    }
}
