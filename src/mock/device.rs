//! The mock device's firmware: protocol semantics (SPEC.md §3) on top of the simulator.
//!
//! [`MockDevice::handle`] takes one decoded frame and returns the frames the device sends back;
//! [`MockDevice::advance`] moves device time forward, executing queued motions and emitting
//! telemetry and motion-done events. Both are synchronous and deterministic, so tests can drive
//! the device directly; [`mod@super::serve`] puts them behind a byte stream.

pub use super::error::MockError;
use crate::kinematics::{wrap_angle, WheelParams};
use crate::protocol::frame::{Frame, FrameKind, CRC16, MAJOR, MINOR};
use crate::protocol::message::{
    capability, fault, DeviceInfo, Encoders, Event, FirmwareId, GetParamsRequest, Heading,
    HelloRequest, MotionAccepted, MotionDone, MotionMode, MotionState, MoveStraightRequest, Nack,
    NackCode, Packet, ParamSource, ParamsBlock, Request, Response, RestoreDefaultsRequest,
    RestoreTarget, SavedCrc, Status, StoredParams, Telemetry, TelemetryPeriod, TurnInPlaceRequest,
    WatchdogState, WatchdogTimeout, WheelSpeedRequest,
};
use crate::protocol::{units, Payload, Writer};
use crate::sim::sensor::HeadingModel;
use crate::sim::{Motion, MotionPlan, NoiseModel, SimError, Simulator};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::path::PathBuf;

/// Deepest motion queue the mock accepts (SPEC.md requires at least 4).
pub const QUEUE_DEPTH: usize = 8;

/// How the mock's heading sensor reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CompassConvention {
    /// As SPEC.md requires: counter-clockwise positive.
    #[default]
    CounterClockwise,
    /// A misconfigured firmware that forwards a compass azimuth (clockwise positive).
    Clockwise,
}

/// Everything that defines a mock device.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MockConfig {
    /// The simulated robot's true parameters.
    pub truth: WheelParams,
    /// Factory-default controller parameters (active at first power-up).
    pub factory: WheelParams,
    /// Sensor and wheel noise of the simulator.
    pub noise: NoiseModel,
    /// Seed of every random draw of the device (faults use their own).
    pub seed: u64,
    /// Heading sign convention of the reports.
    pub compass: CompassConvention,
    /// Absolute speed limit (m/s).
    pub max_speed_m_s: f64,
    /// Absolute turn-rate limit (rad/s).
    pub max_rate_rad_s: f64,
    /// File that holds the non-volatile parameter copy across processes, if any.
    pub storage_path: Option<PathBuf>,
    /// Serial number reported by HELLO.
    pub serial_number: u64,
    /// Simulate broken storage: every write of the stored copy fails (NACK STORAGE_FAILURE).
    #[serde(default)]
    pub storage_fails: bool,
    /// How the heading sensor errs (deviation, a gyro's scale, latency, loss…).
    #[serde(default)]
    pub heading_model: HeadingModel,
}

impl MockConfig {
    /// A robot with true ratios `e_b`, `e_d` (left wheel nominal) to `nominal`, which is also the
    /// factory configuration.
    pub fn with_ratios(nominal: WheelParams, e_b: f64, e_d: f64) -> Result<Self, SimError> {
        let truth = WheelParams::from_ratios(
            &nominal,
            e_b,
            e_d,
            &crate::kinematics::SplitConvention::LeftNominal,
        )
        .map_err(|source| SimError::Params {
            which: "true",
            source,
        })?;
        Ok(MockConfig {
            truth,
            factory: nominal,
            noise: NoiseModel::default(),
            seed: 1,
            compass: CompassConvention::CounterClockwise,
            max_speed_m_s: 1.0,
            max_rate_rad_s: 4.0,
            storage_path: None,
            serial_number: 0x0DC0_0001,
            storage_fails: false,
            heading_model: HeadingModel::default(),
        })
    }
}

/// One queued or executing motion.
#[derive(Debug, Clone, Copy)]
struct ActiveMotion {
    id: u16,
    plan: MotionPlan,
    duration_s: f64,
    elapsed_s: f64,
}

/// The remembered last request and its answer (SPEC.md §3, safe retries).
#[derive(Debug, Clone)]
struct LastRequest {
    seq: u8,
    msg: u8,
    crc: u16,
    answer: Frame,
}

/// Counters a test can read to check the device's behaviour.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct DeviceCounters {
    /// Requests executed (retries answered from the cache are not counted).
    pub executed_requests: u64,
    /// Requests answered from the retry cache.
    pub replayed_answers: u64,
    /// Motions accepted.
    pub motions_accepted: u64,
    /// Motions completed.
    pub motions_completed: u64,
    /// Times the watchdog stopped the base.
    pub watchdog_trips: u64,
    /// STOP requests executed.
    pub stops: u64,
    /// Telemetry samples taken.
    pub telemetry_samples: u64,
    /// Telemetry samples not sent because one step of device time produced more than
    /// [`MAX_EVENTS_PER_STEP`] events (the host sees them as lost).
    pub telemetry_over_bound: u64,
}

/// Most events one step of device time ([`MockDevice::advance`]) returns; telemetry beyond it
/// is skipped and counted.
pub const MAX_EVENTS_PER_STEP: usize = 50_000;

/// The mock device's state.
#[derive(Debug)]
pub struct MockDevice {
    config: MockConfig,
    sim: Simulator,
    rng: ChaCha8Rng,
    stored: Option<ParamsBlock>,
    /// Why the non-volatile file was discarded at power-up, if it was.
    storage_discarded: Option<String>,
    queue: VecDeque<ActiveMotion>,
    next_motion_id: u16,
    completed_motions: u32,
    now_us: u64,
    telemetry_period_us: u64,
    next_telemetry_us: u64,
    sample_index: u32,
    event_seq: u8,
    watchdog_timeout_us: u64,
    /// Wall-clock seconds per device second of the host watching this device (see
    /// [`MockDevice::set_host_time_scale`]).
    host_time_scale: f64,
    watchdog_state: WatchdogState,
    last_request_us: u64,
    fault_flags: u16,
    last: Option<LastRequest>,
    counters: DeviceCounters,
    /// The last heading the sensor gave (µrad), reported with a lost reading.
    last_heading_urad: i32,
}

fn block(p: &WheelParams) -> ParamsBlock {
    // Parameters inside the mock were validated on the way in, so they always fit the wire.
    ParamsBlock::try_from(p).unwrap_or(ParamsBlock {
        left_wheel_diameter_nm: 0,
        right_wheel_diameter_nm: 0,
        wheelbase_nm: 0,
        counts_per_wheel_rev_micro: 0,
    })
}

fn block_crc(b: &ParamsBlock) -> u16 {
    let mut bytes = [0u8; <ParamsBlock as Payload>::LEN];
    b.put(&mut Writer::new(&mut bytes));
    CRC16.checksum(&bytes)
}

fn nack<T>(code: NackCode, detail: u8) -> Result<T, Nack> {
    Err(Nack { code, detail })
}

impl MockDevice {
    /// Powers the device up: loads the stored copy (from `storage_path` if given) or the
    /// factory defaults.
    pub fn new(config: MockConfig) -> Result<Self, MockError> {
        // The factory parameters must be ones the device could report and accept on the wire.
        if !ParamsBlock::try_from(&config.factory).is_ok_and(|b| b.validate().is_ok()) {
            return Err(MockError::FactoryOutOfRange(config.factory));
        }
        // A missing file means "never saved"; an unreadable or invalid one is discarded like a
        // copy failing its CRC (SPEC.md §7.9), but said, not silently.
        let mut storage_discarded = None;
        let stored = match config.storage_path.as_ref() {
            None => None,
            Some(p) => match crate::io::read_bounded(p, crate::io::MAX_TEXT_FILE) {
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
                Err(e) => {
                    storage_discarded = Some(format!("{}: {e}", p.display()));
                    None
                }
                Ok(text) => match serde_json::from_str::<ParamsBlock>(&text) {
                    Err(e) => {
                        storage_discarded =
                            Some(format!("{}: not a parameter block ({e})", p.display()));
                        None
                    }
                    Ok(b) => match b.validate() {
                        Ok(()) => Some(b),
                        Err(field) => {
                            storage_discarded =
                                Some(format!("{}: field {field} out of range", p.display()));
                            None
                        }
                    },
                },
            },
        };
        let active = stored.map_or(config.factory, |b| WheelParams::from(&b));
        // The firmware counts whole encoder counts: targets are rounded (SPEC.md §7.6),
        // whatever the noise model says.
        let noise = NoiseModel {
            quantise_encoders: true,
            ..config.noise
        };
        let sim = Simulator::new(config.truth, active, noise, config.seed)?
            .with_heading_model(config.heading_model)?;
        Ok(MockDevice {
            rng: ChaCha8Rng::seed_from_u64(config.seed ^ 0x7E1E_3E7F),
            sim,
            stored,
            storage_discarded,
            queue: VecDeque::new(),
            next_motion_id: 1,
            completed_motions: 0,
            now_us: 0,
            telemetry_period_us: 0,
            next_telemetry_us: 0,
            sample_index: 0,
            event_seq: 0,
            watchdog_timeout_us: 0,
            host_time_scale: 1.0,
            watchdog_state: WatchdogState::Disabled,
            last_request_us: 0,
            fault_flags: 0,
            last: None,
            counters: DeviceCounters::default(),
            last_heading_urad: 0,
            config,
        })
    }

    /// Simulates a power cycle: RAM parameters are lost, the stored copy (or factory) is loaded,
    /// motion, telemetry and watchdog settings reset. The robot stays where it is.
    pub fn power_cycle(&mut self) -> Result<(), MockError> {
        let active = self
            .stored
            .map_or(self.config.factory, |b| WheelParams::from(&b));
        self.sim.set_configured(active)?;
        self.queue.clear();
        self.telemetry_period_us = 0;
        self.watchdog_timeout_us = 0;
        self.watchdog_state = WatchdogState::Disabled;
        self.fault_flags = 0;
        self.last = None;
        Ok(())
    }

    /// The parameters motions use now.
    pub fn active_params(&self) -> WheelParams {
        *self.sim.configured()
    }

    /// The non-volatile copy, if one was saved.
    pub fn stored_params(&self) -> Option<WheelParams> {
        self.stored.map(|b| WheelParams::from(&b))
    }

    /// The simulator (true pose, true parameters).
    pub fn sim(&self) -> &Simulator {
        &self.sim
    }

    /// Mutable simulator access (tests place the robot).
    pub fn sim_mut(&mut self) -> &mut Simulator {
        &mut self.sim
    }

    /// What the device has done.
    pub fn counters(&self) -> DeviceCounters {
        self.counters
    }

    /// The device clock (µs since power-up).
    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    /// Whether a motion is executing or queued.
    pub fn is_moving(&self) -> bool {
        !self.queue.is_empty()
    }

    /// Status as GET_STATUS reports it.
    pub fn status(&self) -> Status {
        Status {
            motion_state: if self.queue.is_empty() {
                MotionState::Idle
            } else {
                MotionState::Moving
            },
            queue_depth: self.queue.len().min(255) as u8,
            current_motion_id: self.queue.front().map_or(0, |m| m.id),
            completed_motions: self.completed_motions,
            fault_flags: self.fault_flags,
            watchdog_state: self.watchdog_state,
            uptime_ms: (self.now_us / 1000) as u32,
        }
    }

    /// A heading reading now (µrad) and whether the sensor gave one (a lost reading is
    /// reported invalid, with the last value).
    fn heading_urad(&mut self) -> (i32, bool) {
        let noise = self.config.noise;
        let n = if noise.compass_sigma_rad > 0.0 {
            Normal::new(0.0, noise.compass_sigma_rad).map_or(0.0, |d| d.sample(&mut self.rng))
        } else {
            0.0
        };
        self.sim.set_time(self.now_us as f64 * 1e-6);
        let Some(mut h) = self.sim.heading_reading_with(n) else {
            return (self.last_heading_urad, false);
        };
        if self.config.compass == CompassConvention::Clockwise {
            h = wrap_angle(-h);
        }
        // A wrapped heading always fits the µrad field.
        self.last_heading_urad = units::rad_to_urad("heading", h).unwrap_or(0);
        (self.last_heading_urad, true)
    }

    fn encoders(&self) -> (i32, i32) {
        let (l, r) = self.sim.encoder_counts();
        // Cumulative counters wrap modulo 2^32 on the wire (SPEC.md §4).
        (l.round() as i64 as i32, r.round() as i64 as i32)
    }

    fn next_event_seq(&mut self) -> u8 {
        let s = self.event_seq;
        self.event_seq = self.event_seq.wrapping_add(1);
        s
    }

    /// Handles one received frame; returns the frames to send (the answer, if any).
    pub fn handle(&mut self, frame: &Frame) -> Vec<Frame> {
        if frame.kind != FrameKind::Request {
            return Vec::new();
        }
        // Any accepted request feeds the watchdog.
        self.last_request_us = self.now_us;
        let crc = CRC16.checksum(frame.payload());
        if let Some(last) = &self.last {
            if last.seq == frame.seq && last.msg == frame.msg && last.crc == crc {
                self.counters.replayed_answers += 1;
                return vec![last.answer];
            }
        }
        self.counters.executed_requests += 1;
        let answer = match Packet::from_frame(frame) {
            Ok(Packet {
                body: crate::protocol::Body::Request { request },
                ..
            }) => match self.execute(&request) {
                Ok(response) => Packet::response(frame.seq, response),
                Err(n) => Packet::nack(frame.seq, frame.msg, n),
            },
            Ok(_) => return Vec::new(),
            Err(e) => Packet::nack(frame.seq, frame.msg, e.nack()),
        };
        let answer = answer.to_frame();
        if frame.msg == crate::protocol::message::id::HELLO {
            self.last = None;
        } else {
            self.last = Some(LastRequest {
                seq: frame.seq,
                msg: frame.msg,
                crc,
                answer,
            });
        }
        vec![answer]
    }

    /// Why the non-volatile copy was discarded at power-up (unreadable, not a parameter block,
    /// out of range), if it was: the device then started from its factory defaults.
    pub fn storage_discarded(&self) -> Option<&str> {
        self.storage_discarded.as_deref()
    }

    /// Tells the device that its time runs `scale` times faster than the host's (the mock
    /// served in sped-up real time): watchdog timeouts, which measure host silence, are
    /// stretched by it. Ignored unless finite and positive.
    pub fn set_host_time_scale(&mut self, scale: f64) {
        if scale.is_finite() && scale > 0.0 {
            self.host_time_scale = scale;
        }
    }

    /// Answers a NACK BUSY to `frame` without executing it (fault injection), remembering
    /// nothing, so a retry with a new sequence number executes normally.
    pub fn busy(frame: &Frame) -> Option<Frame> {
        Packet::nack(
            frame.seq,
            frame.msg,
            Nack {
                code: NackCode::Busy,
                detail: 0xFF,
            },
        )
        .to_frame()
        .into()
    }

    fn execute(&mut self, request: &Request) -> Result<Response, Nack> {
        match *request {
            Request::Hello(HelloRequest {
                host_major,
                host_min_minor,
            }) => {
                if host_major != MAJOR || MINOR < host_min_minor {
                    // SPEC 1.1: the detail tells the host which version this device speaks.
                    return nack(NackCode::VersionMismatch, (MAJOR << 4) | MINOR);
                }
                Ok(Response::Hello(DeviceInfo {
                    major: MAJOR,
                    minor: MINOR,
                    firmware_id: FirmwareId::new("odocal-mock").unwrap_or_else(|_| unreachable!()),
                    firmware_version: (env!("CARGO_PKG_VERSION_MAJOR").parse::<u32>().unwrap_or(0)
                        << 16)
                        | (env!("CARGO_PKG_VERSION_MINOR").parse::<u32>().unwrap_or(0) << 8),
                    capabilities: capability::HEADING
                        | capability::TELEMETRY
                        | capability::WATCHDOG
                        | capability::STORAGE
                        | capability::WHEEL_SPEED
                        | capability::MOTION_QUEUE,
                    serial_number: self.config.serial_number,
                    max_speed_mm_s: units::m_s_to_mm_s("speed limit", self.config.max_speed_m_s)
                        .unwrap_or(u16::MAX),
                    max_rate_mrad_s: units::rad_s_to_mrad_s(
                        "rate limit",
                        self.config.max_rate_rad_s,
                    )
                    .unwrap_or(u16::MAX),
                }))
            }
            Request::GetParams(GetParamsRequest { source }) => {
                let (params, stored_crc) = match source {
                    ParamSource::Active => (block(&self.active_params()), 0),
                    ParamSource::Stored => match self.stored {
                        Some(b) => (b, block_crc(&b)),
                        None => return nack(NackCode::StorageFailure, 0),
                    },
                    ParamSource::Factory => (block(&self.config.factory), 0),
                };
                Ok(Response::GetParams(StoredParams {
                    source,
                    params,
                    stored_crc,
                }))
            }
            Request::SetParams(b) => {
                if let Err(field) = b.validate() {
                    return nack(NackCode::OutOfRange, field);
                }
                if self.is_moving() {
                    return nack(NackCode::InvalidState, 0xFF);
                }
                self.set_active(b)?;
                Ok(Response::SetParams(block(&self.active_params())))
            }
            Request::SaveParams => {
                if self.is_moving() {
                    return nack(NackCode::InvalidState, 0xFF);
                }
                let b = block(&self.active_params());
                self.store(b)?;
                Ok(Response::SaveParams(SavedCrc {
                    stored_crc: block_crc(&b),
                }))
            }
            Request::RestoreDefaults(RestoreDefaultsRequest { target }) => {
                if self.is_moving() {
                    return nack(NackCode::InvalidState, 0xFF);
                }
                let b = block(&self.config.factory);
                self.set_active(b)?;
                if target == RestoreTarget::ActiveAndStored {
                    self.store(b)?;
                }
                Ok(Response::RestoreDefaults(b))
            }
            Request::LoadParams => {
                if self.is_moving() {
                    return nack(NackCode::InvalidState, 0xFF);
                }
                let b = self.stored.unwrap_or(block(&self.config.factory));
                self.set_active(b)?;
                Ok(Response::LoadParams(b))
            }
            Request::ResetOdometry => {
                if self.is_moving() {
                    return nack(NackCode::InvalidState, 0xFF);
                }
                self.sim.reset_encoders();
                Ok(Response::ResetOdometry)
            }
            Request::MoveStraight(MoveStraightRequest {
                distance_um,
                max_speed_mm_s,
                mode,
            }) => {
                let distance_m = units::um_to_m(distance_um);
                if distance_um == 0 || distance_um.unsigned_abs() > 100_000_000 {
                    return nack(NackCode::OutOfRange, 0);
                }
                let speed = units::mm_s_to_m_s(i32::from(max_speed_mm_s));
                if max_speed_mm_s == 0 || speed > self.config.max_speed_m_s + 1e-9 {
                    return nack(NackCode::OutOfRange, 1);
                }
                self.accept_motion(
                    Motion::Straight { distance_m },
                    distance_m.abs() / speed,
                    mode,
                )
                .map(Response::MoveStraight)
            }
            Request::TurnInPlace(TurnInPlaceRequest {
                angle_urad,
                max_rate_mrad_s,
                mode,
            }) => {
                let angle_rad = units::urad_to_rad(angle_urad);
                if angle_urad == 0 || angle_rad.abs() > 4.0 * std::f64::consts::PI {
                    return nack(NackCode::OutOfRange, 0);
                }
                let rate = units::mrad_s_to_rad_s(max_rate_mrad_s);
                if max_rate_mrad_s == 0 || rate > self.config.max_rate_rad_s + 1e-9 {
                    return nack(NackCode::OutOfRange, 1);
                }
                self.accept_motion(
                    Motion::TurnInPlace { angle_rad },
                    angle_rad.abs() / rate,
                    mode,
                )
                .map(Response::TurnInPlace)
            }
            Request::WheelSpeed(WheelSpeedRequest {
                left_mm_s,
                right_mm_s,
                duration_ms,
            }) => {
                let limit = self.config.max_speed_m_s + 1e-9;
                let (l, r) = (
                    units::mm_s_to_m_s(i32::from(left_mm_s)),
                    units::mm_s_to_m_s(i32::from(right_mm_s)),
                );
                if l.abs() > limit {
                    return nack(NackCode::OutOfRange, 0);
                }
                if r.abs() > limit {
                    return nack(NackCode::OutOfRange, 1);
                }
                if self.watchdog_state == WatchdogState::Tripped {
                    return nack(NackCode::InvalidState, 0xFF);
                }
                // "Until the next command" runs an hour; STOP, a new motion or the watchdog
                // end it sooner. In virtual time that would be an hour of driving at once, so
                // the mock's virtual mode needs a duration (see `serve`).
                let t = if duration_ms == 0 {
                    3600.0
                } else {
                    f64::from(duration_ms) / 1e3
                };
                self.queue.clear();
                self.accept_motion(
                    Motion::Wheels {
                        left_m: l * t,
                        right_m: r * t,
                    },
                    t,
                    MotionMode::Replace,
                )?;
                Ok(Response::WheelSpeed)
            }
            Request::Stop => {
                self.counters.stops += 1;
                self.stop();
                Ok(Response::Stop)
            }
            Request::GetStatus => Ok(Response::GetStatus(self.status())),
            Request::ReadEncoders => {
                let (left_counts, right_counts) = self.encoders();
                Ok(Response::ReadEncoders(Encoders {
                    timestamp_us: self.now_us as u32,
                    left_counts,
                    right_counts,
                }))
            }
            Request::ReadHeading => {
                let (heading_urad, valid) = self.heading_urad();
                Ok(Response::ReadHeading(Heading {
                    timestamp_us: self.now_us as u32,
                    heading_urad,
                    valid,
                    sensor_status: u8::from(valid),
                }))
            }
            Request::ConfigureTelemetry(TelemetryPeriod { period_ms }) => {
                if period_ms != 0 && !(5..=1000).contains(&period_ms) {
                    return nack(NackCode::OutOfRange, 0);
                }
                self.telemetry_period_us = u64::from(period_ms) * 1000;
                self.next_telemetry_us = self.now_us;
                Ok(Response::ConfigureTelemetry(TelemetryPeriod { period_ms }))
            }
            Request::ConfigureWatchdog(WatchdogTimeout { timeout_ms }) => {
                if timeout_ms != 0 && !(50..=10_000).contains(&timeout_ms) {
                    return nack(NackCode::OutOfRange, 0);
                }
                // The watchdog watches the host, whose clock is the wall clock: when device time
                // runs `scale` times faster, its timeout spans as much more device time.
                self.watchdog_timeout_us =
                    (f64::from(timeout_ms) * 1000.0 * self.host_time_scale).round() as u64;
                self.watchdog_state = if timeout_ms == 0 {
                    WatchdogState::Disabled
                } else {
                    WatchdogState::Armed
                };
                self.fault_flags &= !fault::WATCHDOG_TRIPPED;
                Ok(Response::ConfigureWatchdog(WatchdogTimeout { timeout_ms }))
            }
            Request::Heartbeat => {
                if self.watchdog_state == WatchdogState::Tripped {
                    self.watchdog_state = WatchdogState::Armed;
                    self.fault_flags &= !fault::WATCHDOG_TRIPPED;
                }
                Ok(Response::Heartbeat)
            }
        }
    }

    fn set_active(&mut self, b: ParamsBlock) -> Result<(), Nack> {
        self.sim
            .set_configured(WheelParams::from(&b))
            .map_err(|_| Nack {
                code: NackCode::OutOfRange,
                detail: 0xFF,
            })
    }

    /// Writes the non-volatile copy atomically: the file is written beside its final name and
    /// renamed over it, so a crash leaves either the old or the new copy.
    fn store(&mut self, b: ParamsBlock) -> Result<(), Nack> {
        if self.config.storage_fails {
            return nack(NackCode::StorageFailure, 0xFF);
        }
        if let Some(path) = &self.config.storage_path {
            let tmp = path.with_extension("tmp");
            let text = serde_json::to_string_pretty(&b).map_err(|_| Nack {
                code: NackCode::StorageFailure,
                detail: 0xFF,
            })?;
            std::fs::write(&tmp, text)
                .and_then(|()| std::fs::rename(&tmp, path))
                .map_err(|_| Nack {
                    code: NackCode::StorageFailure,
                    detail: 0xFF,
                })?;
        }
        self.stored = Some(b);
        Ok(())
    }

    fn accept_motion(
        &mut self,
        motion: Motion,
        duration_s: f64,
        mode: MotionMode,
    ) -> Result<MotionAccepted, Nack> {
        if self.watchdog_state == WatchdogState::Tripped {
            return nack(NackCode::InvalidState, 0xFF);
        }
        if mode == MotionMode::Replace {
            self.queue.clear();
        }
        if self.queue.len() >= QUEUE_DEPTH {
            return nack(NackCode::Busy, 0xFF);
        }
        let plan = self.sim.plan(&motion).map_err(|_| Nack {
            code: NackCode::OutOfRange,
            detail: 0,
        })?;
        let id = self.next_motion_id;
        self.next_motion_id = self.next_motion_id.wrapping_add(1).max(1);
        self.queue.push_back(ActiveMotion {
            id,
            plan,
            duration_s,
            elapsed_s: 0.0,
        });
        self.counters.motions_accepted += 1;
        Ok(MotionAccepted {
            queue_depth: self.queue.len() as u8,
            motion_id: id,
        })
    }

    /// Stops at once: the executing motion ends where the robot is, the queue is cleared.
    pub fn stop(&mut self) {
        self.queue.clear();
    }

    /// Time until the queue is empty (s).
    pub fn remaining_motion_s(&self) -> f64 {
        self.queue
            .iter()
            .map(|m| (m.duration_s - m.elapsed_s).max(0.0))
            .sum()
    }

    /// Moves device time forward by `dt_s`: executes motions, checks the watchdog, and returns
    /// the events to send (telemetry at its period, motion-done).
    pub fn advance(&mut self, dt_s: f64) -> Vec<Frame> {
        let mut events = Vec::new();
        let end_us = self.now_us + (dt_s.max(0.0) * 1e6).round() as u64;
        while self.now_us < end_us {
            if self.telemetry_period_us > 0 && self.now_us >= self.next_telemetry_us {
                self.next_telemetry_us += self.telemetry_period_us;
                self.emit_telemetry(&mut events);
                continue;
            }
            // Step to the next thing that happens: a telemetry sample, the end of a motion,
            // the watchdog deadline, or the end of this advance.
            let mut step_end = end_us;
            if self.telemetry_period_us > 0 {
                step_end = step_end.min(self.next_telemetry_us);
            }
            if let Some(m) = self.queue.front() {
                let left_us = ((m.duration_s - m.elapsed_s).max(0.0) * 1e6).ceil() as u64;
                step_end = step_end.min(self.now_us + left_us.max(1));
            }
            if self.watchdog_state == WatchdogState::Armed && !self.queue.is_empty() {
                let deadline = self.last_request_us + self.watchdog_timeout_us;
                step_end = step_end.min(deadline.max(self.now_us + 1));
            }
            let dt = (step_end - self.now_us) as f64 * 1e-6;
            self.now_us = step_end;
            self.sim.set_time(self.now_us as f64 * 1e-6);
            if let Some(m) = self.queue.front_mut() {
                let from = m.elapsed_s / m.duration_s;
                m.elapsed_s = (m.elapsed_s + dt).min(m.duration_s);
                let to = m.elapsed_s / m.duration_s;
                let (plan, done, id) = (m.plan, m.elapsed_s >= m.duration_s - 1e-9, m.id);
                self.sim.advance_plan(&plan, from, to);
                if done {
                    self.queue.pop_front();
                    self.completed_motions = self.completed_motions.wrapping_add(1);
                    self.counters.motions_completed += 1;
                    let seq = self.next_event_seq();
                    events.push(
                        Packet::event(
                            seq,
                            Event::MotionDone(MotionDone {
                                motion_id: id,
                                completed_motions: self.completed_motions,
                            }),
                        )
                        .to_frame(),
                    );
                }
            }
            if self.watchdog_state == WatchdogState::Armed
                && !self.queue.is_empty()
                && self.now_us >= self.last_request_us + self.watchdog_timeout_us
            {
                self.stop();
                self.watchdog_state = WatchdogState::Tripped;
                self.fault_flags |= fault::WATCHDOG_TRIPPED;
                self.counters.watchdog_trips += 1;
            }
            if self.telemetry_period_us > 0 && self.now_us >= self.next_telemetry_us {
                self.next_telemetry_us += self.telemetry_period_us;
                self.emit_telemetry(&mut events);
            }
        }
        events
    }

    /// Runs every queued motion to completion (virtual time) and returns the events.
    ///
    /// Virtual time passes only while the host waits for it, so the host counts as present
    /// throughout: the watchdog cannot trip here (it guards real-time operation).
    pub fn run_until_idle(&mut self) -> Vec<Frame> {
        let mut events = Vec::new();
        while self.is_moving() {
            let dt = self.remaining_motion_s().max(1e-6);
            let armed = self.watchdog_state;
            if armed == WatchdogState::Armed {
                self.watchdog_state = WatchdogState::Disabled;
            }
            events.extend(self.advance(dt));
            self.watchdog_state = armed;
            self.last_request_us = self.now_us;
        }
        events
    }

    /// Appends a telemetry sample to `events`, unless the step already holds
    /// [`MAX_EVENTS_PER_STEP`]: a valid request sequence (5 ms telemetry, a 100 m move at
    /// 1 mm/s) asks for 2·10⁷ samples at once in virtual time. Beyond the bound a sample is
    /// skipped as a link would lose it (its index is used up, so the host counts it lost).
    fn emit_telemetry(&mut self, events: &mut Vec<Frame>) {
        if events.len() < MAX_EVENTS_PER_STEP {
            events.extend(self.telemetry_frame());
        } else {
            self.sample_index = self.sample_index.wrapping_add(1);
            self.counters.telemetry_over_bound += 1;
        }
    }

    fn telemetry_frame(&mut self) -> Option<Frame> {
        self.counters.telemetry_samples += 1;
        let (left_counts, right_counts) = self.encoders();
        let status = self.status();
        let (heading_urad, heading_valid) = self.heading_urad();
        let t = Telemetry {
            sample_index: self.sample_index,
            timestamp_us: self.now_us as u32,
            left_counts,
            right_counts,
            heading_urad,
            heading_valid,
            motion_state: status.motion_state,
            queue_depth: status.queue_depth,
        };
        self.sample_index = self.sample_index.wrapping_add(1);
        let seq = self.next_event_seq();
        Some(Packet::event(seq, Event::Telemetry(t)).to_frame())
    }
}
