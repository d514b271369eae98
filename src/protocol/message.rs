//! Typed messages of SPEC.md §5 and their payload layouts (little endian, fixed point).
//!
//! A [`Packet`] is a sequence number and a [`Body`]: a [`Request`], a [`Response`], a [`Nack`]
//! or an [`Event`]. [`Packet::to_frame`] and [`Packet::from_frame`] convert to and from the
//! frame layer. Decoding checks lengths and enumerated fields only; limits that depend on the
//! device (speeds, parameter ranges) are the device's to check, so that it can NACK them with
//! the field's index. Payloads longer than a message needs are accepted and the tail ignored
//! (SPEC.md §6).

use super::frame::{Frame, FrameKind};
use crate::kinematics::WheelParams;
use bytes::{BufMut, Bytes, BytesMut};
use serde::{Deserialize, Serialize};

/// Errors turning a frame into a typed message (or back).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MessageError {
    /// No message with this id exists for this frame kind.
    #[error("unknown {kind:?} message id 0x{msg:02X}")]
    UnknownMessage {
        /// The frame kind.
        kind: FrameKind,
        /// The message id.
        msg: u8,
    },
    /// The payload is shorter than the message requires.
    #[error("message 0x{msg:02X}: payload of {got} bytes, needs {need}")]
    BadLength {
        /// The message id.
        msg: u8,
        /// Bytes required.
        need: usize,
        /// Bytes received.
        got: usize,
    },
    /// An enumerated or flag field holds a value the spec does not define.
    #[error("message 0x{msg:02X}: field {field} has undefined value {value}")]
    OutOfRange {
        /// The message id.
        msg: u8,
        /// 0-based index of the field in the payload.
        field: u8,
        /// The raw value.
        value: u64,
    },
    /// A firmware id longer than 16 bytes or not ASCII cannot be encoded.
    #[error("firmware id must be at most 16 ASCII bytes")]
    FirmwareId,
}

impl MessageError {
    /// The NACK a device answers this decoding error with.
    pub fn nack(&self) -> Nack {
        let (code, detail) = match self {
            MessageError::UnknownMessage { .. } => (NackCode::UnknownMessage, 0xFF),
            MessageError::BadLength { .. } => (NackCode::BadLength, 0xFF),
            MessageError::OutOfRange { field, .. } => (NackCode::OutOfRange, *field),
            MessageError::FirmwareId => (NackCode::OutOfRange, 0xFF),
        };
        Nack { code, detail }
    }
}

/// Message ids (SPEC.md §5).
pub mod id {
    /// HELLO.
    pub const HELLO: u8 = 0x01;
    /// GET_PARAMS.
    pub const GET_PARAMS: u8 = 0x10;
    /// SET_PARAMS.
    pub const SET_PARAMS: u8 = 0x11;
    /// SAVE_PARAMS.
    pub const SAVE_PARAMS: u8 = 0x12;
    /// RESTORE_DEFAULTS.
    pub const RESTORE_DEFAULTS: u8 = 0x13;
    /// LOAD_PARAMS.
    pub const LOAD_PARAMS: u8 = 0x14;
    /// RESET_ODOMETRY.
    pub const RESET_ODOMETRY: u8 = 0x20;
    /// MOVE_STRAIGHT.
    pub const MOVE_STRAIGHT: u8 = 0x30;
    /// TURN_IN_PLACE.
    pub const TURN_IN_PLACE: u8 = 0x31;
    /// WHEEL_SPEED.
    pub const WHEEL_SPEED: u8 = 0x32;
    /// STOP.
    pub const STOP: u8 = 0x33;
    /// GET_STATUS.
    pub const GET_STATUS: u8 = 0x40;
    /// READ_ENCODERS.
    pub const READ_ENCODERS: u8 = 0x41;
    /// READ_HEADING.
    pub const READ_HEADING: u8 = 0x42;
    /// CONFIGURE_TELEMETRY.
    pub const CONFIGURE_TELEMETRY: u8 = 0x50;
    /// TELEMETRY (event).
    pub const TELEMETRY: u8 = 0x51;
    /// MOTION_DONE (event).
    pub const MOTION_DONE: u8 = 0x52;
    /// CONFIGURE_WATCHDOG.
    pub const CONFIGURE_WATCHDOG: u8 = 0x60;
    /// HEARTBEAT.
    pub const HEARTBEAT: u8 = 0x61;

    /// Every request/response id, in SPEC order.
    pub const REQUESTS: [u8; 17] = [
        HELLO,
        GET_PARAMS,
        SET_PARAMS,
        SAVE_PARAMS,
        RESTORE_DEFAULTS,
        LOAD_PARAMS,
        RESET_ODOMETRY,
        MOVE_STRAIGHT,
        TURN_IN_PLACE,
        WHEEL_SPEED,
        STOP,
        GET_STATUS,
        READ_ENCODERS,
        READ_HEADING,
        CONFIGURE_TELEMETRY,
        CONFIGURE_WATCHDOG,
        HEARTBEAT,
    ];
    /// Every event id.
    pub const EVENTS: [u8; 2] = [TELEMETRY, MOTION_DONE];
}

/// Payload sizes `(request, response)` of a request id, or the event size, as in SPEC.md §5.
pub fn payload_len(kind: FrameKind, msg: u8) -> Option<usize> {
    use id::*;
    let (req, resp) = match msg {
        HELLO => (2, 38),
        GET_PARAMS => (1, 23),
        SET_PARAMS => (20, 20),
        SAVE_PARAMS => (0, 2),
        RESTORE_DEFAULTS => (1, 20),
        LOAD_PARAMS => (0, 20),
        RESET_ODOMETRY | STOP | HEARTBEAT => (0, 0),
        MOVE_STRAIGHT | TURN_IN_PLACE => (7, 3),
        WHEEL_SPEED => (6, 0),
        GET_STATUS => (0, 15),
        READ_ENCODERS => (0, 12),
        READ_HEADING => (0, 10),
        CONFIGURE_TELEMETRY | CONFIGURE_WATCHDOG => (2, 2),
        TELEMETRY if kind == FrameKind::Event => return Some(23),
        MOTION_DONE if kind == FrameKind::Event => return Some(6),
        _ => return None,
    };
    match kind {
        FrameKind::Request => Some(req),
        FrameKind::Response => Some(resp),
        FrameKind::Nack => Some(2),
        FrameKind::Event => None,
    }
}

macro_rules! wire_enum {
    ($(#[$m:meta])* $name:ident { $($(#[$vm:meta])* $var:ident = $val:expr),+ $(,)? }) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
        #[serde(rename_all = "snake_case")]
        pub enum $name { $($(#[$vm])* $var = $val),+ }
        impl $name {
            /// The variant for a wire byte, if defined.
            pub fn from_byte(b: u8) -> Option<Self> {
                match b { $($val => Some($name::$var),)+ _ => None }
            }
        }
    };
}

wire_enum!(
    /// Which parameter copy GET_PARAMS reads.
    ParamSource { /** RAM, used by motions. */ Active = 0, /** Non-volatile copy. */ Stored = 1, /** Factory defaults. */ Factory = 2 }
);
wire_enum!(
    /// What RESTORE_DEFAULTS overwrites.
    RestoreTarget { /** RAM only. */ Active = 0, /** RAM and the stored copy. */ ActiveAndStored = 1 }
);
wire_enum!(
    /// How a motion command joins the queue.
    MotionMode { /** Abort the current motion and clear the queue. */ Replace = 0, /** Append. */ Queue = 1 }
);
wire_enum!(
    /// The base's motion state.
    MotionState { /** Not moving. */ Idle = 0, /** Executing a motion. */ Moving = 1, /** Braking. */ Stopping = 2, /** Stopped by a fault. */ Fault = 3 }
);
wire_enum!(
    /// The watchdog's state.
    WatchdogState { /** Off. */ Disabled = 0, /** Armed. */ Armed = 1, /** Tripped: motions refused until acknowledged. */ Tripped = 2 }
);

/// NACK codes (SPEC.md §3.1); codes a later minor version adds arrive as `Other`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "SCREAMING_SNAKE_CASE")]
pub enum NackCode {
    /// The device does not implement the message.
    UnknownMessage,
    /// Payload too short.
    BadLength,
    /// A field is outside its range.
    OutOfRange,
    /// Not allowed in the current state.
    InvalidState,
    /// Temporarily unable; retry with a new sequence number.
    Busy,
    /// Non-volatile storage failed; the stored copy is unchanged.
    StorageFailure,
    /// HELLO asked for a protocol the device does not speak.
    VersionMismatch,
    /// A code this version does not know.
    Other(u8),
}

impl NackCode {
    /// The wire byte.
    pub fn to_byte(self) -> u8 {
        match self {
            NackCode::UnknownMessage => 0x01,
            NackCode::BadLength => 0x02,
            NackCode::OutOfRange => 0x03,
            NackCode::InvalidState => 0x04,
            NackCode::Busy => 0x05,
            NackCode::StorageFailure => 0x06,
            NackCode::VersionMismatch => 0x07,
            NackCode::Other(b) => b,
        }
    }

    /// The code for a wire byte.
    pub fn from_byte(b: u8) -> Self {
        match b {
            0x01 => NackCode::UnknownMessage,
            0x02 => NackCode::BadLength,
            0x03 => NackCode::OutOfRange,
            0x04 => NackCode::InvalidState,
            0x05 => NackCode::Busy,
            0x06 => NackCode::StorageFailure,
            0x07 => NackCode::VersionMismatch,
            other => NackCode::Other(other),
        }
    }
}

/// A device's refusal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Nack {
    /// Why.
    pub code: NackCode,
    /// Index of the offending field, or 0xFF.
    pub detail: u8,
}

/// Kinematic parameters as they travel on the wire (SPEC.md §4.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ParamsBlock {
    /// Left wheel diameter (nm).
    pub left_wheel_diameter_nm: u32,
    /// Right wheel diameter (nm).
    pub right_wheel_diameter_nm: u32,
    /// Wheelbase (nm).
    pub wheelbase_nm: u32,
    /// Encoder counts per wheel revolution (millionths of a count).
    pub counts_per_wheel_rev_micro: u64,
}

impl ParamsBlock {
    /// The block for `p`, rounded to the wire resolution; `None` if a value does not fit.
    pub fn from_params(p: &WheelParams) -> Option<Self> {
        fn nm(m: f64) -> Option<u32> {
            let v = (m * 1e9).round();
            (v.is_finite() && v >= 0.0 && v <= f64::from(u32::MAX)).then_some(v as u32)
        }
        let cpr = (p.counts_per_wheel_rev * 1e6).round();
        // 2^64 as f64; anything at or above it does not fit a u64.
        let cpr_ok = (0.0..18_446_744_073_709_551_616.0).contains(&cpr);
        Some(ParamsBlock {
            left_wheel_diameter_nm: nm(p.left_wheel_diameter_m)?,
            right_wheel_diameter_nm: nm(p.right_wheel_diameter_m)?,
            wheelbase_nm: nm(p.wheelbase_m)?,
            counts_per_wheel_rev_micro: cpr_ok.then_some(cpr as u64)?,
        })
    }

    /// The parameters in SI units.
    pub fn to_params(&self) -> WheelParams {
        WheelParams {
            // Dividing (not multiplying by 1e-9) is correctly rounded: 150 000 000 nm is 0.15.
            left_wheel_diameter_m: f64::from(self.left_wheel_diameter_nm) / 1e9,
            right_wheel_diameter_m: f64::from(self.right_wheel_diameter_nm) / 1e9,
            wheelbase_m: f64::from(self.wheelbase_nm) / 1e9,
            counts_per_wheel_rev: self.counts_per_wheel_rev_micro as f64 / 1e6,
        }
    }

    /// Checks SPEC.md §4.1's ranges; the error is the index of the first bad field
    /// (a diameter ratio outside [0.8, 1.25] reports field 1).
    pub fn validate(&self) -> Result<(), u8> {
        const D: std::ops::RangeInclusive<u32> = 10_000_000..=1_000_000_000;
        if !D.contains(&self.left_wheel_diameter_nm) {
            return Err(0);
        }
        if !D.contains(&self.right_wheel_diameter_nm) {
            return Err(1);
        }
        if !(20_000_000..=2_000_000_000).contains(&self.wheelbase_nm) {
            return Err(2);
        }
        if !(1_000_000..=10_000_000_000_000).contains(&self.counts_per_wheel_rev_micro) {
            return Err(3);
        }
        let ratio =
            f64::from(self.right_wheel_diameter_nm) / f64::from(self.left_wheel_diameter_nm);
        if !(0.8..=1.25).contains(&ratio) {
            return Err(1);
        }
        Ok(())
    }
}

/// HELLO's answer.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct DeviceInfo {
    /// Protocol major version.
    pub major: u8,
    /// Protocol minor version.
    pub minor: u8,
    /// Firmware name, ASCII, at most 16 bytes.
    pub firmware_id: String,
    /// `(major << 16) | (minor << 8) | patch`.
    pub firmware_version: u32,
    /// Capability bits (SPEC.md §5, HELLO).
    pub capabilities: u32,
    /// Serial number.
    pub serial_number: u64,
    /// Absolute speed limit (mm/s).
    pub max_speed_mm_s: u16,
    /// Absolute turn-rate limit (mrad/s).
    pub max_rate_mrad_s: u16,
}

/// Capability bits of [`DeviceInfo::capabilities`].
pub mod capability {
    /// Has a heading sensor.
    pub const HEADING: u32 = 1 << 0;
    /// Sends telemetry.
    pub const TELEMETRY: u32 = 1 << 1;
    /// Has a watchdog.
    pub const WATCHDOG: u32 = 1 << 2;
    /// Has non-volatile parameter storage.
    pub const STORAGE: u32 = 1 << 3;
    /// Accepts WHEEL_SPEED.
    pub const WHEEL_SPEED: u32 = 1 << 4;
    /// Queues motions.
    pub const MOTION_QUEUE: u32 = 1 << 5;
}

/// Fault bits of [`Status::fault_flags`].
pub mod fault {
    /// Motor over-current.
    pub const MOTOR_OVERCURRENT: u16 = 1 << 0;
    /// Encoder fault.
    pub const ENCODER: u16 = 1 << 1;
    /// Heading sensor fault.
    pub const HEADING_SENSOR: u16 = 1 << 2;
    /// The watchdog stopped the base.
    pub const WATCHDOG_TRIPPED: u16 = 1 << 3;
    /// Storage fault.
    pub const STORAGE: u16 = 1 << 4;
    /// Low battery.
    pub const LOW_BATTERY: u16 = 1 << 5;
}

/// A motion command's acceptance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct MotionAccepted {
    /// Motions queued, including this one.
    pub queue_depth: u8,
    /// Device-assigned id of this motion.
    pub motion_id: u16,
}

/// GET_STATUS's answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Status {
    /// Motion state.
    pub motion_state: MotionState,
    /// Motions queued.
    pub queue_depth: u8,
    /// Id of the executing motion, 0 when idle.
    pub current_motion_id: u16,
    /// Motions completed since power-up.
    pub completed_motions: u32,
    /// Fault bits ([`fault`]).
    pub fault_flags: u16,
    /// Watchdog state.
    pub watchdog_state: WatchdogState,
    /// Time since power-up (ms).
    pub uptime_ms: u32,
}

/// READ_ENCODERS's answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Encoders {
    /// Device clock (µs, wrapping).
    pub timestamp_us: u32,
    /// Cumulative left counts (wrapping).
    pub left_counts: i32,
    /// Cumulative right counts (wrapping).
    pub right_counts: i32,
}

/// READ_HEADING's answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Heading {
    /// Device clock (µs, wrapping).
    pub timestamp_us: u32,
    /// Heading (µrad), counter-clockwise positive, (−π, π].
    pub heading_urad: i32,
    /// Whether the reading may be used.
    pub valid: bool,
    /// Sensor status bits.
    pub sensor_status: u8,
}

/// The TELEMETRY event.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Telemetry {
    /// Sample counter (gaps are lost samples).
    pub sample_index: u32,
    /// Device clock (µs, wrapping).
    pub timestamp_us: u32,
    /// Cumulative left counts.
    pub left_counts: i32,
    /// Cumulative right counts.
    pub right_counts: i32,
    /// Heading (µrad), counter-clockwise positive.
    pub heading_urad: i32,
    /// Whether the heading may be used.
    pub heading_valid: bool,
    /// Motion state.
    pub motion_state: MotionState,
    /// Motions queued.
    pub queue_depth: u8,
}

/// Host-to-device requests.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "message", rename_all = "SCREAMING_SNAKE_CASE")]
pub enum Request {
    /// Version negotiation.
    Hello {
        /// Host's protocol major.
        host_major: u8,
        /// Lowest minor the host needs.
        host_min_minor: u8,
    },
    /// Read a parameter copy.
    GetParams {
        /// Which copy.
        source: ParamSource,
    },
    /// Write the active parameters.
    SetParams(ParamsBlock),
    /// Commit the active parameters to storage.
    SaveParams,
    /// Restore factory defaults.
    RestoreDefaults {
        /// What to overwrite.
        target: RestoreTarget,
    },
    /// Reload the stored parameters into RAM.
    LoadParams,
    /// Zero the encoders and odometry.
    ResetOdometry,
    /// Drive straight (moves the robot).
    MoveStraight {
        /// Distance (µm), negative backwards.
        distance_um: i32,
        /// Speed limit (mm/s).
        max_speed_mm_s: u16,
        /// Queue or replace.
        mode: MotionMode,
    },
    /// Turn in place (moves the robot).
    TurnInPlace {
        /// Angle (µrad), counter-clockwise positive.
        angle_urad: i32,
        /// Turn-rate limit (mrad/s).
        max_rate_mrad_s: u16,
        /// Queue or replace.
        mode: MotionMode,
    },
    /// Direct wheel speeds (moves the robot).
    WheelSpeed {
        /// Left wheel (mm/s).
        left_mm_s: i16,
        /// Right wheel (mm/s).
        right_mm_s: i16,
        /// Duration (ms), 0 = until replaced.
        duration_ms: u16,
    },
    /// Stop at once and clear the queue.
    Stop,
    /// Read the status.
    GetStatus,
    /// Read the encoders.
    ReadEncoders,
    /// Read the heading.
    ReadHeading,
    /// Set the telemetry period.
    ConfigureTelemetry {
        /// Period (ms), 0 = off.
        period_ms: u16,
    },
    /// Set the watchdog timeout.
    ConfigureWatchdog {
        /// Timeout (ms), 0 = off.
        timeout_ms: u16,
    },
    /// Feed the watchdog.
    Heartbeat,
}

/// Device answers, one variant per request.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "message", rename_all = "SCREAMING_SNAKE_CASE")]
pub enum Response {
    /// Device info.
    Hello(DeviceInfo),
    /// A parameter copy.
    GetParams {
        /// Which copy.
        source: ParamSource,
        /// The parameters.
        params: ParamsBlock,
        /// CRC of the stored copy (0 unless source is stored).
        stored_crc: u16,
    },
    /// The parameters now active.
    SetParams(ParamsBlock),
    /// The stored copy's CRC.
    SaveParams {
        /// CRC-16 of the stored block.
        stored_crc: u16,
    },
    /// The parameters now active.
    RestoreDefaults(ParamsBlock),
    /// The parameters now active.
    LoadParams(ParamsBlock),
    /// Done.
    ResetOdometry,
    /// Accepted.
    MoveStraight(MotionAccepted),
    /// Accepted.
    TurnInPlace(MotionAccepted),
    /// Done.
    WheelSpeed,
    /// Done.
    Stop,
    /// Status.
    GetStatus(Status),
    /// Encoders.
    ReadEncoders(Encoders),
    /// Heading.
    ReadHeading(Heading),
    /// Period applied.
    ConfigureTelemetry {
        /// Period (ms).
        period_ms: u16,
    },
    /// Timeout applied.
    ConfigureWatchdog {
        /// Timeout (ms).
        timeout_ms: u16,
    },
    /// Done.
    Heartbeat,
}

/// Unprompted device messages.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "message", rename_all = "SCREAMING_SNAKE_CASE")]
pub enum Event {
    /// Periodic telemetry.
    Telemetry(Telemetry),
    /// A motion finished.
    MotionDone {
        /// Its id.
        motion_id: u16,
        /// Motions completed since power-up.
        completed_motions: u32,
    },
}

/// What a frame carries.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Body {
    /// A request.
    Request {
        /// The request.
        request: Request,
    },
    /// A response.
    Response {
        /// The response.
        response: Response,
    },
    /// A NACK of message `msg`.
    Nack {
        /// The refused message's id.
        msg: u8,
        /// The refusal.
        nack: Nack,
    },
    /// An event.
    Event {
        /// The event.
        event: Event,
    },
}

/// A typed frame: sequence number and body.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Packet {
    /// Sequence number (for events, the device's event counter).
    pub seq: u8,
    /// The message.
    #[serde(flatten)]
    pub body: Body,
}

impl Request {
    /// The message id.
    pub fn msg(&self) -> u8 {
        use id::*;
        match self {
            Request::Hello { .. } => HELLO,
            Request::GetParams { .. } => GET_PARAMS,
            Request::SetParams(_) => SET_PARAMS,
            Request::SaveParams => SAVE_PARAMS,
            Request::RestoreDefaults { .. } => RESTORE_DEFAULTS,
            Request::LoadParams => LOAD_PARAMS,
            Request::ResetOdometry => RESET_ODOMETRY,
            Request::MoveStraight { .. } => MOVE_STRAIGHT,
            Request::TurnInPlace { .. } => TURN_IN_PLACE,
            Request::WheelSpeed { .. } => WHEEL_SPEED,
            Request::Stop => STOP,
            Request::GetStatus => GET_STATUS,
            Request::ReadEncoders => READ_ENCODERS,
            Request::ReadHeading => READ_HEADING,
            Request::ConfigureTelemetry { .. } => CONFIGURE_TELEMETRY,
            Request::ConfigureWatchdog { .. } => CONFIGURE_WATCHDOG,
            Request::Heartbeat => HEARTBEAT,
        }
    }

    /// Whether executing this request moves the robot.
    pub fn moves_robot(&self) -> bool {
        matches!(
            self,
            Request::MoveStraight { .. } | Request::TurnInPlace { .. } | Request::WheelSpeed { .. }
        )
    }

    fn encode(&self, w: &mut BytesMut) {
        match *self {
            Request::Hello {
                host_major,
                host_min_minor,
            } => {
                w.put_u8(host_major);
                w.put_u8(host_min_minor);
            }
            Request::GetParams { source } => w.put_u8(source as u8),
            Request::SetParams(p) => put_params(w, &p),
            Request::RestoreDefaults { target } => w.put_u8(target as u8),
            Request::MoveStraight {
                distance_um,
                max_speed_mm_s,
                mode,
            } => {
                w.put_i32_le(distance_um);
                w.put_u16_le(max_speed_mm_s);
                w.put_u8(mode as u8);
            }
            Request::TurnInPlace {
                angle_urad,
                max_rate_mrad_s,
                mode,
            } => {
                w.put_i32_le(angle_urad);
                w.put_u16_le(max_rate_mrad_s);
                w.put_u8(mode as u8);
            }
            Request::WheelSpeed {
                left_mm_s,
                right_mm_s,
                duration_ms,
            } => {
                w.put_i16_le(left_mm_s);
                w.put_i16_le(right_mm_s);
                w.put_u16_le(duration_ms);
            }
            Request::ConfigureTelemetry { period_ms } => w.put_u16_le(period_ms),
            Request::ConfigureWatchdog { timeout_ms } => w.put_u16_le(timeout_ms),
            Request::SaveParams
            | Request::LoadParams
            | Request::ResetOdometry
            | Request::Stop
            | Request::GetStatus
            | Request::ReadEncoders
            | Request::ReadHeading
            | Request::Heartbeat => {}
        }
    }

    fn decode(msg: u8, r: &mut Reader<'_>) -> Result<Self, MessageError> {
        use id::*;
        Ok(match msg {
            HELLO => Request::Hello {
                host_major: r.u8()?,
                host_min_minor: r.u8()?,
            },
            GET_PARAMS => Request::GetParams {
                source: r.wire(ParamSource::from_byte)?,
            },
            SET_PARAMS => Request::SetParams(r.params()?),
            SAVE_PARAMS => Request::SaveParams,
            RESTORE_DEFAULTS => Request::RestoreDefaults {
                target: r.wire(RestoreTarget::from_byte)?,
            },
            LOAD_PARAMS => Request::LoadParams,
            RESET_ODOMETRY => Request::ResetOdometry,
            MOVE_STRAIGHT => Request::MoveStraight {
                distance_um: r.i32()?,
                max_speed_mm_s: r.u16()?,
                mode: r.wire(MotionMode::from_byte)?,
            },
            TURN_IN_PLACE => Request::TurnInPlace {
                angle_urad: r.i32()?,
                max_rate_mrad_s: r.u16()?,
                mode: r.wire(MotionMode::from_byte)?,
            },
            WHEEL_SPEED => Request::WheelSpeed {
                left_mm_s: r.i16()?,
                right_mm_s: r.i16()?,
                duration_ms: r.u16()?,
            },
            STOP => Request::Stop,
            GET_STATUS => Request::GetStatus,
            READ_ENCODERS => Request::ReadEncoders,
            READ_HEADING => Request::ReadHeading,
            CONFIGURE_TELEMETRY => Request::ConfigureTelemetry {
                period_ms: r.u16()?,
            },
            CONFIGURE_WATCHDOG => Request::ConfigureWatchdog {
                timeout_ms: r.u16()?,
            },
            HEARTBEAT => Request::Heartbeat,
            _ => {
                return Err(MessageError::UnknownMessage {
                    kind: FrameKind::Request,
                    msg,
                })
            }
        })
    }
}

impl Response {
    /// The message id (that of the request it answers).
    pub fn msg(&self) -> u8 {
        use id::*;
        match self {
            Response::Hello(_) => HELLO,
            Response::GetParams { .. } => GET_PARAMS,
            Response::SetParams(_) => SET_PARAMS,
            Response::SaveParams { .. } => SAVE_PARAMS,
            Response::RestoreDefaults(_) => RESTORE_DEFAULTS,
            Response::LoadParams(_) => LOAD_PARAMS,
            Response::ResetOdometry => RESET_ODOMETRY,
            Response::MoveStraight(_) => MOVE_STRAIGHT,
            Response::TurnInPlace(_) => TURN_IN_PLACE,
            Response::WheelSpeed => WHEEL_SPEED,
            Response::Stop => STOP,
            Response::GetStatus(_) => GET_STATUS,
            Response::ReadEncoders(_) => READ_ENCODERS,
            Response::ReadHeading(_) => READ_HEADING,
            Response::ConfigureTelemetry { .. } => CONFIGURE_TELEMETRY,
            Response::ConfigureWatchdog { .. } => CONFIGURE_WATCHDOG,
            Response::Heartbeat => HEARTBEAT,
        }
    }

    fn encode(&self, w: &mut BytesMut) -> Result<(), MessageError> {
        match self {
            Response::Hello(info) => {
                let id = info.firmware_id.as_bytes();
                if id.len() > 16 || !info.firmware_id.is_ascii() || id.contains(&0) {
                    return Err(MessageError::FirmwareId);
                }
                w.put_u8(info.major);
                w.put_u8(info.minor);
                let mut padded = [0u8; 16];
                padded[..id.len()].copy_from_slice(id);
                w.put_slice(&padded);
                w.put_u32_le(info.firmware_version);
                w.put_u32_le(info.capabilities);
                w.put_u64_le(info.serial_number);
                w.put_u16_le(info.max_speed_mm_s);
                w.put_u16_le(info.max_rate_mrad_s);
            }
            Response::GetParams {
                source,
                params,
                stored_crc,
            } => {
                w.put_u8(*source as u8);
                put_params(w, params);
                w.put_u16_le(*stored_crc);
            }
            Response::SetParams(p) | Response::RestoreDefaults(p) | Response::LoadParams(p) => {
                put_params(w, p)
            }
            Response::SaveParams { stored_crc } => w.put_u16_le(*stored_crc),
            Response::MoveStraight(a) | Response::TurnInPlace(a) => {
                w.put_u8(a.queue_depth);
                w.put_u16_le(a.motion_id);
            }
            Response::GetStatus(s) => {
                w.put_u8(s.motion_state as u8);
                w.put_u8(s.queue_depth);
                w.put_u16_le(s.current_motion_id);
                w.put_u32_le(s.completed_motions);
                w.put_u16_le(s.fault_flags);
                w.put_u8(s.watchdog_state as u8);
                w.put_u32_le(s.uptime_ms);
            }
            Response::ReadEncoders(e) => {
                w.put_u32_le(e.timestamp_us);
                w.put_i32_le(e.left_counts);
                w.put_i32_le(e.right_counts);
            }
            Response::ReadHeading(h) => {
                w.put_u32_le(h.timestamp_us);
                w.put_i32_le(h.heading_urad);
                w.put_u8(u8::from(h.valid));
                w.put_u8(h.sensor_status);
            }
            Response::ConfigureTelemetry { period_ms } => w.put_u16_le(*period_ms),
            Response::ConfigureWatchdog { timeout_ms } => w.put_u16_le(*timeout_ms),
            Response::ResetOdometry
            | Response::WheelSpeed
            | Response::Stop
            | Response::Heartbeat => {}
        }
        Ok(())
    }

    fn decode(msg: u8, r: &mut Reader<'_>) -> Result<Self, MessageError> {
        use id::*;
        Ok(match msg {
            HELLO => Response::Hello(DeviceInfo {
                major: r.u8()?,
                minor: r.u8()?,
                firmware_id: {
                    let raw = r.bytes::<16>()?;
                    let end = raw.iter().position(|&b| b == 0).unwrap_or(16);
                    String::from_utf8_lossy(&raw[..end]).into_owned()
                },
                firmware_version: r.u32()?,
                capabilities: r.u32()?,
                serial_number: r.u64()?,
                max_speed_mm_s: r.u16()?,
                max_rate_mrad_s: r.u16()?,
            }),
            GET_PARAMS => Response::GetParams {
                source: r.wire(ParamSource::from_byte)?,
                params: r.params()?,
                stored_crc: r.u16()?,
            },
            SET_PARAMS => Response::SetParams(r.params()?),
            SAVE_PARAMS => Response::SaveParams {
                stored_crc: r.u16()?,
            },
            RESTORE_DEFAULTS => Response::RestoreDefaults(r.params()?),
            LOAD_PARAMS => Response::LoadParams(r.params()?),
            RESET_ODOMETRY => Response::ResetOdometry,
            MOVE_STRAIGHT => Response::MoveStraight(r.accepted()?),
            TURN_IN_PLACE => Response::TurnInPlace(r.accepted()?),
            WHEEL_SPEED => Response::WheelSpeed,
            STOP => Response::Stop,
            GET_STATUS => Response::GetStatus(Status {
                motion_state: r.wire(MotionState::from_byte)?,
                queue_depth: r.u8()?,
                current_motion_id: r.u16()?,
                completed_motions: r.u32()?,
                fault_flags: r.u16()?,
                watchdog_state: r.wire(WatchdogState::from_byte)?,
                uptime_ms: r.u32()?,
            }),
            READ_ENCODERS => Response::ReadEncoders(Encoders {
                timestamp_us: r.u32()?,
                left_counts: r.i32()?,
                right_counts: r.i32()?,
            }),
            READ_HEADING => Response::ReadHeading(Heading {
                timestamp_us: r.u32()?,
                heading_urad: r.i32()?,
                valid: r.bool()?,
                sensor_status: r.u8()?,
            }),
            CONFIGURE_TELEMETRY => Response::ConfigureTelemetry {
                period_ms: r.u16()?,
            },
            CONFIGURE_WATCHDOG => Response::ConfigureWatchdog {
                timeout_ms: r.u16()?,
            },
            HEARTBEAT => Response::Heartbeat,
            _ => {
                return Err(MessageError::UnknownMessage {
                    kind: FrameKind::Response,
                    msg,
                })
            }
        })
    }
}

impl Event {
    /// The message id.
    pub fn msg(&self) -> u8 {
        match self {
            Event::Telemetry(_) => id::TELEMETRY,
            Event::MotionDone { .. } => id::MOTION_DONE,
        }
    }

    fn encode(&self, w: &mut BytesMut) {
        match self {
            Event::Telemetry(t) => {
                w.put_u32_le(t.sample_index);
                w.put_u32_le(t.timestamp_us);
                w.put_i32_le(t.left_counts);
                w.put_i32_le(t.right_counts);
                w.put_i32_le(t.heading_urad);
                w.put_u8(u8::from(t.heading_valid));
                w.put_u8(t.motion_state as u8);
                w.put_u8(t.queue_depth);
            }
            Event::MotionDone {
                motion_id,
                completed_motions,
            } => {
                w.put_u16_le(*motion_id);
                w.put_u32_le(*completed_motions);
            }
        }
    }

    fn decode(msg: u8, r: &mut Reader<'_>) -> Result<Self, MessageError> {
        Ok(match msg {
            id::TELEMETRY => Event::Telemetry(Telemetry {
                sample_index: r.u32()?,
                timestamp_us: r.u32()?,
                left_counts: r.i32()?,
                right_counts: r.i32()?,
                heading_urad: r.i32()?,
                heading_valid: r.bool()?,
                motion_state: r.wire(MotionState::from_byte)?,
                queue_depth: r.u8()?,
            }),
            id::MOTION_DONE => Event::MotionDone {
                motion_id: r.u16()?,
                completed_motions: r.u32()?,
            },
            _ => {
                return Err(MessageError::UnknownMessage {
                    kind: FrameKind::Event,
                    msg,
                })
            }
        })
    }
}

fn put_params(w: &mut BytesMut, p: &ParamsBlock) {
    w.put_u32_le(p.left_wheel_diameter_nm);
    w.put_u32_le(p.right_wheel_diameter_nm);
    w.put_u32_le(p.wheelbase_nm);
    w.put_u64_le(p.counts_per_wheel_rev_micro);
}

/// A bounds-checked little-endian reader that also counts fields (for NACK details).
struct Reader<'a> {
    msg: u8,
    buf: &'a [u8],
    pos: usize,
    field: u8,
}

impl<'a> Reader<'a> {
    fn bytes<const N: usize>(&mut self) -> Result<[u8; N], MessageError> {
        let end = self.pos + N;
        let out = self
            .buf
            .get(self.pos..end)
            .and_then(|s| <[u8; N]>::try_from(s).ok())
            .ok_or(MessageError::BadLength {
                msg: self.msg,
                need: end,
                got: self.buf.len(),
            })?;
        self.pos = end;
        self.field = self.field.saturating_add(1);
        Ok(out)
    }
    fn u8(&mut self) -> Result<u8, MessageError> {
        Ok(self.bytes::<1>()?[0])
    }
    fn u16(&mut self) -> Result<u16, MessageError> {
        self.bytes().map(u16::from_le_bytes)
    }
    fn i16(&mut self) -> Result<i16, MessageError> {
        self.bytes().map(i16::from_le_bytes)
    }
    fn u32(&mut self) -> Result<u32, MessageError> {
        self.bytes().map(u32::from_le_bytes)
    }
    fn i32(&mut self) -> Result<i32, MessageError> {
        self.bytes().map(i32::from_le_bytes)
    }
    fn u64(&mut self) -> Result<u64, MessageError> {
        self.bytes().map(u64::from_le_bytes)
    }
    fn wire<T>(&mut self, from: fn(u8) -> Option<T>) -> Result<T, MessageError> {
        let b = self.u8()?;
        from(b).ok_or(MessageError::OutOfRange {
            msg: self.msg,
            field: self.field - 1,
            value: u64::from(b),
        })
    }
    fn bool(&mut self) -> Result<bool, MessageError> {
        self.wire(|b| match b {
            0 => Some(false),
            1 => Some(true),
            _ => None,
        })
    }
    fn params(&mut self) -> Result<ParamsBlock, MessageError> {
        Ok(ParamsBlock {
            left_wheel_diameter_nm: self.u32()?,
            right_wheel_diameter_nm: self.u32()?,
            wheelbase_nm: self.u32()?,
            counts_per_wheel_rev_micro: self.u64()?,
        })
    }
    fn accepted(&mut self) -> Result<MotionAccepted, MessageError> {
        Ok(MotionAccepted {
            queue_depth: self.u8()?,
            motion_id: self.u16()?,
        })
    }
}

impl Packet {
    /// A request packet.
    pub fn request(seq: u8, request: Request) -> Self {
        Packet {
            seq,
            body: Body::Request { request },
        }
    }

    /// A response packet.
    pub fn response(seq: u8, response: Response) -> Self {
        Packet {
            seq,
            body: Body::Response { response },
        }
    }

    /// A NACK of message `msg`.
    pub fn nack(seq: u8, msg: u8, nack: Nack) -> Self {
        Packet {
            seq,
            body: Body::Nack { msg, nack },
        }
    }

    /// An event packet.
    pub fn event(seq: u8, event: Event) -> Self {
        Packet {
            seq,
            body: Body::Event { event },
        }
    }

    /// The frame carrying this packet.
    pub fn to_frame(&self) -> Result<Frame, MessageError> {
        let mut w = BytesMut::new();
        let (kind, msg) = match &self.body {
            Body::Request { request } => {
                request.encode(&mut w);
                (FrameKind::Request, request.msg())
            }
            Body::Response { response } => {
                response.encode(&mut w)?;
                (FrameKind::Response, response.msg())
            }
            Body::Nack { msg, nack } => {
                w.put_u8(nack.code.to_byte());
                w.put_u8(nack.detail);
                (FrameKind::Nack, *msg)
            }
            Body::Event { event } => {
                event.encode(&mut w);
                (FrameKind::Event, event.msg())
            }
        };
        Ok(Frame::new(kind, self.seq, msg, Bytes::from(w)))
    }

    /// The typed packet a frame carries.
    pub fn from_frame(frame: &Frame) -> Result<Packet, MessageError> {
        let msg = frame.msg;
        let need = payload_len(frame.kind, msg).ok_or(MessageError::UnknownMessage {
            kind: frame.kind,
            msg,
        })?;
        if frame.payload.len() < need {
            return Err(MessageError::BadLength {
                msg,
                need,
                got: frame.payload.len(),
            });
        }
        let mut r = Reader {
            msg,
            buf: &frame.payload,
            pos: 0,
            field: 0,
        };
        let body = match frame.kind {
            FrameKind::Request => Body::Request {
                request: Request::decode(msg, &mut r)?,
            },
            FrameKind::Response => Body::Response {
                response: Response::decode(msg, &mut r)?,
            },
            FrameKind::Nack => Body::Nack {
                msg,
                nack: Nack {
                    code: NackCode::from_byte(r.u8()?),
                    detail: r.u8()?,
                },
            },
            FrameKind::Event => Body::Event {
                event: Event::decode(msg, &mut r)?,
            },
        };
        Ok(Packet {
            seq: frame.seq,
            body,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_round_trip_within_wire_resolution() {
        let p = WheelParams {
            left_wheel_diameter_m: 0.084,
            right_wheel_diameter_m: 0.083_937_808_9,
            wheelbase_m: 0.201_232_677,
            counts_per_wheel_rev: 2796.8,
        };
        let block = ParamsBlock::from_params(&p).unwrap();
        assert_eq!(block.validate(), Ok(()));
        let back = block.to_params();
        for (a, b) in [
            (p.left_wheel_diameter_m, back.left_wheel_diameter_m),
            (p.right_wheel_diameter_m, back.right_wheel_diameter_m),
            (p.wheelbase_m, back.wheelbase_m),
            (p.counts_per_wheel_rev, back.counts_per_wheel_rev),
        ] {
            assert!(((a - b) / a).abs() <= 1e-7, "{a} vs {b}");
        }
        assert!(ParamsBlock::from_params(&WheelParams {
            wheelbase_m: f64::NAN,
            ..p
        })
        .is_none());
        assert!(ParamsBlock::from_params(&WheelParams {
            wheelbase_m: 5.0,
            ..p
        })
        .is_none());
    }

    #[test]
    fn validation_names_the_bad_field() {
        let good = ParamsBlock::from_params(&WheelParams::nominal(0.15, 0.39, 4096.0)).unwrap();
        assert_eq!(good.validate(), Ok(()));
        let bad = |f: fn(&mut ParamsBlock)| {
            let mut b = good;
            f(&mut b);
            b.validate()
        };
        assert_eq!(bad(|b| b.left_wheel_diameter_nm = 0), Err(0));
        assert_eq!(bad(|b| b.right_wheel_diameter_nm = 2_000_000_000), Err(1));
        assert_eq!(bad(|b| b.right_wheel_diameter_nm = 100_000_000), Err(1));
        assert_eq!(bad(|b| b.wheelbase_nm = 1), Err(2));
        assert_eq!(bad(|b| b.counts_per_wheel_rev_micro = 0), Err(3));
    }

    #[test]
    fn short_unknown_and_undefined_payloads_are_typed_errors() {
        let f = Frame::new(FrameKind::Request, 1, id::MOVE_STRAIGHT, vec![0u8; 6]);
        let e = Packet::from_frame(&f).unwrap_err();
        assert_eq!(
            e,
            MessageError::BadLength {
                msg: 0x30,
                need: 7,
                got: 6
            }
        );
        assert_eq!(e.nack().code, NackCode::BadLength);
        let f = Frame::new(FrameKind::Request, 1, 0x7F, Vec::new());
        assert_eq!(
            Packet::from_frame(&f).unwrap_err().nack().code,
            NackCode::UnknownMessage
        );
        // mode = 2 is undefined: OUT_OF_RANGE naming field 2.
        let f = Frame::new(
            FrameKind::Request,
            1,
            id::MOVE_STRAIGHT,
            vec![1, 0, 0, 0, 100, 0, 2],
        );
        let e = Packet::from_frame(&f).unwrap_err();
        assert_eq!(
            e.nack(),
            Nack {
                code: NackCode::OutOfRange,
                detail: 2
            }
        );
        // Telemetry is an event, not a request.
        let f = Frame::new(FrameKind::Request, 1, id::TELEMETRY, vec![0u8; 23]);
        assert!(matches!(
            Packet::from_frame(&f),
            Err(MessageError::UnknownMessage { .. })
        ));
    }

    #[test]
    fn longer_payloads_are_accepted_for_forward_compatibility() {
        let f = Frame::new(
            FrameKind::Request,
            9,
            id::CONFIGURE_WATCHDOG,
            vec![0xF4, 0x01, 0xEE, 0xEE],
        );
        assert_eq!(
            Packet::from_frame(&f).unwrap(),
            Packet::request(9, Request::ConfigureWatchdog { timeout_ms: 500 })
        );
    }

    #[test]
    fn firmware_ids_that_do_not_fit_are_refused() {
        let info = DeviceInfo {
            major: 1,
            minor: 0,
            firmware_id: "a-very-long-firmware-name".into(),
            firmware_version: 0,
            capabilities: 0,
            serial_number: 0,
            max_speed_mm_s: 1,
            max_rate_mrad_s: 1,
        };
        assert_eq!(
            Packet::response(0, Response::Hello(info)).to_frame(),
            Err(MessageError::FirmwareId)
        );
    }
}
