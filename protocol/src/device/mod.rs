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

mod board;
mod execute;
mod motion;

pub use board::*;
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
use execute::*;
use motion::*;
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

/// CRC-16 of a parameter block's 20 bytes (GET_PARAMS, SAVE_PARAMS).
pub fn block_crc(b: &ParamsBlock) -> u16 {
    let mut bytes = [0u8; <ParamsBlock as Payload>::LEN];
    b.put(&mut Writer::new(&mut bytes));
    CRC16.checksum(&bytes)
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
