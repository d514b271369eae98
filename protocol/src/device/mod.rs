//! The device side of SPEC.md, for firmware authors: a [`Device`] state machine that owns
//! everything the protocol asks of a device — the receiver with its inter-byte gap, the
//! safe-retry cache ([`retry`]), the watchdog ([`watchdog`]), the motion queue with its ids and
//! completion events ([`queue`]), telemetry ([`telemetry`]), the parameter copies and their
//! storage ([`storage`]) and every rule of §7 — over a small [`Board`] trait that the firmware
//! implements: motors, encoders, heading and a clock. `no_std`, no allocator: everything lives
//! in fixed buffers.
//!
//! A firmware's main loop feeds received bytes to [`Device::receive`] and calls
//! [`Device::poll`] often (every millisecond or so); answers and events go to a [`Sink`]
//! (the UART's transmit side, e.g. a [`ByteSink`]):
//!
//! ```
//! use odocal_protocol::device::{ByteSink, Device, DeviceConfig, IdealBoard, RamStorage};
//! use odocal_protocol::message::{FirmwareId, ParamsBlock};
//!
//! let robot = ParamsBlock {
//!     left_wheel_diameter_nm: 150_000_000,
//!     right_wheel_diameter_nm: 150_000_000,
//!     wheelbase_nm: 390_000_000,
//!     counts_per_wheel_rev_micro: 4_096_000_000,
//! };
//! let config = DeviceConfig {
//!     firmware_id: FirmwareId::new("my-robot").unwrap(),
//!     firmware_version: 0x01_00_00,
//!     serial_number: 42,
//!     max_speed_mm_s: 500,
//!     max_rate_mrad_s: 2000,
//!     factory: robot,
//! };
//! // A real firmware passes its own board (motor driver, encoder counters, IMU, timer).
//! let mut device = Device::new(IdealBoard::new(&robot), RamStorage::default(), config).unwrap();
//! let mut sent = 0;
//! let mut uart_tx = ByteSink(|bytes: &[u8]| { sent += bytes.len(); true });
//! // A STOP request (SEQ 7) arrives; the device answers it.
//! device.receive(&[0xAA, 0x55, 0x00, 0x10, 0x00, 0x07, 0x33, 0x0C, 0x95], &mut uart_tx);
//! device.poll(&mut uart_tx);
//! assert_eq!(sent, 9);
//! ```
//!
//! How a motion is executed: the device turns each motion into whole-count wheel targets from
//! the active parameters (SPEC.md §5, rounded as §7.6 says) and a constant speed that reaches
//! them in the commanded time, and hands both wheels to [`Board::drive`] once, when the motion
//! starts. The board's wheel controller runs each wheel at that speed (ramping as its motors
//! need) and stops it on its encoder target. The device completes the motion (MOTION_DONE)
//! once its time has passed and both encoders read their targets. A harness that controls the
//! board's clock ([`SimulatedBoard`], [`Device::advance_to`]) runs the §7 vectors against the
//! device without waiting; [`ideal`] is a board of perfect motors for that.

pub mod ideal;
pub mod queue;
pub mod retry;
pub mod storage;
pub mod telemetry;
pub mod watchdog;

pub use ideal::{IdealBoard, IdealWheels};
pub use storage::{ParamStorage, RamStorage, StorageError};

use crate::frame::{Frame, FrameDecoder, FrameKind, CRC16, MAJOR, MAX_FRAME, MINOR};
use crate::message::{
    capability, fault, heading_status, id, DeviceInfo, Encoders, Event, FirmwareId,
    GetParamsRequest, Heading, HelloRequest, MotionAccepted, MotionDone, MotionMode, MotionState,
    MoveStraightRequest, Nack, NackCode, Packet, ParamSource, ParamsBlock, Request, Response,
    RestoreDefaultsRequest, RestoreTarget, SavedCrc, Status, StoredParams, Telemetry,
    TelemetryPeriod, TurnInPlaceRequest, WatchdogState, WatchdogTimeout, WheelSpeedRequest,
};
use crate::units;
use crate::wire::{Payload, Writer};
use core::f64::consts::PI;
use queue::{MotionQueue, Planned, Travel};
use retry::RetryCache;
use telemetry::TelemetrySchedule;
use watchdog::Watchdog;

/// Motions the queue holds, the executing one included (SPEC.md §7.3 asks for at least 4).
pub const QUEUE_CAPACITY: usize = 8;

/// SPEC.md §2.1: a partial frame is discarded after this long without a byte (µs).
pub const INTER_BYTE_GAP_US: u64 = 20_000;

/// The longest MOVE_STRAIGHT (µm): 100 m.
pub const MAX_DISTANCE_UM: u32 = 100_000_000;

/// The largest TURN_IN_PLACE (µrad): ⌊4π·10⁶⌋ (SPEC.md §7.6).
pub const MAX_ANGLE_URAD: u32 = 12_566_370;

/// Faults that stop the base and refuse motions (motion state 3, SPEC.md §7.7).
pub const BLOCKING_FAULTS: u16 = fault::MOTOR_OVERCURRENT | fault::ENCODER | fault::STORAGE;

/// Receive buffer: room for a frame and for the garbage in front of it.
const RX_BUFFER: usize = 2 * MAX_FRAME;

/// A heading reading as the board takes it, in wire units.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HeadingReading {
    /// Heading (µrad), counter-clockwise positive seen from above, wrapped to (−π, π]. A
    /// magnetic compass's azimuth (clockwise from north) must be negated (SPEC.md §4).
    pub heading_urad: i32,
    /// Whether the reading may be used.
    pub valid: bool,
    /// Sensor status bits ([`crate::message::heading_status`]): 0 calibrated, 1 magnetic
    /// disturbance, 2 not responding (bit 3, not new, is the device's: see
    /// [`Board::heading_sample`]).
    pub sensor_status: u8,
}

/// What one wheel is to do.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelDrive {
    /// Speed in encoder counts per second; negative turns the wheel backwards.
    pub speed_counts_s: f64,
    /// The encoder reading (wrapping like the counter) at which the wheel stops and holds;
    /// `None`: keep turning until the next command (WHEEL_SPEED with duration 0).
    pub stop_at: Option<i32>,
}

/// What both wheels are to do, from the start of a motion until the next command or
/// [`Board::stop`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveCommand {
    /// The motion this command executes (a new id: a new motion; boards may ignore it).
    pub motion_id: u16,
    /// Left wheel.
    pub left: WheelDrive,
    /// Right wheel.
    pub right: WheelDrive,
}

/// What the firmware implements: the robot's hardware as the device sees it.
pub trait Board {
    /// A monotonic clock: µs since power-up.
    fn now_us(&mut self) -> u64;

    /// Starts a motion: each wheel at its speed until its encoder reads its target, then held
    /// there. Called once per motion, when it starts; replaces any command before.
    fn drive(&mut self, command: &DriveCommand);

    /// Stops both wheels at once, with the maximum deceleration (STOP, a watchdog trip, a
    /// fault).
    fn stop(&mut self);

    /// Whether both wheels are at rest (after [`Board::stop`]: motion state 2 until then). A
    /// board that stops instantly keeps the default.
    fn at_rest(&mut self) -> bool {
        true
    }

    /// The cumulative encoder counts (left, right), wrapping; positive drives forward.
    fn encoders(&mut self) -> (i32, i32);

    /// Zeroes both encoder counters (RESET_ODOMETRY).
    fn reset_encoders(&mut self);

    /// The sensor's newest reading.
    fn heading(&mut self) -> HeadingReading;

    /// A number that changes with every new sample of the heading sensor (a counter, the
    /// sample's time), for a sensor slower than the host's requests: READ_HEADING then flags a
    /// sample it has already answered ([`crate::message::heading_status::NOT_NEW`]) and the
    /// host reads again. `None` (the default): every reading is a new one.
    fn heading_sample(&mut self) -> Option<u32> {
        None
    }

    /// Whether the board has a heading sensor (HELLO capability bit 0).
    fn has_heading(&self) -> bool {
        true
    }

    /// What its heading sensor is, as HELLO capability bits 6 and 7
    /// ([`capability::HEADING_MAGNETIC`], [`capability::HEADING_GYRO`]); 0: not said.
    fn heading_kind(&self) -> u32 {
        0
    }

    /// Fault bits the board detects ([`fault`]: motor over-current, encoder, heading sensor,
    /// storage, low battery). Bits in [`BLOCKING_FAULTS`] stop the base and refuse motions.
    fn faults(&mut self) -> u16 {
        0
    }

    /// The watchdog timeout on this board's clock for a host silence of `timeout_ms`. Only a
    /// simulated board whose clock runs faster than its host's (sped-up time) changes it.
    fn watchdog_timeout_us(&self, timeout_ms: u16) -> u64 {
        u64::from(timeout_ms) * 1000
    }
}

/// A board whose clock the caller moves: simulators and the harness of the §7 vectors, which
/// need to hold, advance or run device time ([`Device::advance_to`]).
pub trait SimulatedBoard: Board {
    /// Moves the clock forward to `now_us`, the wheels executing their command meanwhile.
    fn advance_to(&mut self, now_us: u64);
}

/// Where the device's frames go: the transmit side of the link.
pub trait Sink {
    /// Sends one frame (see [`Frame::encode`] for its bytes); `false` if it could not be sent
    /// (it is then lost: the host retries a request, counts a telemetry gap).
    fn send(&mut self, frame: &Frame) -> bool;

    /// Whether a telemetry frame can be sent now; when not, the sample is skipped without
    /// reading the sensors (its index is used up). Answers and MOTION_DONE are always sent.
    fn has_room(&self) -> bool {
        true
    }
}

/// A [`Sink`] over a byte writer (a UART's transmit function): `F` gets each frame's bytes
/// and returns whether it took them.
pub struct ByteSink<F>(pub F);

impl<F: FnMut(&[u8]) -> bool> Sink for ByteSink<F> {
    fn send(&mut self, frame: &Frame) -> bool {
        let mut buf = [0u8; MAX_FRAME];
        match frame.encode(&mut buf) {
            Ok(n) => (self.0)(&buf[..n]),
            Err(_) => false,
        }
    }
}

/// A [`Sink`] that keeps every frame (hosts, tests, simulators), telemetry only up to
/// `telemetry_limit` frames held (beyond it samples are skipped, as a link would lose them).
#[cfg(feature = "std")]
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VecSink {
    /// The frames sent, in order.
    pub frames: std::vec::Vec<Frame>,
    /// Most frames held while telemetry is still sent.
    pub telemetry_limit: usize,
}

#[cfg(feature = "std")]
impl Default for VecSink {
    fn default() -> Self {
        VecSink {
            frames: std::vec::Vec::new(),
            telemetry_limit: usize::MAX,
        }
    }
}

#[cfg(feature = "std")]
impl Sink for VecSink {
    fn send(&mut self, frame: &Frame) -> bool {
        self.frames.push(*frame);
        true
    }

    fn has_room(&self) -> bool {
        self.frames.len() < self.telemetry_limit
    }
}

/// What HELLO reports and the factory parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceConfig {
    /// Firmware name.
    pub firmware_id: FirmwareId,
    /// `(major << 16) | (minor << 8) | patch`.
    pub firmware_version: u32,
    /// Serial number.
    pub serial_number: u64,
    /// Absolute speed limit (mm/s): faster motions are refused.
    pub max_speed_mm_s: u16,
    /// Absolute turn-rate limit (mrad/s).
    pub max_rate_mrad_s: u16,
    /// Factory-default parameters (active at power-up while nothing valid is stored).
    pub factory: ParamsBlock,
}

/// A configuration the device cannot run with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ConfigError {
    /// A factory parameter is outside SPEC.md §4.1.
    #[error("factory parameter field {0} is outside SPEC.md §4.1")]
    Factory(u8),
    /// A speed or rate limit of 0 would refuse every motion.
    #[error("the speed and turn-rate limits must be above 0")]
    Limits,
}

/// What the device has done since it was made (power cycles included).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DeviceStats {
    /// Requests executed (retries answered from the cache not counted).
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
    pub stop_requests: u64,
    /// Telemetry frames sent.
    pub telemetry_sent: u64,
    /// Telemetry samples not sent (the sink had no room).
    pub telemetry_unsent: u64,
}

/// The executing motion, once started.
#[derive(Debug, Clone, Copy)]
struct Running {
    id: u16,
    /// When its commanded time is over (µs); `None`: open-ended.
    end_us: Option<u64>,
    /// Each wheel's travel (counts) and target reading.
    travel: [i32; 2],
    target: [i32; 2],
}

fn refuse<T>(code: NackCode, detail: u8) -> Result<T, Nack> {
    Err(Nack { code, detail })
}

/// The field checks of MOVE_STRAIGHT and TURN_IN_PLACE: the size (field 0) non-zero and at
/// most `max`, the speed or rate (field 1) non-zero and within the device's `limit`.
fn motion_fields(size: u32, max: u32, rate: u16, limit: u16) -> Result<(), Nack> {
    if size == 0 || size > max {
        return refuse(NackCode::OutOfRange, 0);
    }
    if rate == 0 || rate > limit {
        return refuse(NackCode::OutOfRange, 1);
    }
    Ok(())
}

/// CRC-16 of a parameter block's 20 bytes (GET_PARAMS, SAVE_PARAMS).
pub fn block_crc(b: &ParamsBlock) -> u16 {
    let mut bytes = [0u8; <ParamsBlock as Payload>::LEN];
    b.put(&mut Writer::new(&mut bytes));
    CRC16.checksum(&bytes)
}

/// Whether a wheel that was to travel `travel` counts to `target` has reached it.
fn reached(reading: i32, target: i32, travel: i32) -> bool {
    let past = reading.wrapping_sub(target);
    match travel {
        0 => true,
        t if t > 0 => past >= 0,
        _ => past <= 0,
    }
}

/// A device: the protocol's state machine over a board `B` and its parameter storage `S`.
#[derive(Debug)]
pub struct Device<B, S> {
    board: B,
    storage: S,
    config: DeviceConfig,
    decoder: FrameDecoder<RX_BUFFER>,
    last_byte_us: u64,
    active: ParamsBlock,
    stored: Option<ParamsBlock>,
    queue: MotionQueue<QUEUE_CAPACITY>,
    running: Option<Running>,
    completed_motions: u32,
    stopping: bool,
    telemetry: TelemetrySchedule,
    event_seq: u8,
    watchdog: Watchdog,
    hold_watchdog: bool,
    /// Faults the device latched (the watchdog trip).
    faults: u16,
    /// The board's faults and whether its wheels were at rest, as last read.
    board_faults: u16,
    at_rest: bool,
    /// The board's clock when last read (µs).
    now_us: u64,
    /// The heading sample READ_HEADING last answered ([`Board::heading_sample`]).
    heading_answered: Option<u32>,
    retry: RetryCache,
    stats: DeviceStats,
}

impl<B: Board, S: ParamStorage> Device<B, S> {
    /// Powers the device up: loads the stored parameters (the factory ones if none is valid).
    pub fn new(board: B, storage: S, config: DeviceConfig) -> Result<Self, ConfigError> {
        config.factory.validate().map_err(ConfigError::Factory)?;
        if config.max_speed_mm_s == 0 || config.max_rate_mrad_s == 0 {
            return Err(ConfigError::Limits);
        }
        let mut device = Device {
            board,
            storage,
            config,
            decoder: FrameDecoder::new(),
            last_byte_us: 0,
            active: config.factory,
            stored: None,
            queue: MotionQueue::new(),
            running: None,
            completed_motions: 0,
            stopping: false,
            telemetry: TelemetrySchedule::new(),
            event_seq: 0,
            watchdog: Watchdog::new(),
            hold_watchdog: false,
            faults: 0,
            board_faults: 0,
            at_rest: true,
            now_us: 0,
            heading_answered: None,
            retry: RetryCache::new(),
            stats: DeviceStats::default(),
        };
        device.power_cycle();
        Ok(device)
    }

    /// A power cycle: the motors stop, the stored copy (or the factory parameters) becomes
    /// active, and motions, ids, telemetry, the watchdog and the retry cache start afresh. The
    /// board (clock, encoders) and the storage are kept.
    pub fn power_cycle(&mut self) {
        self.board.stop();
        self.stored = self.storage.load().filter(|b| b.validate().is_ok());
        self.active = self.stored.unwrap_or(self.config.factory);
        self.decoder.clear();
        self.queue = MotionQueue::new();
        self.running = None;
        self.completed_motions = 0;
        self.stopping = false;
        self.telemetry = TelemetrySchedule::new();
        self.event_seq = 0;
        self.watchdog = Watchdog::new();
        self.faults = 0;
        self.retry.forget();
        self.refresh();
    }

    /// Reads the board's clock.
    fn clock(&mut self) -> u64 {
        self.now_us = self.board.now_us();
        self.now_us
    }

    /// Reads what the status reports from the board: its faults, and whether the wheels
    /// have come to rest after a stop.
    fn refresh(&mut self) {
        self.board_faults = self.board.faults();
        if self.stopping {
            self.at_rest = self.board.at_rest();
            self.stopping = !self.at_rest;
        }
    }

    /// The board.
    pub fn board(&self) -> &B {
        &self.board
    }

    /// The board, mutably (a simulator places its robot).
    pub fn board_mut(&mut self) -> &mut B {
        &mut self.board
    }

    /// The parameter storage.
    pub fn storage(&self) -> &S {
        &self.storage
    }

    /// The configuration.
    pub fn config(&self) -> &DeviceConfig {
        &self.config
    }

    /// The parameters motions use now.
    pub fn active(&self) -> ParamsBlock {
        self.active
    }

    /// The stored copy, if a valid one exists.
    pub fn stored(&self) -> Option<ParamsBlock> {
        self.stored
    }

    /// What the device has done.
    pub fn stats(&self) -> DeviceStats {
        self.stats
    }

    /// Whether a motion is executing or queued.
    pub fn is_moving(&self) -> bool {
        !self.queue.is_empty()
    }

    /// The receiver's counters (bytes dropped, frames rejected).
    pub fn decoder_stats(&self) -> crate::frame::DecoderStats {
        self.decoder.stats()
    }

    /// Feeds received bytes: every complete request is handled and answered into `sink`. A
    /// partial frame older than [`INTER_BYTE_GAP_US`] is discarded first.
    pub fn receive(&mut self, bytes: &[u8], sink: &mut impl Sink) {
        if bytes.is_empty() {
            return;
        }
        let now = self.clock();
        if self.decoder.buffered() > 0 && now.saturating_sub(self.last_byte_us) > INTER_BYTE_GAP_US
        {
            self.decoder.clear();
        }
        self.last_byte_us = now;
        // The decoder is taken out while its frames are handled (they need the whole device).
        let mut decoder = core::mem::take(&mut self.decoder);
        decoder.feed(bytes, |frame| self.handle_frame(&frame, sink));
        self.decoder = decoder;
    }

    /// Handles one received frame (for callers that decode frames themselves): a request is
    /// answered into `sink`, from the retry cache if it repeats the last one; other kinds are
    /// ignored.
    pub fn handle_frame(&mut self, frame: &Frame, sink: &mut impl Sink) {
        if frame.kind != FrameKind::Request {
            return;
        }
        // Every request that passed the CRC feeds the watchdog, a retry included (§7.2).
        let now = self.clock();
        self.watchdog.feed(now);
        self.refresh();
        if let Some(answer) = self.retry.replay(frame) {
            self.stats.replayed_answers += 1;
            sink.send(answer);
            return;
        }
        self.stats.executed_requests += 1;
        let answer = match Packet::from_frame(frame) {
            Ok(Packet {
                body: crate::message::Body::Request { request },
                ..
            }) => match self.execute(&request) {
                Ok(response) => Packet::response(frame.seq, response),
                Err(nack) => Packet::nack(frame.seq, frame.msg, nack),
            },
            // A request frame decodes to a request or an error, nothing else.
            Ok(_) => return,
            Err(e) => Packet::nack(frame.seq, frame.msg, e.nack()),
        }
        .to_frame();
        if frame.msg == id::HELLO {
            self.retry.forget();
        } else {
            self.retry.remember(frame, answer);
        }
        sink.send(&answer);
    }

    /// Runs the device at the board's current time: starts, completes and stops motions,
    /// checks the watchdog and sends telemetry that is due. Call it often (about every
    /// millisecond); [`Device::next_deadline_us`] says when it next has something to do.
    pub fn poll(&mut self, sink: &mut impl Sink) {
        let now = self.clock();
        if self.hold_watchdog {
            self.watchdog.feed(now);
        }
        self.refresh();
        if self.board_faults & BLOCKING_FAULTS != 0 && self.is_moving() {
            self.stop();
        }
        self.run_queue(now, sink);
        if self.watchdog.check(now, self.is_moving()) {
            self.stop();
            self.faults |= fault::WATCHDOG_TRIPPED;
            self.stats.watchdog_trips += 1;
        }
        if let Some(index) = self.telemetry.take(now) {
            self.send_telemetry(index, now, sink);
        }
    }

    /// When [`Device::poll`] next has something to do (µs on the board's clock): a telemetry
    /// sample, the end of the executing motion, the start of a queued one, the watchdog's
    /// deadline. `None`: nothing until a request arrives (or a board's wheels reach targets
    /// after their time).
    pub fn next_deadline_us(&self) -> Option<u64> {
        let motion = match (self.queue.front(), self.running) {
            (Some(front), Some(run)) if run.id == front.id => run.end_us,
            (Some(_), _) => Some(0),
            (None, _) => None,
        };
        [
            self.telemetry.next_due_us(),
            motion,
            self.watchdog.deadline_us(self.is_moving()),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// Time until every queued motion has had its commanded time (µs from `now_us`); `None`
    /// while an open-ended one is queued.
    pub fn remaining_us(&self, now_us: u64) -> Option<u64> {
        let mut total = 0u64;
        for m in self.queue.iter() {
            let left = match self.running {
                Some(run) if run.id == m.id => run.end_us.map(|e| e.saturating_sub(now_us)),
                _ => m.duration_us(),
            }?;
            total = total.saturating_add(left);
        }
        Some(total)
    }

    /// Stops at once: the executing motion ends where the wheels are, the queue is cleared.
    /// (STOP does this; so can a firmware's own stop button.)
    pub fn stop(&mut self) {
        self.queue.clear();
        self.running = None;
        self.board.stop();
        self.stopping = true;
        self.refresh();
    }

    /// While `on`, the host counts as present: the watchdog is fed at every poll. For
    /// harnesses whose device time passes only while the host waits for it (virtual time).
    pub fn hold_watchdog(&mut self, on: bool) {
        self.hold_watchdog = on;
        if on {
            let now = self.clock();
            self.watchdog.feed(now);
        }
    }

    /// The status, as GET_STATUS reports it (the board's faults and rest as last read, at
    /// the last poll, request or stop).
    pub fn status(&self) -> Status {
        Status {
            motion_state: self.motion_state(),
            queue_depth: self.queue.len().min(255) as u8,
            current_motion_id: self.queue.front().map_or(0, |m| m.id),
            completed_motions: self.completed_motions,
            fault_flags: self.fault_flags(),
            watchdog_state: self.watchdog.state(),
            // uptime and timestamps wrap modulo 2^32 on the wire (SPEC.md §4).
            uptime_ms: (self.now_us / 1000) as u32,
        }
    }

    fn fault_flags(&self) -> u16 {
        self.faults | self.board_faults
    }

    fn motion_state(&self) -> MotionState {
        if self.fault_flags() & BLOCKING_FAULTS != 0 {
            MotionState::Fault
        } else if !self.queue.is_empty() {
            MotionState::Moving
        } else if self.stopping {
            MotionState::Stopping
        } else {
            MotionState::Idle
        }
    }

    fn next_event_seq(&mut self) -> u8 {
        let s = self.event_seq;
        self.event_seq = self.event_seq.wrapping_add(1);
        s
    }

    /// Starts the front motion if it has not started, completes it once its time is over and
    /// both wheels read their targets, and so on down the queue.
    fn run_queue(&mut self, now: u64, sink: &mut impl Sink) {
        // Each pass starts or completes one motion: a bounded number of passes.
        for _ in 0..=2 * QUEUE_CAPACITY {
            let Some(front) = self.queue.front().copied() else {
                self.running = None;
                return;
            };
            match self.running {
                Some(run) if run.id == front.id => {
                    if !self.finished(&run, now) {
                        return;
                    }
                    self.queue.pop_front();
                    self.running = None;
                    self.completed_motions = self.completed_motions.wrapping_add(1);
                    self.stats.motions_completed += 1;
                    let done = MotionDone {
                        motion_id: run.id,
                        completed_motions: self.completed_motions,
                    };
                    let seq = self.next_event_seq();
                    sink.send(&Packet::event(seq, Event::MotionDone(done)).to_frame());
                }
                _ => self.start(&front, now),
            }
        }
    }

    fn start(&mut self, motion: &Planned, now: u64) {
        let (l, r) = self.board.encoders();
        let (left, right, run) = match motion.travel {
            Travel::Counts {
                left,
                right,
                duration_us,
            } => {
                let secs = duration_us.max(1) as f64 * 1e-6;
                let target = [l.wrapping_add(left), r.wrapping_add(right)];
                let wheel = |travel: i32, target: i32| WheelDrive {
                    speed_counts_s: f64::from(travel) / secs,
                    stop_at: Some(target),
                };
                (
                    wheel(left, target[0]),
                    wheel(right, target[1]),
                    Running {
                        id: motion.id,
                        end_us: Some(now.saturating_add(duration_us)),
                        travel: [left, right],
                        target,
                    },
                )
            }
            Travel::OpenEnded {
                left_counts_s,
                right_counts_s,
            } => {
                let wheel = |speed| WheelDrive {
                    speed_counts_s: speed,
                    stop_at: None,
                };
                (
                    wheel(left_counts_s),
                    wheel(right_counts_s),
                    Running {
                        id: motion.id,
                        end_us: None,
                        travel: [0, 0],
                        target: [l, r],
                    },
                )
            }
        };
        self.board.drive(&DriveCommand {
            motion_id: motion.id,
            left,
            right,
        });
        self.stopping = false;
        self.running = Some(run);
    }

    fn finished(&mut self, run: &Running, now: u64) -> bool {
        let Some(end) = run.end_us else {
            return false;
        };
        if now < end {
            return false;
        }
        let (l, r) = self.board.encoders();
        reached(l, run.target[0], run.travel[0]) && reached(r, run.target[1], run.travel[1])
    }

    fn send_telemetry(&mut self, sample_index: u32, now: u64, sink: &mut impl Sink) {
        if !sink.has_room() {
            self.stats.telemetry_unsent += 1;
            return;
        }
        let (left_counts, right_counts) = self.board.encoders();
        let status = self.status();
        let heading = self.board.heading();
        let sample = Telemetry {
            sample_index,
            timestamp_us: now as u32,
            left_counts,
            right_counts,
            heading_urad: heading.heading_urad,
            heading_valid: heading.valid,
            motion_state: status.motion_state,
            queue_depth: status.queue_depth,
        };
        let seq = self.next_event_seq();
        if sink.send(&Packet::event(seq, Event::Telemetry(sample)).to_frame()) {
            self.stats.telemetry_sent += 1;
        } else {
            self.stats.telemetry_unsent += 1;
        }
    }

    /// Refuses a parameter or odometry change unless the base is idle (SPEC.md §7.10).
    fn require_idle(&mut self) -> Result<(), Nack> {
        if self.motion_state() == MotionState::Idle {
            Ok(())
        } else {
            refuse(NackCode::InvalidState, 0xFF)
        }
    }

    /// Each wheel's target (whole counts, halves away from zero) for these arcs (m) by the
    /// active parameters; `None` if one does not fit a signed 32-bit count.
    fn counts(&self, arcs_m: [f64; 2]) -> Option<[i32; 2]> {
        let p = self.active.to_si();
        let per_count = [
            PI * p.left_wheel_diameter_m / p.counts_per_wheel_rev,
            PI * p.right_wheel_diameter_m / p.counts_per_wheel_rev,
        ];
        let mut out = [0i32; 2];
        for ((o, arc), m) in out.iter_mut().zip(arcs_m).zip(per_count) {
            let c = libm::round(arc / m);
            if !(c.is_finite() && libm::fabs(c) < 2_147_483_647.0) {
                return None;
            }
            *o = c as i32;
        }
        Some(out)
    }

    /// Queues (or, with `Replace`, runs at once) a motion whose fields passed their checks.
    fn accept(&mut self, travel: Travel, mode: MotionMode) -> Result<MotionAccepted, Nack> {
        if self.watchdog.state() == WatchdogState::Tripped
            || self.fault_flags() & BLOCKING_FAULTS != 0
        {
            return refuse(NackCode::InvalidState, 0xFF);
        }
        if mode == MotionMode::Replace {
            self.queue.clear();
            self.running = None;
        }
        let planned = self
            .queue
            .push(travel)
            .or_else(|_| refuse(NackCode::Busy, 0xFF))?;
        self.stats.motions_accepted += 1;
        Ok(MotionAccepted {
            queue_depth: self.queue.len() as u8,
            motion_id: planned.id,
        })
    }

    /// Accepts a MOVE_STRAIGHT or TURN_IN_PLACE whose fields passed: wheel arcs (m), and its
    /// size (µm or µrad) at `rate` (mm/s or mrad/s), which gives its time.
    fn accept_counts(
        &mut self,
        arcs_m: [f64; 2],
        size: u32,
        rate: u16,
        mode: MotionMode,
    ) -> Result<MotionAccepted, Nack> {
        let [left, right] = self.counts(arcs_m).ok_or(Nack {
            code: NackCode::OutOfRange,
            detail: 0,
        })?;
        let duration_us = (u64::from(size) * 1000).div_ceil(u64::from(rate.max(1)));
        let travel = Travel::Counts {
            left,
            right,
            duration_us,
        };
        self.accept(travel, mode)
    }

    fn info(&self) -> DeviceInfo {
        let mut capabilities = capability::TELEMETRY
            | capability::WATCHDOG
            | capability::WHEEL_SPEED
            | capability::MOTION_QUEUE;
        if self.board.has_heading() {
            capabilities |= capability::HEADING
                | (self.board.heading_kind()
                    & (capability::HEADING_MAGNETIC | capability::HEADING_GYRO));
        }
        if S::NON_VOLATILE {
            capabilities |= capability::STORAGE;
        }
        DeviceInfo {
            major: MAJOR,
            minor: MINOR,
            firmware_id: self.config.firmware_id,
            firmware_version: self.config.firmware_version,
            capabilities,
            serial_number: self.config.serial_number,
            max_speed_mm_s: self.config.max_speed_mm_s,
            max_rate_mrad_s: self.config.max_rate_mrad_s,
        }
    }

    /// Executes one decoded request, checking in SPEC.md §7.5's order: fields in payload
    /// order, then state, then queue space.
    fn execute(&mut self, request: &Request) -> Result<Response, Nack> {
        let now = self.clock();
        match *request {
            Request::Hello(HelloRequest {
                host_major,
                host_min_minor,
            }) => {
                if host_major != MAJOR || MINOR < host_min_minor {
                    // SPEC 1.1: the detail tells the host which version this device speaks.
                    return refuse(NackCode::VersionMismatch, (MAJOR << 4) | MINOR);
                }
                Ok(Response::Hello(self.info()))
            }
            Request::GetParams(GetParamsRequest { source }) => {
                let (params, stored_crc) = match source {
                    ParamSource::Active => (self.active, 0),
                    ParamSource::Stored => match self.stored {
                        Some(b) => (b, block_crc(&b)),
                        None => return refuse(NackCode::StorageFailure, 0),
                    },
                    ParamSource::Factory => (self.config.factory, 0),
                };
                Ok(Response::GetParams(StoredParams {
                    source,
                    params,
                    stored_crc,
                }))
            }
            Request::SetParams(b) => {
                if let Err(field) = b.validate() {
                    return refuse(NackCode::OutOfRange, field);
                }
                self.require_idle()?;
                self.active = b;
                Ok(Response::SetParams(b))
            }
            Request::SaveParams => {
                self.require_idle()?;
                let b = self.active;
                self.save(b)?;
                Ok(Response::SaveParams(SavedCrc {
                    stored_crc: block_crc(&b),
                }))
            }
            Request::RestoreDefaults(RestoreDefaultsRequest { target }) => {
                self.require_idle()?;
                let b = self.config.factory;
                // Stored first: a failed write leaves everything as it was.
                if target == RestoreTarget::ActiveAndStored {
                    self.save(b)?;
                }
                self.active = b;
                Ok(Response::RestoreDefaults(b))
            }
            Request::LoadParams => {
                self.require_idle()?;
                self.active = self.stored.unwrap_or(self.config.factory);
                Ok(Response::LoadParams(self.active))
            }
            Request::ResetOdometry => {
                self.require_idle()?;
                self.board.reset_encoders();
                Ok(Response::ResetOdometry)
            }
            Request::MoveStraight(MoveStraightRequest {
                distance_um,
                max_speed_mm_s,
                mode,
            }) => {
                let d = distance_um.unsigned_abs();
                motion_fields(
                    d,
                    MAX_DISTANCE_UM,
                    max_speed_mm_s,
                    self.config.max_speed_mm_s,
                )?;
                let arc = units::um_to_m(distance_um);
                self.accept_counts([arc, arc], d, max_speed_mm_s, mode)
                    .map(Response::MoveStraight)
            }
            Request::TurnInPlace(TurnInPlaceRequest {
                angle_urad,
                max_rate_mrad_s,
                mode,
            }) => {
                let a = angle_urad.unsigned_abs();
                motion_fields(
                    a,
                    MAX_ANGLE_URAD,
                    max_rate_mrad_s,
                    self.config.max_rate_mrad_s,
                )?;
                // Right wheel +angle·b/2, left −angle·b/2 (SPEC.md §5).
                let half = 0.5 * units::urad_to_rad(angle_urad) * self.active.to_si().wheelbase_m;
                self.accept_counts([0.0 - half, 0.0 + half], a, max_rate_mrad_s, mode)
                    .map(Response::TurnInPlace)
            }
            Request::WheelSpeed(WheelSpeedRequest {
                left_mm_s,
                right_mm_s,
                duration_ms,
            }) => {
                if left_mm_s.unsigned_abs() > self.config.max_speed_mm_s {
                    return refuse(NackCode::OutOfRange, 0);
                }
                if right_mm_s.unsigned_abs() > self.config.max_speed_mm_s {
                    return refuse(NackCode::OutOfRange, 1);
                }
                let speeds = [
                    units::mm_s_to_m_s(i32::from(left_mm_s)),
                    units::mm_s_to_m_s(i32::from(right_mm_s)),
                ];
                let travel = if duration_ms == 0 {
                    // Counts per second: the targets of one second's travel, unrounded.
                    let p = self.active.to_si();
                    Travel::OpenEnded {
                        left_counts_s: speeds[0]
                            / (PI * p.left_wheel_diameter_m / p.counts_per_wheel_rev),
                        right_counts_s: speeds[1]
                            / (PI * p.right_wheel_diameter_m / p.counts_per_wheel_rev),
                    }
                } else {
                    let t = f64::from(duration_ms) / 1e3;
                    let [left, right] =
                        self.counts([speeds[0] * t, speeds[1] * t]).ok_or(Nack {
                            code: NackCode::OutOfRange,
                            detail: 2,
                        })?;
                    Travel::Counts {
                        left,
                        right,
                        duration_us: u64::from(duration_ms) * 1000,
                    }
                };
                // A WHEEL_SPEED replaces the queue (SPEC.md §7.4).
                self.accept(travel, MotionMode::Replace)?;
                Ok(Response::WheelSpeed)
            }
            Request::Stop => {
                self.stats.stop_requests += 1;
                self.stop();
                Ok(Response::Stop)
            }
            Request::GetStatus => Ok(Response::GetStatus(self.status())),
            Request::ReadEncoders => {
                let (left_counts, right_counts) = self.board.encoders();
                Ok(Response::ReadEncoders(Encoders {
                    timestamp_us: now as u32,
                    left_counts,
                    right_counts,
                }))
            }
            Request::ReadHeading => {
                let h = self.board.heading();
                // The same sample as the last answer is flagged (SPEC.md §5): the host reads
                // again. Telemetry reads the sensor too and does not count.
                let sample = self.board.heading_sample();
                let repeated = sample.is_some() && sample == self.heading_answered;
                self.heading_answered = sample;
                Ok(Response::ReadHeading(Heading {
                    timestamp_us: now as u32,
                    heading_urad: h.heading_urad,
                    valid: h.valid,
                    sensor_status: if repeated {
                        h.sensor_status | heading_status::NOT_NEW
                    } else {
                        h.sensor_status
                    },
                }))
            }
            Request::ConfigureTelemetry(TelemetryPeriod { period_ms }) => {
                if period_ms != 0 && !(5..=1000).contains(&period_ms) {
                    return refuse(NackCode::OutOfRange, 0);
                }
                self.telemetry.configure(u64::from(period_ms) * 1000, now);
                Ok(Response::ConfigureTelemetry(TelemetryPeriod { period_ms }))
            }
            Request::ConfigureWatchdog(WatchdogTimeout { timeout_ms }) => {
                if timeout_ms != 0 && !(50..=10_000).contains(&timeout_ms) {
                    return refuse(NackCode::OutOfRange, 0);
                }
                let timeout_us = if timeout_ms == 0 {
                    0
                } else {
                    self.board.watchdog_timeout_us(timeout_ms).max(1)
                };
                self.watchdog.configure(timeout_us, now);
                self.faults &= !fault::WATCHDOG_TRIPPED;
                Ok(Response::ConfigureWatchdog(WatchdogTimeout { timeout_ms }))
            }
            Request::Heartbeat => {
                if self.watchdog.state() == WatchdogState::Tripped {
                    self.watchdog.acknowledge();
                    self.faults &= !fault::WATCHDOG_TRIPPED;
                }
                Ok(Response::Heartbeat)
            }
        }
    }

    fn save(&mut self, b: ParamsBlock) -> Result<(), Nack> {
        self.storage
            .save(&b)
            .or_else(|_| refuse(NackCode::StorageFailure, 0xFF))?;
        self.stored = Some(b);
        Ok(())
    }
}

impl<B: SimulatedBoard, S: ParamStorage> Device<B, S> {
    /// Runs device time forward to `end_us` on the board's clock (the clock hook of the §7
    /// vectors): the board's clock is moved from one thing that happens to the next (a
    /// telemetry sample, a motion's end, the watchdog's deadline) and the device polled at
    /// each, so events carry exact times however long the step.
    pub fn advance_to(&mut self, end_us: u64, sink: &mut impl Sink) {
        if self.board.now_us() >= end_us {
            return;
        }
        loop {
            self.poll(sink);
            let now = self.clock();
            if now >= end_us {
                return;
            }
            let next = self
                .next_deadline_us()
                .map_or(end_us, |d| d.clamp(now + 1, end_us));
            self.board.advance_to(next);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::message::MotionAccepted;

    const ROBOT: ParamsBlock = ParamsBlock {
        left_wheel_diameter_nm: 150_000_000,
        right_wheel_diameter_nm: 150_000_000,
        wheelbase_nm: 390_000_000,
        counts_per_wheel_rev_micro: 4_096_000_000,
    };

    fn device() -> Device<IdealBoard, RamStorage> {
        let config = DeviceConfig {
            firmware_id: FirmwareId::new("test").unwrap(),
            firmware_version: 1,
            serial_number: 1,
            max_speed_mm_s: 1000,
            max_rate_mrad_s: 4000,
            factory: ROBOT,
        };
        Device::new(IdealBoard::new(&ROBOT), RamStorage::default(), config).unwrap()
    }

    /// The frames a device sent, in a fixed buffer.
    struct Out {
        frames: [Option<Frame>; 8],
        n: usize,
    }

    impl Out {
        fn new() -> Self {
            Out {
                frames: [None; 8],
                n: 0,
            }
        }

        fn packets(&self) -> impl Iterator<Item = Packet> + '_ {
            self.frames[..self.n]
                .iter()
                .flatten()
                .filter_map(|f| Packet::from_frame(f).ok())
        }

        fn response(&self) -> Option<Response> {
            self.packets().find_map(|p| match p.body {
                crate::message::Body::Response { response } => Some(response),
                _ => None,
            })
        }

        fn nack(&self) -> Option<Nack> {
            self.packets().find_map(|p| match p.body {
                crate::message::Body::Nack { nack, .. } => Some(nack),
                _ => None,
            })
        }
    }

    impl Sink for Out {
        fn send(&mut self, frame: &Frame) -> bool {
            if self.n < self.frames.len() {
                self.frames[self.n] = Some(*frame);
                self.n += 1;
                true
            } else {
                false
            }
        }
    }

    fn send(d: &mut Device<IdealBoard, RamStorage>, seq: u8, request: Request) -> Out {
        let mut out = Out::new();
        d.handle_frame(&Packet::request(seq, request).to_frame(), &mut out);
        out
    }

    fn move_m(mm: i32) -> Request {
        Request::MoveStraight(MoveStraightRequest {
            distance_um: mm * 1000,
            max_speed_mm_s: 100,
            mode: MotionMode::Queue,
        })
    }

    #[test]
    fn a_retried_motion_is_answered_from_the_cache_and_runs_once() {
        let mut d = device();
        let first = send(&mut d, 5, move_m(100)).response();
        let again = send(&mut d, 5, move_m(100)).response();
        assert_eq!(
            first,
            Some(Response::MoveStraight(MotionAccepted {
                queue_depth: 1,
                motion_id: 1
            }))
        );
        assert_eq!(again, first);
        assert_eq!(
            (d.stats().motions_accepted, d.stats().replayed_answers),
            (1, 1)
        );
        // Run it: one MOTION_DONE, one completed motion, the wheels on their targets.
        let mut out = Out::new();
        d.advance_to(2_000_000, &mut out);
        let done = out.packets().filter(|p| {
            p.body
                == crate::message::Body::Event {
                    event: Event::MotionDone(MotionDone {
                        motion_id: 1,
                        completed_motions: 1,
                    }),
                }
        });
        assert_eq!(done.count(), 1);
        // 0.1 m on 0.15 m wheels of 4096 counts: 869.2 counts, rounded.
        assert_eq!(d.board_mut().encoders(), (869, 869));
        assert_eq!(d.status().completed_motions, 1);
        // A new sequence number is a new request.
        assert!(send(&mut d, 6, move_m(100)).response().is_some());
        assert_eq!(d.stats().motions_accepted, 2);
    }

    #[test]
    fn a_silent_host_trips_the_watchdog_and_motions_wait_for_a_heartbeat() {
        let mut d = device();
        let arm = Request::ConfigureWatchdog(WatchdogTimeout { timeout_ms: 100 });
        assert!(send(&mut d, 1, arm).response().is_some());
        assert!(send(&mut d, 2, move_m(1000)).response().is_some());
        d.advance_to(99_000, &mut Out::new());
        assert!(d.is_moving(), "fed at 0 ms, 100 ms timeout");
        d.advance_to(150_000, &mut Out::new());
        let s = d.status();
        assert_eq!(
            (s.motion_state, s.watchdog_state, s.fault_flags),
            (
                MotionState::Idle,
                WatchdogState::Tripped,
                fault::WATCHDOG_TRIPPED
            )
        );
        // 100 ms of 100 mm/s: the base stopped after 1 cm, not 1 m.
        let (l, _) = d.board_mut().encoders();
        assert!((80..=90).contains(&l), "{l}");
        assert_eq!(
            send(&mut d, 3, move_m(10)).nack().map(|n| n.code),
            Some(NackCode::InvalidState)
        );
        assert!(send(&mut d, 4, Request::Heartbeat).response().is_some());
        assert_eq!(d.status().watchdog_state, WatchdogState::Armed);
        assert!(send(&mut d, 5, move_m(10)).response().is_some());
    }

    #[test]
    fn a_partial_frame_is_dropped_after_the_inter_byte_gap() {
        let mut d = device();
        let mut wire = [0u8; MAX_FRAME];
        let n = Packet::request(9, Request::GetStatus)
            .to_frame()
            .encode(&mut wire)
            .unwrap();
        let mut out = Out::new();
        // Half a frame, then 30 ms of silence, then a whole one: the half is discarded by the
        // gap (resynchronisation would have dropped it byte by byte, and counted them).
        d.receive(&wire[..4], &mut out);
        d.advance_to(30_000, &mut out);
        d.receive(&wire[..n], &mut out);
        assert_eq!(out.packets().count(), 1);
        assert!(matches!(out.response(), Some(Response::GetStatus(_))));
        assert_eq!(d.decoder_stats().bytes_dropped, 0);
        // A frame split 5 ms apart is one frame.
        let n = Packet::request(10, Request::GetStatus)
            .to_frame()
            .encode(&mut wire)
            .unwrap();
        let mut out = Out::new();
        d.receive(&wire[..4], &mut out);
        d.advance_to(35_000, &mut out);
        d.receive(&wire[4..n], &mut out);
        assert_eq!(out.packets().count(), 1);
    }
}
