//! Where a robot is: typed specs of its drive, its heading source and its parameter store,
//! parsed from the command line or a routine file's `[robot]` table, each opened by
//! [`BaseSpec::open`] into a [`Base`].
//!
//! Any drive combines with any heading source: a controller of our protocol with a separate
//! compass, a ROS robot whose IMU is poor with an NMEA compass, a RoboClaw (which has no
//! heading sensor) with a compass. The backends are listed once, in [`registry`]: a new drive,
//! heading source or store is its module (exporting a [`DriveBackend`], [`HeadingBackend`] or
//! [`StoreBackend`](crate::base::store_backend::StoreBackend)) plus one line there; its text
//! form, options, what it brings of its own and how it opens come from there. The rules that
//! combine the parts ([`BaseSpec::new`]) read those fields: a drive that cannot honour a setting
//! refuses it by name.
//!
//! Text forms (URL-like: quote them in a shell, `&` would end the command):
//!
//! | spec | forms |
//! |---|---|
//! | drive | `PORT` or `odocal:PORT[?baud=115200]` (odocal's protocol); `rosbridge://HOST:PORT` or `ws://HOST:PORT` (ROS, with `[robot.ros]` settings); `roboclaw:PORT[?address=128&baud=38400]`; `mock` (the built-in simulated robot) |
//! | heading | `drive` (the drive's own); `nmea:PORT[?baud=4800]` |
//! | store | `drive` (the drive's own); `profile:PATH` (a robot profile, for a drive that keeps no parameters) |
//! | a store on its own ([`StoreLocation`]: `odocal restore --to`) | a controller's `PORT` (or `odocal:PORT?baud=…`); `profile:PATH`; `ros-yaml:PATH[?controller=diff_drive_controller]` (a controller's ros2_control YAML) |

pub mod flags;
pub mod registry;
pub mod restore_target;
pub mod routine_file;
pub mod store;

#[cfg(test)]
mod core_tests;

use crate::base::adjusted::Adjusted;
use crate::base::drive_backend::{
    BackendError, DriveBackend, DriveOpen, DriveStatus, DriveTarget, HeadingPart, StorePart,
};
use crate::base::heading_backend::HeadingBackend;
use crate::base::port_spec::PortSpec;
use crate::base::transaction::BackupError;
use crate::base::{Base, BaseError, HeadingKind, HeadingSource};
#[cfg(feature = "odocal-protocol")]
use crate::hal::HalError;
use crate::kinematics::Deviation;
#[cfg(feature = "roboclaw")]
use crate::roboclaw::profile::ProfileError;
use crate::routine::config::ConfigError;
use registry::{forms, Role, DRIVE_BACKENDS, STORE_BACKENDS};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::Arc;

#[cfg(feature = "ros")]
pub use crate::ros::yaml::DEFAULT_CONTROLLER;
pub use registry::HEADING_BACKENDS;
pub use routine_file::RoutineFile;
pub use store::{StoreLocation, StoreSpec};

/// Baud rate of odocal's protocol unless configured (SPEC.md §1).
pub const ODOCAL_BAUD: u32 = 115_200;

/// Settings of a ROS robot ([`crate::ros::live::RosBaseConfig`]).
#[cfg(feature = "ros")]
pub type RosSettings = crate::ros::live::RosBaseConfig;
/// Settings of a ROS robot, in a build without the `ros` feature: kept as the table they are
/// given as, and refused by name.
#[cfg(not(feature = "ros"))]
pub type RosSettings = toml::Table;

/// Why a spec cannot be parsed, combined or opened.
#[derive(Debug, thiserror::Error)]
pub enum SpecError {
    /// The text is not a spec.
    #[error("{text:?}: {reason}")]
    Parse {
        /// The text given.
        text: String,
        /// What is wrong, and the forms that are right.
        reason: String,
    },
    /// A flag's value cannot be used (the message names the flag and what it takes).
    #[error("{0}")]
    Flag(String),
    /// The parts do not make a robot (a RoboClaw without a profile, a drive without a heading).
    #[error("{0}")]
    Combination(String),
    /// A controller of our protocol could not be opened.
    #[cfg(feature = "odocal-protocol")]
    #[error(transparent)]
    Odocal(#[from] HalError),
    /// A backend, or a setting of one, that this build of odocal leaves out.
    #[error(transparent)]
    NotBuilt(#[from] crate::features::NotBuilt),
    /// A drive could not be opened (its backend's error).
    #[error(transparent)]
    Drive(BackendError),
    /// A store could not be opened (its backend's error).
    #[error(transparent)]
    Store(BackendError),
    /// A robot profile could not be read.
    #[cfg(feature = "roboclaw")]
    #[error(transparent)]
    Profile(#[from] ProfileError),
    /// A heading source could not be opened.
    #[error(transparent)]
    Heading(#[from] BaseError),
    /// A backup file could not be read.
    #[error(transparent)]
    Backup(#[from] BackupError),
    /// A backup does not say which store it was taken from.
    #[error("{}: {source}", path.display())]
    InBackup {
        /// The backup.
        path: PathBuf,
        /// Why.
        #[source]
        source: Box<SpecError>,
    },
    /// A routine file could not be read.
    #[error("cannot read {}: {source}", path.display())]
    RoutineUnreadable {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// A routine file is not one (the line and what is wrong on it).
    #[error("{}: {source}", path.display())]
    RoutineFile {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        #[source]
        source: ConfigError,
    },
}

fn parse_err(text: &str, reason: impl Into<String>) -> SpecError {
    SpecError::Parse {
        text: text.into(),
        reason: reason.into(),
    }
}

/// The refusal of `text`, given as a `role`, when it names a backend this build leaves out
/// (by its scheme or whole, or, when `bare` and no built backend takes one, as a bare port).
fn not_built(text: &str, role: Role, bare: bool) -> Result<(), SpecError> {
    let table = registry::OPTIONAL;
    let bare = || {
        bare.then(|| registry::bare_port_not_built(table, text))
            .flatten()
    };
    match registry::not_built(table, role, text).or_else(bare) {
        Some(e) => Err(e.into()),
        None => Ok(()),
    }
}

/// `backend` cannot honour `setting`: refused by name rather than ignored.
fn refused(backend: &DriveBackend, setting: &str) -> SpecError {
    SpecError::Combination(format!(
        "{} does not take {setting}, which it would ignore: remove it",
        backend.what
    ))
}

/// `text` has the form of some backend other than a bare port (a scheme a list knows, or of a
/// backend this build leaves out, a URL), or is empty: not a bare port.
fn other_form(text: &str) -> bool {
    let scheme = |s: &str| text.starts_with(&format!("{s}:"));
    text.is_empty()
        || text.contains("://")
        || registry::names_one_left_out(registry::OPTIONAL, text)
        || DRIVE_BACKENDS.iter().any(|b| (b.recognise)(text).is_some())
        || HEADING_BACKENDS.iter().any(|b| scheme(b.scheme))
        || STORE_BACKENDS.iter().any(|b| scheme(b.scheme))
}

/// The part of a robot that moves: one of the [`registry::DRIVE_BACKENDS`] and its target.
#[derive(Debug, Clone, PartialEq)]
pub struct DriveSpec {
    /// Its backend.
    pub backend: &'static DriveBackend,
    /// Its port or URL, options and settings.
    pub target: DriveTarget,
}

impl FromStr for DriveSpec {
    type Err = SpecError;

    fn from_str(text: &str) -> Result<Self, SpecError> {
        let text = text.trim();
        let recognised = DRIVE_BACKENDS
            .iter()
            .find_map(|&b| (b.recognise)(text).map(|parts| (b, parts)));
        let (backend, parts) = match recognised {
            Some(found) => found,
            None => match DRIVE_BACKENDS.iter().find(|b| b.bare_port) {
                Some(&b) if !other_form(text) => (b, Ok(PortSpec::bare(text))),
                found => {
                    not_built(text, Role::Drive, found.is_none() && !other_form(text))?;
                    let each = DRIVE_BACKENDS
                        .iter()
                        .map(|b| format!("{} ({})", b.form, b.what));
                    let each: Vec<String> = each.collect();
                    return Err(parse_err(
                        text,
                        format!(
                            "not a drive: give {}",
                            forms(each.iter().map(String::as_str))
                        ),
                    ));
                }
            },
        };
        let spec = parts.map_err(|reason| parse_err(text, reason))?;
        (backend.check)(&spec).map_err(|reason| parse_err(text, reason))?;
        Ok(DriveSpec {
            backend,
            target: DriveTarget {
                spec,
                settings: None,
            },
        })
    }
}

impl DriveSpec {
    /// Where it is, for messages (a port or a URL).
    pub fn place(&self) -> String {
        (self.backend.place)(&self.target.spec)
    }

    /// It is a drive of `backend`.
    pub fn is(&self, backend: &DriveBackend) -> bool {
        self.backend == backend
    }

    /// The port and baud rate of the odocal-protocol controller this names, for a command that
    /// talks to one alone (`status`, `params`); refused for another robot.
    #[cfg(feature = "odocal-protocol")]
    pub fn controller_port(&self) -> Result<(String, u32), SpecError> {
        let hal = registry::CONTROLLER;
        if !self.is(hal) {
            return Err(SpecError::Combination(format!(
                "`{}` names {}; this command talks to an odocal-protocol controller: give its port \
                 ({})",
                self.target.spec.port,
                self.backend.what,
                hal.form
            )));
        }
        let spec = &self.target.spec;
        let baud =
            crate::hal::base::baud_of(spec).map_err(|reason| parse_err(&spec.port, reason))?;
        Ok((spec.port.clone(), baud))
    }

    /// **Connects to the drive's controller** alone and reads its status (`odocal status`; it
    /// does not move); refused for a drive without a controller to ask.
    pub async fn status(&self) -> Result<DriveStatus, SpecError> {
        let Some(status) = self.backend.status else {
            let each = DRIVE_BACKENDS.iter().filter(|b| b.status.is_some());
            return Err(SpecError::Combination(format!(
                "`{}` names {}; `odocal status` talks to a motor controller: give its port ({})",
                self.target.spec.port,
                self.backend.what,
                forms(each.map(|b| b.form))
            )));
        };
        status(self.target.clone()).await.map_err(SpecError::Drive)
    }

    /// `baud` (from `--baud` or a routine file) laid under the drive's own options (a `baud=`
    /// in its `text` wins) and checked; refused for a drive that takes no baud rate.
    pub fn with_baud(&mut self, baud: u32, text: &str) -> Result<(), SpecError> {
        if !self.backend.takes_baud() {
            return Err(refused(self.backend, "a baud rate (`baud`, --baud)"));
        }
        self.target.spec.or_option("baud", baud);
        (self.backend.check)(&self.target.spec).map_err(|reason| parse_err(text, reason))
    }
}

/// The sensor of the robot's heading.
#[derive(Debug, Clone, Default, PartialEq)]
pub enum HeadingSpec {
    /// The drive's own (a controller's compass, a ROS robot's IMU).
    #[default]
    Drive,
    /// A sensor on a port of its own, of one of the [`HEADING_BACKENDS`].
    Port {
        /// Its backend.
        backend: &'static HeadingBackend,
        /// The port and options.
        spec: PortSpec,
    },
}

impl FromStr for HeadingSpec {
    type Err = SpecError;

    fn from_str(text: &str) -> Result<Self, SpecError> {
        let text = text.trim();
        if text == "drive" {
            return Ok(HeadingSpec::Drive);
        }
        for &backend in HEADING_BACKENDS {
            if let Some(parts) = PortSpec::parse(text, backend.scheme, backend.options) {
                let spec = parts.map_err(|reason| parse_err(text, reason))?;
                (backend.check)(&spec).map_err(|reason| parse_err(text, reason))?;
                return Ok(HeadingSpec::Port { backend, spec });
            }
        }
        not_built(text, Role::Heading, false)?;
        let forms: Vec<&str> = HEADING_BACKENDS.iter().map(|b| b.form).collect();
        Err(parse_err(
            text,
            format!(
                "not a heading source: give drive (the drive's own) or {}",
                forms.join(" or ")
            ),
        ))
    }
}

impl HeadingSpec {
    /// Opens a heading source that is not the drive's; `None` for [`HeadingSpec::Drive`].
    pub async fn open(&self) -> Result<Option<Arc<dyn HeadingSource>>, SpecError> {
        Ok(match self {
            HeadingSpec::Drive => None,
            HeadingSpec::Port { backend, spec } => Some((backend.open)(spec.clone()).await?),
        })
    }
}

/// A robot: its drive, heading source and store.
#[derive(Debug, Clone, PartialEq)]
pub struct BaseSpec {
    /// The drive.
    pub drive: DriveSpec,
    /// The heading source.
    pub heading: HeadingSpec,
    /// The store.
    pub store: StoreSpec,
    /// What the heading sensor is, when the user says so (else the backend's word).
    pub heading_kind: Option<HeadingKind>,
    /// A compass deviation removed from every reading ([`Adjusted`]).
    pub deviation: Deviation,
}

/// Where a robot is, as a routine file's `[robot]` table (or, in older files, its top-level
/// keys) and the command line give it: every key optional, flags laid over the file
/// ([`RobotSection::over`]), then made a [`BaseSpec`].
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobotSection {
    /// The drive ([`DriveSpec`]'s text form); `port` is the same key.
    #[serde(alias = "port", skip_serializing_if = "Option::is_none")]
    pub drive: Option<String>,
    /// Baud rate of a drive on a serial port, when its text gives none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub baud: Option<u32>,
    /// The heading source ([`HeadingSpec`]'s text form).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heading: Option<String>,
    /// The store ([`StoreSpec`]'s text form).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub store: Option<String>,
    /// A robot profile: the same as `store = "profile:PATH"`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub profile: Option<PathBuf>,
    /// Settings of a ROS robot ([`RosSettings`]; its `url` comes from `drive`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ros: Option<RosSettings>,
    /// What the heading sensor is ([`HeadingKind`]'s name: `magnetic`, `gyro`, `reference`,
    /// `unknown`), when the backend cannot tell.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heading_kind: Option<String>,
    /// A compass deviation to remove from every reading, `"A1,B1,A2,B2"` in degrees (what
    /// `odocal swing` measured; [`Deviation`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub compass_deviation_deg: Option<String>,
}

impl RobotSection {
    /// `self` with every key `flags` sets replaced by the flag's (the ROS table merged by the
    /// caller, who knows which ROS flags were given).
    pub fn over(self, flags: RobotSection) -> RobotSection {
        // The store is one setting with two spellings: a flag's replaces the file's.
        let (store, profile) = if flags.store.is_some() || flags.profile.is_some() {
            (flags.store, flags.profile)
        } else {
            (self.store, self.profile)
        };
        RobotSection {
            drive: flags.drive.or(self.drive),
            baud: flags.baud.or(self.baud),
            heading: flags.heading.or(self.heading),
            store,
            profile,
            ros: flags.ros.or(self.ros),
            heading_kind: flags.heading_kind.or(self.heading_kind),
            compass_deviation_deg: flags.compass_deviation_deg.or(self.compass_deviation_deg),
        }
    }

    /// The robot these keys describe.
    pub fn spec(&self) -> Result<BaseSpec, SpecError> {
        let text = self.drive.as_deref().ok_or_else(|| {
            let based = DRIVE_BACKENDS.iter().filter(|b| !b.bare_port);
            SpecError::Combination(format!(
                "no robot given: a serial port (--port), {} (--base), or `drive` in the routine \
                 file's [robot] table",
                forms(based.map(|b| b.form))
            ))
        })?;
        let mut drive: DriveSpec = text.parse()?;
        let backend = drive.backend;
        if let Some(baud) = self.baud {
            drive.with_baud(baud, text)?;
        }
        drive.target.settings = match (backend.settings, &self.ros) {
            // TOML keeps what the settings hold (an infinite timeout, say) as they were given.
            (Some("ros"), ros) => Some(
                toml::Value::try_from(ros.clone().unwrap_or_default()).map_err(|e| {
                    SpecError::Combination(format!("the ROS settings cannot be kept: {e}"))
                })?,
            ),
            (_, Some(_)) => {
                return Err(refused(
                    backend,
                    "ROS settings (a [robot.ros] or [ros] table, or the ROS flags: --ros-yaml, \
                     --controller, --cmd-vel, the topics, …)",
                ));
            }
            _ => None,
        };
        let heading = match &self.heading {
            Some(h) => h.parse()?,
            None => HeadingSpec::Drive,
        };
        let store = match (&self.store, &self.profile) {
            (Some(_), Some(_)) => {
                return Err(SpecError::Combination(
                    "give the store once: `store = \"profile:PATH\"` or `profile = PATH`".into(),
                ))
            }
            (Some(s), None) => s.parse()?,
            (None, Some(p)) => StoreSpec::profile(p)?,
            (None, None) => StoreSpec::Drive,
        };
        let (kind, deviation) = self.heading_flags()?;
        BaseSpec::new(drive, heading, store)?.with_correction(kind, deviation)
    }

    /// The heading kind and deviation these keys give (none: `None`, no deviation).
    fn heading_flags(&self) -> Result<(Option<HeadingKind>, Deviation), SpecError> {
        let error = |text: &String| {
            let text = text.clone();
            move |reason: String| SpecError::Parse { text, reason }
        };
        let kind = match &self.heading_kind {
            Some(k) => Some(k.parse().map_err(error(k))?),
            None => None,
        };
        let deviation = match &self.compass_deviation_deg {
            Some(d) => d.parse().map_err(error(d))?,
            None => Deviation::default(),
        };
        Ok((kind, deviation))
    }

    /// Opens the heading sensor `text` alone (`nmea:PORT…`, or an odocal-protocol
    /// controller's port at `baud`), with these keys' heading kind and deviation applied, and a
    /// robot profile's saved curve when the keys name a profile and give none: what `odocal
    /// heading` reads without opening the robot.
    pub async fn open_heading_alone(
        &self,
        text: &str,
        baud: u32,
    ) -> Result<Arc<dyn HeadingSource>, SpecError> {
        let source = open_heading(text, baud).await?;
        let (kind, deviation) = self.heading_flags()?;
        let (kind, deviation) = with_profile(kind, deviation, self.profile.as_deref())?;
        Ok(Adjusted::wrap(source, kind, deviation))
    }
}

/// A heading kind and deviation given (by flags or keys), completed by what the robot profile
/// at `profile` keeps in its `[heading]` table: its kind when none was given, its curve when no
/// deviation was.
fn with_profile(
    kind: Option<HeadingKind>,
    deviation: Deviation,
    profile: Option<&std::path::Path>,
) -> Result<(Option<HeadingKind>, Deviation), SpecError> {
    let Some(path) = profile else {
        return Ok((kind, deviation));
    };
    #[cfg(not(feature = "roboclaw"))]
    return Err(crate::features::NotBuilt::new(
        format!("the robot profile {}", path.display()),
        &["roboclaw"],
    )
    .into());
    #[cfg(feature = "roboclaw")]
    {
        let section = crate::roboclaw::profile::Profile::load(path)?.heading;
        let deviation = if deviation.is_zero() {
            section.deviation()
        } else {
            deviation
        };
        Ok((kind.or(section.kind), deviation))
    }
}

impl BaseSpec {
    /// The robot profile a compass swing keeps its curve in (`swing --save`): only a profile
    /// store keeps one; other robots take the printed curve as a flag.
    pub fn profile_for_curve(&self) -> Result<&Path, SpecError> {
        self.store.profile_path().ok_or_else(|| {
            SpecError::Combination(
                "--save keeps the curve in a robot profile: give --profile (for other robots, \
                 pass the printed --compass-deviation-deg)"
                    .into(),
            )
        })
    }

    /// **Rewrites the robot profile** ([`Self::profile_for_curve`]) with the curve a swing
    /// keeps (what was already removed and what it found; the kind of a magnetic `heading`),
    /// through the write service (backed up beside it first): the outcome, saying where.
    pub async fn save_curve(
        &self,
        heading: HeadingKind,
        mut outcome: crate::routine::swing::SwingOutcome,
    ) -> Result<crate::routine::swing::SwingOutcome, SpecError> {
        let path = self.profile_for_curve()?;
        #[cfg(feature = "roboclaw")]
        {
            use crate::roboclaw::profile::{save_heading, HeadingSection};
            let section = HeadingSection::of_swing(heading, outcome.total_deg());
            let backup = save_heading(path, &section).await?;
            outcome.saved = Some((path.to_path_buf(), backup));
            Ok(outcome)
        }
        // (Without `roboclaw` there is no profile store, so `profile_for_curve` refused
        // above; this says the same should one come another way.)
        #[cfg(not(feature = "roboclaw"))]
        {
            let _ = (heading, &mut outcome);
            let what = format!("--save {}", path.display());
            Err(crate::features::NotBuilt::new(what, &["roboclaw"]).into())
        }
    }

    /// A robot of these parts, checked to make one by what the drive brings
    /// ([`DriveBackend::heading`], [`DriveBackend::store`]): a drive without a heading sensor
    /// needs one, a drive that keeps no parameters needs its profile, a drive that keeps its
    /// own takes no other store, a drive whose sensor is fixed takes no other; and the drive
    /// has what it needs to open ([`DriveBackend::ready`]).
    pub fn new(
        drive: DriveSpec,
        heading: HeadingSpec,
        store: StoreSpec,
    ) -> Result<Self, SpecError> {
        let backend = drive.backend;
        let what = backend.what;
        if backend.store == StorePart::Profile && store.profile_path().is_none() {
            return Err(SpecError::Combination(format!(
                "{what} keeps no geometry: give its robot profile (--profile robot.toml)"
            )));
        }
        match (backend.heading, &heading) {
            (HeadingPart::Needed, HeadingSpec::Drive) => {
                let needed = format!("a heading source for {what}");
                if let Some(e) =
                    registry::role_not_built(registry::OPTIONAL, Role::Heading, &needed)
                {
                    return Err(e.into());
                }
                let each = forms(HEADING_BACKENDS.iter().map(|b| b.form));
                return Err(SpecError::Combination(format!(
                    "{what} has no heading sensor: give one (--heading {each})"
                )));
            }
            (HeadingPart::OwnOnly, HeadingSpec::Port { .. }) => {
                return Err(refused(backend, "a heading source (`heading`, --heading)"));
            }
            _ => {}
        }
        if let (StorePart::Own, StoreSpec::Located(location)) = (backend.store, &store) {
            return Err(SpecError::Combination(format!(
                "{what} keeps its own parameters; a store of its own ({location}) is for a drive \
                 that keeps none ({})",
                store::profile_drives()
            )));
        }
        (backend.ready)(&drive.target).map_err(SpecError::Combination)?;
        Ok(BaseSpec {
            drive,
            heading,
            store,
            heading_kind: None,
            deviation: Deviation::default(),
        })
    }

    /// This robot with what its heading sensor is and a deviation to remove from its readings
    /// (a flag's, a routine file's), refused by a drive whose sensor takes neither
    /// ([`HeadingPart::OwnOnly`]).
    pub fn with_correction(
        self,
        heading_kind: Option<HeadingKind>,
        deviation: Deviation,
    ) -> Result<Self, SpecError> {
        if self.drive.backend.heading == HeadingPart::OwnOnly {
            if heading_kind.is_some() {
                let what = "a heading kind (`heading_kind`, --heading-kind)";
                return Err(refused(self.drive.backend, what));
            }
            if !deviation.is_zero() {
                let what = "a compass deviation (`compass_deviation_deg`, --compass-deviation-deg)";
                return Err(refused(self.drive.backend, what));
            }
        }
        Ok(BaseSpec {
            heading_kind,
            deviation,
            ..self
        })
    }

    /// Where the robot is, for messages.
    pub fn place(&self) -> String {
        self.drive.place()
    }

    /// What the heading sensor is and the deviation removed from its readings: the spec's
    /// (a flag's), else the robot profile's (a swing saved there).
    pub fn heading_correction(&self) -> Result<(Option<HeadingKind>, Deviation), SpecError> {
        with_profile(self.heading_kind, self.deviation, self.store.profile_path())
    }

    /// **Connects to the robot** (it does not move): opens the heading source when it is not
    /// the drive's, then the drive through its backend (with that heading source and the
    /// robot profile, for a drive that needs them), and composes the [`Base`].
    pub async fn open(&self) -> Result<Base, SpecError> {
        let own_heading = self.heading.open().await?;
        let (heading_kind, deviation) = self.heading_correction()?;
        let how = DriveOpen {
            target: self.drive.target.clone(),
            heading: own_heading.clone(),
            profile: self.store.profile_path().map(Path::to_path_buf),
        };
        let mut base = (self.drive.backend.open)(how)
            .await
            .map_err(SpecError::Drive)?;
        if let Some(heading) = own_heading {
            base.heading = heading;
        }
        base.heading = Adjusted::wrap(base.heading.clone(), heading_kind, deviation);
        Ok(base)
    }
}

/// Opens a heading source alone, from a heading spec (`nmea:PORT…`) or a drive spec whose
/// drive has a heading sensor (an odocal-protocol port): for `odocal heading`.
pub async fn open_heading(text: &str, baud: u32) -> Result<Arc<dyn HeadingSource>, SpecError> {
    match text.parse::<HeadingSpec>() {
        Ok(h) => {
            if let Some(source) = h.open().await? {
                return Ok(source);
            }
        }
        Err(e @ SpecError::NotBuilt(_)) => return Err(e),
        Err(_) => {}
    }
    let forms: Vec<&str> = HEADING_BACKENDS.iter().map(|b| b.form).collect();
    let hint = format!(
        "give {} or the port of an odocal-protocol controller",
        forms.join(" or ")
    );
    #[cfg(feature = "odocal-protocol")]
    return Ok(Arc::new(open_controller(text, baud, &hint).await?));
    #[cfg(not(feature = "odocal-protocol"))]
    {
        // The drive spec's own refusal names the feature a controller's port needs.
        let _ = baud;
        text.parse::<DriveSpec>()?;
        Err(parse_err(text, hint))
    }
}

/// An odocal-protocol controller named by a drive spec (its `baud=` over `baud`), or an error
/// with `hint` for any other drive.
#[cfg(feature = "odocal-protocol")]
async fn open_controller(
    text: &str,
    baud: u32,
    hint: &str,
) -> Result<crate::hal::Client, SpecError> {
    let mut drive = text.parse::<DriveSpec>()?;
    if !drive.is(registry::CONTROLLER) {
        return Err(parse_err(text, hint));
    }
    drive.target.spec.or_option("baud", baud);
    let baud = drive
        .target
        .spec
        .option("baud", baud)
        .map_err(|reason| parse_err(text, reason))?;
    Ok(crate::hal::open_port(&drive.target.spec.port, baud)
        .await?
        .0)
}

#[cfg(test)]
#[cfg(all(feature = "odocal-protocol", feature = "ros", feature = "roboclaw"))]
#[cfg(all(feature = "nmea", feature = "mock"))]
mod tests {
    use super::*;
    use crate::ros::live::RosBaseConfig;

    /// A drive of `backend` at `port` with `options`, as parsed (no settings).
    fn drive(backend: &'static DriveBackend, port: &str, options: &[(&str, &str)]) -> DriveSpec {
        let mut spec = PortSpec::bare(port);
        for (k, v) in options {
            spec.or_option(k, v);
        }
        DriveSpec {
            backend,
            target: DriveTarget {
                spec,
                settings: None,
            },
        }
    }

    #[test]
    fn the_default_baud_is_the_controllers() {
        // Written as a number so the core has it without the protocol crate.
        assert_eq!(ODOCAL_BAUD, crate::hal::DEFAULT_BAUD);
    }

    #[test]
    fn specs_parse_from_their_text_forms() {
        assert_eq!(
            "/dev/ttyUSB0".parse::<DriveSpec>().unwrap(),
            drive(&crate::hal::base::DRIVE_BACKEND, "/dev/ttyUSB0", &[])
        );
        assert_eq!(
            "odocal:/dev/ttyUSB0?baud=9600"
                .parse::<DriveSpec>()
                .unwrap(),
            drive(
                &crate::hal::base::DRIVE_BACKEND,
                "/dev/ttyUSB0",
                &[("baud", "9600")]
            )
        );
        let claw = "roboclaw:/dev/ttyACM0?address=129&baud=115200"
            .parse::<DriveSpec>()
            .unwrap();
        assert_eq!(
            claw,
            drive(
                &crate::roboclaw::DRIVE_BACKEND,
                "/dev/ttyACM0",
                &[("address", "129"), ("baud", "115200")]
            )
        );
        let cfg = crate::roboclaw::config_of(&claw.target.spec).unwrap();
        assert_eq!((cfg.address, cfg.baud), (129, 115_200));
        let ros = "rosbridge://localhost:9090".parse::<DriveSpec>().unwrap();
        assert!(ros.is(&crate::ros::live::DRIVE_BACKEND));
        assert_eq!(ros.place(), "rosbridge://localhost:9090");
        assert!("mock"
            .parse::<DriveSpec>()
            .unwrap()
            .is(&registry::SIMULATED));
        match "nmea:/dev/ttyUSB1?baud=9600"
            .parse::<HeadingSpec>()
            .unwrap()
        {
            HeadingSpec::Port { backend, spec } => {
                assert_eq!(backend.scheme, "nmea");
                assert_eq!(spec.port, "/dev/ttyUSB1");
                assert_eq!(spec.option("baud", 0u32), Ok(9600));
            }
            other => panic!("{other:?}"),
        }
        for bad in [
            "roboclaw:",
            "roboclaw:/dev/x?speed=3",
            "roboclaw:/dev/x?address=999",
            "odocal:/dev/x?baud=fast",
            "nmea:/dev/x",
            "profile:r.toml",
            "http://h:1",
            "",
        ] {
            let e = bad.parse::<DriveSpec>().unwrap_err().to_string();
            assert!(e.starts_with(&format!("{bad:?}")), "{e}");
        }
        let e = "nmea:/dev/x".parse::<DriveSpec>().unwrap_err().to_string();
        for backend in DRIVE_BACKENDS {
            assert!(e.contains(backend.form), "{e}");
        }
        assert!("nmea:/dev/x?baud=fast".parse::<HeadingSpec>().is_err());
        assert!("/dev/ttyUSB0".parse::<HeadingSpec>().is_err());
    }

    #[test]
    fn every_listed_drive_backend_is_reached_by_its_own_form() {
        for &backend in DRIVE_BACKENDS {
            let form = backend.form.rsplit(" or ").next().unwrap_or(backend.form);
            let text = form
                .replace(['[', ']'], "")
                .replace("PORT", "/dev/x")
                .replace("HOST:/dev/x", "localhost:9090");
            let got: DriveSpec = text.parse().unwrap_or_else(|e| panic!("{text}: {e}"));
            assert!(got.is(backend), "{text}: {}", got.backend.name);
        }
    }

    #[test]
    fn every_listed_heading_backend_is_reached_by_its_own_form() {
        for backend in HEADING_BACKENDS {
            let text = backend
                .form
                .replace("PORT", "/dev/x")
                .replace(['[', ']'], "");
            match text.parse::<HeadingSpec>() {
                Ok(HeadingSpec::Port { backend: b, spec }) => {
                    assert_eq!(b.scheme, backend.scheme);
                    assert_eq!(spec.port, "/dev/x");
                }
                other => panic!("{text}: {other:?}"),
            }
            // Its scheme is not taken for a drive.
            assert!(text.parse::<DriveSpec>().is_err(), "{text}");
        }
    }

    #[test]
    fn parts_that_make_no_robot_are_refused_before_anything_opens() {
        let section = |drive: &str, heading: Option<&str>, profile: Option<&str>| RobotSection {
            drive: Some(drive.into()),
            heading: heading.map(String::from),
            profile: profile.map(PathBuf::from),
            ..RobotSection::default()
        };
        let e = section("roboclaw:/dev/x", Some("nmea:/dev/y"), None)
            .spec()
            .unwrap_err()
            .to_string();
        assert!(e.contains("--profile"), "{e}");
        let e = section("roboclaw:/dev/x", None, Some("r.toml"))
            .spec()
            .unwrap_err()
            .to_string();
        assert!(e.contains("--heading"), "{e}");
        let e = section("/dev/x", None, Some("r.toml"))
            .spec()
            .unwrap_err()
            .to_string();
        assert!(e.contains("keeps its own parameters"), "{e}");
        let e = section("rosbridge://h:1", None, None)
            .spec()
            .unwrap_err()
            .to_string();
        assert!(e.contains("--ros-yaml"), "{e}");
        // Any drive with any heading source: our protocol with a compass.
        let s = section("/dev/x", Some("nmea:/dev/y"), None).spec().unwrap();
        assert!(matches!(s.heading, HeadingSpec::Port { backend, .. } if backend.scheme == "nmea"));
        // Flags over the file.
        let file = RobotSection {
            drive: Some("/dev/a".into()),
            baud: Some(57_600),
            ..RobotSection::default()
        };
        let merged = file.over(RobotSection {
            drive: Some("/dev/b".into()),
            ..RobotSection::default()
        });
        let drive = merged.spec().unwrap().drive;
        assert!(drive.is(&crate::hal::base::DRIVE_BACKEND));
        assert_eq!(drive.target.spec.port, "/dev/b");
        assert_eq!(drive.target.spec.option("baud", 0u32), Ok(57_600));
        // The text's own baud rate over the key's.
        let own = RobotSection {
            drive: Some("odocal:/dev/c?baud=9600".into()),
            baud: Some(57_600),
            ..RobotSection::default()
        };
        let drive = own.spec().unwrap().drive;
        assert_eq!(drive.target.spec.option("baud", 0u32), Ok(9_600));
    }

    #[test]
    fn the_simulated_robot_refuses_by_name_what_it_cannot_honour() {
        let mock = |section: RobotSection| {
            RobotSection {
                drive: Some("mock".into()),
                ..section
            }
            .spec()
        };
        assert!(mock(RobotSection::default()).is_ok());
        for (section, named) in [
            (
                RobotSection {
                    heading: Some("nmea:/dev/y".into()),
                    ..RobotSection::default()
                },
                "a heading source",
            ),
            (
                RobotSection {
                    profile: Some("r.toml".into()),
                    ..RobotSection::default()
                },
                "keeps its own parameters",
            ),
            (
                RobotSection {
                    store: Some("profile:r.toml".into()),
                    ..RobotSection::default()
                },
                "keeps its own parameters",
            ),
            (
                RobotSection {
                    heading_kind: Some("gyro".into()),
                    ..RobotSection::default()
                },
                "a heading kind",
            ),
            (
                RobotSection {
                    compass_deviation_deg: Some("1,0,0,0".into()),
                    ..RobotSection::default()
                },
                "a compass deviation",
            ),
            (
                RobotSection {
                    baud: Some(9600),
                    ..RobotSection::default()
                },
                "a baud rate",
            ),
            (
                RobotSection {
                    ros: Some(RosBaseConfig::default()),
                    ..RobotSection::default()
                },
                "ROS settings",
            ),
        ] {
            let e = mock(section).unwrap_err().to_string();
            assert!(e.starts_with("the built-in simulated robot"), "{e}");
            assert!(e.contains(named), "{named}: {e}");
        }
        // A zero deviation is no deviation: nothing to refuse.
        let zero = RobotSection {
            compass_deviation_deg: Some("0,0,0,0".into()),
            ..RobotSection::default()
        };
        assert!(mock(zero).is_ok());
    }

    #[test]
    fn baud_rates_and_settings_go_only_to_drives_that_take_them() {
        let section = |drive: &str, baud: Option<u32>, ros: bool| RobotSection {
            drive: Some(drive.into()),
            baud,
            heading: Some("nmea:/dev/y".into()),
            profile: drive.starts_with("roboclaw").then(|| "r.toml".into()),
            ros: ros.then(|| RosBaseConfig {
                yaml: "c.yaml".into(),
                // What a routine file may hold, kept as given (the connection clamps it).
                first_message_timeout_s: f64::INFINITY,
                left_joint: Some("wheel_l".into()),
                ..RosBaseConfig::default()
            }),
            ..RobotSection::default()
        };
        // A RoboClaw takes --baud as an odocal controller does.
        let claw = section("roboclaw:/dev/x", Some(115_200), false)
            .spec()
            .unwrap();
        assert_eq!(claw.drive.target.spec.option("baud", 0u32), Ok(115_200));
        let e = section("rosbridge://h:1", Some(9600), true)
            .spec()
            .unwrap_err()
            .to_string();
        assert!(e.contains("a ROS robot does not take a baud rate"), "{e}");
        let e = section("/dev/x", None, true)
            .spec()
            .unwrap_err()
            .to_string();
        assert!(e.contains("does not take ROS settings"), "{e}");
        let ros = section("rosbridge://h:1", None, true).spec().unwrap();
        let cfg = crate::ros::live::config_of(&ros.drive.target).unwrap();
        assert_eq!(
            (cfg.url.as_str(), cfg.yaml.as_path()),
            ("rosbridge://h:1", Path::new("c.yaml"))
        );
        assert_eq!(cfg.first_message_timeout_s, f64::INFINITY);
        // Settings of the wrong type are refused before anything connects, naming them.
        let mut bad = ros.drive.target.clone();
        bad.settings = Some(toml::toml! { first_message_timeout_s = "soon" }.into());
        let e = (crate::ros::live::DRIVE_BACKEND.ready)(&bad).unwrap_err();
        assert!(
            e.contains("the ROS settings ([robot.ros]) cannot be read"),
            "{e}"
        );
        assert_eq!(
            (cfg.left_joint.as_deref(), cfg.right_joint),
            (Some("wheel_l"), None)
        );
        // A robot's store is its own or a profile: a bare file name is neither.
        let e = RobotSection {
            store: Some("robot.toml".into()),
            profile: None,
            ..section("roboclaw:/dev/x", None, false)
        };
        let e = e.spec().unwrap_err().to_string();
        assert!(e.contains("not a parameter store: give drive"), "{e}");
        assert!(e.contains("profile:PATH"), "{e}");
    }

    /// `odocal status` of a drive without a controller to ask (the simulator, a ROS robot) is
    /// refused before anything connects, naming the drives that have one.
    #[tokio::test]
    async fn status_of_a_drive_without_a_controller_is_refused_by_name() {
        for text in ["mock", "rosbridge://127.0.0.1:9"] {
            let drive: DriveSpec = text.parse().unwrap();
            match drive.status().await {
                Err(SpecError::Combination(e)) => {
                    assert!(
                        e.contains("`odocal status` talks to a motor controller"),
                        "{e}"
                    );
                    assert!(e.contains("roboclaw:PORT"), "{e}");
                }
                Err(other) => panic!("{text}: another error: {other}"),
                Ok(_) => panic!("{text}: a status without a controller"),
            }
        }
    }
}
