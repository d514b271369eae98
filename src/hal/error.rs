//! Errors of the HAL, in two layers: [`LinkError`] (the link or the protocol failed) and
//! [`HalError`] (a call failed: the link, the device's refusal, the caller's argument, or a
//! device state such as a tripped watchdog).

use crate::protocol::message::{Nack, NackCode};
use crate::protocol::MessageError;
use std::sync::Arc;
use std::time::Duration;

/// The link or the protocol failed (as opposed to the device refusing).
#[derive(Debug, Clone, thiserror::Error)]
pub enum LinkError {
    /// Reading or writing the stream failed.
    #[error("link I/O error: {0}")]
    Io(#[source] Arc<std::io::Error>),
    /// The stream ended (device unplugged, port closed).
    #[error("the link closed")]
    Closed,
    /// No answer after every retry.
    #[error("no answer to message 0x{msg:02X} after {attempts} attempts ({})", crate::io::seconds(.after))]
    Timeout {
        /// The request's message id.
        msg: u8,
        /// Attempts made.
        attempts: u32,
        /// Total time waited.
        after: Duration,
    },
    /// An answer could not be decoded, or a request could not be encoded.
    #[error("undecodable message: {0}")]
    Decode(#[source] MessageError),
    /// The device answered with something that does not fit the request.
    #[error("protocol violation: {0}")]
    Protocol(String),
    /// The device speaks another major protocol version.
    #[error("{}, this host speaks {host}.x: use an odocal of the device's major version", match device {
        Some((major, minor)) => format!("the device speaks protocol {major}.{minor}"),
        None => "the device speaks another protocol version (a 1.0 device does not say which)".to_string(),
    })]
    VersionMismatch {
        /// The device's (major, minor), when it said.
        device: Option<(u8, u8)>,
        /// Host's major.
        host: u8,
    },
    /// Bytes arrive but none forms a frame of this protocol.
    #[error("{bytes} bytes arrived in {} but none forms an odocal frame: wrong baud rate (this link runs at {baud}; try --baud), or not an odocal device on this port", crate::io::seconds(.after))]
    NotOdocal {
        /// Bytes received and skipped.
        bytes: u64,
        /// Time the handshake was tried.
        after: Duration,
        /// The baud rate used.
        baud: u32,
    },
    /// Nothing at all arrives.
    #[error("nothing arrived in {} at {baud} baud: is the device powered, on this port, and does it speak the odocal protocol?", crate::io::seconds(.after))]
    Silent {
        /// Time the handshake was tried.
        after: Duration,
        /// The baud rate used.
        baud: u32,
    },
    /// An emergency stop abandoned the request.
    #[error("cancelled by an emergency stop")]
    Cancelled,
}

impl From<std::io::Error> for LinkError {
    fn from(e: std::io::Error) -> Self {
        LinkError::Io(Arc::new(e))
    }
}

/// Errors of HAL calls.
#[derive(Debug, Clone, thiserror::Error)]
pub enum HalError {
    /// Transport or protocol failure.
    #[error(transparent)]
    Link(#[from] LinkError),
    /// The device answered NACK.
    #[error("device refused message 0x{msg:02X}: {} (field {})", nack.code, nack.detail)]
    Nack {
        /// The refused message id.
        msg: u8,
        /// Code and detail.
        nack: Nack,
    },
    /// A caller-supplied value cannot be sent (outside the wire's range); nothing was sent.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// The port could not be opened.
    #[error("cannot open {path}: {source}")]
    Open {
        /// The port path.
        path: String,
        /// Why.
        #[source]
        source: Arc<std::io::Error>,
    },
    /// A motion did not finish in the time it should take.
    #[error("motion {motion_id} did not finish within {}", crate::io::seconds(.after))]
    MotionTimeout {
        /// The motion.
        motion_id: u16,
        /// Time waited.
        after: Duration,
    },
    /// The device's watchdog stopped the base.
    #[error("the device watchdog stopped the base")]
    WatchdogTripped,
    /// The device went idle without completing the motion (a STOP, a fault, a trip already
    /// acknowledged).
    #[error("motion {motion_id} was stopped before it completed")]
    MotionStopped {
        /// The motion.
        motion_id: u16,
    },
}

impl HalError {
    /// The NACK code, if the device refused.
    pub fn nack_code(&self) -> Option<NackCode> {
        match self {
            HalError::Nack { nack, .. } => Some(nack.code),
            _ => None,
        }
    }
}
