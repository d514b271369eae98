//! Typed messages of SPEC.md §5, described once.
//!
//! Each payload is a struct whose field list (in `wire_struct!` form) *is* its layout: the
//! [`Payload`] length, encoding and decoding follow from it. Each message is one row of the
//! tables at the end of this file — its id and its payload type — from which [`Request`],
//! [`Response`] and [`Event`], their ids, their lengths ([`payload_len`]) and their encoding
//! and decoding follow. A new message is one `id` constant, one row per direction, and one
//! golden vector.
//!
//! A [`Packet`] is a sequence number and a [`Body`]. Decoding checks lengths and enumerated
//! fields only; limits that depend on the device (speeds, parameter ranges) are the device's
//! to check, so it can NACK them with the field's index. Payloads longer than a message needs
//! are accepted and the tail ignored (SPEC.md §6).

use crate::frame::{Frame, FrameKind, MAX_PAYLOAD};
use crate::wire::{Payload, Reader, Writer};

/// Errors turning a frame into a typed message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum MessageError {
    /// No message with this id exists for this frame kind.
    #[error("unknown {kind} message id 0x{msg:02X}")]
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
    /// A firmware id longer than 16 bytes, not ASCII, or holding NUL.
    #[error("firmware id must be at most 16 ASCII bytes without NUL")]
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

    /// The name SPEC.md §5 gives message `msg` ("MOVE_STRAIGHT"), if it defines one.
    pub const fn name(msg: u8) -> Option<&'static str> {
        Some(match msg {
            HELLO => "HELLO",
            GET_PARAMS => "GET_PARAMS",
            SET_PARAMS => "SET_PARAMS",
            SAVE_PARAMS => "SAVE_PARAMS",
            RESTORE_DEFAULTS => "RESTORE_DEFAULTS",
            LOAD_PARAMS => "LOAD_PARAMS",
            RESET_ODOMETRY => "RESET_ODOMETRY",
            MOVE_STRAIGHT => "MOVE_STRAIGHT",
            TURN_IN_PLACE => "TURN_IN_PLACE",
            WHEEL_SPEED => "WHEEL_SPEED",
            STOP => "STOP",
            GET_STATUS => "GET_STATUS",
            READ_ENCODERS => "READ_ENCODERS",
            READ_HEADING => "READ_HEADING",
            CONFIGURE_TELEMETRY => "CONFIGURE_TELEMETRY",
            TELEMETRY => "TELEMETRY",
            MOTION_DONE => "MOTION_DONE",
            CONFIGURE_WATCHDOG => "CONFIGURE_WATCHDOG",
            HEARTBEAT => "HEARTBEAT",
            _ => return None,
        })
    }
}

/// Payload sizes as in SPEC.md §5: of a request, a response or a NACK of request `msg`, or of
/// event `msg`; `None` for an id that kind does not have.
pub const fn payload_len(kind: FrameKind, msg: u8) -> Option<usize> {
    match kind {
        FrameKind::Request => Request::payload_len(msg),
        FrameKind::Response => Response::payload_len(msg),
        FrameKind::Nack => match Request::payload_len(msg) {
            Some(_) => Some(Nack::LEN),
            None => None,
        },
        FrameKind::Event => Event::payload_len(msg),
    }
}

macro_rules! wire_enum {
    ($(#[$m:meta])* $name:ident { $($(#[$vm:meta])* $var:ident = $val:expr),+ $(,)? }) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
        #[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
        pub enum $name { $($(#[$vm])* $var = $val),+ }
        impl $name {
            /// The variant for a wire byte, if defined.
            pub const fn from_byte(b: u8) -> Option<Self> {
                match b { $($val => Some($name::$var),)+ _ => None }
            }
        }
        impl core::fmt::Display for $name {
            /// The variant's name in snake case (`active_and_stored`), as serde writes it.
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                write_snake(f, match self { $($name::$var => stringify!($var)),+ })
            }
        }
        impl Payload for $name {
            const LEN: usize = 1;
            fn put(&self, w: &mut Writer<'_>) {
                w.bytes(&[*self as u8]);
            }
            fn get(r: &mut Reader<'_>) -> Result<Self, MessageError> {
                let b = r.bytes::<1>()?[0];
                Self::from_byte(b).ok_or_else(|| r.out_of_range(u64::from(b)))
            }
        }
    };
}

/// Writes a CamelCase name in snake case (`ActiveAndStored` → `active_and_stored`).
fn write_snake(f: &mut core::fmt::Formatter<'_>, name: &str) -> core::fmt::Result {
    use core::fmt::Write as _;
    for (i, c) in name.chars().enumerate() {
        if c.is_ascii_uppercase() && i > 0 {
            f.write_char('_')?;
        }
        f.write_char(c.to_ascii_lowercase())?;
    }
    Ok(())
}

/// Declares a payload struct from its field list; the list is the wire layout.
macro_rules! wire_struct {
    ($(#[$m:meta])* pub struct $name:ident { $($(#[$fm:meta])* pub $f:ident : $t:ty),* $(,)? }) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
        pub struct $name { $($(#[$fm])* pub $f: $t),* }
        impl Payload for $name {
            const LEN: usize = 0 $(+ <$t as Payload>::LEN)*;
            fn put(&self, w: &mut Writer<'_>) {
                $(self.$f.put(w);)*
            }
            fn get(r: &mut Reader<'_>) -> Result<Self, MessageError> {
                Ok($name { $($f: <$t as Payload>::get(r)?),* })
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
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "SCREAMING_SNAKE_CASE"))]
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

impl core::fmt::Display for NackCode {
    /// The code's name as SPEC.md §3.1 spells it (`OUT_OF_RANGE`), or its byte (`code 0x09`).
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            NackCode::UnknownMessage => "UNKNOWN_MESSAGE",
            NackCode::BadLength => "BAD_LENGTH",
            NackCode::OutOfRange => "OUT_OF_RANGE",
            NackCode::InvalidState => "INVALID_STATE",
            NackCode::Busy => "BUSY",
            NackCode::StorageFailure => "STORAGE_FAILURE",
            NackCode::VersionMismatch => "VERSION_MISMATCH",
            NackCode::Other(b) => return write!(f, "code 0x{b:02X}"),
        })
    }
}

impl NackCode {
    /// The wire byte.
    pub const fn to_byte(self) -> u8 {
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
    pub const fn from_byte(b: u8) -> Self {
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

impl Payload for NackCode {
    const LEN: usize = 1;
    fn put(&self, w: &mut Writer<'_>) {
        w.bytes(&[self.to_byte()]);
    }
    fn get(r: &mut Reader<'_>) -> Result<Self, MessageError> {
        Ok(NackCode::from_byte(r.bytes::<1>()?[0]))
    }
}

wire_struct!(
    /// A device's refusal.
    pub struct Nack {
        /// Why.
        pub code: NackCode,
        /// Index of the offending field, or 0xFF.
        pub detail: u8,
    }
);

wire_struct!(
    /// Kinematic parameters as they travel on the wire (SPEC.md §4.1); see
    /// [`crate::units::ParamsSi`] for SI units.
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
);

/// One field of the parameter block as SPEC.md §4.1 defines it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamsField {
    /// What it is ("wheelbase").
    pub name: &'static str,
    /// Its SI unit ("m"; empty for a count).
    pub unit: &'static str,
    /// Wire units per SI unit (1e9 nm per m, 1e6 millionths per count).
    pub per_si: f64,
    /// Smallest allowed value, in wire units.
    pub min: u64,
    /// Largest allowed value, in wire units.
    pub max: u64,
}

impl ParamsBlock {
    /// SPEC.md §4.1's fields in payload order, with their ranges: the one table
    /// [`ParamsBlock::validate`] checks and hosts describe refusals from.
    pub const FIELDS: [ParamsField; 4] = [
        ParamsField {
            name: "left wheel diameter",
            unit: "m",
            per_si: 1e9,
            min: 10_000_000,
            max: 1_000_000_000,
        },
        ParamsField {
            name: "right wheel diameter",
            unit: "m",
            per_si: 1e9,
            min: 10_000_000,
            max: 1_000_000_000,
        },
        ParamsField {
            name: "wheelbase",
            unit: "m",
            per_si: 1e9,
            min: 20_000_000,
            max: 2_000_000_000,
        },
        ParamsField {
            name: "counts per wheel revolution",
            unit: "",
            per_si: 1e6,
            min: 1_000_000,
            max: 10_000_000_000_000,
        },
    ];

    /// Checks SPEC.md §4.1's ranges ([`ParamsBlock::FIELDS`]); the error is the index of the
    /// first bad field (a diameter ratio outside [0.8, 1.25] reports field 1).
    pub fn validate(&self) -> Result<(), u8> {
        let values = [
            u64::from(self.left_wheel_diameter_nm),
            u64::from(self.right_wheel_diameter_nm),
            u64::from(self.wheelbase_nm),
            self.counts_per_wheel_rev_micro,
        ];
        for (i, (v, f)) in values.iter().zip(Self::FIELDS.iter()).enumerate() {
            if !(f.min..=f.max).contains(v) {
                return Err(i as u8);
            }
        }
        // In integers: 0.8 ≤ R/L ≤ 1.25 ⇔ 4L ≤ 5R and 4R ≤ 5L.
        let (l, r) = (values[0], values[1]);
        if 4 * l > 5 * r || 4 * r > 5 * l {
            return Err(1);
        }
        Ok(())
    }
}

/// A firmware name: at most 16 ASCII bytes without NUL, NUL-padded on the wire.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct FirmwareId([u8; 16]);

impl FirmwareId {
    /// The id for `name`, if it fits the wire.
    pub fn new(name: &str) -> Result<Self, MessageError> {
        let b = name.as_bytes();
        if b.len() > 16 || !name.is_ascii() || b.contains(&0) {
            return Err(MessageError::FirmwareId);
        }
        let mut raw = [0u8; 16];
        raw[..b.len()].copy_from_slice(b);
        Ok(FirmwareId(raw))
    }

    /// The raw bytes up to the first NUL (a device may send anything here).
    pub fn as_bytes(&self) -> &[u8] {
        let end = self.0.iter().position(|&b| b == 0).unwrap_or(16);
        &self.0[..end]
    }

    /// The name, up to its first byte that is not UTF-8.
    pub fn as_str(&self) -> &str {
        let b = self.as_bytes();
        match core::str::from_utf8(b) {
            Ok(s) => s,
            // valid_up_to() is a UTF-8 boundary, so this cannot fail.
            Err(e) => core::str::from_utf8(&b[..e.valid_up_to()]).unwrap_or(""),
        }
    }
}

impl core::fmt::Debug for FirmwareId {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{:?}", self.as_str())
    }
}

impl core::fmt::Display for FirmwareId {
    /// Shows the name with every control or non-ASCII byte escaped, so a device cannot write
    /// terminal escape codes through it.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        for &b in self.as_bytes() {
            if (0x20..0x7F).contains(&b) {
                write!(f, "{}", b as char)?;
            } else {
                write!(f, "\\x{b:02x}")?;
            }
        }
        Ok(())
    }
}

impl Payload for FirmwareId {
    const LEN: usize = 16;
    fn put(&self, w: &mut Writer<'_>) {
        w.bytes(&self.0);
    }
    fn get(r: &mut Reader<'_>) -> Result<Self, MessageError> {
        r.bytes::<16>().map(FirmwareId)
    }
}

#[cfg(feature = "serde")]
impl serde::Serialize for FirmwareId {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

#[cfg(feature = "serde")]
impl<'de> serde::Deserialize<'de> for FirmwareId {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = FirmwareId;
            fn expecting(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                f.write_str("at most 16 ASCII characters")
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<FirmwareId, E> {
                FirmwareId::new(v).map_err(E::custom)
            }
        }
        d.deserialize_str(V)
    }
}

wire_struct!(
    /// HELLO's answer.
    pub struct DeviceInfo {
        /// Protocol major version.
        pub major: u8,
        /// Protocol minor version.
        pub minor: u8,
        /// Firmware name.
        pub firmware_id: FirmwareId,
        /// `(major << 16) | (minor << 8) | patch`.
        pub firmware_version: u32,
        /// Capability bits ([`capability`]).
        pub capabilities: u32,
        /// Serial number.
        pub serial_number: u64,
        /// Absolute speed limit (mm/s).
        pub max_speed_mm_s: u16,
        /// Absolute turn-rate limit (mrad/s).
        pub max_rate_mrad_s: u16,
    }
);

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
    /// The heading sensor is magnetic (a compass, a 9-axis IMU's fused yaw): it may deviate.
    pub const HEADING_MAGNETIC: u32 = 1 << 6;
    /// The heading sensor integrates a gyro: its scale error enters `E_b` one to one.
    pub const HEADING_GYRO: u32 = 1 << 7;
}

/// Bits of [`Heading::sensor_status`] (SPEC.md §5, READ_HEADING).
pub mod heading_status {
    /// The sensor is calibrated.
    pub const CALIBRATED: u8 = 1 << 0;
    /// The sensor senses a magnetic disturbance.
    pub const MAGNETIC_DISTURBANCE: u8 = 1 << 1;
    /// The sensor does not respond.
    pub const NOT_RESPONDING: u8 = 1 << 2;
    /// No reading since the previous READ_HEADING was answered: the fields repeat that one.
    pub const NOT_NEW: u8 = 1 << 3;
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

wire_struct!(
    /// HELLO's request.
    pub struct HelloRequest {
        /// Host's protocol major.
        pub host_major: u8,
        /// Lowest minor the host needs.
        pub host_min_minor: u8,
    }
);

wire_struct!(
    /// GET_PARAMS's request.
    pub struct GetParamsRequest {
        /// Which copy.
        pub source: ParamSource,
    }
);

wire_struct!(
    /// GET_PARAMS's answer.
    pub struct StoredParams {
        /// Which copy.
        pub source: ParamSource,
        /// The parameters.
        pub params: ParamsBlock,
        /// CRC of the stored copy (0 unless source is stored).
        pub stored_crc: u16,
    }
);

wire_struct!(
    /// SAVE_PARAMS's answer.
    pub struct SavedCrc {
        /// CRC-16 of the stored block.
        pub stored_crc: u16,
    }
);

wire_struct!(
    /// RESTORE_DEFAULTS's request.
    pub struct RestoreDefaultsRequest {
        /// What to overwrite.
        pub target: RestoreTarget,
    }
);

wire_struct!(
    /// MOVE_STRAIGHT's request (moves the robot).
    pub struct MoveStraightRequest {
        /// Distance (µm), negative backwards.
        pub distance_um: i32,
        /// Speed limit (mm/s).
        pub max_speed_mm_s: u16,
        /// Queue or replace.
        pub mode: MotionMode,
    }
);

wire_struct!(
    /// TURN_IN_PLACE's request (moves the robot).
    pub struct TurnInPlaceRequest {
        /// Angle (µrad), counter-clockwise positive.
        pub angle_urad: i32,
        /// Turn-rate limit (mrad/s).
        pub max_rate_mrad_s: u16,
        /// Queue or replace.
        pub mode: MotionMode,
    }
);

wire_struct!(
    /// WHEEL_SPEED's request (moves the robot).
    pub struct WheelSpeedRequest {
        /// Left wheel (mm/s).
        pub left_mm_s: i16,
        /// Right wheel (mm/s).
        pub right_mm_s: i16,
        /// Duration (ms), 0 = until replaced.
        pub duration_ms: u16,
    }
);

wire_struct!(
    /// A motion command's acceptance.
    pub struct MotionAccepted {
        /// Motions queued, including this one.
        pub queue_depth: u8,
        /// Device-assigned id of this motion.
        pub motion_id: u16,
    }
);

wire_struct!(
    /// GET_STATUS's answer.
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
);

wire_struct!(
    /// READ_ENCODERS's answer.
    pub struct Encoders {
        /// Device clock (µs, wrapping).
        pub timestamp_us: u32,
        /// Cumulative left counts (wrapping).
        pub left_counts: i32,
        /// Cumulative right counts (wrapping).
        pub right_counts: i32,
    }
);

wire_struct!(
    /// READ_HEADING's answer.
    pub struct Heading {
        /// Device clock (µs, wrapping).
        pub timestamp_us: u32,
        /// Heading (µrad), counter-clockwise positive, (−π, π].
        pub heading_urad: i32,
        /// Whether the reading may be used.
        pub valid: bool,
        /// Sensor status bits ([`heading_status`]).
        pub sensor_status: u8,
    }
);

wire_struct!(
    /// CONFIGURE_TELEMETRY's request and answer.
    pub struct TelemetryPeriod {
        /// Period (ms), 0 = off.
        pub period_ms: u16,
    }
);

wire_struct!(
    /// CONFIGURE_WATCHDOG's request and answer.
    pub struct WatchdogTimeout {
        /// Timeout (ms), 0 = off.
        pub timeout_ms: u16,
    }
);

wire_struct!(
    /// The TELEMETRY event.
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
);

wire_struct!(
    /// The MOTION_DONE event.
    pub struct MotionDone {
        /// Its id.
        pub motion_id: u16,
        /// Motions completed since power-up.
        pub completed_motions: u32,
    }
);

/// Declares one direction's message table: unit rows (no payload) and payload rows.
macro_rules! message_table {
    (
        $(#[$m:meta])* $name:ident, $kind:expr;
        unit { $($(#[$um:meta])* $uvar:ident = $uid:ident),* $(,)? }
        payload { $($(#[$pm:meta])* $pvar:ident = $pid:ident ($pty:ty)),* $(,)? }
    ) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
        #[cfg_attr(feature = "serde", serde(tag = "message", rename_all = "SCREAMING_SNAKE_CASE"))]
        pub enum $name {
            $($(#[$um])* $uvar,)*
            $($(#[$pm])* $pvar($pty),)*
        }

        impl $name {
            /// The message id.
            pub const fn msg(&self) -> u8 {
                match self {
                    $(Self::$uvar => id::$uid,)*
                    $(Self::$pvar(_) => id::$pid,)*
                }
            }

            /// The message's name as SPEC.md spells it (`GET_STATUS`).
            pub const fn name(&self) -> &'static str {
                match id::name(self.msg()) {
                    Some(name) => name,
                    None => "an unnamed message",
                }
            }

            /// The payload length of message `msg` in this direction, if it exists.
            pub const fn payload_len(msg: u8) -> Option<usize> {
                match msg {
                    $(id::$uid => Some(0),)*
                    $(id::$pid => Some(<$pty as Payload>::LEN),)*
                    _ => None,
                }
            }

            fn put(&self, w: &mut Writer<'_>) {
                match self {
                    $(Self::$uvar => {})*
                    $(Self::$pvar(p) => p.put(w),)*
                }
            }

            fn get(msg: u8, r: &mut Reader<'_>) -> Result<Self, MessageError> {
                Ok(match msg {
                    $(id::$uid => Self::$uvar,)*
                    $(id::$pid => Self::$pvar(<$pty as Payload>::get(r)?),)*
                    _ => return Err(MessageError::UnknownMessage { kind: $kind, msg }),
                })
            }
        }
    };
}

message_table!(
    /// Host-to-device requests.
    Request, FrameKind::Request;
    unit {
        /// Commit the active parameters to storage.
        SaveParams = SAVE_PARAMS,
        /// Reload the stored parameters into RAM.
        LoadParams = LOAD_PARAMS,
        /// Zero the encoders and odometry.
        ResetOdometry = RESET_ODOMETRY,
        /// Stop at once and clear the queue.
        Stop = STOP,
        /// Read the status.
        GetStatus = GET_STATUS,
        /// Read the encoders.
        ReadEncoders = READ_ENCODERS,
        /// Read the heading.
        ReadHeading = READ_HEADING,
        /// Feed the watchdog.
        Heartbeat = HEARTBEAT,
    }
    payload {
        /// Version negotiation.
        Hello = HELLO(HelloRequest),
        /// Read a parameter copy.
        GetParams = GET_PARAMS(GetParamsRequest),
        /// Write the active parameters.
        SetParams = SET_PARAMS(ParamsBlock),
        /// Restore factory defaults.
        RestoreDefaults = RESTORE_DEFAULTS(RestoreDefaultsRequest),
        /// Drive straight (moves the robot).
        MoveStraight = MOVE_STRAIGHT(MoveStraightRequest),
        /// Turn in place (moves the robot).
        TurnInPlace = TURN_IN_PLACE(TurnInPlaceRequest),
        /// Direct wheel speeds (moves the robot).
        WheelSpeed = WHEEL_SPEED(WheelSpeedRequest),
        /// Set the telemetry period.
        ConfigureTelemetry = CONFIGURE_TELEMETRY(TelemetryPeriod),
        /// Set the watchdog timeout.
        ConfigureWatchdog = CONFIGURE_WATCHDOG(WatchdogTimeout),
    }
);

message_table!(
    /// Device answers, one per request.
    Response, FrameKind::Response;
    unit {
        /// Done.
        ResetOdometry = RESET_ODOMETRY,
        /// Done.
        WheelSpeed = WHEEL_SPEED,
        /// Done.
        Stop = STOP,
        /// Done.
        Heartbeat = HEARTBEAT,
    }
    payload {
        /// Device info.
        Hello = HELLO(DeviceInfo),
        /// A parameter copy.
        GetParams = GET_PARAMS(StoredParams),
        /// The parameters now active.
        SetParams = SET_PARAMS(ParamsBlock),
        /// The stored copy's CRC.
        SaveParams = SAVE_PARAMS(SavedCrc),
        /// The parameters now active.
        RestoreDefaults = RESTORE_DEFAULTS(ParamsBlock),
        /// The parameters now active.
        LoadParams = LOAD_PARAMS(ParamsBlock),
        /// Accepted.
        MoveStraight = MOVE_STRAIGHT(MotionAccepted),
        /// Accepted.
        TurnInPlace = TURN_IN_PLACE(MotionAccepted),
        /// Status.
        GetStatus = GET_STATUS(Status),
        /// Encoders.
        ReadEncoders = READ_ENCODERS(Encoders),
        /// Heading.
        ReadHeading = READ_HEADING(Heading),
        /// Period applied.
        ConfigureTelemetry = CONFIGURE_TELEMETRY(TelemetryPeriod),
        /// Timeout applied.
        ConfigureWatchdog = CONFIGURE_WATCHDOG(WatchdogTimeout),
    }
);

message_table!(
    /// Unprompted device messages.
    Event, FrameKind::Event;
    unit {}
    payload {
        /// Periodic telemetry.
        Telemetry = TELEMETRY(Telemetry),
        /// A motion finished.
        MotionDone = MOTION_DONE(MotionDone),
    }
);

impl Request {
    /// Whether executing this request moves the robot.
    pub const fn moves_robot(&self) -> bool {
        matches!(
            self,
            Request::MoveStraight(_) | Request::TurnInPlace(_) | Request::WheelSpeed(_)
        )
    }
}

/// What a frame carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(tag = "kind", rename_all = "snake_case"))]
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
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Packet {
    /// Sequence number (for events, the device's event counter).
    pub seq: u8,
    /// The message.
    #[cfg_attr(feature = "serde", serde(flatten))]
    pub body: Body,
}

impl Packet {
    /// A request packet.
    pub const fn request(seq: u8, request: Request) -> Self {
        Packet {
            seq,
            body: Body::Request { request },
        }
    }

    /// A response packet.
    pub const fn response(seq: u8, response: Response) -> Self {
        Packet {
            seq,
            body: Body::Response { response },
        }
    }

    /// A NACK packet refusing message `msg`.
    pub const fn nack(seq: u8, msg: u8, nack: Nack) -> Self {
        Packet {
            seq,
            body: Body::Nack { msg, nack },
        }
    }

    /// An event packet.
    pub const fn event(seq: u8, event: Event) -> Self {
        Packet {
            seq,
            body: Body::Event { event },
        }
    }

    /// The frame carrying this packet.
    pub fn to_frame(&self) -> Frame {
        let mut buf = [0u8; MAX_PAYLOAD];
        let mut w = Writer::new(&mut buf);
        let (kind, msg) = match &self.body {
            Body::Request { request } => {
                request.put(&mut w);
                (FrameKind::Request, request.msg())
            }
            Body::Response { response } => {
                response.put(&mut w);
                (FrameKind::Response, response.msg())
            }
            Body::Nack { msg, nack } => {
                nack.put(&mut w);
                (FrameKind::Nack, *msg)
            }
            Body::Event { event } => {
                event.put(&mut w);
                (FrameKind::Event, event.msg())
            }
        };
        debug_assert!(!w.overflowed(), "every payload fits MAX_PAYLOAD");
        let len = w.len();
        Frame::from_parts(kind, self.seq, msg, buf, len)
    }

    /// The typed packet in `frame`.
    pub fn from_frame(frame: &Frame) -> Result<Packet, MessageError> {
        let msg = frame.msg;
        let payload = frame.payload();
        let need = payload_len(frame.kind, msg).ok_or(MessageError::UnknownMessage {
            kind: frame.kind,
            msg,
        })?;
        if payload.len() < need {
            return Err(MessageError::BadLength {
                msg,
                need,
                got: payload.len(),
            });
        }
        let mut r = Reader::new(msg, payload);
        let body = match frame.kind {
            FrameKind::Request => Body::Request {
                request: Request::get(msg, &mut r)?,
            },
            FrameKind::Response => Body::Response {
                response: Response::get(msg, &mut r)?,
            },
            FrameKind::Nack => Body::Nack {
                msg,
                nack: Nack::get(&mut r)?,
            },
            FrameKind::Event => Body::Event {
                event: Event::get(msg, &mut r)?,
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

    fn frame(kind: FrameKind, msg: u8, payload: &[u8]) -> Frame {
        Frame::new(kind, 1, msg, payload).unwrap()
    }

    #[test]
    fn table_lengths_are_the_spec_lengths() {
        use id::*;
        let spec: [(u8, usize, usize); 17] = [
            (HELLO, 2, 38),
            (GET_PARAMS, 1, 23),
            (SET_PARAMS, 20, 20),
            (SAVE_PARAMS, 0, 2),
            (RESTORE_DEFAULTS, 1, 20),
            (LOAD_PARAMS, 0, 20),
            (RESET_ODOMETRY, 0, 0),
            (MOVE_STRAIGHT, 7, 3),
            (TURN_IN_PLACE, 7, 3),
            (WHEEL_SPEED, 6, 0),
            (STOP, 0, 0),
            (GET_STATUS, 0, 15),
            (READ_ENCODERS, 0, 12),
            (READ_HEADING, 0, 10),
            (CONFIGURE_TELEMETRY, 2, 2),
            (CONFIGURE_WATCHDOG, 2, 2),
            (HEARTBEAT, 0, 0),
        ];
        for (msg, req, resp) in spec {
            assert_eq!(payload_len(FrameKind::Request, msg), Some(req), "{msg:#x}");
            assert_eq!(
                payload_len(FrameKind::Response, msg),
                Some(resp),
                "{msg:#x}"
            );
            assert_eq!(payload_len(FrameKind::Nack, msg), Some(2), "{msg:#x}");
            assert_eq!(payload_len(FrameKind::Event, msg), None, "{msg:#x}");
        }
        assert_eq!(payload_len(FrameKind::Event, TELEMETRY), Some(23));
        assert_eq!(payload_len(FrameKind::Event, MOTION_DONE), Some(6));
        assert_eq!(payload_len(FrameKind::Request, TELEMETRY), None);
    }

    #[test]
    fn validation_names_the_bad_field() {
        let good = ParamsBlock {
            left_wheel_diameter_nm: 150_000_000,
            right_wheel_diameter_nm: 150_000_000,
            wheelbase_nm: 390_000_000,
            counts_per_wheel_rev_micro: 4_096_000_000,
        };
        assert_eq!(good.validate(), Ok(()));
        let bad = |f: fn(&mut ParamsBlock)| {
            let mut b = good;
            f(&mut b);
            b.validate()
        };
        assert_eq!(bad(|b| b.left_wheel_diameter_nm = 0), Err(0));
        assert_eq!(bad(|b| b.right_wheel_diameter_nm = 2_000_000_000), Err(1));
        assert_eq!(bad(|b| b.right_wheel_diameter_nm = 100_000_000), Err(1));
        assert_eq!(bad(|b| b.right_wheel_diameter_nm = 120_000_000), Ok(()));
        assert_eq!(bad(|b| b.right_wheel_diameter_nm = 119_999_999), Err(1));
        assert_eq!(bad(|b| b.wheelbase_nm = 1), Err(2));
        assert_eq!(bad(|b| b.counts_per_wheel_rev_micro = 0), Err(3));
    }

    #[test]
    fn short_unknown_and_undefined_payloads_are_typed_errors() {
        let e = Packet::from_frame(&frame(FrameKind::Request, id::MOVE_STRAIGHT, &[0u8; 6]))
            .unwrap_err();
        assert_eq!(
            e,
            MessageError::BadLength {
                msg: 0x30,
                need: 7,
                got: 6
            }
        );
        assert_eq!(e.nack().code, NackCode::BadLength);
        let e = Packet::from_frame(&frame(FrameKind::Request, 0x7F, &[])).unwrap_err();
        assert_eq!(e.nack().code, NackCode::UnknownMessage);
        // mode = 2 is undefined: OUT_OF_RANGE naming field 2.
        let f = frame(
            FrameKind::Request,
            id::MOVE_STRAIGHT,
            &[1, 0, 0, 0, 100, 0, 2],
        );
        assert_eq!(
            Packet::from_frame(&f).unwrap_err().nack(),
            Nack {
                code: NackCode::OutOfRange,
                detail: 2
            }
        );
        // Telemetry is an event, not a request.
        let f = frame(FrameKind::Request, id::TELEMETRY, &[0u8; 23]);
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
            &[0xF4, 0x01, 0xEE, 0xEE],
        )
        .unwrap();
        assert_eq!(
            Packet::from_frame(&f).unwrap(),
            Packet::request(
                9,
                Request::ConfigureWatchdog(WatchdogTimeout { timeout_ms: 500 })
            )
        );
    }

    #[test]
    fn firmware_ids_that_do_not_fit_are_refused_and_odd_ones_are_escaped() {
        assert_eq!(
            FirmwareId::new("a-very-long-firmware-name"),
            Err(MessageError::FirmwareId)
        );
        assert_eq!(FirmwareId::new("ünï"), Err(MessageError::FirmwareId));
        let mut raw = [0u8; 16];
        raw[..5].copy_from_slice(b"\x1b[2Jx");
        let id = FirmwareId(raw);
        struct S([u8; 64], usize);
        impl core::fmt::Write for S {
            fn write_str(&mut self, s: &str) -> core::fmt::Result {
                self.0[self.1..self.1 + s.len()].copy_from_slice(s.as_bytes());
                self.1 += s.len();
                Ok(())
            }
        }
        let mut s = S([0; 64], 0);
        core::fmt::write(&mut s, format_args!("{id}")).unwrap();
        assert_eq!(&s.0[..s.1], b"\\x1b[2Jx");
    }
}
