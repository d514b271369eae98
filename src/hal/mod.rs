//! The hardware-abstraction layer: an async client for `protocol/SPEC.md` over any byte stream.
//!
//! [`Client::connect`] takes any [`Transport`] (a serial port from [`open_port`], a
//! pseudo-terminal, an in-memory [`crate::io::transport::pair`]), spawns the task that owns the link ([`link`]) and
//! performs the HELLO handshake. Calls are typed, carry deadlines computed from frame sizes and
//! the baud rate, and are retried with the same sequence number so the device never executes
//! one twice. Errors come in two layers: [`LinkError`] (the link or the protocol failed) and
//! [`HalError::Nack`] (the device understood and said no). Telemetry arrives on a broadcast
//! channel with encoder counts and device time unwrapped on the host ([`Client::subscribe`]).
//! [`base`] makes a client a drive, a heading source and a parameter store of the seam;
//! [`conformance`] checks a device against SPEC.md §7 over a raw link, in real time.

pub mod base;
#[cfg(feature = "conformance")]
pub mod conformance;
pub mod error;
pub mod link;
pub mod params;
pub mod status;

pub use error::{HalError, LinkError};

/// Stops the base over a link of its own (after an error or a signal ended the link that was
/// driving it): opens `port` at `baud`, sends STOP, closes.
pub async fn stop_over_new_link(port: &str, baud: u32) -> Result<(), HalError> {
    let (client, _) = open_port(port, baud).await?;
    let stopped = client.stop().await;
    client.close().await;
    stopped
}

use crate::io::transport::Transport;
use crate::kinematics::{wrap_angle, WheelParams};
use crate::protocol::frame::{MAJOR, VERSION};
use crate::protocol::message::{
    fault, DeviceInfo, Encoders, FirmwareId, GetParamsRequest, HelloRequest, MotionAccepted,
    MotionDone, MotionMode, MotionState, MoveStraightRequest, NackCode, ParamSource, ParamsBlock,
    RestoreDefaultsRequest, RestoreTarget, Status, TelemetryPeriod, TurnInPlaceRequest,
    WatchdogState, WatchdogTimeout, WheelSpeedRequest,
};
use crate::protocol::units::{self, UnitError};
use crate::protocol::{Request, Response};
use link::{Command, Link, LinkConfig};
use serde::Serialize;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{broadcast, mpsc, oneshot, watch};

/// The link's baud rate unless configured (SPEC.md §1).
pub const DEFAULT_BAUD: u32 = 115_200;

/// Baud rates a serial link may be opened at.
pub const BAUD_RANGE: std::ops::RangeInclusive<u32> = 300..=4_000_000;

/// How long the HELLO handshake is retried before the port is diagnosed (see [`Client::connect`]).
pub const HELLO_BUDGET: Duration = Duration::from_millis(2500);

/// Longest [`Client::close`] waits for the link to let go of its port.
pub const CLOSE_TIMEOUT: Duration = Duration::from_secs(2);

/// How often [`Client::wait_motion`] polls the status while a motion runs (its end normally
/// arrives as a MOTION_DONE event).
pub const STATUS_POLL: Duration = Duration::from_millis(250);

/// How often [`Client::wait_motion`] feeds the watchdog while a motion runs: a third of the
/// shortest timeout the routine arms (SPEC.md: hosts feed it every `timeout_ms / 3`).
pub const HEARTBEAT_EVERY: Duration = Duration::from_millis(100);

/// Counters of the link's health.
#[derive(Debug, Default)]
pub struct LinkStats {
    /// Requests sent (first attempts, including BUSY resends).
    pub requests: AtomicU64,
    /// Resends with the same sequence number after a missing answer.
    pub retries: AtomicU64,
    /// Requests that failed for lack of an answer.
    pub timeouts: AtomicU64,
    /// BUSY answers retried.
    pub busy: AtomicU64,
    /// Answers that matched no pending request (late duplicates).
    pub stale_answers: AtomicU64,
    /// Frames that passed the CRC but not the message layer.
    pub undecodable: AtomicU64,
    /// Bytes the decoder skipped.
    pub decoder_dropped_bytes: AtomicU64,
    /// Telemetry samples received.
    pub telemetry_received: AtomicU64,
    /// Telemetry samples lost (gaps in the sample index).
    pub telemetry_dropped: AtomicU64,
    /// Valid frames received of any kind (a sign of life of the device).
    pub frames_received: AtomicU64,
    /// The shortest answer time beyond transmission seen so far, plus one (µs; 0 before the
    /// first): what the adapter and the device's turnaround add to every exchange. Read it
    /// with [`LinkStats::adapter_latency`].
    pub adapter_latency_us: AtomicU64,
    /// The watchdog timeout the device last acknowledged (ms; 0: off).
    pub watchdog_ms: AtomicU64,
    /// The longest time beyond transmission from a retried request's first attempt to its
    /// answer (µs): the latency used while no first attempt has been answered.
    pub latency_bound_us: AtomicU64,
}

/// A snapshot of [`LinkStats`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct LinkStatsSnapshot {
    /// See [`LinkStats::requests`].
    pub requests: u64,
    /// See [`LinkStats::retries`].
    pub retries: u64,
    /// See [`LinkStats::timeouts`].
    pub timeouts: u64,
    /// See [`LinkStats::busy`].
    pub busy: u64,
    /// See [`LinkStats::stale_answers`].
    pub stale_answers: u64,
    /// See [`LinkStats::undecodable`].
    pub undecodable: u64,
    /// See [`LinkStats::decoder_dropped_bytes`].
    pub decoder_dropped_bytes: u64,
    /// See [`LinkStats::telemetry_received`].
    pub telemetry_received: u64,
    /// See [`LinkStats::telemetry_dropped`].
    pub telemetry_dropped: u64,
    /// See [`LinkStats::frames_received`].
    pub frames_received: u64,
    /// See [`LinkStats::adapter_latency_us`] (`None` before the first answer).
    pub adapter_latency_us: Option<u64>,
    /// See [`LinkStats::watchdog_ms`].
    pub watchdog_ms: u64,
}

impl LinkStats {
    /// The adapter's latency as measured so far (`None` before the first answer).
    pub fn adapter_latency(&self) -> Option<Duration> {
        match self.adapter_latency_us.load(Ordering::Relaxed) {
            0 => None,
            l => Some(Duration::from_micros(l - 1)),
        }
    }

    /// Takes an answer time beyond transmission on a first attempt: the shortest is kept.
    fn record_latency(&self, beyond: Duration) {
        let stored = u64::try_from(beyond.as_micros())
            .unwrap_or(u64::MAX - 1)
            .saturating_add(1);
        let _ = self
            .adapter_latency_us
            .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |now| {
                (now == 0 || stored < now).then_some(stored)
            });
    }

    fn snapshot(&self) -> LinkStatsSnapshot {
        let g = |a: &AtomicU64| a.load(Ordering::Relaxed);
        LinkStatsSnapshot {
            requests: g(&self.requests),
            retries: g(&self.retries),
            timeouts: g(&self.timeouts),
            busy: g(&self.busy),
            stale_answers: g(&self.stale_answers),
            undecodable: g(&self.undecodable),
            decoder_dropped_bytes: g(&self.decoder_dropped_bytes),
            telemetry_received: g(&self.telemetry_received),
            telemetry_dropped: g(&self.telemetry_dropped),
            frames_received: g(&self.frames_received),
            adapter_latency_us: self
                .adapter_latency()
                .map(|l| u64::try_from(l.as_micros()).unwrap_or(u64::MAX)),
            watchdog_ms: g(&self.watchdog_ms),
        }
    }
}

/// One telemetry sample with host-side unwrapping.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
pub struct TelemetrySample {
    /// Device sample index.
    pub sample_index: u32,
    /// Device time since the first sample seen (s), unwrapped.
    pub device_time_s: f64,
    /// Left encoder counts, unwrapped.
    pub left_counts: i64,
    /// Right encoder counts, unwrapped.
    pub right_counts: i64,
    /// Heading (rad), counter-clockwise positive.
    pub heading_rad: f64,
    /// Whether the heading may be used.
    pub heading_valid: bool,
    /// Motion state.
    pub motion_state: MotionState,
    /// Motions queued.
    pub queue_depth: u8,
    /// Samples lost just before this one.
    pub dropped_before: u32,
}

impl TelemetrySample {
    /// The heading of this sample as the seam has it, on the device's clock.
    pub fn heading_sample(&self) -> crate::samples::HeadingSample {
        let (t, h, valid) = (self.device_time_s, self.heading_rad, self.heading_valid);
        crate::samples::HeadingSample::flagged(t, h, valid)
    }
}

/// A heading reading in SI units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct HeadingReading {
    /// Heading (rad), counter-clockwise positive, wrapped.
    pub heading_rad: f64,
    /// Whether the reading may be used.
    pub valid: bool,
    /// Sensor status bits.
    pub sensor_status: u8,
    /// Device clock (µs, wrapping).
    pub timestamp_us: u32,
}

/// A handle to a connected device; cheap to clone, all clones share one link.
#[derive(Clone)]
pub struct Client {
    commands: mpsc::UnboundedSender<Command>,
    events: broadcast::Sender<TelemetrySample>,
    motion_done: broadcast::Sender<MotionDone>,
    stats: Arc<LinkStats>,
    config: LinkConfig,
    info: DeviceInfo,
    /// The port path, or what the stream is, for reports.
    label: Arc<str>,
    /// The active parameters as last read or written, to turn counts into metres.
    geometry: Arc<std::sync::Mutex<Option<WheelParams>>>,
    /// The last request handed to the link, for a report of where a failed run stopped.
    last_request: Arc<std::sync::Mutex<Option<Request>>>,
    /// Becomes `true` once the link task has ended and dropped its stream (the port is free).
    released: watch::Receiver<bool>,
}

/// Opens a serial port by path (through [`crate::io::serial::open`]) and connects.
pub async fn open_port(path: &str, baud: u32) -> Result<(Client, DeviceInfo), HalError> {
    // Deadlines are computed from the baud rate: 0 (or a typo) would make them hours long.
    if !BAUD_RANGE.contains(&baud) {
        return Err(HalError::InvalidArgument(format!(
            "baud rate {baud} is outside {}..={} (SPEC.md §1: 115200 unless configured)",
            BAUD_RANGE.start(),
            BAUD_RANGE.end()
        )));
    }
    let port = crate::io::serial::open(path, baud).map_err(|e| HalError::Open {
        path: path.to_string(),
        source: Arc::new(e),
    })?;
    let (mut client, info) = Client::connect(
        port,
        LinkConfig {
            baud,
            ..LinkConfig::default()
        },
    )
    .await?;
    client.label = Arc::from(path);
    Ok((client, info))
}

macro_rules! expect {
    ($resp:expr, $pat:pat => $out:expr) => {
        match $resp {
            $pat => Ok($out),
            other => Err(HalError::Link(LinkError::Protocol(format!(
                "unexpected answer {}",
                other.name()
            )))),
        }
    };
}

impl Client {
    /// Starts the link task on `stream` and performs the HELLO handshake.
    pub async fn connect<S: Transport>(
        stream: S,
        config: LinkConfig,
    ) -> Result<(Client, DeviceInfo), HalError> {
        let (tx, rx) = mpsc::unbounded_channel();
        let (events, _) = broadcast::channel(1 << 16);
        let (motion_done, _) = broadcast::channel(64);
        let stats = Arc::new(LinkStats::default());
        let link = Link {
            config,
            stats: stats.clone(),
            events: events.clone(),
            motion_done: motion_done.clone(),
        };
        let (released_tx, released) = watch::channel(false);
        tokio::spawn(async move {
            // `run` drops the stream before it returns, so the port is free when this fires.
            link.run(stream, rx).await;
            let _ = released_tx.send(true);
        });
        let placeholder = DeviceInfo {
            major: 0,
            minor: 0,
            firmware_id: FirmwareId::new("").unwrap_or_else(|_| unreachable!()),
            firmware_version: 0,
            capabilities: 0,
            serial_number: 0,
            max_speed_mm_s: 0,
            max_rate_mrad_s: 0,
        };
        let mut client = Client {
            commands: tx,
            events,
            motion_done,
            stats,
            config,
            info: placeholder,
            label: Arc::from("stream"),
            geometry: Arc::default(),
            last_request: Arc::default(),
            released,
        };
        // HELLO is retried for HELLO_BUDGET: long enough for a board that resets when its port
        // opens (Arduino-style bootloaders take 1–2 s), short enough to diagnose a wrong port.
        let hello = client
            .request_within(
                Request::Hello(HelloRequest {
                    host_major: MAJOR,
                    host_min_minor: 0,
                }),
                Some(HELLO_BUDGET),
            )
            .await;
        let info = match hello {
            Ok(Response::Hello(info)) => info,
            Ok(other) => {
                return Err(
                    LinkError::Protocol(format!("HELLO answered with {}", other.name())).into(),
                )
            }
            Err(HalError::Nack { nack, .. }) if nack.code == NackCode::VersionMismatch => {
                // SPEC 1.1: the detail is the device's own VER byte; 0xFF from a 1.0 device.
                return Err(LinkError::VersionMismatch {
                    device: (nack.detail != 0xFF).then_some((nack.detail >> 4, nack.detail & 0x0F)),
                    host: MAJOR,
                }
                .into());
            }
            Err(HalError::Link(LinkError::Timeout { after, .. })) => {
                let snapshot = client.stats();
                let err = if snapshot.frames_received == 0 && snapshot.decoder_dropped_bytes > 0 {
                    LinkError::NotOdocal {
                        bytes: snapshot.decoder_dropped_bytes,
                        after,
                        baud: config.baud,
                    }
                } else {
                    LinkError::Silent {
                        after,
                        baud: config.baud,
                    }
                };
                return Err(err.into());
            }
            Err(e) => return Err(e),
        };
        if info.major != MAJOR {
            return Err(LinkError::VersionMismatch {
                device: Some((info.major, info.minor)),
                host: VERSION >> 4,
            }
            .into());
        }
        client.info = info;
        Ok((client, info))
    }

    /// What the device said about itself at the handshake.
    pub fn device_info(&self) -> &DeviceInfo {
        &self.info
    }

    /// The port path this client was opened on (`stream` for other transports).
    pub fn label(&self) -> &str {
        &self.label
    }

    /// The active parameters as last read or written through this client.
    pub fn known_geometry(&self) -> Option<WheelParams> {
        *self.geometry.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn remember(&self, params: WheelParams) -> WheelParams {
        *self.geometry.lock().unwrap_or_else(|p| p.into_inner()) = Some(params);
        params
    }

    /// The link's timing policy.
    pub fn link_config(&self) -> LinkConfig {
        self.config
    }

    /// Link health counters.
    pub fn stats(&self) -> LinkStatsSnapshot {
        self.stats.snapshot()
    }

    /// A receiver of every telemetry sample from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<TelemetrySample> {
        self.events.subscribe()
    }

    /// A receiver of every MOTION_DONE event from now on (subscribe before starting a motion
    /// to be sure to see its end).
    pub fn subscribe_motion_done(&self) -> broadcast::Receiver<MotionDone> {
        self.motion_done.subscribe()
    }

    /// Sends any request and waits for its answer (with retries and deadlines).
    pub async fn request(&self, request: Request) -> Result<Response, HalError> {
        self.request_within(request, None).await
    }

    /// [`Client::request`] retried for `budget` instead of the configured retry budget.
    async fn request_within(
        &self,
        request: Request,
        budget: Option<Duration>,
    ) -> Result<Response, HalError> {
        let (reply, rx) = oneshot::channel();
        if let Ok(mut last) = self.last_request.lock() {
            *last = Some(request);
        }
        self.commands
            .send(Command::Request {
                request,
                budget,
                reply,
            })
            .map_err(|_| LinkError::Closed)?;
        rx.await.map_err(|_| LinkError::Closed)?
    }

    /// The last request handed to the link (answered or not).
    pub fn last_request(&self) -> Option<Request> {
        self.last_request.lock().ok().and_then(|l| *l)
    }

    /// Lets go of the link: pending requests fail, STOP is sent if this host moved the base,
    /// and the stream is dropped. Returns once the port is free to be opened again, or after
    /// [`CLOSE_TIMEOUT`] (a STOP written to a port nobody reads may block).
    pub async fn close(&self) {
        let _ = self.commands.send(Command::Close);
        let mut released = self.released.clone();
        let _ = tokio::time::timeout(CLOSE_TIMEOUT, released.wait_for(|r| *r)).await;
    }

    /// Abandons pending requests and sends STOP at once, without waiting. Safe from `Drop`.
    pub fn emergency_stop(&self) {
        let _ = self.commands.send(Command::EmergencyStop);
    }

    /// Reads a parameter copy.
    pub async fn get_params(&self, source: ParamSource) -> Result<WheelParams, HalError> {
        let params = expect!(self.request(Request::GetParams(GetParamsRequest { source })).await?,
            Response::GetParams(p) => WheelParams::from(&p.params))?;
        if source == ParamSource::Active {
            self.remember(params);
        }
        Ok(params)
    }

    /// Writes the active (RAM) parameters; returns them as the device applied them.
    pub async fn set_params(&self, params: &WheelParams) -> Result<WheelParams, HalError> {
        // Checked here, before anything is sent, rather than left to the device's NACK.
        let block = wire_params(params)?;
        expect!(self.request(Request::SetParams(block)).await?,
            Response::SetParams(b) => self.remember(WheelParams::from(&b)))
    }

    /// Commits the active parameters to non-volatile storage; returns the stored copy's CRC.
    pub async fn save_params(&self) -> Result<u16, HalError> {
        expect!(self.request(Request::SaveParams).await?,
            Response::SaveParams(c) => c.stored_crc)
    }

    /// Restores factory defaults (RAM, or RAM and storage).
    pub async fn restore_defaults(&self, target: RestoreTarget) -> Result<WheelParams, HalError> {
        expect!(self.request(Request::RestoreDefaults(RestoreDefaultsRequest { target })).await?,
            Response::RestoreDefaults(b) => self.remember(WheelParams::from(&b)))
    }

    /// Reloads the stored parameters into RAM.
    pub async fn load_params(&self) -> Result<WheelParams, HalError> {
        expect!(self.request(Request::LoadParams).await?, Response::LoadParams(b) => self.remember(WheelParams::from(&b)))
    }

    /// Zeroes the encoders.
    pub async fn reset_odometry(&self) -> Result<(), HalError> {
        expect!(self.request(Request::ResetOdometry).await?, Response::ResetOdometry => ())
    }

    /// **Moves the robot**: drive straight `distance_m` at most `max_speed_m_s`.
    pub async fn move_straight(
        &self,
        distance_m: f64,
        max_speed_m_s: f64,
        mode: MotionMode,
    ) -> Result<MotionAccepted, HalError> {
        let request = MoveStraightRequest {
            distance_um: units::m_to_um("distance", distance_m).map_err(invalid)?,
            max_speed_mm_s: units::m_s_to_mm_s("speed limit", max_speed_m_s).map_err(invalid)?,
            mode,
        };
        expect!(self.request(Request::MoveStraight(request)).await?,
            Response::MoveStraight(a) => a)
    }

    /// **Moves the robot**: turn in place by `angle_rad` (counter-clockwise positive) at most
    /// `max_rate_rad_s`.
    pub async fn turn_in_place(
        &self,
        angle_rad: f64,
        max_rate_rad_s: f64,
        mode: MotionMode,
    ) -> Result<MotionAccepted, HalError> {
        let request = TurnInPlaceRequest {
            angle_urad: units::rad_to_urad("angle", angle_rad).map_err(invalid)?,
            max_rate_mrad_s: units::rad_s_to_mrad_s("turn-rate limit", max_rate_rad_s)
                .map_err(invalid)?,
            mode,
        };
        expect!(self.request(Request::TurnInPlace(request)).await?,
            Response::TurnInPlace(a) => a)
    }

    /// **Moves the robot**: drive the wheels at these speeds (m/s) for `duration` (`None`: until
    /// the next motion command, STOP or a watchdog trip). Speeds must be within the device's
    /// limit; devices without the wheel-speed capability answer UNKNOWN_MESSAGE.
    pub async fn wheel_speed(
        &self,
        left_m_s: f64,
        right_m_s: f64,
        duration: Option<Duration>,
    ) -> Result<(), HalError> {
        let request = Request::WheelSpeed(WheelSpeedRequest {
            left_mm_s: units::m_s_to_mm_s_signed("left speed", left_m_s).map_err(invalid)?,
            right_mm_s: units::m_s_to_mm_s_signed("right speed", right_m_s).map_err(invalid)?,
            duration_ms: units::s_to_ms("duration", duration.map_or(0.0, |d| d.as_secs_f64()))
                .map_err(invalid)?,
        });
        expect!(self.request(request).await?, Response::WheelSpeed => ())
    }

    /// Stops the base and clears its queue.
    pub async fn stop(&self) -> Result<(), HalError> {
        expect!(self.request(Request::Stop).await?, Response::Stop => ())
    }

    /// Reads the status.
    pub async fn status(&self) -> Result<Status, HalError> {
        expect!(self.request(Request::GetStatus).await?, Response::GetStatus(s) => s)
    }

    /// Who the device is and how it is now ([`status::DeviceStatus`], what `odocal status`
    /// shows).
    pub async fn device_status(&self) -> Result<status::DeviceStatus, HalError> {
        Ok(status::DeviceStatus {
            device: *self.device_info(),
            status: self.status().await?,
        })
    }

    /// Reads the encoders (raw, wrapping counters).
    pub async fn read_encoders(&self) -> Result<Encoders, HalError> {
        expect!(self.request(Request::ReadEncoders).await?, Response::ReadEncoders(e) => e)
    }

    /// Reads the heading.
    pub async fn read_heading(&self) -> Result<HeadingReading, HalError> {
        expect!(self.request(Request::ReadHeading).await?, Response::ReadHeading(h) => HeadingReading {
            heading_rad: wrap_angle(units::urad_to_rad(h.heading_urad)),
            valid: h.valid,
            sensor_status: h.sensor_status,
            timestamp_us: h.timestamp_us,
        })
    }

    /// Sets the telemetry period (`None` turns telemetry off); returns the period applied.
    pub async fn configure_telemetry(
        &self,
        period: Option<Duration>,
    ) -> Result<Duration, HalError> {
        let period_ms = units::s_to_ms("telemetry period", period.map_or(0.0, |p| p.as_secs_f64()))
            .map_err(invalid)?;
        expect!(self.request(Request::ConfigureTelemetry(TelemetryPeriod { period_ms })).await?,
            Response::ConfigureTelemetry(p) => Duration::from_millis(u64::from(p.period_ms)))
    }

    /// Arms the device watchdog (`None` disarms it); returns the timeout applied.
    pub async fn configure_watchdog(
        &self,
        timeout: Option<Duration>,
    ) -> Result<Duration, HalError> {
        let timeout_ms =
            units::s_to_ms("watchdog timeout", timeout.map_or(0.0, |p| p.as_secs_f64()))
                .map_err(invalid)?;
        expect!(self.request(Request::ConfigureWatchdog(WatchdogTimeout { timeout_ms })).await?,
            Response::ConfigureWatchdog(t) => Duration::from_millis(u64::from(t.timeout_ms)))
    }

    /// Waits until `completed` motions are done and the base is idle, failing if that takes
    /// longer than `limit` or the watchdog stops the base.
    ///
    /// The end of a motion is taken from its MOTION_DONE event (`done`, subscribed before the
    /// motion started). Events can be lost, so the status is also polled, but slowly
    /// ([`STATUS_POLL`]), and the watchdog is fed with HEARTBEAT in between
    /// ([`HEARTBEAT_EVERY`]). While the motion is known to run, a poll or heartbeat that gets no
    /// answer is not an error: the motion's own deadline is what ends the wait.
    pub async fn wait_motion(
        &self,
        motion_id: u16,
        completed: u32,
        limit: Duration,
        done: &mut broadcast::Receiver<MotionDone>,
    ) -> Result<(), HalError> {
        let start = tokio::time::Instant::now();
        let reached = |count: u32| count.wrapping_sub(completed) < u32::MAX / 2;
        let mut tick = tokio::time::interval(HEARTBEAT_EVERY);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut last_poll = start;
        loop {
            tokio::select! {
                biased;
                ev = done.recv() => match ev {
                    Ok(d) if d.motion_id == motion_id || reached(d.completed_motions) => {
                        return Ok(());
                    }
                    Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => continue,
                    // The link is gone: the next request says why.
                    Err(broadcast::error::RecvError::Closed) => {
                        self.status().await?;
                    }
                },
                _ = tick.tick() => {
                    let heard_before = self.stats.frames_received.load(Ordering::Relaxed);
                    // A request that got no answer is tolerated only if the device was heard
                    // from meanwhile (a bad line); a silent device has gone away.
                    let alive = || self.stats.frames_received.load(Ordering::Relaxed) > heard_before;
                    if last_poll.elapsed() >= STATUS_POLL {
                        last_poll = tokio::time::Instant::now();
                        match self.status().await {
                            Ok(s) => {
                                if s.motion_state == MotionState::Idle {
                                    if reached(s.completed_motions) {
                                        return Ok(());
                                    }
                                    // Idle and the motion not completed: something stopped it.
                                    // (A heartbeat may have acknowledged a watchdog trip already,
                                    // so the watchdog state alone cannot be relied on.)
                                    if s.watchdog_state == WatchdogState::Tripped
                                        || s.fault_flags & fault::WATCHDOG_TRIPPED != 0
                                    {
                                        return Err(HalError::WatchdogTripped);
                                    }
                                    return Err(HalError::MotionStopped { motion_id });
                                }
                                if s.watchdog_state == WatchdogState::Tripped {
                                    return Err(HalError::WatchdogTripped);
                                }
                            }
                            Err(HalError::Link(LinkError::Timeout { .. })) if alive() => {}
                            Err(e) => return Err(e),
                        }
                    } else {
                        match self.heartbeat().await {
                            Ok(()) => {}
                            Err(HalError::Link(LinkError::Timeout { .. })) if alive() => {}
                            Err(e) => return Err(e),
                        }
                    }
                }
            }
            if start.elapsed() > limit {
                return Err(HalError::MotionTimeout {
                    motion_id,
                    after: limit,
                });
            }
        }
    }

    /// Feeds the watchdog (and acknowledges a trip).
    pub async fn heartbeat(&self) -> Result<(), HalError> {
        expect!(self.request(Request::Heartbeat).await?, Response::Heartbeat => ())
    }
}

/// `params` as the wire carries them, if SPEC.md §4.1 allows them: the host's own range check,
/// so nothing out of range is sent (or backed up for) and the refusal names the field.
pub fn wire_params(params: &WheelParams) -> Result<ParamsBlock, HalError> {
    let si = [
        params.left_wheel_diameter_m,
        params.right_wheel_diameter_m,
        params.wheelbase_m,
        params.counts_per_wheel_rev,
    ];
    let refuse = |field: u8| {
        let i = usize::from(field).min(3);
        let f = ParamsBlock::FIELDS[i];
        let ratio = si[1] / si[0];
        let why = if i == 1 && ratio.is_finite() && !(0.8..=1.25).contains(&ratio) {
            format!("right/left wheel diameter ratio {ratio:.4} is outside 0.8..=1.25")
        } else {
            let unit = if f.unit.is_empty() {
                String::new()
            } else {
                format!(" {}", f.unit)
            };
            format!(
                "{} {}{unit} is outside {}..={}{unit}",
                f.name,
                si[i],
                f.min as f64 / f.per_si,
                f.max as f64 / f.per_si
            )
        };
        HalError::InvalidArgument(format!("{why} (SPEC.md §4.1): not sent"))
    };
    // A value too large for the wire's integer is out of range too: name the first such field.
    let block = ParamsBlock::try_from(params).map_err(|_| {
        let first = ParamsBlock::FIELDS.iter().zip(si).position(|(f, v)| {
            let wire = v * f.per_si;
            !(wire.is_finite() && wire >= f.min as f64 && wire <= f.max as f64)
        });
        refuse(first.unwrap_or(3) as u8)
    })?;
    block.validate().map_err(refuse)?;
    Ok(block)
}

fn invalid(e: UnitError) -> HalError {
    HalError::InvalidArgument(e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parameters_outside_the_spec_are_named_in_si_from_the_protocol_table() {
        let ok = WheelParams::nominal(0.15, 0.39, 4096.0);
        assert!(wire_params(&ok).is_ok());
        let refused = |p: WheelParams| match wire_params(&p) {
            Err(HalError::InvalidArgument(why)) => why,
            other => panic!("{p:?} accepted: {other:?}"),
        };
        let why = refused(WheelParams {
            left_wheel_diameter_m: f64::NAN,
            ..ok
        });
        assert!(
            why.starts_with("left wheel diameter NaN m is outside 0.01..=1 m"),
            "{why}"
        );
        let why = refused(WheelParams {
            counts_per_wheel_rev: 1e20,
            ..ok
        });
        assert!(
            why.contains("counts per wheel revolution") && why.contains("..=10000000 ("),
            "{why}"
        );
        let why = refused(WheelParams {
            wheelbase_m: 0.01,
            ..ok
        });
        assert!(
            why.starts_with("wheelbase 0.01 m is outside 0.02..=2 m"),
            "{why}"
        );
    }
}
