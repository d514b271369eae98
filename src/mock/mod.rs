//! Simulated robots: the kinematic simulator behind each protocol, and behind the seam itself.
//!
//! [`device`] is firmware that speaks `protocol/SPEC.md` (protocol semantics, motion,
//! telemetry, non-volatile parameters, a watchdog, seeded faults); [`mod@serve`] puts it on an
//! in-memory duplex or a real pseudo-terminal, in virtual or scaled real time. [`kit`] is the
//! protocol crate's device kit as it comes (an ideal board) on a pseudo-terminal. [`sim_base`] is
//! the same simulator as a [`crate::base`] backend in process, with no protocol at all;
//! [`rosbridge`] is a ROS 2 robot behind a mock rosbridge server on a loopback socket; [`stop`]
//! is how a mock server started from a shell or a test is stopped.

#[cfg(feature = "odocal-protocol")]
pub mod device;
pub mod error;
#[cfg(feature = "odocal-protocol")]
pub mod kit;
pub mod nmea;
pub mod options;
pub mod pty;
#[cfg(feature = "roboclaw")]
pub mod roboclaw;
#[cfg(feature = "ros")]
pub mod rosbridge;
#[cfg(feature = "odocal-protocol")]
pub mod serve;
pub mod sim_base;
pub mod stop;

pub use pty::PtyServer;
pub use sim_base::{SimBase, SimCounters, SimFaults};

#[cfg(feature = "odocal-protocol")]
pub use device::{CompassConvention, DeviceCounters, MockConfig, MockDevice, MAX_EVENTS_PER_STEP};
pub use error::MockError;
#[cfg(feature = "odocal-protocol")]
pub use serve::{
    lock, separate_compass, serve, spawn_duplex, spawn_pty, FaultConfig, ServeEnd, SharedDevice,
    TimeMode,
};

/// What kind of heading a simulated sensor is, as a backend would say it.
pub fn heading_kind(model: &crate::sim::sensor::HeadingModel) -> crate::base::HeadingKind {
    model.kind.into()
}
