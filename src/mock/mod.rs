//! Simulated robots: the kinematic simulator behind each protocol, and behind the seam itself.
//!
//! [`device`] is firmware that speaks `protocol/SPEC.md` (protocol semantics, motion,
//! telemetry, non-volatile parameters, a watchdog, seeded faults); [`mod@serve`] puts it on an
//! in-memory duplex or a real pseudo-terminal, in virtual or scaled real time. [`sim_base`] is
//! the same simulator as a [`crate::base`] backend in process, with no protocol at all;
//! [`rosbridge`] is a ROS 2 robot behind a mock rosbridge server on a loopback socket.

pub mod device;
pub mod error;
pub mod roboclaw;
pub mod rosbridge;
pub mod serve;
pub mod sim_base;

pub use sim_base::{SimBase, SimCounters, SimFaults};

pub use device::{
    CompassConvention, DeviceCounters, MockConfig, MockDevice, MockError, MAX_EVENTS_PER_STEP,
};
pub use serve::{
    lock, serve, spawn_duplex, spawn_pty, FaultConfig, PtyServer, ServeEnd, SharedDevice, TimeMode,
};
