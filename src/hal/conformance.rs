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
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

/// The vectors, as the independent generator wrote them from SPEC.md alone.
const VECTORS: &str = include_str!("../../protocol/vectors/vectors.json");

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

/// The port's frames, one request at a time.
struct Wire<S> {
    stream: S,
    codec: FrameCodec,
    buf: BytesMut,
    pending: VecDeque<Frame>,
    seq: u8,
}

/// A request's answer and the events that came before it.
struct Exchange {
    events: Vec<Frame>,
    answer: Frame,
}

impl<S: AsyncRead + AsyncWrite + Unpin> Wire<S> {
    /// The next frame received before `until`.
    async fn next(&mut self, until: Instant) -> std::io::Result<Option<Frame>> {
        loop {
            if let Some(f) = self.pending.pop_front() {
                return Ok(Some(f));
            }
            let mut chunk = [0u8; 512];
            match tokio::time::timeout_at(until, self.stream.read(&mut chunk)).await {
                Err(_) => return Ok(None),
                Ok(Ok(0)) => return Err(std::io::ErrorKind::UnexpectedEof.into()),
                Ok(Ok(n)) => {
                    let frames = self.codec.feed(&mut self.buf, &chunk[..n]);
                    self.pending.extend(frames);
                }
                Ok(Err(e)) => return Err(e),
            }
        }
    }

    /// The events received during `wait`.
    async fn collect(&mut self, wait: Duration) -> std::io::Result<Vec<Frame>> {
        let until = Instant::now() + wait;
        let mut events = Vec::new();
        while let Some(f) = self.next(until).await? {
            if f.kind == FrameKind::Event {
                events.push(f);
            }
        }
        Ok(events)
    }

    /// Sends `bytes` (a request) and waits for its answer, sending it again once (a safe
    /// retry: same sequence number) if none comes; `None` if none ever does.
    async fn exchange(&mut self, bytes: &[u8]) -> std::io::Result<Option<Exchange>> {
        let (Some(&seq), Some(&msg)) = (bytes.get(5), bytes.get(6)) else {
            return Ok(None);
        };
        let mut events = Vec::new();
        for _ in 0..2 {
            self.stream.write_all(bytes).await?;
            self.stream.flush().await?;
            let until = Instant::now() + ANSWER_TIMEOUT;
            while let Some(f) = self.next(until).await? {
                match f.kind {
                    FrameKind::Event => events.push(f),
                    FrameKind::Response | FrameKind::Nack if f.seq == seq && f.msg == msg => {
                        return Ok(Some(Exchange { events, answer: f }));
                    }
                    // A late answer to an earlier request.
                    _ => {}
                }
            }
        }
        Ok(None)
    }

    /// The bytes of `request` with the harness's next sequence number (kept clear of the
    /// vectors', which count from 1).
    fn frame(&mut self, request: Request) -> Vec<u8> {
        self.seq = self.seq.wrapping_add(1).max(0x80);
        Packet::request(self.seq, request).to_frame().to_bytes()
    }

    /// One of the harness's own requests: the answer, or the NACK.
    async fn call(
        &mut self,
        what: &'static str,
        request: Request,
    ) -> Result<Result<Response, Nack>, ConformanceError> {
        let bytes = self.frame(request);
        let ex = self
            .exchange(&bytes)
            .await?
            .ok_or(ConformanceError::Silent {
                what,
                after: 2 * ANSWER_TIMEOUT,
            })?;
        match Packet::from_frame(&ex.answer).map(|p| p.body) {
            Ok(Body::Response { response }) => Ok(Ok(response)),
            Ok(Body::Nack { nack, .. }) => Ok(Err(nack)),
            Ok(Body::Request { request }) => Err(ConformanceError::Setup {
                what,
                why: format!("answered with a request ({})", request.name()),
            }),
            Ok(Body::Event { .. }) => Err(ConformanceError::Setup {
                what,
                why: "answered with an event".into(),
            }),
            Err(e) => Err(ConformanceError::Setup {
                what,
                why: format!("undecodable answer: {e}"),
            }),
        }
    }

    /// [`Wire::call`] that must be answered, not refused.
    async fn ok(
        &mut self,
        what: &'static str,
        request: Request,
    ) -> Result<Response, ConformanceError> {
        self.call(what, request)
            .await?
            .map_err(|nack| ConformanceError::Setup {
                what,
                why: format!("refused {} (detail {})", nack.code, nack.detail),
            })
    }

    async fn status(&mut self) -> Result<crate::protocol::message::Status, ConformanceError> {
        match self.ok("GET_STATUS", Request::GetStatus).await? {
            Response::GetStatus(s) => Ok(s),
            other => Err(ConformanceError::Setup {
                what: "GET_STATUS",
                why: format!("answered {}", other.name()),
            }),
        }
    }

    /// STOP, then waits until the base reports idle.
    async fn stop_and_settle(&mut self) -> Result<(), ConformanceError> {
        self.ok("STOP", Request::Stop).await?;
        let until = Instant::now() + Duration::from_secs(3);
        loop {
            let s = self.status().await?;
            if s.motion_state == MotionState::Idle && s.queue_depth == 0 {
                return Ok(());
            }
            if Instant::now() > until {
                return Err(ConformanceError::Setup {
                    what: "STOP",
                    why: format!(
                        "the base is still {} 3 s after STOP (fault flags {:#06x})",
                        s.motion_state, s.fault_flags
                    ),
                });
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
}

/// What the harness knows about the device and how it may move it.
struct Device {
    info: DeviceInfo,
    params: ParamsBlock,
    speed_mm_s: u16,
    rate_mrad_s: u16,
    time_scale: f64,
}

impl Device {
    /// Device milliseconds as wall-clock time.
    fn wall(&self, device_ms: f64) -> Duration {
        Duration::from_secs_f64((device_ms / self.time_scale).max(0.0) / 1e3)
    }

    fn has(&self, bit: u32) -> bool {
        self.info.capabilities & bit != 0
    }

    /// Puts the device in a rule's starting state (see the module documentation); returns
    /// `completed_motions` there.
    async fn fresh<S: AsyncRead + AsyncWrite + Unpin>(
        &self,
        w: &mut Wire<S>,
    ) -> Result<u32, ConformanceError> {
        w.stop_and_settle().await?;
        if self.has(capability::WATCHDOG) {
            let off = WatchdogTimeout { timeout_ms: 0 };
            w.ok("CONFIGURE_WATCHDOG", Request::ConfigureWatchdog(off))
                .await?;
        }
        if self.has(capability::TELEMETRY) {
            let off = crate::protocol::message::TelemetryPeriod { period_ms: 0 };
            w.ok("CONFIGURE_TELEMETRY", Request::ConfigureTelemetry(off))
                .await?;
        }
        w.ok("SET_PARAMS", Request::SetParams(self.params)).await?;
        let completed = w.status().await?.completed_motions;
        if self.has(capability::WATCHDOG) {
            let safety = WatchdogTimeout {
                timeout_ms: SAFETY_WATCHDOG_MS,
            };
            w.ok("CONFIGURE_WATCHDOG", Request::ConfigureWatchdog(safety))
                .await?;
        }
        w.ok("HELLO", hello()).await?;
        // Telemetry still in flight belongs to the previous rule.
        w.collect(Duration::from_millis(20)).await?;
        Ok(completed)
    }

    /// A vector's request as sent here: speeds capped, a motion that only needs to run cut
    /// to [`LONG_MS`] (`wait` false), or kept whole and stopped once accepted (`wait` true).
    fn adapt(&self, frame: &Frame, wait: bool) -> Sent {
        let mut sent = Sent {
            bytes: frame.to_bytes(),
            stop_at_once: false,
            expected_ms: 0.0,
        };
        let Ok(Packet {
            seq,
            body: Body::Request { request },
        }) = Packet::from_frame(frame)
        else {
            return sent;
        };
        // A motion of `size` (µm or µrad, signed) at `rate` (mm/s or mrad/s): the rate capped,
        // the size cut to LONG_MS unless it is out of range or to be kept whole (`wait`).
        let mut motion = |size: i32, rate: u16, cap: u16, max: u32| -> (i32, u16) {
            let rate = if rate == 0 { 0 } else { rate.min(cap) };
            let abs = size.unsigned_abs();
            let ms = f64::from(abs) / f64::from(rate.max(1));
            sent.expected_ms = ms;
            sent.stop_at_once = wait && ms > LONG_MS as f64;
            if abs == 0 || abs > max || rate == 0 || ms <= LONG_MS as f64 || wait {
                return (size, rate);
            }
            sent.expected_ms = LONG_MS as f64;
            let cut = (u64::from(rate) * LONG_MS).min(u64::from(max)) as i32;
            (cut * size.signum(), rate)
        };
        let adapted = match request {
            Request::MoveStraight(m) => {
                let (distance_um, max_speed_mm_s) = motion(
                    m.distance_um,
                    m.max_speed_mm_s,
                    self.speed_mm_s,
                    crate::protocol::device::MAX_DISTANCE_UM,
                );
                Request::MoveStraight(MoveStraightRequest {
                    distance_um,
                    max_speed_mm_s,
                    mode: m.mode,
                })
            }
            Request::TurnInPlace(t) => {
                let (angle_urad, max_rate_mrad_s) = motion(
                    t.angle_urad,
                    t.max_rate_mrad_s,
                    self.rate_mrad_s,
                    crate::protocol::device::MAX_ANGLE_URAD,
                );
                Request::TurnInPlace(TurnInPlaceRequest {
                    angle_urad,
                    max_rate_mrad_s,
                    mode: t.mode,
                })
            }
            Request::WheelSpeed(s) => {
                let limit = self.speed_mm_s.min(i16::MAX as u16) as i16;
                sent.expected_ms = f64::from(s.duration_ms);
                Request::WheelSpeed(WheelSpeedRequest {
                    left_mm_s: s.left_mm_s.clamp(-limit, limit),
                    right_mm_s: s.right_mm_s.clamp(-limit, limit),
                    duration_ms: s.duration_ms,
                })
            }
            other => other,
        };
        if adapted != request {
            sent.bytes = Packet::request(seq, adapted).to_frame().to_bytes();
        }
        sent
    }
}

/// A request as sent, and what to do after its answer.
struct Sent {
    bytes: Vec<u8>,
    /// A long motion accepted only to check its acceptance: STOP it at once.
    stop_at_once: bool,
    /// How long the motion takes at its speed (device ms).
    expected_ms: f64,
}

fn hello() -> Request {
    Request::Hello(HelloRequest {
        host_major: crate::protocol::frame::MAJOR,
        host_min_minor: 0,
    })
}

fn message_name(msg: u8) -> String {
    id::name(msg).map_or_else(|| format!("0x{msg:02X}"), str::to_string)
}

fn unhex(s: &str) -> Result<Vec<u8>, String> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).map_err(|e| format!("{b:?}: {e}")))
        .collect()
}

/// The one frame a vector's hex holds.
fn vector_frame(hex: &str) -> Result<Frame, String> {
    let bytes = unhex(hex)?;
    let mut codec = FrameCodec::new();
    let frames = codec.feed(&mut BytesMut::new(), &bytes);
    match frames.as_slice() {
        [f] => Ok(*f),
        other => Err(format!("{hex:?} holds {} frames", other.len())),
    }
}

/// Motion ids and completed-motion counts of the rule mapped onto the device's counters.
struct Counters {
    /// The device's id of the rule's motion 1, less 1 (learned from the first id seen).
    id_offset: Option<u64>,
    /// `completed_motions` when the rule started.
    completed: u32,
}

impl Counters {
    /// The device's id for the rule's `want`, learning the offset from `got` if it is the
    /// first.
    fn id(&mut self, want: u64, got: Option<u64>) -> u64 {
        let offset = *self.id_offset.get_or_insert_with(|| {
            got.filter(|g| (1..=65535).contains(g))
                .map_or(0, |g| (g + 65535 - want % 65535) % 65535)
        });
        (want + 65534 + offset) % 65535 + 1
    }

    /// A vector's expected value of `field`, as this device should show it.
    fn expected(&mut self, field: &str, want: &Value, got: &Value) -> Value {
        match (field, want.as_u64()) {
            ("motion_id", Some(w)) => self.id(w, got.as_u64()).into(),
            ("current_motion_id", Some(w)) if w != 0 => self.id(w, got.as_u64()).into(),
            ("completed_motions", Some(w)) => self.completed.wrapping_add(w as u32).into(),
            _ => want.clone(),
        }
    }
}

/// Checks an answer against a vector's expectation: message, kind, NACK code and detail, and
/// the listed fields (spelled as the vectors' packets spell them).
fn check_answer(answer: &Frame, want: &Value, counters: &mut Counters) -> Result<(), String> {
    if answer.version != VERSION {
        return Err(format!(
            "answered in a frame with VER 0x{:02X}, not 0x{VERSION:02X}",
            answer.version
        ));
    }
    let packet = Packet::from_frame(answer).map_err(|e| format!("undecodable answer: {e}"))?;
    let want_kind = want["kind"].as_str().unwrap_or("");
    match (packet.body, want_kind) {
        (Body::Response { .. }, "response") => {
            let got = serde_json::to_value(packet).map_err(|e| e.to_string())?;
            if let Some(fields) = want.get("fields").and_then(Value::as_object) {
                for (field, value) in fields {
                    let got_value = &got["response"][field];
                    let expected = counters.expected(field, value, got_value);
                    if *got_value != expected {
                        return Err(format!("{field} is {got_value}, expected {expected}"));
                    }
                }
            }
            Ok(())
        }
        (Body::Nack { nack, .. }, "nack") => {
            let code = serde_json::to_value(nack.code).unwrap_or_default();
            if code != want["code"] || Some(u64::from(nack.detail)) != want["detail"].as_u64() {
                return Err(format!(
                    "refused {code} detail {}, expected {} detail {}",
                    nack.detail, want["code"], want["detail"]
                ));
            }
            Ok(())
        }
        (Body::Nack { nack, .. }, _) => Err(format!(
            "refused {} (detail {}), expected a {want_kind}",
            nack.code, nack.detail
        )),
        (Body::Response { response }, _) => Err(format!(
            "answered {}, expected a {want_kind}",
            response.name()
        )),
        (Body::Request { request }, _) => Err(format!(
            "answered with a request ({}), expected a {want_kind}",
            request.name()
        )),
        (Body::Event { .. }, _) => Err(format!("answered with an event, expected a {want_kind}")),
    }
}

fn motion_done_of(events: &[Frame]) -> Vec<(u16, u32)> {
    events
        .iter()
        .filter_map(|f| match Packet::from_frame(f).ok()?.body {
            Body::Event {
                event: Event::MotionDone(d),
            } => Some((d.motion_id, d.completed_motions)),
            _ => None,
        })
        .collect()
}

/// Checks a step's MOTION_DONE events against the vector's list.
fn check_motion_done(events: &[Frame], step: &Value, c: &mut Counters) -> Result<(), String> {
    let Some(want) = step.get("motion_done").and_then(Value::as_array) else {
        return Ok(());
    };
    let got = motion_done_of(events);
    let want: Vec<(u16, u32)> = want
        .iter()
        .enumerate()
        .map(|(i, pair)| {
            let w_id = pair[0].as_u64().unwrap_or(0);
            let id = c.id(w_id, got.get(i).map(|g| u64::from(g.0)));
            let done = c
                .completed
                .wrapping_add(pair[1].as_u64().unwrap_or(0) as u32);
            (id as u16, done)
        })
        .collect();
    if got == want {
        Ok(())
    } else {
        let list = |v: &[(u16, u32)]| match v {
            [] => "none".to_string(),
            v => v
                .iter()
                .map(|(id, done)| format!("motion {id} (completed {done})"))
                .collect::<Vec<_>>()
                .join(", "),
        };
        Err(format!(
            "MOTION_DONE events: {}, expected {}",
            list(&got),
            list(&want)
        ))
    }
}

/// The most TELEMETRY samples whose timestamps fall within `span_us` of each other.
fn telemetry_within(events: &[Frame], span_us: u64) -> usize {
    let times: Vec<u32> = events
        .iter()
        .filter_map(|f| match Packet::from_frame(f).ok()?.body {
            Body::Event {
                event: Event::Telemetry(t),
            } => Some(t.timestamp_us),
            _ => None,
        })
        .collect();
    (0..times.len())
        .map(|i| {
            times[i..]
                .iter()
                .take_while(|&&t| u64::from(t.wrapping_sub(times[i])) < span_us)
                .count()
        })
        .max()
        .unwrap_or(0)
}

/// A step's request: the first of a `[request, answer]` pair, or its `send`.
fn request_of(step: &Value) -> &Value {
    match step.as_array() {
        Some(pair) => pair.first().unwrap_or(&Value::Null),
        None => &step["send"],
    }
}

/// A step's expected answer.
fn answer_of(step: &Value) -> &Value {
    match step.as_array() {
        Some(pair) => pair.get(1).unwrap_or(&Value::Null),
        None => &step["answer"],
    }
}

/// The optional message a rule sends that the device does not report having (SPEC.md §8).
fn missing_capability(steps: &[Value], capabilities: u32) -> Option<String> {
    let optional = [
        (id::WHEEL_SPEED, capability::WHEEL_SPEED, 4),
        (id::CONFIGURE_TELEMETRY, capability::TELEMETRY, 1),
        (id::CONFIGURE_WATCHDOG, capability::WATCHDOG, 2),
        (id::HEARTBEAT, capability::WATCHDOG, 2),
    ];
    let sent = steps
        .iter()
        .flat_map(|s| request_of(s).as_str().and_then(|h| vector_frame(h).ok()));
    for frame in sent {
        if let Some((msg, _, bit)) = optional
            .iter()
            .find(|(msg, cap, _)| *msg == frame.msg && capabilities & cap == 0)
        {
            return Some(format!(
                "the rule sends {}, and the device does not report that capability (HELLO \
                 capability bit {bit})",
                message_name(*msg)
            ));
        }
    }
    None
}

/// Whether a rule needs a device that never saved its parameters (it expects GET_PARAMS of
/// the stored copy to be refused STORAGE_FAILURE).
fn needs_nothing_saved(steps: &[Value]) -> bool {
    steps.iter().any(|s| {
        answer_of(s)["code"] == "STORAGE_FAILURE"
            && request_of(s)
                .as_str()
                .and_then(|h| vector_frame(h).ok())
                .is_some_and(|f| f.msg == id::GET_PARAMS && f.payload().first() == Some(&1))
    })
}

/// A device the rules' steps run against: over a port in real time ([`Live`]), or in
/// process with its clock held ([`Clocked`]).
#[async_trait::async_trait]
trait Target {
    /// Sends a vector's request; with `until_idle`, device time then runs until the base is
    /// idle. The answer and the events that came before it; `Err` is why there is none.
    async fn send(&mut self, frame: &Frame, until_idle: bool) -> Result<Exchange, String>;
    /// `ms` of device time pass with the host silent; the events sent meanwhile (with
    /// `late`, also those that arrive a little after: their timestamps say when they were
    /// taken).
    async fn advance(&mut self, ms: u64, late: bool) -> Result<Vec<Frame>, String>;
}

/// A device on a port, in real time, its requests adapted ([`Device::adapt`]).
struct Live<'a, S> {
    w: &'a mut Wire<S>,
    dev: &'a Device,
}

#[async_trait::async_trait]
impl<S: AsyncRead + AsyncWrite + Unpin + Send> Target for Live<'_, S> {
    async fn send(&mut self, frame: &Frame, until_idle: bool) -> Result<Exchange, String> {
        let what = message_name(frame.msg);
        let sent = self.dev.adapt(frame, until_idle);
        let io = |e: std::io::Error| format!("the link failed: {e}");
        let ex = self
            .w
            .exchange(&sent.bytes)
            .await
            .map_err(io)?
            .ok_or_else(|| format!("no answer to {what}"))?;
        let accepted_motion = ex.answer.kind == FrameKind::Response
            && matches!(
                ex.answer.msg,
                id::MOVE_STRAIGHT | id::TURN_IN_PLACE | id::WHEEL_SPEED
            );
        if !(until_idle && accepted_motion) {
            return Ok(ex);
        }
        if sent.stop_at_once {
            self.w.stop_and_settle().await.map_err(|e| e.to_string())?;
            return Ok(ex);
        }
        // "Until idle", the host present: the status polled until the base is idle.
        let limit = self.dev.wall(sent.expected_ms * 1.5 + 2000.0) + Duration::from_secs(1);
        let until = Instant::now() + limit;
        loop {
            tokio::time::sleep(STATUS_POLL).await;
            let s = self.w.status().await.map_err(|e| e.to_string())?;
            if s.motion_state == MotionState::Idle && s.queue_depth == 0 {
                return Ok(ex);
            }
            if Instant::now() > until {
                return Err(format!(
                    "{what} accepted but the base is still {} after {:.1} s",
                    s.motion_state,
                    limit.as_secs_f64()
                ));
            }
        }
    }

    async fn advance(&mut self, ms: u64, late: bool) -> Result<Vec<Frame>, String> {
        // A busy host or link delivers telemetry late, not less of it.
        let grace = if late { LATE_EVENTS } else { Duration::ZERO };
        let wait = self.dev.wall(ms as f64) + grace;
        self.w
            .collect(wait)
            .await
            .map_err(|e| format!("the link failed: {e}"))
    }
}

/// A device built on the kit, in process, its clock held by the harness (the clock hook of
/// SPEC.md §7): its board's clock moves only when a step says.
pub struct Clocked<B, S>(pub KitDevice<B, S>);

#[async_trait::async_trait]
impl<B, S> Target for Clocked<B, S>
where
    B: SimulatedBoard + Send,
    S: ParamStorage + Send,
{
    async fn send(&mut self, frame: &Frame, until_idle: bool) -> Result<Exchange, String> {
        let d = &mut self.0;
        let mut out = VecSink::default();
        d.handle_frame(frame, &mut out);
        let at = out
            .frames
            .iter()
            .position(|f| f.kind != FrameKind::Event)
            .ok_or_else(|| format!("no answer to {}", message_name(frame.msg)))?;
        let answer = out.frames.remove(at);
        if until_idle {
            // The host waits for the base: it counts as present, the watchdog cannot trip.
            d.hold_watchdog(true);
            while d.is_moving() {
                let now = d.board_mut().now_us();
                let Some(left) = d.remaining_us(now) else {
                    return Err("an open-ended WHEEL_SPEED never becomes idle".into());
                };
                d.advance_to(now + left.max(1), &mut VecSink::default());
            }
            d.hold_watchdog(false);
        }
        Ok(Exchange {
            events: out.frames,
            answer,
        })
    }

    async fn advance(&mut self, ms: u64, _late: bool) -> Result<Vec<Frame>, String> {
        let d = &mut self.0;
        let mut out = VecSink::default();
        let now = d.board_mut().now_us();
        d.advance_to(now + ms * 1000, &mut out);
        Ok(out.frames)
    }
}

/// Runs one rule's steps; `Err` is why it failed.
async fn run_steps(
    target: &mut (dyn Target + Send),
    steps: &[Value],
    c: &mut Counters,
) -> Result<(), String> {
    for (i, step) in steps.iter().enumerate() {
        let at = |why: String| format!("step {}: {why}", i + 1);
        if let Some(ms) = step["advance_ms"].as_u64() {
            let min = step["telemetry_min"].as_u64();
            let events = target.advance(ms, min.is_some()).await.map_err(at)?;
            check_motion_done(&events, step, c).map_err(at)?;
            if let Some(min) = min {
                let n = telemetry_within(&events, ms * 1000) as u64;
                if n < min {
                    return Err(at(format!(
                        "{n} TELEMETRY samples in {ms} ms, expected {min}"
                    )));
                }
            }
            continue;
        }
        // `[request, answer]` runs until idle; `send` does not; `repeat` sends a cycle.
        let (requests, want, until_idle) = match (step.as_array(), step["repeat"].as_u64()) {
            (Some(_), _) => (vec![request_of(step).clone()], answer_of(step), true),
            (None, Some(n)) => {
                let cycle = step["send_cycle"].as_array().cloned().unwrap_or_default();
                let all = cycle.iter().cycle().take(n as usize).cloned().collect();
                (all, &step["answer"], true)
            }
            (None, None) => (vec![step["send"].clone()], &step["answer"], false),
        };
        for hex in &requests {
            let hex = hex
                .as_str()
                .ok_or_else(|| at(format!("unknown step {step}")))?;
            let frame = vector_frame(hex).map_err(&at)?;
            let ex = target.send(&frame, until_idle).await.map_err(&at)?;
            let what = message_name(frame.msg);
            check_answer(&ex.answer, want, c).map_err(|e| at(format!("{what} {e}")))?;
            check_motion_done(&ex.events, step, c).map_err(&at)?;
        }
    }
    Ok(())
}

/// A rule's section, its text, and its steps.
fn rule_parts(rule: &Value) -> (RuleResult, &[Value]) {
    let name = rule["name"].as_str().unwrap_or("");
    let (section, text) = name.split_once(' ').unwrap_or((name, ""));
    let result = RuleResult {
        section: section.to_string(),
        rule: text.to_string(),
        outcome: Outcome::Skip,
        reason: None,
    };
    (result, rule["steps"].as_array().map_or(&[], Vec::as_slice))
}

/// Runs one vector rule in real time.
async fn run_rule<S: AsyncRead + AsyncWrite + Unpin + Send>(
    w: &mut Wire<S>,
    dev: &Device,
    rule: &Value,
    saved_copy: bool,
) -> Result<RuleResult, ConformanceError> {
    let (mut result, steps) = rule_parts(rule);
    if let Some(n) = steps.iter().find_map(|s| s["repeat"].as_u64()) {
        result.reason = Some(format!(
            "needs the clock hook: {n} motions in a row (run the vectors against the device \
             with its clock held, SPEC.md §7)"
        ));
        return Ok(result);
    }
    if let Some(why) = missing_capability(steps, dev.info.capabilities) {
        result.reason = Some(why);
        return Ok(result);
    }
    if saved_copy && needs_nothing_saved(steps) {
        result.reason = Some(
            "the device holds a saved parameter copy; the rule needs one that never saved".into(),
        );
        return Ok(result);
    }
    let completed = dev.fresh(w).await?;
    let mut counters = Counters {
        id_offset: None,
        completed,
    };
    let outcome = run_steps(&mut Live { w, dev }, steps, &mut counters).await;
    result.set(outcome);
    w.stop_and_settle().await?;
    Ok(result)
}

impl RuleResult {
    fn set(&mut self, outcome: Result<(), String>) {
        match outcome {
            Ok(()) => self.outcome = Outcome::Pass,
            Err(why) => {
                self.outcome = Outcome::Fail;
                self.reason = Some(why);
            }
        }
    }
}

/// Runs every rule of the vectors, each against a freshly powered-up device from `power_up`
/// with its clock held (SPEC.md §7's harness): nothing is adapted or skipped, ids and counts
/// are checked as written.
pub async fn run_clocked<B, S>(
    mut power_up: impl FnMut() -> KitDevice<B, S>,
) -> Result<Vec<RuleResult>, ConformanceError>
where
    B: SimulatedBoard + Send,
    S: ParamStorage + Send,
{
    let mut results = Vec::new();
    for rule in device_rules()?.iter() {
        let (mut result, steps) = rule_parts(rule);
        let mut counters = Counters {
            id_offset: Some(0),
            completed: 0,
        };
        let mut target = Clocked(power_up());
        result.set(run_steps(&mut target, steps, &mut counters).await);
        results.push(result);
    }
    Ok(results)
}

/// The vectors' device rules.
fn device_rules() -> Result<Vec<Value>, ConformanceError> {
    let mut vectors: Value =
        serde_json::from_str(VECTORS).map_err(|e| ConformanceError::Vectors(e.to_string()))?;
    match vectors["device_rules"].take() {
        Value::Array(rules) => Ok(rules),
        _ => Err(ConformanceError::Vectors("no device_rules".into())),
    }
}

/// §3: a retried motion is answered from the cache and runs once.
async fn retried_motion_runs_once<S: AsyncRead + AsyncWrite + Unpin + Send>(
    w: &mut Wire<S>,
    dev: &Device,
) -> Result<Result<(), String>, ConformanceError> {
    let completed = dev.fresh(w).await?;
    // Half a second of driving at the capped speed.
    let request = Request::MoveStraight(MoveStraightRequest {
        distance_um: i32::from(dev.speed_mm_s) * 500,
        max_speed_mm_s: dev.speed_mm_s,
        mode: MotionMode::Queue,
    });
    let bytes = w.frame(request);
    let first = w.exchange(&bytes).await?;
    let again = w.exchange(&bytes).await?;
    let (Some(first), Some(again)) = (first, again) else {
        return Ok(Err("no answer to MOVE_STRAIGHT or to its retry".into()));
    };
    if first.answer.to_bytes() != again.answer.to_bytes() {
        return Ok(Err(format!(
            "the retry was answered {}, the request {} (frames in hex)",
            hex(&again.answer.to_bytes()),
            hex(&first.answer.to_bytes())
        )));
    }
    let mut events = first.events;
    events.extend(again.events);
    events.extend(w.collect(dev.wall(500.0 * 3.0 + 1000.0)).await?);
    let status = w.status().await?;
    let done = motion_done_of(&events);
    if status.completed_motions != completed.wrapping_add(1) || done.len() != 1 {
        return Ok(Err(format!(
            "completed_motions went from {completed} to {} and {} MOTION_DONE came: \
             the retry ran again",
            status.completed_motions,
            done.len()
        )));
    }
    Ok(Ok(()))
}

/// §7.2: a retry answered from the cache feeds the watchdog.
async fn retries_feed_the_watchdog<S: AsyncRead + AsyncWrite + Unpin + Send>(
    w: &mut Wire<S>,
    dev: &Device,
) -> Result<Result<(), String>, ConformanceError> {
    const TIMEOUT_MS: u16 = 500;
    const RETRYING: Duration = Duration::from_millis(1500);
    dev.fresh(w).await?;
    let timeout = WatchdogTimeout {
        timeout_ms: TIMEOUT_MS,
    };
    w.ok("CONFIGURE_WATCHDOG", Request::ConfigureWatchdog(timeout))
        .await?;
    // A motion that outlasts the retrying twice over.
    let run_ms = 2.0 * RETRYING.as_secs_f64() * 1e3 * dev.time_scale;
    let request = Request::MoveStraight(MoveStraightRequest {
        distance_um: (f64::from(dev.speed_mm_s) * run_ms) as i32,
        max_speed_mm_s: dev.speed_mm_s,
        mode: MotionMode::Replace,
    });
    w.ok("MOVE_STRAIGHT", request).await?;
    let status = w.frame(Request::GetStatus);
    let until = Instant::now() + RETRYING;
    while Instant::now() < until {
        if w.exchange(&status).await?.is_none() {
            return Ok(Err("no answer to a retried GET_STATUS".into()));
        }
        tokio::time::sleep(Duration::from_millis(u64::from(TIMEOUT_MS) / 10)).await;
    }
    let s = w.status().await?;
    let outcome = if s.watchdog_state == WatchdogState::Tripped {
        Err(format!(
            "the watchdog ({TIMEOUT_MS} ms) tripped while the same GET_STATUS was retried every \
             {} ms",
            TIMEOUT_MS / 10
        ))
    } else if s.motion_state != MotionState::Moving {
        Err(format!(
            "the {run_ms:.0} ms motion ended early: {}",
            s.motion_state
        ))
    } else {
        Ok(())
    };
    w.stop_and_settle().await?;
    Ok(outcome)
}

/// The stored parameter copy as GET_PARAMS reports it (or its refusal).
/// Bytes as hex pairs (`a5 01 …`), for frames in a reason.
fn hex(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// How long [`clock_rate`] watches the device's clock (wall time).
const CLOCK_WATCH: Duration = Duration::from_millis(400);

/// The device's clock rate: device milliseconds (STATUS `uptime_ms`) per wall-clock millisecond
/// over [`CLOCK_WATCH`]; 1 for hardware, the speed-up of a simulator, 0 for one in virtual time.
/// Returns the rate and the last uptime.
async fn clock_rate<S: AsyncRead + AsyncWrite + Unpin>(
    w: &mut Wire<S>,
) -> Result<(f64, u32), ConformanceError> {
    let t0 = Instant::now();
    let first = w.status().await?.uptime_ms;
    tokio::time::sleep(CLOCK_WATCH).await;
    let last = w.status().await?.uptime_ms;
    let wall_ms = t0.elapsed().as_secs_f64() * 1e3;
    Ok((f64::from(last.wrapping_sub(first)) / wall_ms, last))
}

/// The scale the rules time themselves by: `given` when it agrees with the device's clock rate
/// within 25 %, the measured rate (rounded, in [1, 100]) when none is given; a clock that
/// stands still is [`ConformanceError::ClockStill`].
async fn time_scale<S: AsyncRead + AsyncWrite + Unpin>(
    w: &mut Wire<S>,
    given: Option<f64>,
) -> Result<f64, ConformanceError> {
    let (rate, uptime_ms) = clock_rate(w).await?;
    if rate < 0.05 {
        return Err(ConformanceError::ClockStill {
            uptime_ms,
            waited_ms: CLOCK_WATCH.as_millis() as u64,
        });
    }
    let measured = rate.round().clamp(1.0, 100.0);
    match given {
        None => Ok(measured),
        Some(k) if (0.8..=1.25).contains(&(rate / k)) => Ok(k),
        Some(k) => Err(ConformanceError::InvalidArgument(format!(
            "--time-scale {k} was given, but the device's clock runs {rate:.2} times the wall \
             clock: give --time-scale {measured}, or leave it out (it is measured)"
        ))),
    }
}

async fn stored<S: AsyncRead + AsyncWrite + Unpin>(
    w: &mut Wire<S>,
) -> Result<Result<Response, Nack>, ConformanceError> {
    let stored = GetParamsRequest {
        source: ParamSource::Stored,
    };
    w.call("GET_PARAMS", Request::GetParams(stored)).await
}

/// Runs every rule against the device on `stream` (the port), calling `progress` after each;
/// the device is stopped and its parameters written back before this returns.
pub async fn run<S: AsyncRead + AsyncWrite + Unpin + Send>(
    stream: S,
    options: &Options,
    mut progress: impl FnMut(&RuleResult),
) -> Result<Report, ConformanceError> {
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
    let rules = device_rules()?;
    let mut w = Wire {
        stream,
        codec: FrameCodec::new(),
        buf: BytesMut::new(),
        pending: VecDeque::new(),
        seq: 0x80,
    };
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
    let stored_before = stored(&mut w).await?;
    let time_scale = time_scale(&mut w, options.time_scale).await?;
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
    let wanted = |section: &str| {
        options.only.is_empty() || options.only.iter().any(|o| section.starts_with(o.as_str()))
    };
    let mut results = Vec::new();
    let outcome = async {
        for rule in &rules {
            let section = rule["name"].as_str().unwrap_or("").split(' ').next();
            if !section.is_some_and(wanted) {
                continue;
            }
            let r = run_rule(&mut w, &dev, rule, stored_before.is_ok()).await?;
            progress(&r);
            results.push(r);
        }
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
            let check = if !possible {
                Ok(Err("the device has no watchdog".to_string()))
            } else if i == 0 {
                retried_motion_runs_once(&mut w, &dev).await
            } else {
                retries_feed_the_watchdog(&mut w, &dev).await
            };
            let r = match check? {
                Ok(()) => RuleResult {
                    section: section.into(),
                    rule: rule.into(),
                    outcome: Outcome::Pass,
                    reason: None,
                },
                Err(why) => RuleResult {
                    section: section.into(),
                    rule: rule.into(),
                    outcome: if possible {
                        Outcome::Fail
                    } else {
                        Outcome::Skip
                    },
                    reason: Some(why),
                },
            };
            progress(&r);
            results.push(r);
        }
        Ok::<(), ConformanceError>(())
    }
    .await;
    // Whatever happened: stopped, settings off, the parameters in use at the start back.
    let restored = async {
        dev.fresh(&mut w).await?;
        if dev.has(capability::WATCHDOG) {
            let off = WatchdogTimeout { timeout_ms: 0 };
            w.ok("CONFIGURE_WATCHDOG", Request::ConfigureWatchdog(off))
                .await?;
        }
        Ok::<(), ConformanceError>(())
    }
    .await;
    outcome?;
    restored?;
    let stored_after = stored(&mut w).await?;
    let unchanged = match (&stored_before, &stored_after) {
        (Ok(a), Ok(b)) => a == b,
        (Err(a), Err(b)) => a.code == b.code,
        _ => false,
    };
    let r = RuleResult {
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
                text(&stored_before),
                text(&stored_after)
            )
        }),
    };
    progress(&r);
    results.push(r);
    Ok(Report {
        device: info,
        rules: results,
    })
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
