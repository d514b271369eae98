//! A drive as a backend module offers it: how its text form is recognised, which options and
//! settings it takes, what it brings of its own (a heading sensor, a parameter store), and how
//! it opens into a [`Base`].
//!
//! Each drive module exports one [`DriveBackend`]; [`crate::spec::registry::DRIVE_BACKENDS`]
//! lists them, so a new drive is its module plus one line there. What the spec layer decides
//! for every drive alike — a drive without a heading sensor needs one, a drive that keeps its
//! parameters takes no profile, a drive that cannot honour a setting refuses it by name — is
//! read from the fields here, not from a match on the drive.

use super::port_spec::PortSpec;
use super::{Base, HeadingSource};
use futures_util::future::BoxFuture;
use std::path::PathBuf;
use std::sync::Arc;

/// Why a backend could not open: its own typed error, kept as the source.
pub type BackendError = Box<dyn std::error::Error + Send + Sync>;

/// The future a [`DriveBackend::open`] returns.
pub type OpenDrive = BoxFuture<'static, Result<Base, BackendError>>;

/// What a drive's controller says of itself (`odocal status`): as text and as JSON.
#[derive(Debug, Clone, PartialEq)]
pub struct DriveStatus {
    /// The report, one line per item.
    pub text: String,
    /// The same, as JSON.
    pub json: serde_json::Value,
}

/// The future a [`DriveBackend::status`] returns.
pub type StatusFuture = BoxFuture<'static, Result<DriveStatus, BackendError>>;

/// The heading sensor a drive brings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeadingPart {
    /// Its own (a controller's compass, a ROS robot's IMU); a sensor on a port of its own may
    /// replace it.
    Own,
    /// Its own, and no other can replace it; nor does it take a heading kind or deviation
    /// (the built-in simulated robot, whose compass errors are its own settings).
    OwnOnly,
    /// None: a heading source must be given (a RoboClaw).
    Needed,
}

/// Where a drive keeps its parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StorePart {
    /// In itself (a controller's memory, a ROS controller's YAML): no other store is taken.
    Own,
    /// Nowhere: a robot profile (`profile:PATH`) must be given, holding its geometry and wiring.
    Profile,
}

/// A drive's target: its port (or URL) and options, and the settings table it reads.
#[derive(Debug, Clone, PartialEq)]
pub struct DriveTarget {
    /// The port or URL and the options its text gave.
    pub spec: PortSpec,
    /// The drive's settings (a routine file's `[robot.<settings>]` table, with flags laid
    /// over it), for a drive that takes some ([`DriveBackend::settings`]). As TOML: it keeps
    /// every value a routine file can hold.
    pub settings: Option<toml::Value>,
}

/// What a drive opens with.
pub struct DriveOpen {
    /// The target.
    pub target: DriveTarget,
    /// A heading source on a port of its own, already open, when one was given.
    pub heading: Option<Arc<dyn HeadingSource>>,
    /// The robot profile, for a drive that keeps its parameters in one.
    pub profile: Option<PathBuf>,
}

/// A drive.
pub struct DriveBackend {
    /// Its name, as the text form starts (`odocal`, `rosbridge`, `roboclaw`, `mock`).
    pub name: &'static str,
    /// What it is, for messages (`a RoboClaw`).
    pub what: &'static str,
    /// Its text form with defaults, for help and errors.
    pub form: &'static str,
    /// The option keys its text form takes.
    pub options: &'static [&'static str],
    /// Splits a text of its form (`None`: not its form).
    pub recognise: fn(&str) -> Option<Result<PortSpec, String>>,
    /// It takes a bare port (`/dev/ttyUSB0`, no scheme): the default drive.
    pub bare_port: bool,
    /// The heading sensor it brings.
    pub heading: HeadingPart,
    /// Where it keeps its parameters.
    pub store: StorePart,
    /// The settings table it reads (`ros`: `[robot.ros]` and the `--ros-*` flags).
    pub settings: Option<&'static str>,
    /// Checks the options its text gave, when the text is parsed.
    pub check: fn(&PortSpec) -> Result<(), String>,
    /// Checks that a target, its settings laid in, has what the drive needs to open (a ROS
    /// robot's controller YAML), before anything opens.
    pub ready: fn(&DriveTarget) -> Result<(), String>,
    /// Where it is, for messages (a port, a URL).
    pub place: fn(&PortSpec) -> String,
    /// **Connects to the robot** (it does not move).
    pub open: fn(DriveOpen) -> OpenDrive,
    /// Connects to the drive's controller alone and reads its status (firmware, state,
    /// faults), for a drive that has a controller to ask; it does not move.
    pub status: Option<fn(DriveTarget) -> StatusFuture>,
}

impl DriveBackend {
    /// It takes a `baud` option (a serial drive): the `baud` key or `--baud` fills it in
    /// when the text gives none.
    pub fn takes_baud(&self) -> bool {
        self.options.contains(&"baud")
    }
}

impl std::fmt::Debug for DriveBackend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DriveBackend")
            .field("name", &self.name)
            .finish_non_exhaustive()
    }
}

impl PartialEq for DriveBackend {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name
    }
}
