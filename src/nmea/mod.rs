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

pub mod compass;
pub mod sentence;

pub use compass::{NmeaCompass, NmeaStats};
pub use sentence::{azimuth_to_heading, parse, sentence, Kind, NmeaError, MAX_SENTENCE};
