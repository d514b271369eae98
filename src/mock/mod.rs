//! Simulated robots: the kinematic simulator behind each protocol, and behind the seam itself.
//!
//! [`device`] is firmware that speaks `protocol/SPEC.md` (protocol semantics, motion,
//! telemetry, non-volatile parameters, a watchdog, seeded faults); [`mod@serve`] puts it on an
//! in-memory duplex or a real pseudo-terminal, in virtual or scaled real time. [`kit`] is the
//! protocol crate's device kit as it comes (an ideal board) on a pseudo-terminal. [`sim_base`] is
//! the same simulator as a [`crate::base`] backend in process, with no protocol at all;
//! [`rosbridge`] is a ROS 2 robot behind a mock rosbridge server on a loopback socket.

pub mod device;
pub mod error;
pub mod kit;
pub mod nmea;
pub mod options;
pub mod pty;
pub mod roboclaw;
pub mod rosbridge;
pub mod serve;
pub mod sim_base;

pub use pty::PtyServer;
pub use sim_base::{SimBase, SimCounters, SimFaults};

pub use device::{
    CompassConvention, DeviceCounters, MockConfig, MockDevice, MockError, MAX_EVENTS_PER_STEP,
};
pub use serve::{
    lock, separate_compass, serve, spawn_duplex, spawn_pty, FaultConfig, ServeEnd, SharedDevice,
    TimeMode,
};

/// What kind of heading a simulated sensor is, as a backend would say it.
pub fn heading_kind(model: &crate::sim::sensor::HeadingModel) -> crate::base::HeadingKind {
    model.kind.into()
}
