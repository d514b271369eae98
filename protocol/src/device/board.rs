//! What the device kit runs on: the [`Board`] (clock, motors, encoders, heading, faults), its
//! simulated form that can be advanced in time, and the [`Sink`] frames leave through.

use super::*;

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
