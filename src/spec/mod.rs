//! Where a robot is: typed specs of its drive, its heading source and its parameter store,
//! parsed from the command line or a routine file's `[robot]` table, each opened by
//! [`BaseSpec::open`] into a [`Base`].
//!
//! Any drive combines with any heading source: a controller of our protocol with a separate
//! compass, a ROS robot whose IMU is poor with an NMEA compass, a RoboClaw (which has no
//! heading sensor) with a compass. This file is the one place the backends are listed: a new
//! heading source is its module (exporting a [`HeadingBackend`]) plus one line in
//! [`HEADING_BACKENDS`]; its text form, options and opening come from there.
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
pub mod restore_target;

use crate::base::adjusted::Adjusted;
use crate::base::heading_backend::{HeadingBackend, PortSpec};
use crate::base::transaction::{BackupError, BackupFile};
use crate::base::{Base, BaseError, HeadingKind, HeadingSource, ParamFile, ParamStore};
use crate::hal::HalError;
use crate::kinematics::Deviation;
use crate::roboclaw::client::{RoboClaw, RoboClawConfig, RoboClawError};
use crate::roboclaw::profile::{ProfileError, ProfileFile, ProfileStore};
use crate::ros::live::{RosBaseConfig, RosBaseError};
use crate::ros::yaml::{YamlError, YamlStore};
use crate::routine::config::{key_line, parse_table, table_error, ConfigError, RoutineConfig};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::Arc;

/// Baud rate of odocal's protocol unless configured (SPEC.md §1).
pub const ODOCAL_BAUD: u32 = crate::hal::DEFAULT_BAUD;
/// Baud rate of a RoboClaw unless configured.
pub const ROBOCLAW_BAUD: u32 = 38_400;
/// Packet serial address of a RoboClaw unless configured.
pub const ROBOCLAW_ADDRESS: u8 = 0x80;

/// The heading sources on ports of their own, by scheme: a new one is its module plus one
/// line here.
pub const HEADING_BACKENDS: &[&HeadingBackend] = &[&crate::nmea::HEADING_BACKEND];

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
    #[error(transparent)]
    Odocal(#[from] HalError),
    /// A ROS robot could not be reached.
    #[error(transparent)]
    Ros(#[from] RosBaseError),
    /// A RoboClaw could not be opened.
    #[error(transparent)]
    RoboClaw(#[from] RoboClawError),
    /// A robot profile could not be read.
    #[error(transparent)]
    Profile(#[from] ProfileError),
    /// A controller's YAML could not be read.
    #[error(transparent)]
    Yaml(#[from] YamlError),
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

/// `scheme:PATH?k=v&k=v` split into the path and its options; `None` when the text does not
/// start with `scheme:`.
fn scheme_parts(text: &str, scheme: &str, allowed: &[&str]) -> Option<Result<PortSpec, SpecError>> {
    let rest = text.strip_prefix(scheme)?.strip_prefix(':')?;
    Some((|| {
        let (path, query) = rest.split_once('?').unwrap_or((rest, ""));
        if path.is_empty() {
            return Err(parse_err(text, format!("no port (expected {scheme}:PORT)")));
        }
        let mut options = BTreeMap::new();
        for kv in query.split('&').filter(|s| !s.is_empty()) {
            let (k, v) = kv
                .split_once('=')
                .ok_or_else(|| parse_err(text, format!("option {kv:?} is not key=value")))?;
            if !allowed.contains(&k) {
                return Err(parse_err(
                    text,
                    format!("unknown option {k} (options: {})", allowed.join(", ")),
                ));
            }
            options.insert(k.to_string(), v.to_string());
        }
        Ok(PortSpec {
            port: path.to_string(),
            options,
        })
    })())
}

fn option<T: FromStr>(text: &str, spec: &PortSpec, key: &str, default: T) -> Result<T, SpecError> {
    spec.option(key, default)
        .map_err(|reason| parse_err(text, reason))
}

/// The part of a robot that moves.
#[derive(Debug, Clone, PartialEq)]
pub enum DriveSpec {
    /// A controller that speaks odocal's protocol on a serial port: drive, heading source and
    /// store at once.
    Odocal {
        /// The port.
        port: String,
        /// Its baud rate.
        baud: u32,
    },
    /// A ROS robot through rosbridge: drive, its IMU as heading source, the controller's YAML
    /// as store.
    Rosbridge(Box<RosBaseConfig>),
    /// A RoboClaw on a serial port: a drive only, whose geometry and wiring are in a robot
    /// profile ([`StoreSpec::Profile`]); it has no heading sensor.
    RoboClaw {
        /// The port.
        port: String,
        /// Packet serial address.
        address: u8,
        /// Baud rate.
        baud: u32,
    },
    /// The built-in simulated robot (opened by the demo, not by [`BaseSpec::open`]).
    Simulated,
}

impl FromStr for DriveSpec {
    type Err = SpecError;

    fn from_str(text: &str) -> Result<Self, SpecError> {
        let text = text.trim();
        if text == "mock" {
            return Ok(DriveSpec::Simulated);
        }
        if text.starts_with("rosbridge://") || text.starts_with("ws://") {
            return Ok(DriveSpec::Rosbridge(Box::new(RosBaseConfig {
                url: text.into(),
                ..RosBaseConfig::default()
            })));
        }
        if let Some(parts) = scheme_parts(text, "roboclaw", &["address", "baud"]) {
            let spec = parts?;
            return Ok(DriveSpec::RoboClaw {
                address: option(text, &spec, "address", ROBOCLAW_ADDRESS)?,
                baud: option(text, &spec, "baud", ROBOCLAW_BAUD)?,
                port: spec.port,
            });
        }
        if let Some(parts) = scheme_parts(text, "odocal", &["baud"]) {
            let spec = parts?;
            return Ok(DriveSpec::Odocal {
                baud: option(text, &spec, "baud", ODOCAL_BAUD)?,
                port: spec.port,
            });
        }
        let heading_scheme = HEADING_BACKENDS
            .iter()
            .any(|b| text.starts_with(&format!("{}:", b.scheme)));
        if text.is_empty() || text.contains("://") || heading_scheme {
            return Err(parse_err(
                text,
                "not a drive: give a serial port of an odocal-protocol controller, \
                 rosbridge://HOST:PORT, roboclaw:PORT[?address=128&baud=38400] or mock",
            ));
        }
        Ok(DriveSpec::Odocal {
            port: text.into(),
            baud: ODOCAL_BAUD,
        })
    }
}

impl DriveSpec {
    /// Where it is, for messages (a port or a URL).
    pub fn place(&self) -> String {
        match self {
            DriveSpec::Odocal { port, .. } | DriveSpec::RoboClaw { port, .. } => port.clone(),
            DriveSpec::Rosbridge(c) => c.url.clone(),
            DriveSpec::Simulated => "the built-in simulated robot".into(),
        }
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
            if let Some(parts) = scheme_parts(text, backend.scheme, backend.options) {
                let spec = parts?;
                (backend.check)(&spec).map_err(|reason| parse_err(text, reason))?;
                return Ok(HeadingSpec::Port { backend, spec });
            }
        }
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

/// Where the parameters live.
#[derive(Debug, Clone, Default, PartialEq)]
pub enum StoreSpec {
    /// The drive's own (a controller's memory, a ROS robot's YAML).
    #[default]
    Drive,
    /// A robot profile, for a drive that keeps no parameters of its own (a RoboClaw).
    Profile(PathBuf),
}

impl FromStr for StoreSpec {
    type Err = SpecError;

    fn from_str(text: &str) -> Result<Self, SpecError> {
        let text = text.trim();
        if text == "drive" {
            return Ok(StoreSpec::Drive);
        }
        match text.strip_prefix("profile:") {
            Some(path) if !path.is_empty() => Ok(StoreSpec::Profile(path.into())),
            _ => Err(parse_err(
                text,
                "not a parameter store: give drive (the drive's own) or profile:PATH",
            )),
        }
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
    /// Baud rate of an odocal-protocol controller.
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
    /// Settings of a ROS robot ([`RosBaseConfig`]; its `url` comes from `drive`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ros: Option<RosBaseConfig>,
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
            SpecError::Combination(
                "no robot given: a serial port (--port), rosbridge://HOST:PORT or \
                 roboclaw:PORT (--base), or `drive` in the routine file's [robot] table"
                    .into(),
            )
        })?;
        let mut drive: DriveSpec = text.parse()?;
        match &mut drive {
            DriveSpec::Odocal { baud, .. } if !text.contains("baud=") => {
                *baud = self.baud.unwrap_or(ODOCAL_BAUD);
            }
            DriveSpec::Rosbridge(cfg) => {
                let url = cfg.url.clone();
                **cfg = RosBaseConfig {
                    url,
                    ..self.ros.clone().unwrap_or_default()
                };
            }
            _ => {}
        }
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
            (None, Some(p)) => StoreSpec::Profile(p.clone()),
            (None, None) => StoreSpec::Drive,
        };
        let mut spec = BaseSpec::new(drive, heading, store)?;
        (spec.heading_kind, spec.deviation) = self.heading_flags()?;
        Ok(spec)
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
    let section = crate::roboclaw::profile::Profile::load(path)?.heading;
    let deviation = if deviation.is_zero() {
        section.deviation()
    } else {
        deviation
    };
    Ok((kind.or(section.kind), deviation))
}

impl BaseSpec {
    /// The robot profile a compass swing keeps its curve in (`swing --save`): only a profile
    /// store keeps one; other robots take the printed curve as a flag.
    pub fn profile_for_curve(&self) -> Result<&Path, SpecError> {
        match &self.store {
            StoreSpec::Profile(path) => Ok(path),
            _ => Err(SpecError::Combination(
                "--save keeps the curve in a robot profile: give --profile (for other robots, \
                 pass the printed --compass-deviation-deg)"
                    .into(),
            )),
        }
    }

    /// A robot of these parts, checked to make one: a RoboClaw needs a profile and a heading
    /// source of its own; a drive that keeps its parameters takes no profile.
    pub fn new(
        drive: DriveSpec,
        heading: HeadingSpec,
        store: StoreSpec,
    ) -> Result<Self, SpecError> {
        match (&drive, &heading, &store) {
            (DriveSpec::RoboClaw { .. }, _, StoreSpec::Drive) => Err(SpecError::Combination(
                "a RoboClaw keeps no geometry: give its robot profile (--profile robot.toml)"
                    .into(),
            )),
            (DriveSpec::RoboClaw { .. }, HeadingSpec::Drive, _) => Err(SpecError::Combination(
                "a RoboClaw has no heading sensor: give one (--heading nmea:PORT)".into(),
            )),
            (DriveSpec::RoboClaw { .. }, _, StoreSpec::Profile(_)) => Ok(()),
            (_, _, StoreSpec::Profile(p)) => Err(SpecError::Combination(format!(
                "this drive keeps its own parameters; a robot profile ({}) is for a drive that \
                 keeps none (a RoboClaw)",
                p.display()
            ))),
            (DriveSpec::Rosbridge(cfg), _, _) if cfg.yaml.as_os_str().is_empty() => {
                Err(SpecError::Combination(
                    "a ROS robot needs the controller's ros2_control YAML (--ros-yaml, or \
                     `yaml` in the routine file's [robot.ros] table)"
                        .into(),
                ))
            }
            _ => Ok(()),
        }?;
        Ok(BaseSpec {
            drive,
            heading,
            store,
            heading_kind: None,
            deviation: Deviation::default(),
        })
    }

    /// Where the robot is, for messages.
    pub fn place(&self) -> String {
        self.drive.place()
    }

    /// What the heading sensor is and the deviation removed from its readings: the spec's
    /// (a flag's), else the robot profile's (a swing saved there).
    pub fn heading_correction(&self) -> Result<(Option<HeadingKind>, Deviation), SpecError> {
        let profile = match &self.store {
            StoreSpec::Profile(path) => Some(path.as_path()),
            StoreSpec::Drive => None,
        };
        with_profile(self.heading_kind, self.deviation, profile)
    }

    /// **Connects to the robot** (it does not move): opens the drive, and the heading source
    /// and store when they are not the drive's, and composes the [`Base`].
    pub async fn open(&self) -> Result<Base, SpecError> {
        let own_heading = self.heading.open().await?;
        let (heading_kind, deviation) = self.heading_correction()?;
        let mut base =
            match &self.drive {
                DriveSpec::Odocal { port, baud } => {
                    let (client, _) = crate::hal::open_port(port, *baud).await?;
                    // A device that resets or is re-plugged mid-run is reopened to restore the
                    // backup.
                    let reconnect =
                        crate::hal::base::reconnect_port(client.clone(), port.clone(), *baud);
                    Base::single(client).with_reconnect(reconnect)
                }
                DriveSpec::Rosbridge(cfg) => crate::ros::live::connect(cfg).await?,
                DriveSpec::RoboClaw {
                    port,
                    address,
                    baud,
                } => {
                    let StoreSpec::Profile(path) = &self.store else {
                        return Err(SpecError::Combination("a RoboClaw needs a profile".into()));
                    };
                    let Some(heading) = own_heading.clone() else {
                        return Err(SpecError::Combination(
                            "a RoboClaw needs a heading source".into(),
                        ));
                    };
                    let claw = RoboClaw::open(
                        port,
                        RoboClawConfig {
                            address: *address,
                            baud: *baud,
                            ..RoboClawConfig::default()
                        },
                    )?;
                    crate::roboclaw::base(claw, heading, ProfileStore::open(path)?).await?
                }
                DriveSpec::Simulated => return Err(SpecError::Combination(
                    "the built-in simulated robot is opened by `odocal demo` or a routine file \
                     with drive = \"mock\""
                        .into(),
                )),
            };
        if let Some(heading) = own_heading {
            base.heading = heading;
        }
        base.heading = Adjusted::wrap(base.heading.clone(), heading_kind, deviation);
        Ok(base)
    }
}

/// A routine file: where the robot is, and the procedure ([`RoutineConfig`]).
///
/// ```toml
/// [robot]
/// drive = "roboclaw:/dev/ttyACM0?address=128"
/// heading = "nmea:/dev/ttyUSB1?baud=4800"
/// profile = "robot.toml"
///
/// side_m = 2.0   # … the procedure's keys, at the top
/// ```
///
/// Older files give the robot's keys at the top (`port`, `baud`, `heading`, `profile`, and a
/// `[ros]` table); they mean the same.
#[derive(Debug, Clone, PartialEq)]
pub struct RoutineFile {
    /// Where the robot is (any key may be missing: flags fill them in).
    pub robot: RobotSection,
    /// The procedure.
    pub routine: RoutineConfig,
}

/// The robot's keys an older routine file gives at the top.
const TOP_LEVEL_ROBOT_KEYS: [&str; 5] = ["port", "baud", "heading", "profile", "ros"];

impl RoutineFile {
    /// Reads the routine file at `path`; an error names the file (and the line).
    pub fn load(path: &Path) -> Result<Self, SpecError> {
        let text = crate::io::read_bounded(path, crate::io::MAX_TEXT_FILE).map_err(|source| {
            SpecError::RoutineUnreadable {
                path: path.to_path_buf(),
                source,
            }
        })?;
        RoutineFile::from_toml(&text).map_err(|source| SpecError::RoutineFile {
            path: path.to_path_buf(),
            source,
        })
    }

    /// Parses a routine file; errors name the line.
    pub fn from_toml(text: &str) -> Result<Self, ConfigError> {
        let mut table = parse_table(text)?;
        let mut robot = match table.remove("robot") {
            Some(toml::Value::Table(t)) => t,
            Some(_) => {
                return Err(ConfigError {
                    line: key_line(text, "robot"),
                    message: "robot: must be a table ([robot])".into(),
                })
            }
            None => toml::Table::new(),
        };
        for key in TOP_LEVEL_ROBOT_KEYS {
            if let Some(v) = table.remove(key) {
                let name = if key == "port" { "drive" } else { key };
                if robot.contains_key(name) || (key == "port" && robot.contains_key("port")) {
                    return Err(ConfigError {
                        line: key_line(text, key),
                        message: format!("{key}: given twice (at the top and in [robot])"),
                    });
                }
                robot.insert(key.into(), v);
            }
        }
        let robot: RobotSection = robot.try_into().map_err(|e| table_error(&e, text))?;
        Ok(RoutineFile {
            robot,
            routine: RoutineConfig::from_table(table, text)?,
        })
    }
}

/// Opens a heading source alone, from a heading spec (`nmea:PORT…`) or a drive spec whose
/// drive has a heading sensor (an odocal-protocol port): for `odocal heading`.
pub async fn open_heading(text: &str, baud: u32) -> Result<Arc<dyn HeadingSource>, SpecError> {
    if let Ok(h) = text.parse::<HeadingSpec>() {
        if let Some(source) = h.open().await? {
            return Ok(source);
        }
    }
    let forms: Vec<&str> = HEADING_BACKENDS.iter().map(|b| b.form).collect();
    let hint = format!(
        "give {} or the port of an odocal-protocol controller",
        forms.join(" or ")
    );
    Ok(Arc::new(open_controller(text, baud, &hint).await?))
}

/// Opens a parameter store alone: an odocal-protocol controller's port, or a file store
/// (`profile:PATH`, `ros-yaml:PATH?controller=NAME`); see [`StoreLocation`].
pub async fn open_store(text: &str, baud: u32) -> Result<Arc<dyn ParamStore>, SpecError> {
    StoreLocation::parse(text, baud)?.open().await
}

/// The controller a `ros-yaml:` store names unless told.
pub const DEFAULT_CONTROLLER: &str = "diff_drive_controller";

/// A parameter store on its own, as `odocal restore --to` names it and a backup records it:
/// opened without a drive, to read or restore its parameters.
#[derive(Debug, Clone, PartialEq)]
pub enum StoreLocation {
    /// A controller of our protocol on a serial port (its memory and storage).
    Odocal {
        /// The port.
        port: String,
        /// Its baud rate.
        baud: u32,
    },
    /// A robot profile (`profile:PATH`).
    Profile(PathBuf),
    /// The `diff_drive_controller` section of a ros2_control YAML
    /// (`ros-yaml:PATH[?controller=NAME]`): its multipliers, as [`YamlStore`] writes them.
    RosYaml {
        /// The file.
        path: PathBuf,
        /// The controller (its section).
        controller: String,
    },
}

impl StoreLocation {
    /// Parses `profile:PATH`, `ros-yaml:PATH[?controller=NAME]`, or an odocal-protocol
    /// controller's port (`PORT` or `odocal:PORT?baud=…`; `baud` unless the text gives one).
    pub fn parse(text: &str, baud: u32) -> Result<Self, SpecError> {
        let text = text.trim();
        if let Ok(StoreSpec::Profile(path)) = text.parse::<StoreSpec>() {
            return Ok(StoreLocation::Profile(path));
        }
        if let Some(parts) = scheme_parts(text, "ros-yaml", &["controller"]) {
            let spec = parts?;
            return Ok(StoreLocation::RosYaml {
                controller: option(text, &spec, "controller", DEFAULT_CONTROLLER.to_string())?,
                path: spec.port.into(),
            });
        }
        match text.parse::<DriveSpec>() {
            Ok(DriveSpec::Odocal { port, baud: b }) => Ok(StoreLocation::Odocal {
                port,
                baud: if text.contains("baud=") { b } else { baud },
            }),
            _ => Err(parse_err(
                text,
                "not a parameter store: give the port of an odocal-protocol controller, \
                 profile:PATH or ros-yaml:PATH[?controller=NAME]",
            )),
        }
    }

    /// Reads any backup odocal wrote: a backup record ([`crate::base::transaction::read_backup`]),
    /// or a copy of a file made beside it (`robot.toml.odocal-backup-<UTC time>`, what odocal
    /// before 0.2 wrote beside a profile or a controller's YAML on every write). A copy is read
    /// as a record of the file it is named after, holding the copy's whole text; its format is
    /// found by reading it (a profile, else `controller`'s section of a YAML, by default
    /// `diff_drive_controller`).
    pub fn read_backup(path: &Path, controller: Option<&str>) -> Result<BackupFile, SpecError> {
        let record = crate::base::transaction::read_backup(path);
        let (Err(BackupError::Malformed { .. }), Some(file)) = (&record, copied_file(path)) else {
            return Ok(record?);
        };
        let text = crate::io::read_bounded(path, crate::io::MAX_TEXT_FILE).map_err(|source| {
            BackupError::Read {
                path: path.to_path_buf(),
                source,
            }
        })?;
        let file = std::path::absolute(&file).unwrap_or(file);
        let (store, active) = match ProfileFile.parse(&text, path) {
            Ok(profile) => (ProfileFile.info(&file), ProfileFile::params(&profile)),
            Err(profile_error) => {
                let format = crate::ros::yaml::ControllerYaml {
                    controller: controller.unwrap_or(DEFAULT_CONTROLLER).into(),
                };
                let config = format.parse(&text, path).map_err(|yaml_error| {
                    SpecError::Combination(format!(
                        "{} is named like a copy odocal made of {}, but reads neither as a robot \
                         profile ({profile_error}) nor as a controller's YAML ({yaml_error})",
                        path.display(),
                        file.display()
                    ))
                })?;
                (
                    format.info(&file),
                    crate::ros::yaml::ControllerYaml::params(&config),
                )
            }
        };
        let backup = BackupFile {
            odocal_version: "before 0.2 (a copy of the file)".into(),
            store,
            taken_utc: None,
            file: Some(file),
            active,
            committed: Some(active),
            text: Some(text),
        };
        crate::base::transaction::check_restorable(&backup, path)?;
        Ok(backup)
    }

    /// Where the store a backup was taken from is: the file it records (absolute; in older
    /// backups, as it was given) or a controller's port (at `baud`). A store odocal cannot
    /// open by itself (the simulated robot, a live ROS controller's running parameters) is
    /// an error that asks for `--to`.
    pub fn of_backup(backup: &BackupFile, baud: u32) -> Result<Self, SpecError> {
        let details = &backup.store.details;
        let detail = |key: &str| details.get(key).and_then(serde_json::Value::as_str);
        let file = backup
            .file
            .clone()
            .or_else(|| detail("file").map(PathBuf::from));
        let unknown = |what: &str| {
            SpecError::Combination(format!(
                "the backup of {} `{}` does not say {what}: give the store with --to",
                backup.store.kind, backup.store.id
            ))
        };
        match backup.store.kind.as_str() {
            crate::hal::base::KIND => Ok(StoreLocation::Odocal {
                port: detail("port")
                    .ok_or_else(|| unknown("which port the controller was on"))?
                    .into(),
                baud,
            }),
            kind if kind == ProfileFile.kind() => Ok(StoreLocation::Profile(
                file.ok_or_else(|| unknown("which file"))?,
            )),
            crate::ros::yaml::KIND => Ok(StoreLocation::RosYaml {
                path: file.ok_or_else(|| unknown("which file"))?,
                controller: detail("controller")
                    .ok_or_else(|| unknown("which controller"))?
                    .into(),
            }),
            kind => Err(SpecError::Combination(format!(
                "odocal cannot open a store of kind `{kind}` (`{}`) by itself: give one with \
                 --to (a controller's port, profile:PATH or ros-yaml:PATH?controller=NAME)",
                backup.store.id
            ))),
        }
    }

    /// **Connects to the store** (a controller: the handshake; a file: read and parsed).
    pub async fn open(&self) -> Result<Arc<dyn ParamStore>, SpecError> {
        Ok(match self {
            StoreLocation::Odocal { port, baud } => {
                Arc::new(crate::hal::open_port(port, *baud).await?.0)
            }
            StoreLocation::Profile(path) => Arc::new(ProfileStore::open(path)?),
            StoreLocation::RosYaml { path, controller } => {
                Arc::new(YamlStore::open(path, controller)?)
            }
        })
    }
}

/// The file `path` is a copy of, when it is named like one (`<file>.odocal-backup-<UTC time>`
/// or `…-<n>`, no `.json`), in the same directory.
fn copied_file(path: &Path) -> Option<PathBuf> {
    let name = path.file_name()?.to_str()?;
    let (file, stamp) = name.rsplit_once(".odocal-backup-")?;
    let stamped = !file.is_empty()
        && !stamp.ends_with(".json")
        && stamp.starts_with(|c: char| c.is_ascii_digit())
        && stamp.contains('T');
    stamped.then(|| crate::io::dir_of(path).join(file))
}

impl std::fmt::Display for StoreLocation {
    /// The text form [`StoreLocation::parse`] reads.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StoreLocation::Odocal { port, baud } if *baud == ODOCAL_BAUD => f.write_str(port),
            StoreLocation::Odocal { port, baud } => write!(f, "odocal:{port}?baud={baud}"),
            StoreLocation::Profile(path) => write!(f, "profile:{}", path.display()),
            StoreLocation::RosYaml { path, controller } => {
                write!(f, "ros-yaml:{}?controller={controller}", path.display())
            }
        }
    }
}

/// An odocal-protocol controller named by a drive spec (its `baud=` over `baud`), or an error
/// with `hint` for any other drive.
async fn open_controller(
    text: &str,
    baud: u32,
    hint: &str,
) -> Result<crate::hal::Client, SpecError> {
    match text.parse::<DriveSpec>()? {
        DriveSpec::Odocal { port, baud: b } => {
            let baud = if text.contains("baud=") { b } else { baud };
            Ok(crate::hal::open_port(&port, baud).await?.0)
        }
        _ => Err(parse_err(text, hint)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_parse_from_their_text_forms() {
        assert_eq!(
            "/dev/ttyUSB0".parse::<DriveSpec>().unwrap(),
            DriveSpec::Odocal {
                port: "/dev/ttyUSB0".into(),
                baud: ODOCAL_BAUD
            }
        );
        assert_eq!(
            "roboclaw:/dev/ttyACM0?address=129&baud=115200"
                .parse::<DriveSpec>()
                .unwrap(),
            DriveSpec::RoboClaw {
                port: "/dev/ttyACM0".into(),
                address: 129,
                baud: 115_200
            }
        );
        assert!(matches!(
            "rosbridge://localhost:9090".parse::<DriveSpec>(),
            Ok(DriveSpec::Rosbridge(c)) if c.url == "rosbridge://localhost:9090"
        ));
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
        assert_eq!(
            "profile:robot.toml".parse::<StoreSpec>().unwrap(),
            StoreSpec::Profile("robot.toml".into())
        );
        for bad in [
            "roboclaw:",
            "roboclaw:/dev/x?speed=3",
            "roboclaw:/dev/x?address=999",
        ] {
            let e = bad.parse::<DriveSpec>().unwrap_err().to_string();
            assert!(e.starts_with(&format!("{bad:?}")), "{e}");
        }
        assert!("nmea:/dev/x?baud=fast".parse::<HeadingSpec>().is_err());
        assert!("/dev/ttyUSB0".parse::<HeadingSpec>().is_err());
    }

    #[test]
    fn stores_on_their_own_parse_print_and_are_found_from_a_backup() {
        use serde_json::json;
        for (text, want) in [
            (
                "/dev/ttyUSB0",
                StoreLocation::Odocal {
                    port: "/dev/ttyUSB0".into(),
                    baud: 57_600,
                },
            ),
            (
                "profile:/r/robot.toml",
                StoreLocation::Profile("/r/robot.toml".into()),
            ),
            (
                "ros-yaml:/c/d.yaml",
                StoreLocation::RosYaml {
                    path: "/c/d.yaml".into(),
                    controller: DEFAULT_CONTROLLER.into(),
                },
            ),
            (
                "ros-yaml:/c/d.yaml?controller=ns/ctrl",
                StoreLocation::RosYaml {
                    path: "/c/d.yaml".into(),
                    controller: "ns/ctrl".into(),
                },
            ),
        ] {
            let got = StoreLocation::parse(text, 57_600).unwrap();
            assert_eq!(got, want, "{text}");
            assert_eq!(
                StoreLocation::parse(&got.to_string(), 57_600).unwrap(),
                want
            );
        }
        for bad in [
            "ros-yaml:",
            "ros-yaml:/c.yaml?ctrl=x",
            "rosbridge://h:1",
            "mock",
        ] {
            let e = StoreLocation::parse(bad, ODOCAL_BAUD)
                .unwrap_err()
                .to_string();
            assert!(e.starts_with(&format!("{bad:?}")), "{e}");
        }
        let backup = |kind: &str, details: serde_json::Value, file: Option<&str>| BackupFile {
            odocal_version: "0".into(),
            store: crate::base::ComponentInfo {
                kind: kind.into(),
                id: "x".into(),
                details,
            },
            taken_utc: None,
            file: file.map(PathBuf::from),
            active: crate::kinematics::WheelParams::nominal(0.15, 0.39, 4096.0),
            committed: None,
            text: None,
        };
        assert_eq!(
            StoreLocation::of_backup(
                &backup("odocal-protocol", json!({"port": "/dev/pts/3"}), None),
                ODOCAL_BAUD
            )
            .unwrap()
            .to_string(),
            "/dev/pts/3"
        );
        // The absolute file the backup records, else (older backups) the one in its details.
        assert_eq!(
            StoreLocation::of_backup(
                &backup(
                    "robot-profile",
                    json!({"file": "robot.toml"}),
                    Some("/r/robot.toml")
                ),
                ODOCAL_BAUD
            )
            .unwrap(),
            StoreLocation::Profile("/r/robot.toml".into())
        );
        assert_eq!(
            StoreLocation::of_backup(
                &backup(
                    "ros2-control-yaml",
                    json!({"file": "d.yaml", "controller": "c"}),
                    None
                ),
                ODOCAL_BAUD
            )
            .unwrap(),
            StoreLocation::RosYaml {
                path: "d.yaml".into(),
                controller: "c".into()
            }
        );
        let e = StoreLocation::of_backup(&backup("simulated", json!(null), None), ODOCAL_BAUD)
            .unwrap_err()
            .to_string();
        assert!(e.contains("--to"), "{e}");
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
    fn routine_files_hold_the_robot_apart_from_the_procedure() {
        let f = RoutineFile::from_toml(
            "side_m = 2.0\n[robot]\ndrive = \"roboclaw:/dev/x\"\nheading = \"nmea:/dev/y\"\n\
             profile = \"r.toml\"\n",
        )
        .unwrap();
        assert_eq!(f.routine.side_m, 2.0);
        assert!(matches!(
            f.robot.spec().unwrap().drive,
            DriveSpec::RoboClaw { .. }
        ));
        // An older file: the robot at the top, a [ros] table.
        let f = RoutineFile::from_toml(
            "port = \"rosbridge://localhost:9090\"\nside_m = 1.5\n[ros]\nyaml = \"c.yaml\"\n\
             controller = \"diffbot_base_controller\"\n",
        )
        .unwrap();
        match f.robot.spec().unwrap().drive {
            DriveSpec::Rosbridge(c) => {
                assert_eq!(c.url, "rosbridge://localhost:9090");
                assert_eq!(c.controller, "diffbot_base_controller");
            }
            other => panic!("{other:?}"),
        }
        // Errors keep their line, in either part.
        let e =
            RoutineFile::from_toml("[robot]\ndrive = \"/dev/x\"\nbaud = \"fast\"\n").unwrap_err();
        assert_eq!(e.line, Some(3), "{e}");
        let e =
            RoutineFile::from_toml("side_m = 2.0\nruns_per_direction = \"five\"\n").unwrap_err();
        assert_eq!(e.line, Some(2), "{e}");
        let e =
            RoutineFile::from_toml("port = \"/dev/x\"\n[robot]\ndrive = \"/dev/y\"\n").unwrap_err();
        assert!(e.message.contains("twice"), "{e}");
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
        assert_eq!(
            merged.spec().unwrap().drive,
            DriveSpec::Odocal {
                port: "/dev/b".into(),
                baud: 57_600
            }
        );
    }
}
