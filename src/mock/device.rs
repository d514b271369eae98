//! The mock device's firmware: the device kit of the protocol crate
//! ([`crate::protocol::device`]) over a board that is the simulator.
//!
//! Everything the protocol asks of a device (retry cache, watchdog, motion queue, telemetry,
//! parameter copies) is the kit's, exactly as a firmware built on it gets it; what is the
//! mock's own is the board ([`SimBoard`]: the simulator's robot, its encoders and heading
//! sensor, with the noise and the compass conventions of [`MockConfig`]) and the storage
//! ([`FileStorage`]: a JSON file, or memory, that can be made to fail).
//!
//! [`MockDevice::handle`] takes one decoded frame and returns the frames the device sends back;
//! [`MockDevice::advance`] moves device time forward, executing queued motions and emitting
//! telemetry and motion-done events. Both are synchronous and deterministic, so tests can drive
//! the device directly; [`mod@super::serve`] puts them behind a byte stream.

pub use super::error::MockError;
use crate::kinematics::{wrap_angle, WheelParams};
use crate::protocol::device::ideal::encoder_reading;
use crate::protocol::device::{
    Board, Device, DeviceConfig, DriveCommand, HeadingReading, IdealWheels, ParamStorage,
    SimulatedBoard, StorageError, VecSink, QUEUE_CAPACITY,
};
use crate::protocol::frame::Frame;
use crate::protocol::message::{FirmwareId, Nack, NackCode, Packet, ParamsBlock, Status};
use crate::protocol::units;
use crate::sim::sensor::HeadingModel;
use crate::sim::{MotionPlan, NoiseModel, SimError, Simulator};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Deepest motion queue the mock accepts (SPEC.md requires at least 4): the kit's.
pub const QUEUE_DEPTH: usize = QUEUE_CAPACITY;

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

impl std::fmt::Display for DeviceCounters {
    /// What the device did, in a sentence (`mock-device` says it when it stops).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} requests executed ({} retries answered again), {} of {} motions completed, {} \
             STOP(s), {} watchdog trip(s), {} telemetry samples ({} not sent)",
            self.executed_requests,
            self.replayed_answers,
            self.motions_completed,
            self.motions_accepted,
            self.stops,
            self.watchdog_trips,
            self.telemetry_samples,
            self.telemetry_over_bound
        )
    }
}

/// Most events one step of device time ([`MockDevice::advance`]) returns; telemetry beyond it
/// is skipped and counted.
pub const MAX_EVENTS_PER_STEP: usize = 50_000;

/// How long virtual time runs an open-ended WHEEL_SPEED before [`MockDevice::run_until_idle`]
/// stops it (s).
const OPEN_ENDED_S: f64 = 3600.0;

/// The simulator as the kit's board: its robot turns the wheels as commanded, its encoders and
/// heading sensor report, its clock is the mock's device time.
#[derive(Debug)]
pub struct SimBoard {
    sim: Simulator,
    /// Draws of the heading noise (the simulator's own RNG draws slip and sensor errors).
    rng: ChaCha8Rng,
    compass: CompassConvention,
    compass_sigma_rad: f64,
    now_us: u64,
    wheels: IdealWheels,
    /// The motion being executed and its slip (drawn once per motion).
    motion_id: Option<u16>,
    slip: (f64, f64),
    /// The last heading the sensor gave (µrad), reported with a lost reading.
    last_heading_urad: i32,
    /// Wall-clock seconds per device second of the host watching this device (see
    /// [`MockDevice::set_host_time_scale`]).
    host_time_scale: f64,
}

impl SimBoard {
    /// The device clock (µs since power-up).
    pub fn now(&self) -> u64 {
        self.now_us
    }

    fn position(&self) -> [f64; 2] {
        let (l, r) = self.sim.encoder_counts();
        [l, r]
    }
}

impl Board for SimBoard {
    fn now_us(&mut self) -> u64 {
        self.now_us
    }

    /// The simulated sensor's kind, as a real firmware would say it.
    fn heading_kind(&self) -> u32 {
        use crate::protocol::message::capability;
        match self.sim.heading_model().kind {
            crate::sim::sensor::SensorKind::Compass => capability::HEADING_MAGNETIC,
            crate::sim::sensor::SensorKind::Gyro => capability::HEADING_GYRO,
        }
    }

    fn drive(&mut self, command: &DriveCommand) {
        if self.motion_id != Some(command.motion_id) {
            self.motion_id = Some(command.motion_id);
            self.slip = self.sim.slip_factors();
        }
        let position = self.position();
        self.wheels.command(command, position);
    }

    fn stop(&mut self) {
        self.wheels.stop();
    }

    fn at_rest(&mut self) -> bool {
        self.wheels.at_rest(self.position())
    }

    fn encoders(&mut self) -> (i32, i32) {
        let [l, r] = self.position();
        (encoder_reading(l), encoder_reading(r))
    }

    fn reset_encoders(&mut self) {
        self.wheels.stop();
        self.sim.reset_encoders();
    }

    fn heading(&mut self) -> HeadingReading {
        let n = if self.compass_sigma_rad > 0.0 {
            Normal::new(0.0, self.compass_sigma_rad).map_or(0.0, |d| d.sample(&mut self.rng))
        } else {
            0.0
        };
        self.sim.set_time(self.now_us as f64 * 1e-6);
        let reading = match self.sim.heading_reading_with(n) {
            None => None,
            Some(mut h) => {
                if self.compass == CompassConvention::Clockwise {
                    h = wrap_angle(-h);
                }
                // A wrapped heading always fits the µrad field.
                self.last_heading_urad = units::rad_to_urad("heading", h).unwrap_or(0);
                Some(self.last_heading_urad)
            }
        };
        // A lost reading is reported invalid, with the last value.
        HeadingReading {
            heading_urad: reading.unwrap_or(self.last_heading_urad),
            valid: reading.is_some(),
            sensor_status: u8::from(reading.is_some()),
        }
    }

    fn watchdog_timeout_us(&self, timeout_ms: u16) -> u64 {
        // The watchdog watches the host, whose clock is the wall clock: when device time runs
        // `scale` times faster, its timeout spans as much more device time.
        (f64::from(timeout_ms) * 1000.0 * self.host_time_scale).round() as u64
    }
}

impl SimulatedBoard for SimBoard {
    fn advance_to(&mut self, now_us: u64) {
        let dt_s = now_us.saturating_sub(self.now_us) as f64 * 1e-6;
        self.now_us = self.now_us.max(now_us);
        self.sim.set_time(self.now_us as f64 * 1e-6);
        let before = self.position();
        let after = self.wheels.step(dt_s, before);
        let (left_counts, right_counts) = (after[0] - before[0], after[1] - before[1]);
        if left_counts != 0.0 || right_counts != 0.0 {
            let truth = *self.sim.truth();
            let plan = MotionPlan {
                left_counts,
                right_counts,
                left_arc_m: left_counts * truth.left_m_per_count() * self.slip.0,
                right_arc_m: right_counts * truth.right_m_per_count() * self.slip.1,
            };
            self.sim.advance_plan(&plan, 0.0, 1.0);
        }
    }
}

/// The mock's non-volatile parameter copy: a JSON file if a path is configured (written beside
/// its final name and renamed over it, so a crash leaves the old or the new copy), memory
/// otherwise; every write fails if the configuration says so.
#[derive(Debug)]
pub struct FileStorage {
    path: Option<PathBuf>,
    fails: bool,
    memory: Option<ParamsBlock>,
    /// Why the copy was discarded at the last power-up, if it was.
    discarded: Option<String>,
}

impl FileStorage {
    fn read(&mut self, path: &std::path::Path) -> Option<ParamsBlock> {
        // A missing file means "never saved"; an unreadable or invalid one is discarded like a
        // copy failing its CRC (SPEC.md §7.9), but said, not silently.
        let text = match crate::io::read_bounded(path, crate::io::MAX_TEXT_FILE) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return None,
            Err(e) => {
                self.discarded = Some(format!("{}: {e}", path.display()));
                return None;
            }
            Ok(text) => text,
        };
        match serde_json::from_str::<ParamsBlock>(&text) {
            Err(e) => {
                self.discarded = Some(format!("{}: not a parameter block ({e})", path.display()));
                None
            }
            Ok(b) => match b.validate() {
                Ok(()) => Some(b),
                Err(field) => {
                    self.discarded =
                        Some(format!("{}: field {field} out of range", path.display()));
                    None
                }
            },
        }
    }
}

impl ParamStorage for FileStorage {
    fn load(&mut self) -> Option<ParamsBlock> {
        self.discarded = None;
        match self.path.clone() {
            Some(path) => self.read(&path),
            None => self.memory,
        }
    }

    fn save(&mut self, block: &ParamsBlock) -> Result<(), StorageError> {
        if self.fails {
            return Err(StorageError);
        }
        if let Some(path) = &self.path {
            let tmp = path.with_extension("tmp");
            let text = serde_json::to_string_pretty(block).map_err(|_| StorageError)?;
            std::fs::write(&tmp, text)
                .and_then(|()| std::fs::rename(&tmp, path))
                .map_err(|_| StorageError)?;
        }
        self.memory = Some(*block);
        Ok(())
    }
}

/// The frames one call returns: answers, and events up to [`MAX_EVENTS_PER_STEP`] (beyond it
/// telemetry is skipped as a link would lose it).
fn frames() -> VecSink {
    VecSink {
        frames: Vec::new(),
        telemetry_limit: MAX_EVENTS_PER_STEP,
    }
}

/// The mock device: the kit over the simulator.
#[derive(Debug)]
pub struct MockDevice {
    kit: Device<SimBoard, FileStorage>,
}

fn block(p: &WheelParams) -> Option<ParamsBlock> {
    ParamsBlock::try_from(p)
        .ok()
        .filter(|b| b.validate().is_ok())
}

impl MockDevice {
    /// Powers the device up: loads the stored copy (from `storage_path` if given) or the
    /// factory defaults.
    pub fn new(config: MockConfig) -> Result<Self, MockError> {
        // The factory parameters must be ones the device could report and accept on the wire.
        let factory = block(&config.factory).ok_or(MockError::FactoryOutOfRange(config.factory))?;
        // The firmware counts whole encoder counts: targets are rounded (SPEC.md §7.6),
        // whatever the noise model says.
        let noise = NoiseModel {
            quantise_encoders: true,
            ..config.noise
        };
        let sim = Simulator::new(config.truth, config.factory, noise, config.seed)?
            .with_heading_model(config.heading_model)?;
        let board = SimBoard {
            sim,
            rng: ChaCha8Rng::seed_from_u64(config.seed ^ 0x7E1E_3E7F),
            compass: config.compass,
            compass_sigma_rad: config.noise.compass_sigma_rad,
            now_us: 0,
            wheels: IdealWheels::default(),
            motion_id: None,
            slip: (1.0, 1.0),
            last_heading_urad: 0,
            host_time_scale: 1.0,
        };
        let storage = FileStorage {
            path: config.storage_path.clone(),
            fails: config.storage_fails,
            memory: None,
            discarded: None,
        };
        let limit = |v: Result<u16, units::UnitError>| v.unwrap_or(u16::MAX).max(1);
        let device_config = DeviceConfig {
            firmware_id: FirmwareId::new("odocal-mock").unwrap_or_else(|_| unreachable!()),
            firmware_version: (env!("CARGO_PKG_VERSION_MAJOR").parse::<u32>().unwrap_or(0) << 16)
                | (env!("CARGO_PKG_VERSION_MINOR").parse::<u32>().unwrap_or(0) << 8),
            serial_number: config.serial_number,
            max_speed_mm_s: limit(units::m_s_to_mm_s("speed limit", config.max_speed_m_s)),
            max_rate_mrad_s: limit(units::rad_s_to_mrad_s("rate limit", config.max_rate_rad_s)),
            factory,
        };
        let mut device = MockDevice {
            kit: Device::new(board, storage, device_config)?,
        };
        device.sync_configured();
        Ok(device)
    }

    /// The simulator's controller uses the parameters the kit holds active.
    fn sync_configured(&mut self) {
        let active = WheelParams::from(&self.kit.active());
        if *self.kit.board().sim.configured() != active {
            // Active parameters passed SPEC.md §4.1's ranges, which the simulator accepts.
            let _ = self.kit.board_mut().sim.set_configured(active);
        }
    }

    /// Simulates a power cycle: RAM parameters are lost, the stored copy (or factory) is loaded,
    /// motion, telemetry and watchdog settings reset. The robot stays where it is.
    pub fn power_cycle(&mut self) -> Result<(), MockError> {
        self.kit.power_cycle();
        self.sync_configured();
        Ok(())
    }

    /// The kit device inside (its statistics, its receiver).
    pub fn kit(&self) -> &Device<SimBoard, FileStorage> {
        &self.kit
    }

    /// The parameters motions use now.
    pub fn active_params(&self) -> WheelParams {
        WheelParams::from(&self.kit.active())
    }

    /// The non-volatile copy, if one was saved.
    pub fn stored_params(&self) -> Option<WheelParams> {
        self.kit.stored().map(|b| WheelParams::from(&b))
    }

    /// The simulator (true pose, true parameters).
    pub fn sim(&self) -> &Simulator {
        &self.kit.board().sim
    }

    /// Mutable simulator access (tests place the robot).
    pub fn sim_mut(&mut self) -> &mut Simulator {
        &mut self.kit.board_mut().sim
    }

    /// What the device has done.
    pub fn counters(&self) -> DeviceCounters {
        let s = self.kit.stats();
        DeviceCounters {
            executed_requests: s.executed_requests,
            replayed_answers: s.replayed_answers,
            motions_accepted: s.motions_accepted,
            motions_completed: s.motions_completed,
            watchdog_trips: s.watchdog_trips,
            stops: s.stop_requests,
            telemetry_samples: s.telemetry_sent,
            telemetry_over_bound: s.telemetry_unsent,
        }
    }

    /// The device clock (µs since power-up).
    pub fn now_us(&self) -> u64 {
        self.kit.board().now()
    }

    /// Whether a motion is executing or queued.
    pub fn is_moving(&self) -> bool {
        self.kit.is_moving()
    }

    /// Status as GET_STATUS reports it.
    pub fn status(&self) -> Status {
        self.kit.status()
    }

    /// Handles one received frame; returns the frames to send (the answer, if any).
    pub fn handle(&mut self, frame: &Frame) -> Vec<Frame> {
        let mut out = frames();
        self.kit.handle_frame(frame, &mut out);
        self.sync_configured();
        out.frames
    }

    /// Why the non-volatile copy was discarded at power-up (unreadable, not a parameter block,
    /// out of range), if it was: the device then started from its factory defaults.
    pub fn storage_discarded(&self) -> Option<&str> {
        self.kit.storage().discarded.as_deref()
    }

    /// Tells the device that its time runs `scale` times faster than the host's (the mock
    /// served in sped-up real time): watchdog timeouts, which measure host silence, are
    /// stretched by it. Ignored unless finite and positive.
    pub fn set_host_time_scale(&mut self, scale: f64) {
        if scale.is_finite() && scale > 0.0 {
            self.kit.board_mut().host_time_scale = scale;
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

    /// Stops at once: the executing motion ends where the robot is, the queue is cleared.
    pub fn stop(&mut self) {
        self.kit.stop();
    }

    /// Time until the queue is empty (s); infinite while an open-ended WHEEL_SPEED runs.
    pub fn remaining_motion_s(&self) -> f64 {
        self.kit
            .remaining_us(self.now_us())
            .map_or(f64::INFINITY, |us| us as f64 * 1e-6)
    }

    /// Moves device time forward by `dt_s`: executes motions, checks the watchdog, and returns
    /// the events to send (telemetry at its period, motion-done).
    pub fn advance(&mut self, dt_s: f64) -> Vec<Frame> {
        let mut out = frames();
        let end = self.now_us() + (dt_s.max(0.0) * 1e6).round() as u64;
        self.kit.advance_to(end, &mut out);
        out.frames
    }

    /// Runs every queued motion to completion (virtual time) and returns the events; an
    /// open-ended WHEEL_SPEED runs an hour and is then stopped.
    ///
    /// Virtual time passes only while the host waits for it, so the host counts as present
    /// throughout: the watchdog cannot trip here (it guards real-time operation).
    pub fn run_until_idle(&mut self) -> Vec<Frame> {
        let mut events = Vec::new();
        self.kit.hold_watchdog(true);
        while self.is_moving() {
            match self.kit.remaining_us(self.now_us()) {
                Some(us) => events.extend(self.advance(us.max(1) as f64 * 1e-6)),
                None => {
                    events.extend(self.advance(OPEN_ENDED_S));
                    self.kit.stop();
                }
            }
        }
        self.kit.hold_watchdog(false);
        events
    }
}
