//! A heading source that stands apart from the drive, as a backend module offers it: its
//! text form (`scheme:PORT?key=value&…`), the options it takes, and how it opens.
//!
//! Each such backend module exports one [`HeadingBackend`]; [`crate::spec::registry::HEADING_BACKENDS`]
//! lists them, so a new heading source (a serial IMU, a second compass protocol) is its module
//! plus one line there. The spec parser, the command line and the routine file learn its
//! scheme from that list.

use super::{BaseError, HeadingSource};
use futures_util::future::BoxFuture;
use std::sync::Arc;

pub use super::port_spec::PortSpec;

/// How a heading backend opens: the future a [`HeadingBackend::open`] returns.
pub type OpenHeading = BoxFuture<'static, Result<Arc<dyn HeadingSource>, BaseError>>;

/// A heading source on a port of its own.
pub struct HeadingBackend {
    /// The scheme of its text form (`nmea` in `nmea:/dev/ttyUSB1?baud=4800`).
    pub scheme: &'static str,
    /// Its text form with defaults, for help and errors (`nmea:PORT[?baud=4800]`).
    pub form: &'static str,
    /// The option keys it takes.
    pub options: &'static [&'static str],
    /// Checks the options (called when the text is parsed, before anything opens).
    pub check: fn(&PortSpec) -> Result<(), String>,
    /// **Opens the port** (nothing moves).
    pub open: fn(PortSpec) -> OpenHeading,
}

impl std::fmt::Debug for HeadingBackend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HeadingBackend")
            .field("scheme", &self.scheme)
            .finish_non_exhaustive()
    }
}

impl PartialEq for HeadingBackend {
    fn eq(&self, other: &Self) -> bool {
        self.scheme == other.scheme
    }
}
