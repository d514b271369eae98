//! Where parameters live: a robot's store ([`StoreSpec`]: the drive's own, or a store named
//! on its own) and a store on its own ([`StoreLocation`]: what `odocal restore --to` names and
//! a backup records), in one grammar read from [`STORE_BACKENDS`].

use super::registry::{forms, Role, DRIVE_BACKENDS, PROFILE, STORE_BACKENDS};
use super::{other_form, parse_err, SpecError};
use crate::base::port_spec::PortSpec;
use crate::base::store_backend::StoreBackend;
use crate::base::transaction::{BackupError, BackupFile};
use crate::base::ParamStore;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::Arc;

/// Where a robot's parameters live.
#[derive(Debug, Clone, Default, PartialEq)]
pub enum StoreSpec {
    /// The drive's own (a controller's memory, a ROS robot's YAML).
    #[default]
    Drive,
    /// A store named on its own: a robot profile (`profile:PATH`), for a drive that keeps no
    /// parameters of its own (a RoboClaw).
    Located(StoreLocation),
}

impl FromStr for StoreSpec {
    type Err = SpecError;

    /// `drive`, or a store some drive keeps its parameters in (a robot profile).
    fn from_str(text: &str) -> Result<Self, SpecError> {
        let text = text.trim();
        if text == "drive" {
            return Ok(StoreSpec::Drive);
        }
        let profile = PROFILE.and_then(|p| Some((p, PortSpec::parse(text, p.scheme, p.options)?)));
        match profile {
            Some((backend, spec)) => Ok(StoreSpec::Located(StoreLocation {
                backend,
                spec: spec.map_err(|reason| parse_err(text, reason))?,
            })),
            None => {
                super::not_built(text, Role::Store, false)?;
                let profile = PROFILE
                    .map(|p| format!(" or {} ({}, for {})", p.form, p.what, profile_drives()));
                Err(parse_err(
                    text,
                    format!(
                        "not a parameter store: give drive (the drive's own){}",
                        profile.unwrap_or_default()
                    ),
                ))
            }
        }
    }
}

impl StoreSpec {
    /// A robot profile; its path must be UTF-8 (it is written back in backups and messages).
    pub fn profile(path: &Path) -> Result<Self, SpecError> {
        let name = path.to_str().ok_or_else(|| {
            SpecError::Flag(format!(
                "the robot profile's path {} is not UTF-8: rename it",
                path.display()
            ))
        })?;
        let Some(backend) = PROFILE else {
            let what = format!("the robot profile {name}");
            return Err(crate::features::NotBuilt::new(what, &["roboclaw"]).into());
        };
        Ok(StoreSpec::Located(StoreLocation {
            backend,
            spec: PortSpec::bare(name),
        }))
    }

    /// The robot profile this store is, if it is one.
    pub fn profile_path(&self) -> Option<&Path> {
        match self {
            StoreSpec::Located(l) if PROFILE == Some(l.backend) => Some(Path::new(&l.spec.port)),
            _ => None,
        }
    }
}

/// A parameter store on its own, as `odocal restore --to` names it and a backup records it:
/// opened without a drive, to read or restore its parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct StoreLocation {
    /// Its backend.
    pub backend: &'static StoreBackend,
    /// Its port or file, and options (defaults filled in).
    pub spec: PortSpec,
}

impl StoreLocation {
    /// Parses a store of any of the [`STORE_BACKENDS`]' forms (`profile:PATH`,
    /// `ros-yaml:PATH[?controller=NAME]`, an odocal-protocol controller's `PORT` or
    /// `odocal:PORT?baud=…`); a controller at `baud` unless the text gives one.
    pub fn parse(text: &str, baud: u32) -> Result<Self, SpecError> {
        StoreLocation::read(text, Some(baud))
    }

    /// `text` parsed, `baud` (when given) the default of a backend that takes one.
    fn read(text: &str, baud: Option<u32>) -> Result<Self, SpecError> {
        let text = text.trim();
        for &backend in STORE_BACKENDS {
            if let Some(parts) = PortSpec::parse(text, backend.scheme, backend.options) {
                let spec = parts.map_err(|reason| parse_err(text, reason))?;
                return StoreLocation::completed(text, backend, spec, baud);
            }
        }
        match STORE_BACKENDS.iter().find(|b| b.bare_port) {
            Some(backend) if !other_form(text) => {
                StoreLocation::completed(text, backend, PortSpec::bare(text), baud)
            }
            found => {
                super::not_built(text, Role::Store, found.is_none() && !other_form(text))?;
                Err(parse_err(
                    text,
                    format!("not a parameter store: give {}", store_forms()),
                ))
            }
        }
    }

    /// A store of `backend` at `spec`, its defaults filled in and checked.
    fn completed(
        text: &str,
        backend: &'static StoreBackend,
        mut spec: PortSpec,
        baud: Option<u32>,
    ) -> Result<Self, SpecError> {
        if let (Some(baud), true) = (baud, backend.options.contains(&"baud")) {
            spec.or_option("baud", baud);
        }
        (backend.complete)(&mut spec).map_err(|reason| parse_err(text, reason))?;
        Ok(StoreLocation { backend, spec })
    }

    /// An option of the store (`controller` of a `ros-yaml:` store).
    pub fn option(&self, key: &str) -> Option<&str> {
        self.spec.options.get(key).map(String::as_str)
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
        let (store, active) = read_copy(&text, path, &file, controller)?;
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
        let file = backup
            .file
            .clone()
            .or_else(|| StoreBackend::detail(backup, "file").map(PathBuf::from));
        let kind = backup.store.kind.as_str();
        let Some(&backend) = STORE_BACKENDS.iter().find(|b| b.kind == kind) else {
            let table = super::registry::OPTIONAL;
            if let Some(e) = super::registry::store_kind_not_built(table, kind) {
                return Err(e.into());
            }
            return Err(SpecError::Combination(format!(
                "odocal cannot open a store of kind `{kind}` (`{}`) by itself: give one with \
                 --to: {}",
                backup.store.id,
                store_forms()
            )));
        };
        let spec = (backend.of_backup)(backup, file).map_err(|what| {
            SpecError::Combination(format!(
                "the backup of {kind} `{}` does not say {what}: give the store with --to",
                backup.store.id
            ))
        })?;
        StoreLocation::completed(&backup.store.id, backend, spec, Some(baud))
    }

    /// **Connects to the store** (a controller: the handshake; a file: read and parsed).
    pub async fn open(&self) -> Result<Arc<dyn ParamStore>, SpecError> {
        (self.backend.open)(self.spec.clone())
            .await
            .map_err(SpecError::Store)
    }
}

/// What a copy odocal before 0.2 made of `file` (at `path`, holding `text`) was taken from and
/// holds: a robot profile, else `controller`'s section of a controller's YAML (each format as
/// this build reads it).
fn read_copy(
    text: &str,
    path: &Path,
    file: &Path,
    controller: Option<&str>,
) -> Result<(crate::base::ComponentInfo, crate::kinematics::WheelParams), SpecError> {
    #[cfg(feature = "roboclaw")]
    let profile = {
        use crate::base::ParamFile;
        use crate::roboclaw::profile::ProfileFile;
        match ProfileFile.parse(text, path) {
            Ok(profile) => return Ok((ProfileFile.info(file), ProfileFile::params(&profile))),
            Err(e) => Some(format!("as a robot profile ({e})")),
        }
    };
    #[cfg(not(feature = "roboclaw"))]
    let profile = None;
    #[cfg(feature = "ros")]
    let yaml = {
        use crate::base::ParamFile;
        use crate::ros::yaml::{ControllerYaml, DEFAULT_CONTROLLER};
        let format = ControllerYaml {
            controller: controller.unwrap_or(DEFAULT_CONTROLLER).into(),
        };
        match format.parse(text, path) {
            Ok(config) => return Ok((format.info(file), ControllerYaml::params(&config))),
            Err(e) => Some(format!("as a controller's YAML ({e})")),
        }
    };
    #[cfg(not(feature = "ros"))]
    let yaml = None;
    let _ = (text, controller);
    let tried: Vec<String> = [profile, yaml].into_iter().flatten().collect();
    if tried.is_empty() {
        let what = format!(
            "{}, a copy odocal before 0.2 made of a robot profile or a controller's YAML,",
            path.display()
        );
        return Err(crate::features::NotBuilt::new(what, &["roboclaw", "ros"]).into());
    }
    let reads = match tried.len() {
        1 => "does not read",
        _ => "reads neither",
    };
    Err(SpecError::Combination(format!(
        "{} is named like a copy odocal made of {}, but {reads} {}",
        path.display(),
        file.display(),
        tried.join(" nor ")
    )))
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
        f.write_str(&(self.backend.show)(&self.spec))
    }
}

/// Every store's form and what it is, for messages.
fn store_forms() -> String {
    let each: Vec<String> = STORE_BACKENDS
        .iter()
        .map(|b| format!("{} ({})", b.form, b.what))
        .collect();
    forms(each.iter().map(String::as_str))
}

/// The drives that keep their parameters in a robot profile, for messages.
pub(super) fn profile_drives() -> String {
    forms(
        DRIVE_BACKENDS
            .iter()
            .filter(|b| b.store == crate::base::drive_backend::StorePart::Profile)
            .map(|b| b.what),
    )
}

#[cfg(test)]
#[cfg(all(feature = "odocal-protocol", feature = "roboclaw", feature = "ros"))]
mod tests {
    use super::*;
    use crate::ros::yaml::DEFAULT_CONTROLLER;

    /// A store of `backend` at `port` with `options`.
    fn at(backend: &'static StoreBackend, port: &str, options: &[(&str, &str)]) -> StoreLocation {
        let mut spec = PortSpec::bare(port);
        for (k, v) in options {
            spec.or_option(k, v);
        }
        StoreLocation { backend, spec }
    }

    #[test]
    fn stores_on_their_own_parse_print_and_are_found_from_a_backup() {
        use crate::hal::base::STORE_BACKEND as ODOCAL;
        use crate::ros::yaml::STORE_BACKEND as YAML;
        use serde_json::json;
        for (text, want, shown) in [
            (
                "/dev/ttyUSB0",
                at(&ODOCAL, "/dev/ttyUSB0", &[("baud", "57600")]),
                "odocal:/dev/ttyUSB0?baud=57600",
            ),
            (
                "odocal:/dev/ttyUSB0?baud=9600",
                at(&ODOCAL, "/dev/ttyUSB0", &[("baud", "9600")]),
                "odocal:/dev/ttyUSB0?baud=9600",
            ),
            (
                "profile:/r/robot.toml",
                at(PROFILE.unwrap(), "/r/robot.toml", &[]),
                "profile:/r/robot.toml",
            ),
            (
                "ros-yaml:/c/d.yaml",
                at(&YAML, "/c/d.yaml", &[("controller", DEFAULT_CONTROLLER)]),
                "ros-yaml:/c/d.yaml?controller=diff_drive_controller",
            ),
            (
                "ros-yaml:/c/d.yaml?controller=ns/ctrl",
                at(&YAML, "/c/d.yaml", &[("controller", "ns/ctrl")]),
                "ros-yaml:/c/d.yaml?controller=ns/ctrl",
            ),
        ] {
            let got = StoreLocation::parse(text, 57_600).unwrap();
            assert_eq!(got, want, "{text}");
            assert_eq!(got.to_string(), shown);
            assert_eq!(StoreLocation::parse(shown, 57_600).unwrap(), want);
        }
        // The same grammar is a robot's store.
        assert_eq!(
            "profile:robot.toml"
                .parse::<StoreSpec>()
                .unwrap()
                .profile_path(),
            Some(Path::new("robot.toml"))
        );
        assert_eq!("drive".parse::<StoreSpec>().unwrap(), StoreSpec::Drive);
        for bad in [
            "ros-yaml:",
            "ros-yaml:/c.yaml?ctrl=x",
            "odocal:/dev/x?baud=fast",
            "rosbridge://h:1",
            "roboclaw:/dev/x",
            "nmea:/dev/x",
            "mock",
            "",
        ] {
            let e = StoreLocation::parse(bad, crate::hal::DEFAULT_BAUD)
                .unwrap_err()
                .to_string();
            assert!(e.starts_with(&format!("{bad:?}")), "{e}");
        }
        let e = "mock".parse::<StoreSpec>().unwrap_err().to_string();
        assert!(e.contains("not a parameter store: give drive"), "{e}");
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
        let default_baud = crate::hal::DEFAULT_BAUD;
        assert_eq!(
            StoreLocation::of_backup(
                &backup("odocal-protocol", json!({"port": "/dev/pts/3"}), None),
                default_baud
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
                default_baud
            )
            .unwrap(),
            at(PROFILE.unwrap(), "/r/robot.toml", &[])
        );
        assert_eq!(
            StoreLocation::of_backup(
                &backup(
                    "ros2-control-yaml",
                    json!({"file": "d.yaml", "controller": "c"}),
                    None
                ),
                default_baud
            )
            .unwrap(),
            at(&YAML, "d.yaml", &[("controller", "c")])
        );
        let e = StoreLocation::of_backup(&backup("simulated", json!(null), None), default_baud)
            .unwrap_err()
            .to_string();
        assert!(e.contains("--to"), "{e}");
        let e = StoreLocation::of_backup(
            &backup("ros2-control-yaml", json!({}), Some("/d.yaml")),
            default_baud,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("does not say which controller"), "{e}");
    }

    #[test]
    fn every_listed_store_backend_is_reached_by_its_own_form() {
        for backend in STORE_BACKENDS {
            let form = backend.form.rsplit(" or ").next().unwrap_or(backend.form);
            let text = form
                .replace(['[', ']'], "")
                .replace("PORT", "/dev/x")
                .replace("PATH", "/d/f");
            let got = StoreLocation::parse(&text, crate::hal::DEFAULT_BAUD).unwrap();
            assert_eq!(got.backend, *backend, "{text}");
            let again = StoreLocation::parse(&got.to_string(), crate::hal::DEFAULT_BAUD);
            assert_eq!(again.unwrap(), got, "{text}");
        }
    }
}
