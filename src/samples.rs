//! The samples every layer passes along: wheel travel, heading readings and reference poses as
//! a backend stamps them, whether a reading may be used, what a heading sensor measures, and
//! how two streams' clocks relate.
//!
//! They sit below both the pure estimators ([`crate::calibration`], which turn them into
//! estimates) and the seam ([`crate::base`], whose backends produce them), so neither layer
//! names the other to share them; both re-export them under their older paths. Nothing here
//! depends on anything but serde.

use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// Wheel travel since the previous sample of the same stream, as the drive believes it
/// (encoder counts times the *configured* travel per count; metres, forward positive).
///
/// A sample covers the time since the stream's previous one: a drive that sends nothing at
/// rest sends a zero sample when the wheels start again, so that the first travel of a motion
/// is not spread over the rest before it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TravelSample {
    /// Time on the drive's clock (s); streams of different devices need not share a clock.
    pub time_s: f64,
    /// Left wheel travel since the previous sample (m).
    pub left_m: f64,
    /// Right wheel travel since the previous sample (m).
    pub right_m: f64,
}

/// Whether a heading reading may be used, and if not, why.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "state", content = "reason")]
pub enum Validity {
    /// Usable.
    Valid,
    /// Not usable, with the sensor's or the backend's reason.
    Invalid(String),
}

impl Validity {
    /// `true` for [`Validity::Valid`].
    pub fn is_valid(&self) -> bool {
        matches!(self, Validity::Valid)
    }
}

/// One heading reading.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HeadingSample {
    /// Time on the heading source's clock (s).
    pub time_s: f64,
    /// Heading (rad), counter-clockwise positive, wrapped to (−π, π].
    pub heading_rad: f64,
    /// Whether it may be used.
    pub validity: Validity,
}

impl HeadingSample {
    /// A reading a device flags valid or not by one bit (its telemetry, as sent or logged).
    pub fn flagged(time_s: f64, heading_rad: f64, valid: bool) -> Self {
        HeadingSample {
            time_s,
            heading_rad,
            validity: match valid {
                true => Validity::Valid,
                false => Validity::Invalid("telemetry marks the heading invalid".into()),
            },
        }
    }

    /// The heading when the reading may be used and is a number.
    pub fn usable(&self) -> Option<f64> {
        (self.validity.is_valid() && self.heading_rad.is_finite()).then_some(self.heading_rad)
    }
}

/// How the clocks of a recording's two streams relate.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Clocks {
    /// Both streams are stamped by one clock (one device; header stamps of one robot; this
    /// host's clock for devices read by it).
    #[default]
    Shared,
    /// Each stream has a clock of its own and both streams were started at the same moment:
    /// their first samples are taken as simultaneous, then the correlation refines it.
    StartedTogether,
}

/// One pose of the reference frame in the reference's world frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ReferencePose {
    /// Time on the reference's clock (s).
    pub time_s: f64,
    /// x (m).
    pub x_m: f64,
    /// y (m).
    pub y_m: f64,
    /// Yaw (rad, counter-clockwise positive); `None` for a position-only reference.
    pub yaw_rad: Option<f64>,
    /// Standard deviations the source states for this pose (x, y in m; yaw in rad), e.g. from
    /// a message's covariance; `None` when it states none. They weight the samples relative to
    /// each other; the overall scale is still estimated from the residuals.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stated_std: Option<[f64; 3]>,
}

/// What a heading sensor measures, which decides what can go wrong with it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum HeadingKind {
    /// An absolute heading from the Earth's field (a compass, a 9-axis IMU's fused yaw): it
    /// deviates near motors, batteries and steel, by a curve of the azimuth.
    Magnetic,
    /// A heading integrated from a gyro (a 6-axis IMU): no deviation, but its scale error
    /// enters `E_b` one to one.
    Gyro,
    /// An external reference (motion capture): the true heading.
    Reference,
    /// Not known (a ROS IMU may be either): treated as magnetic where it matters.
    #[default]
    Unknown,
}

impl HeadingKind {
    /// The kind's stable name (CLI and JSON).
    pub fn name(self) -> &'static str {
        match self {
            HeadingKind::Magnetic => "magnetic",
            HeadingKind::Gyro => "gyro",
            HeadingKind::Reference => "reference",
            HeadingKind::Unknown => "unknown",
        }
    }

    /// Whether its readings may carry a deviation curve.
    pub fn may_deviate(self) -> bool {
        matches!(self, HeadingKind::Magnetic | HeadingKind::Unknown)
    }
}

impl fmt::Display for HeadingKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for HeadingKind {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        [
            HeadingKind::Magnetic,
            HeadingKind::Gyro,
            HeadingKind::Reference,
            HeadingKind::Unknown,
        ]
        .into_iter()
        .find(|k| k.name() == s)
        .ok_or_else(|| format!("{s:?}: use magnetic, gyro, reference or unknown"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flagged_reading_is_usable_only_when_valid() {
        assert_eq!(HeadingSample::flagged(1.0, 0.5, true).usable(), Some(0.5));
        let invalid = HeadingSample::flagged(1.0, 0.5, false);
        assert_eq!(invalid.usable(), None);
        assert!(matches!(invalid.validity, Validity::Invalid(ref why) if why.contains("invalid")));
    }
}
