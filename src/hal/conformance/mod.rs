//! Conformance: SPEC.md §7's device rules checked against a device on a real port, in real
//! time (`odocal conformance`). **It moves the robot**: short motions at low speed.
//!
//! The rules are the vectors' (`protocol/vectors/vectors.json`, `device_rules`, written by the
//! independent generator), replayed over the port with their expectations as written, except
//! where real time and a real robot make that impossible:
//!
//! - **No clock hook.** "Advance n ms" is a silent wait, "until idle" reads the status until
//!   the base is idle. A rule that needs device time held or thousands of motions (7.3's id
//!   wrap) is skipped, said as such; so is a rule that sends an optional message the device
//!   does not report in HELLO's capabilities (SPEC.md §8).
//! - **Not a fresh device.** Before each rule the base is stopped and settled, the watchdog
//!   and telemetry are turned off, the parameters in use at the start are written back (never
//!   saved), a safety watchdog is armed and HELLO clears the retry cache. Motion ids and
//!   `completed_motions` are checked relative to where the device's counters stand (ids from
//!   the first one the rule sees); that they count from 1 after power-up needs the clock-hook
//!   harness. A rule that needs a device that never saved parameters (7.9) is skipped on one
//!   that has.
//! - **Short, slow motions.** Speeds and turn rates are capped at the speed limit; a motion
//!   the rule only needs to be running (10 m in the vectors) becomes one of [`LONG_MS`] at the
//!   capped speed; a long motion whose acceptance is the point (the 4π turn) is stopped as soon
//!   as it is accepted.
//!
//! A few checks of §3 and §7.2 that no vector can express in device time follow: a retried
//! motion is answered again and runs once, a retry answered from the cache feeds the
//! watchdog; and at the end, that the stored parameter copy is what it was.

use crate::protocol::device::{Device as KitDevice, ParamStorage, SimulatedBoard, VecSink};
use crate::protocol::frame::{Frame, FrameKind, VERSION};
use crate::protocol::message::{
    capability, id, DeviceInfo, GetParamsRequest, HelloRequest, MotionMode, MotionState,
    MoveStraightRequest, Nack, ParamSource, ParamsBlock, TurnInPlaceRequest, WatchdogState,
    WatchdogTimeout, WheelSpeedRequest,
};
use crate::protocol::{Body, Event, FrameCodec, Packet, Request, Response};
use bytes::BytesMut;
use serde::Serialize;
use serde_json::Value;
use std::collections::VecDeque;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::time::Instant;

mod wire;
use wire::*;
mod checks;
use checks::*;
mod target;
pub use target::*;
mod extra_checks;
use extra_checks::*;

/// The vectors, as the independent generator wrote them from SPEC.md alone.
const VECTORS: &str = include_str!("../../../protocol/vectors/vectors.json");

/// How long a motion that a rule only needs running lasts at the capped speed (device ms).
pub const LONG_MS: u64 = 4000;

/// The safety watchdog armed before each rule (host ms): longer than any silent wait of a
/// rule, short enough to stop the base soon if this program dies.
pub const SAFETY_WATCHDOG_MS: u16 = 10_000;

/// How long an answer may take before the request is sent again, once (SPEC.md §3: 50 ms,
/// 500 ms for storage, plus the link).
const ANSWER_TIMEOUT: Duration = Duration::from_millis(700);

/// How long after a wait events are still taken as sent during it (their timestamps are
/// checked).
const LATE_EVENTS: Duration = Duration::from_millis(300);

/// How often the status is read while waiting for the base to become idle.
const STATUS_POLL: Duration = Duration::from_millis(50);

/// The lowest speed limit: the vectors' short motions must complete within their windows.
pub const MIN_SPEED_M_S: f64 = 0.05;

/// How to run the checks (with the `cli` feature, `odocal conformance`'s flags).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct Options {
    /// Wheel speed limit of every motion (m/s, 0.05 to 1); turn rates follow from it and the
    /// wheelbase.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.1))]
    pub max_speed_m_s: f64,
    /// The device's clock runs this many times faster than the wall clock: a simulator such as
    /// `odocal mock-device --time-scale K` (1 for hardware) [default: measured from the
    /// device's uptime]. A given scale must agree with the measured rate within 25 %.
    #[cfg_attr(feature = "cli", arg(long))]
    pub time_scale: Option<f64>,
    /// Check only this SPEC section (e.g. 7.3; repeatable) [default: every rule].
    #[cfg_attr(feature = "cli", arg(long = "rule", value_name = "RULES"))]
    pub only: Vec<String>,
}

impl Options {
    /// Both numbers in their ranges, before anything moves.
    pub fn check(&self) -> Result<(), ConformanceError> {
        // No scale given: measured later, nothing to check here (1 is in range).
        crate::ranges::check_ranges(&[
            ("--max-speed-m-s", self.max_speed_m_s, MIN_SPEED_M_S, 1.0),
            ("--time-scale", self.time_scale.unwrap_or(1.0), 1.0, 100.0),
        ])
        .map_err(ConformanceError::InvalidArgument)
    }
}

impl Default for Options {
    fn default() -> Self {
        Options {
            max_speed_m_s: 0.1,
            time_scale: None,
            only: Vec::new(),
        }
    }
}

/// Why the checks could not run (a failed rule is a result, not an error).
#[derive(Debug, thiserror::Error)]
pub enum ConformanceError {
    /// An option out of its range.
    #[error("{0}")]
    InvalidArgument(String),
    /// Reading or writing the port failed.
    #[error("the link failed: {0}")]
    Io(#[from] std::io::Error),
    /// The device did not answer a request of the harness's own.
    #[error("no answer to {what} within {} (sent twice)", crate::io::seconds(.after))]
    Silent {
        /// The request.
        what: &'static str,
        /// How long was waited in all.
        after: Duration,
    },
    /// The device refused or misanswered a request the harness needs (to set up a rule).
    #[error("{what}: {why}")]
    Setup {
        /// The request.
        what: &'static str,
        /// What came back.
        why: String,
    },
    /// The device's clock did not advance: a simulator in virtual time, whose motions end the
    /// moment they are accepted; SPEC §7's rules are about time and cannot be checked.
    #[error(
        "the device's clock stood still for {waited_ms} ms (uptime {uptime_ms} ms): a simulator \
         in virtual time, whose motions end the moment they are accepted, cannot be checked \
         against SPEC §7's timing; start `odocal mock-device --time-scale 5` (any scale up to \
         100) and run conformance on it"
    )]
    ClockStill {
        /// The device's uptime (ms).
        uptime_ms: u32,
        /// How long the host waited (ms).
        waited_ms: u64,
    },
    /// The embedded vectors could not be read (a build defect).
    #[error("vectors.json: {0}")]
    Vectors(String),
}

/// A rule's outcome.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Outcome {
    /// The device followed the rule.
    Pass,
    /// It did not.
    Fail,
    /// The rule cannot be checked in real time on this device.
    Skip,
}

/// One rule checked.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RuleResult {
    /// The SPEC section ("7.3").
    pub section: String,
    /// What the rule says.
    pub rule: String,
    /// Pass, fail or skip.
    pub outcome: Outcome,
    /// Why it failed or was skipped.
    pub reason: Option<String>,
}

/// Every rule checked, and the device.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// What the device said at HELLO.
    pub device: DeviceInfo,
    /// The results, in order.
    pub rules: Vec<RuleResult>,
}

impl Report {
    /// How many rules had this outcome.
    pub fn count(&self, outcome: Outcome) -> usize {
        self.rules.iter().filter(|r| r.outcome == outcome).count()
    }

    /// The last line: the device, and how many rules passed, failed and were skipped.
    pub fn summary(&self, port: &str) -> String {
        format!(
            "{} ({port}): {} passed, {} failed, {} skipped",
            self.device.firmware_id,
            self.count(Outcome::Pass),
            self.count(Outcome::Fail),
            self.count(Outcome::Skip)
        )
    }

    /// What failed, naming each rule and where its reason was printed; `None` when nothing did.
    pub fn failure(&self, reasons_in: &str) -> Option<String> {
        let failed: Vec<String> = (self.rules.iter())
            .filter(|r| r.outcome == Outcome::Fail)
            .map(|r| format!("§{} {}", r.section, r.rule))
            .collect();
        (!failed.is_empty()).then(|| {
            format!(
                "{} rule(s) failed: {} (the reasons are {reasons_in}; SPEC.md §7 says what \
                 each rule asks of the firmware)",
                failed.len(),
                failed.join("; ")
            )
        })
    }
}

/// One line per rule: outcome, section, rule and why.
impl std::fmt::Display for RuleResult {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let outcome = match self.outcome {
            Outcome::Pass => "PASS",
            Outcome::Fail => "FAIL",
            Outcome::Skip => "SKIP",
        };
        write!(f, "{outcome}  §{:<5} {}", self.section, self.rule)?;
        if let Some(why) = &self.reason {
            write!(f, " — {why}")?;
        }
        Ok(())
    }
}

/// Runs every rule against the device on `stream` (the port), calling `progress` after each;
/// the device is stopped and its parameters written back before this returns.
pub async fn run<S: AsyncRead + AsyncWrite + Unpin + Send>(
    stream: S,
    options: &Options,
    mut progress: impl FnMut(&RuleResult),
) -> Result<Report, ConformanceError> {
    check_limits(options)?;
    let rules = device_rules()?;
    let mut w = Wire {
        stream,
        codec: FrameCodec::new(),
        buf: BytesMut::new(),
        pending: VecDeque::new(),
        seq: 0x80,
    };
    let (dev, stored_before) = prepare(&mut w, options).await?;
    let info = dev.info;
    let wanted = |section: &str| {
        options.only.is_empty() || options.only.iter().any(|o| section.starts_with(o.as_str()))
    };
    let mut results = Vec::new();
    let outcome = async {
        let saved_copy = stored_before.is_ok();
        run_vector_rules(
            &mut w,
            &dev,
            &rules,
            saved_copy,
            &wanted,
            &mut progress,
            &mut results,
        )
        .await?;
        run_extra_checks(&mut w, &dev, &wanted, &mut progress, &mut results).await
    }
    .await;
    // Whatever happened: stopped, settings off, the parameters in use at the start back.
    let restored = restore(&mut w, &dev).await;
    outcome?;
    restored?;
    let stored_after = stored(&mut w).await?;
    let r = stored_copy_result(&stored_before, &stored_after);
    progress(&r);
    results.push(r);
    Ok(Report {
        device: info,
        rules: results,
    })
}

/// Refuses a speed limit or time scale out of its range, before anything is sent.
fn check_limits(options: &Options) -> Result<(), ConformanceError> {
    if !(options.max_speed_m_s.is_finite()
        && (MIN_SPEED_M_S..=1.0).contains(&options.max_speed_m_s))
    {
        return Err(ConformanceError::InvalidArgument(format!(
            "the speed limit must be in [{MIN_SPEED_M_S}, 1] m/s, got {}",
            options.max_speed_m_s
        )));
    }
    if let Some(k) = options.time_scale {
        if !(k.is_finite() && (1.0..=100.0).contains(&k)) {
            return Err(ConformanceError::InvalidArgument(format!(
                "the time scale must be in [1, 100], got {k}"
            )));
        }
    }
    Ok(())
}

/// Reads the device's info, parameters, stored copy and clock rate: how the rules may move it.
async fn prepare<S: AsyncRead + AsyncWrite + Unpin + Send>(
    w: &mut Wire<S>,
    options: &Options,
) -> Result<(Device, Result<Response, Nack>), ConformanceError> {
    let info = match w.ok("HELLO", hello()).await? {
        Response::Hello(info) => info,
        other => {
            return Err(ConformanceError::Setup {
                what: "HELLO",
                why: format!("answered {}", other.name()),
            })
        }
    };
    let active = GetParamsRequest {
        source: ParamSource::Active,
    };
    let params = match w.ok("GET_PARAMS", Request::GetParams(active)).await? {
        Response::GetParams(p) => p.params,
        other => {
            return Err(ConformanceError::Setup {
                what: "GET_PARAMS",
                why: format!("answered {}", other.name()),
            })
        }
    };
    let stored_before = stored(w).await?;
    let time_scale = time_scale(w, options.time_scale).await?;
    let speed_mm_s = ((options.max_speed_m_s * 1e3) as u16).min(info.max_speed_mm_s);
    // A turn at rate ω drives each wheel at ω·b/2: the wheel speed limit caps it.
    let wheelbase_mm = f64::from(params.wheelbase_nm) * 1e-6;
    let rate = 2.0 * f64::from(speed_mm_s) / wheelbase_mm * 1e3;
    let dev = Device {
        info,
        params,
        speed_mm_s,
        rate_mrad_s: (rate as u16).min(info.max_rate_mrad_s).max(1),
        time_scale,
    };
    Ok((dev, stored_before))
}

/// Runs each vector rule `wanted` selects, in order, reporting each to `progress`.
async fn run_vector_rules<S: AsyncRead + AsyncWrite + Unpin + Send>(
    w: &mut Wire<S>,
    dev: &Device,
    rules: &[Value],
    saved_copy: bool,
    wanted: &impl Fn(&str) -> bool,
    progress: &mut impl FnMut(&RuleResult),
    results: &mut Vec<RuleResult>,
) -> Result<(), ConformanceError> {
    for rule in rules {
        let section = rule["name"].as_str().unwrap_or("").split(' ').next();
        if !section.is_some_and(wanted) {
            continue;
        }
        let r = run_rule(w, dev, rule, saved_copy).await?;
        progress(&r);
        results.push(r);
    }
    Ok(())
}

/// Runs the selected checks no vector can express (retried motion, retry feeding the watchdog).
async fn run_extra_checks<S: AsyncRead + AsyncWrite + Unpin + Send>(
    w: &mut Wire<S>,
    dev: &Device,
    wanted: &impl Fn(&str) -> bool,
    progress: &mut impl FnMut(&RuleResult),
    results: &mut Vec<RuleResult>,
) -> Result<(), ConformanceError> {
    let extras: [(&str, &str, bool); 2] = [
        (
            "3",
            "a retried MOVE_STRAIGHT is answered again and runs once",
            true,
        ),
        (
            "7.2",
            "a retry answered from the cache feeds the watchdog",
            dev.has(capability::WATCHDOG),
        ),
    ];
    for (i, (section, rule, possible)) in extras.into_iter().enumerate() {
        if !wanted(section) {
            continue;
        }
        let mut r = RuleResult {
            section: section.into(),
            rule: rule.into(),
            outcome: Outcome::Skip,
            reason: Some("the device has no watchdog".into()),
        };
        if possible {
            r.reason = None;
            r.set(if i == 0 {
                retried_motion_runs_once(w, dev).await?
            } else {
                retries_feed_the_watchdog(w, dev).await?
            });
        }
        progress(&r);
        results.push(r);
    }
    Ok(())
}

/// Stops the base and puts the rules' settings back (watchdog off, parameters as at the start).
async fn restore<S: AsyncRead + AsyncWrite + Unpin + Send>(
    w: &mut Wire<S>,
    dev: &Device,
) -> Result<(), ConformanceError> {
    dev.fresh(w).await?;
    if dev.has(capability::WATCHDOG) {
        let off = WatchdogTimeout { timeout_ms: 0 };
        w.ok("CONFIGURE_WATCHDOG", Request::ConfigureWatchdog(off))
            .await?;
    }
    Ok(())
}

/// §5's result: whether the stored parameter copy is what it was before the rules ran.
fn stored_copy_result(
    stored_before: &Result<Response, Nack>,
    stored_after: &Result<Response, Nack>,
) -> RuleResult {
    let unchanged = match (stored_before, stored_after) {
        (Ok(a), Ok(b)) => a == b,
        (Err(a), Err(b)) => a.code == b.code,
        _ => false,
    };
    RuleResult {
        section: "5".into(),
        rule: "the stored parameter copy changes only by SAVE_PARAMS (none was accepted)".into(),
        outcome: if unchanged {
            Outcome::Pass
        } else {
            Outcome::Fail
        },
        reason: (!unchanged).then(|| {
            let text = |r: &Result<Response, Nack>| match r {
                Ok(Response::GetParams(p)) => format!(
                    "left {} nm, right {} nm, wheelbase {} nm, {} µcounts/rev",
                    p.params.left_wheel_diameter_nm,
                    p.params.right_wheel_diameter_nm,
                    p.params.wheelbase_nm,
                    p.params.counts_per_wheel_rev_micro
                ),
                Ok(other) => format!("answered {}", other.name()),
                Err(nack) => format!("refused {}", nack.code),
            };
            format!(
                "GET_PARAMS stored was {}, is now {}",
                text(stored_before),
                text(stored_after)
            )
        }),
    }
}

/// Opens `path` at `baud` and runs [`run`] on it.
pub async fn run_port(
    path: &str,
    baud: u32,
    options: &Options,
    progress: impl FnMut(&RuleResult),
) -> Result<Report, ConformanceError> {
    let port = crate::io::serial::open(path, baud)
        .map_err(|e| ConformanceError::Io(std::io::Error::other(format!("{path}: {e}"))))?;
    run(port, options, progress).await
}

#[cfg(test)]
mod report_tests {
    use super::*;

    fn rule(section: &str, outcome: Outcome, reason: Option<&str>) -> RuleResult {
        RuleResult {
            section: section.into(),
            rule: "a rule".into(),
            outcome,
            reason: reason.map(String::from),
        }
    }

    #[test]
    fn options_are_checked_and_failures_are_named() {
        Options::default().check().unwrap();
        for bad in [
            Options {
                max_speed_m_s: 0.01,
                ..Options::default()
            },
            Options {
                time_scale: Some(0.5),
                ..Options::default()
            },
        ] {
            assert!(matches!(
                bad.check(),
                Err(ConformanceError::InvalidArgument(_))
            ));
        }
        let failed = rule("7.3", Outcome::Fail, Some("late"));
        assert_eq!(failed.to_string(), "FAIL  §7.3   a rule — late");
        let report = Report {
            device: DeviceInfo {
                major: 1,
                minor: 0,
                firmware_id: crate::protocol::message::FirmwareId::new("kit").unwrap(),
                firmware_version: 0,
                capabilities: 0,
                serial_number: 7,
                max_speed_mm_s: 1000,
                max_rate_mrad_s: 3000,
            },
            rules: vec![rule("7.1", Outcome::Pass, None), failed],
        };
        assert!(report
            .summary("/dev/x")
            .ends_with("(/dev/x): 1 passed, 1 failed, 0 skipped"));
        let why = report.failure("above").unwrap();
        assert!(
            why.starts_with("1 rule(s) failed: §7.3 a rule (the reasons are above"),
            "{why}"
        );
        let passed = Report {
            rules: vec![rule("7.1", Outcome::Pass, None)],
            ..report
        };
        assert_eq!(passed.failure("above"), None);
    }
}
