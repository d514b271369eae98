//! An NMEA 0183 compass as the seam's [`crate::base::HeadingSource`] ([`compass`]): `$--HDT`
//! (true heading), `$--HDG` (magnetic sensor heading with deviation and variation) and
//! `$--HDM` (magnetic heading), checksums verified, any talker, 4800–115200 baud.
//!
//! A compass azimuth is clockwise from north; the seam's heading is counter-clockwise positive
//! ([`crate::kinematics`]): [`azimuth_to_heading`] is the one conversion. A heading calibration
//! needs only changes of heading, so true and magnetic serve equally as long as one source is
//! used throughout: the first sentence type heard is kept, in the order HDT, HDG, HDM.
//!
//! [`mod@sentence`] parses and writes the sentences; [`compass`] reads them from a serial line.

#[cfg(feature = "nmea")]
pub mod compass;
pub mod sentence;

#[cfg(feature = "nmea")]
pub use compass::{NmeaCompass, NmeaStats};

#[cfg(feature = "nmea")]
use crate::base::heading_backend::{HeadingBackend, PortSpec};
#[cfg(feature = "nmea")]
use std::sync::Arc;

#[cfg(feature = "nmea")]
/// Baud rate of an NMEA 0183 compass unless configured (NMEA 0183's own).
pub const NMEA_BAUD: u32 = 4800;

#[cfg(feature = "nmea")]
/// An NMEA compass as a heading source of its own: `nmea:PORT[?baud=4800]`.
pub const HEADING_BACKEND: HeadingBackend = HeadingBackend {
    scheme: "nmea",
    form: "nmea:PORT[?baud=4800]",
    options: &["baud"],
    check: |spec| spec.option("baud", NMEA_BAUD).map(drop),
    open: |spec: PortSpec| {
        Box::pin(async move {
            let baud = spec.option("baud", NMEA_BAUD).map_err(|reason| {
                crate::base::BaseError::InvalidArgument {
                    component: "heading (NMEA)".into(),
                    reason,
                }
            })?;
            let compass = NmeaCompass::open(&spec.port, baud, std::time::Duration::from_secs(1))?;
            Ok(Arc::new(compass) as Arc<dyn crate::base::HeadingSource>)
        })
    },
};
pub use sentence::{azimuth_to_heading, parse, sentence, Kind, NmeaError, MAX_SENTENCE};
