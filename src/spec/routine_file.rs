//! A routine file: the robot's `[robot]` table ([`RobotSection`]) beside the procedure
//! ([`RoutineConfig`]), and the older layout that gave the robot's keys at the top.

use super::{RobotSection, SpecError};
use crate::routine::config::{key_line, parse_table, table_error, ConfigError, RoutineConfig};
use std::path::Path;

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

#[cfg(all(test, feature = "roboclaw", feature = "ros"))]
mod tests {
    use super::*;

    #[test]
    fn routine_files_hold_the_robot_apart_from_the_procedure() {
        let f = RoutineFile::from_toml(
            "side_m = 2.0\n[robot]\ndrive = \"roboclaw:/dev/x\"\nheading = \"nmea:/dev/y\"\n\
             profile = \"r.toml\"\n",
        )
        .unwrap();
        assert_eq!(f.routine.side_m, 2.0);
        assert!(f
            .robot
            .spec()
            .unwrap()
            .drive
            .is(&crate::roboclaw::DRIVE_BACKEND));
        // An older file: the robot at the top, a [ros] table.
        let f = RoutineFile::from_toml(
            "port = \"rosbridge://localhost:9090\"\nside_m = 1.5\n[ros]\nyaml = \"c.yaml\"\n\
             controller = \"diffbot_base_controller\"\n",
        )
        .unwrap();
        let drive = f.robot.spec().unwrap().drive;
        let ros = crate::ros::live::config_of(&drive.target).unwrap();
        assert!(drive.is(&crate::ros::live::DRIVE_BACKEND));
        assert_eq!(ros.url, "rosbridge://localhost:9090");
        assert_eq!(ros.controller, "diffbot_base_controller");
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
}
