//! Errors of the mock layer.

use crate::kinematics::WheelParams;
use crate::sim::SimError;

/// Errors building or power-cycling a mock device.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MockError {
    /// The simulator refused the robot.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// The factory parameters cannot travel on the wire (SPEC.md §4.1).
    #[error("factory parameters ({0}) are outside the protocol's ranges (SPEC.md §4.1)")]
    FactoryOutOfRange(WheelParams),
    #[cfg(feature = "odocal-protocol")]
    /// The device kit refused the configuration.
    #[error("device: {0}")]
    Device(#[from] crate::protocol::device::ConfigError),
    /// A fault specification (`corrupt=0.01,drop=0.05,…`) that cannot be used.
    #[error("faults: {0}")]
    Faults(String),
    /// A setting the mock cannot simulate (the message names the flag and its range).
    #[error("{0}")]
    Setting(String),
}
