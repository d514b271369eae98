//! A simulated robot base that speaks `protocol/SPEC.md`: the kinematic simulator behind the
//! protocol, with non-volatile parameters, a watchdog and seeded faults.
//!
//! [`device`] is the firmware (protocol semantics, motion, telemetry); [`mod@serve`] puts it on an
//! in-memory duplex or a real pseudo-terminal, in virtual or scaled real time.

pub mod device;
pub mod serve;

pub use device::{CompassConvention, DeviceCounters, MockConfig, MockDevice, MockError};
pub use serve::{
    lock, serve, spawn_duplex, spawn_pty, FaultConfig, PtyServer, ServeEnd, SharedDevice, TimeMode,
};
