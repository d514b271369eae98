//! The ros2_control YAML file as a parameter store.
//!
//! `diff_drive_controller` keeps the geometry in its section of a YAML file:
//! `<controller>: ros__parameters: {wheel_separation, wheel_radius, wheel_separation_multiplier,
//! left_wheel_radius_multiplier, right_wheel_radius_multiplier, left_wheel_names, …}`. The
//! controller's odometry uses `b = wheel_separation · wheel_separation_multiplier` and per
//! wheel `r = wheel_radius · <side>_wheel_radius_multiplier`; odocal's [`WheelParams`] for such
//! a robot are those effective values, with wheel angles (rad) as its "counts"
//! (`counts_per_wheel_rev` = 2π).
//!
//! Calibration writes back only the **multipliers** (computed from the new effective values,
//! so they compose with the ones the file already had); the nominal values stay as the URDF
//! and the robot's description have them. The file is edited as text — every other key, the
//! order and the comments stay — then parsed again to check that it says what was meant. It
//! is replaced atomically, and the first replacement in a session first copies the original
//! beside it (`<file>.odocal-backup-<ms>`, created exclusively).

use crate::base::{FileStore, ParamFile};
use crate::kinematics::WheelParams;
use std::path::{Path, PathBuf};
use yaml_rust2::{Yaml, YamlLoader};

/// Wheel angle units per revolution: the "counts" of a ROS robot are radians.
pub const RAD_PER_REV: f64 = 2.0 * std::f64::consts::PI;

/// The multiplier keys odocal writes.
pub const MULTIPLIER_KEYS: [&str; 3] = [
    "wheel_separation_multiplier",
    "left_wheel_radius_multiplier",
    "right_wheel_radius_multiplier",
];

/// A YAML file that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum YamlError {
    /// Reading or writing the file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// Not valid YAML.
    #[error("{}: line {line}: {message}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// The parser's message.
        message: String,
    },
    /// No section for the controller.
    #[error("{}: no `{controller}:` section with `ros__parameters:`; the file has {}", path.display(), if sections.is_empty() { "no sections".to_string() } else { format!("sections {}", sections.join(", ")) })]
    NoController {
        /// The file.
        path: PathBuf,
        /// The controller looked for.
        controller: String,
        /// The top-level sections the file does have.
        sections: Vec<String>,
    },
    /// A required key is missing or not a number.
    #[error("{}: `{controller}.ros__parameters.{key}` {problem}", path.display())]
    BadKey {
        /// The file.
        path: PathBuf,
        /// The controller.
        controller: String,
        /// The key.
        key: &'static str,
        /// What is wrong.
        problem: String,
    },
    /// The section is written in flow style (`{…}`), which odocal does not rewrite.
    #[error("{}: `{controller}` parameters are in flow style ({{…}}); write them one per line so odocal can update them", path.display())]
    FlowStyle {
        /// The file.
        path: PathBuf,
        /// The controller.
        controller: String,
    },
}

/// A `diff_drive_controller` section.
#[derive(Debug, Clone, PartialEq)]
pub struct DiffDriveConfig {
    /// The controller's name (its section).
    pub controller: String,
    /// `wheel_separation` (m).
    pub wheel_separation_m: f64,
    /// `wheel_radius` (m).
    pub wheel_radius_m: f64,
    /// `wheel_separation_multiplier`.
    pub separation_multiplier: f64,
    /// `left_wheel_radius_multiplier`.
    pub left_radius_multiplier: f64,
    /// `right_wheel_radius_multiplier`.
    pub right_radius_multiplier: f64,
    /// `left_wheel_names`.
    pub left_wheel_names: Vec<String>,
    /// `right_wheel_names`.
    pub right_wheel_names: Vec<String>,
    /// `cmd_vel_timeout` (s): the controller stops the wheels when commands stop this long.
    pub cmd_vel_timeout_s: Option<f64>,
}

/// The three multipliers for a set of effective parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Multipliers {
    /// `wheel_separation_multiplier`.
    pub wheel_separation_multiplier: f64,
    /// `left_wheel_radius_multiplier`.
    pub left_wheel_radius_multiplier: f64,
    /// `right_wheel_radius_multiplier`.
    pub right_wheel_radius_multiplier: f64,
}

impl DiffDriveConfig {
    /// Reads `controller`'s section from YAML text (`path` names the file in errors).
    pub fn parse(text: &str, controller: &str, path: &Path) -> Result<Self, YamlError> {
        let docs = YamlLoader::load_from_str(text).map_err(|e| YamlError::Parse {
            path: path.to_path_buf(),
            line: e.marker().line(),
            message: e.to_string(),
        })?;
        let doc = docs.first().cloned().unwrap_or(Yaml::Null);
        let params = &doc[controller]["ros__parameters"];
        if params.as_hash().is_none() {
            let sections = doc
                .as_hash()
                .map(|h| {
                    h.keys()
                        .filter_map(|k| k.as_str().map(String::from))
                        .collect()
                })
                .unwrap_or_default();
            return Err(YamlError::NoController {
                path: path.to_path_buf(),
                controller: controller.into(),
                sections,
            });
        }
        let bad = |key: &'static str, problem: String| YamlError::BadKey {
            path: path.to_path_buf(),
            controller: controller.into(),
            key,
            problem,
        };
        let number = |key: &'static str, default: Option<f64>| -> Result<f64, YamlError> {
            let v = &params[key];
            let x = match v {
                Yaml::BadValue => {
                    return default.ok_or_else(|| bad(key, "is missing".into()));
                }
                Yaml::Real(_) => v.as_f64(),
                Yaml::Integer(i) => Some(*i as f64),
                _ => None,
            };
            match x {
                Some(x) if x.is_finite() && x > 0.0 => Ok(x),
                _ => Err(bad(key, format!("must be a positive number, is {v:?}"))),
            }
        };
        let names = |key: &str| -> Vec<String> {
            params[key]
                .as_vec()
                .map(|v| {
                    v.iter()
                        .filter_map(|n| n.as_str().map(String::from))
                        .collect()
                })
                .unwrap_or_default()
        };
        let cfg = DiffDriveConfig {
            controller: controller.into(),
            wheel_separation_m: number("wheel_separation", None)?,
            wheel_radius_m: number("wheel_radius", None)?,
            separation_multiplier: number("wheel_separation_multiplier", Some(1.0))?,
            left_radius_multiplier: number("left_wheel_radius_multiplier", Some(1.0))?,
            right_radius_multiplier: number("right_wheel_radius_multiplier", Some(1.0))?,
            left_wheel_names: names("left_wheel_names"),
            right_wheel_names: names("right_wheel_names"),
            cmd_vel_timeout_s: number("cmd_vel_timeout", Some(f64::NAN))
                .ok()
                .filter(|t| t.is_finite()),
        };
        Ok(cfg)
    }

    /// Reads a file.
    pub fn load(path: &Path, controller: &str) -> Result<Self, YamlError> {
        let text = read_bounded(path)?;
        Self::parse(&text, controller, path)
    }

    /// The effective parameters the controller's odometry uses.
    pub fn effective(&self) -> WheelParams {
        WheelParams {
            left_wheel_diameter_m: 2.0 * self.wheel_radius_m * self.left_radius_multiplier,
            right_wheel_diameter_m: 2.0 * self.wheel_radius_m * self.right_radius_multiplier,
            wheelbase_m: self.wheel_separation_m * self.separation_multiplier,
            counts_per_wheel_rev: RAD_PER_REV,
        }
    }

    /// The multipliers that make the effective parameters `p`, on this file's nominal values.
    pub fn multipliers_for(&self, p: &WheelParams) -> Multipliers {
        Multipliers {
            wheel_separation_multiplier: p.wheelbase_m / self.wheel_separation_m,
            left_wheel_radius_multiplier: p.left_wheel_diameter_m / (2.0 * self.wheel_radius_m),
            right_wheel_radius_multiplier: p.right_wheel_diameter_m / (2.0 * self.wheel_radius_m),
        }
    }
}

/// Reads a YAML file, refusing anything larger than a configuration file can be (16 MiB).
fn read_bounded(path: &Path) -> Result<String, YamlError> {
    crate::io::read_bounded(path, crate::io::MAX_TEXT_FILE).map_err(|source| YamlError::Io {
        path: path.to_path_buf(),
        source,
    })
}

fn indent_of(line: &str) -> usize {
    line.len() - line.trim_start_matches(' ').len()
}

fn is_content(line: &str) -> bool {
    let t = line.trim();
    !t.is_empty() && !t.starts_with('#')
}

/// Formats a multiplier: ten decimals, which keeps effective lengths to well under a nanometre.
fn format_multiplier(v: f64) -> String {
    format!("{v:.10}")
}

/// Sets the multipliers in `controller`'s section of `text`, keeping every other line as it
/// is (a key already there keeps its position and trailing comment; a new key goes at the end
/// of the section). The result is parsed again and must hold exactly the values written.
pub fn merge_multipliers(
    text: &str,
    controller: &str,
    m: &Multipliers,
    path: &Path,
) -> Result<String, YamlError> {
    // Parse first: a file odocal cannot read it does not edit.
    DiffDriveConfig::parse(text, controller, path)?;
    let flow = || YamlError::FlowStyle {
        path: path.to_path_buf(),
        controller: controller.into(),
    };
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let head = format!("{controller}:");
    let c = lines
        .iter()
        .position(|l| {
            let t = l.trim_start();
            t == head
                || t.starts_with(&format!("{head} "))
                    && t[head.len()..].trim_start().starts_with('#')
        })
        .ok_or_else(flow)?;
    let c_indent = indent_of(&lines[c]);
    let rp = (c + 1..lines.len())
        .take_while(|&i| !is_content(&lines[i]) || indent_of(&lines[i]) > c_indent)
        .find(|&i| {
            let t = lines[i].trim();
            t == "ros__parameters:"
                || t.starts_with("ros__parameters: #")
                || t.starts_with("ros__parameters:  #")
        })
        .ok_or_else(flow)?;
    let rp_indent = indent_of(&lines[rp]);
    let end = (rp + 1..lines.len())
        .find(|&i| is_content(&lines[i]) && indent_of(&lines[i]) <= rp_indent)
        .unwrap_or(lines.len());
    let child = (rp + 1..end)
        .find(|&i| is_content(&lines[i]))
        .map_or(rp_indent + 2, |i| indent_of(&lines[i]));
    let mut last_content = (rp + 1..end)
        .rev()
        .find(|&i| is_content(&lines[i]))
        .unwrap_or(rp);
    for (key, value) in [
        (MULTIPLIER_KEYS[0], m.wheel_separation_multiplier),
        (MULTIPLIER_KEYS[1], m.left_wheel_radius_multiplier),
        (MULTIPLIER_KEYS[2], m.right_wheel_radius_multiplier),
    ] {
        let value = format_multiplier(value);
        let existing = (rp + 1..end).find(|&i| {
            indent_of(&lines[i]) == child && lines[i].trim_start().starts_with(&format!("{key}:"))
        });
        match existing {
            Some(i) => {
                // Keep a trailing comment with the spacing before it.
                let comment = lines[i]
                    .find(" #")
                    .map(|p| lines[i][..p].trim_end().len())
                    .map(|p| lines[i][p..].to_string())
                    .unwrap_or_default();
                lines[i] = format!("{}{key}: {value}{comment}", " ".repeat(child));
            }
            None => {
                lines.insert(
                    last_content + 1,
                    format!("{}{key}: {value}", " ".repeat(child)),
                );
                last_content += 1;
            }
        }
    }
    let mut out = lines.join("\n");
    if text.ends_with('\n') {
        out.push('\n');
    }
    let check = DiffDriveConfig::parse(&out, controller, path)?;
    let got = [
        check.separation_multiplier,
        check.left_radius_multiplier,
        check.right_radius_multiplier,
    ];
    let want = [
        m.wheel_separation_multiplier,
        m.left_wheel_radius_multiplier,
        m.right_wheel_radius_multiplier,
    ];
    if got
        .iter()
        .zip(want)
        .any(|(g, w)| (g - w).abs() > 1e-9 * w.abs().max(1.0))
    {
        return Err(flow());
    }
    Ok(out)
}

/// The controller's YAML as a [`FileStore`] format: `controller`'s section, whose effective
/// geometry is the parameters; writing changes only the multipliers ([`merge_multipliers`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ControllerYaml {
    /// The controller's name (its section).
    pub controller: String,
}

impl ParamFile for ControllerYaml {
    type Content = DiffDriveConfig;
    type Error = YamlError;

    fn kind(&self) -> &'static str {
        "ros2-control-yaml"
    }

    fn id(&self, path: &Path) -> String {
        format!("{}#{}", path.display(), self.controller)
    }

    fn details(&self, path: &Path) -> serde_json::Value {
        serde_json::json!({ "file": path, "controller": self.controller })
    }

    fn parse(&self, text: &str, path: &Path) -> Result<DiffDriveConfig, YamlError> {
        DiffDriveConfig::parse(text, &self.controller, path)
    }

    fn params(content: &DiffDriveConfig) -> WheelParams {
        content.effective()
    }

    fn render(&self, text: &str, params: &WheelParams, path: &Path) -> Result<String, YamlError> {
        // Multipliers on the file's own nominal values, rounded as they will be written.
        let cfg = DiffDriveConfig::parse(text, &self.controller, path)?;
        merge_multipliers(text, &self.controller, &cfg.multipliers_for(params), path)
    }

    fn refuse(&self, _current: &WheelParams, params: &WheelParams) -> Option<String> {
        ((params.counts_per_wheel_rev - RAD_PER_REV).abs() > 1e-9).then(|| {
            format!(
                "a ROS robot's wheel angles are radians: counts per revolution must stay 2π, got {}",
                params.counts_per_wheel_rev
            )
        })
    }

    fn io_error(&self, path: &Path, source: std::io::Error) -> YamlError {
        YamlError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// The controller's YAML file as a [`crate::base::ParamStore`]: `write` stages effective
/// parameters (and updates the section a ROS drive integrates its odometry with), `commit`
/// rewrites the multipliers in the file ([`FileStore`]).
pub type YamlStore = FileStore<ControllerYaml>;

impl FileStore<ControllerYaml> {
    /// Opens `controller`'s section of `path` (which must parse).
    pub fn open(path: &Path, controller: &str) -> Result<Self, YamlError> {
        FileStore::with_format(
            ControllerYaml {
                controller: controller.into(),
            },
            path,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FILE: &str = "\
# robot controllers
controller_manager:
  ros__parameters:
    update_rate: 50  # Hz

diff_drive_controller:
  ros__parameters:
    left_wheel_names: [\"left_wheel_joint\"]
    right_wheel_names: [\"right_wheel_joint\"]
    wheel_separation: 0.39
    wheel_radius: 0.075
    wheel_separation_multiplier: 1.0  # tuned 2024
    publish_rate: 50.0
    cmd_vel_timeout: 0.5
";

    #[test]
    fn the_section_reads_into_effective_parameters() {
        let c = DiffDriveConfig::parse(FILE, "diff_drive_controller", Path::new("f.yaml")).unwrap();
        assert_eq!(c.left_wheel_names, vec!["left_wheel_joint"]);
        assert_eq!(c.cmd_vel_timeout_s, Some(0.5));
        let p = c.effective();
        assert!((p.left_wheel_diameter_m - 0.15).abs() < 1e-15);
        assert!((p.wheelbase_m - 0.39).abs() < 1e-15);
        assert!((p.left_m_per_count() - 0.075).abs() < 1e-15);
    }

    #[test]
    fn a_missing_controller_lists_the_sections_there_are() {
        let e = DiffDriveConfig::parse(FILE, "diff_cont", Path::new("f.yaml")).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("controller_manager") && msg.contains("diff_drive_controller"),
            "{msg}"
        );
        let e = DiffDriveConfig::parse("a: [1,\n", "x", Path::new("f.yaml")).unwrap_err();
        assert!(matches!(e, YamlError::Parse { .. }), "{e}");
    }

    #[test]
    fn merging_keeps_everything_else_and_composes_with_existing_multipliers() {
        let path = Path::new("f.yaml");
        let c = DiffDriveConfig::parse(FILE, "diff_drive_controller", path).unwrap();
        let mut p = c.effective();
        p.wheelbase_m *= 0.976;
        p.right_wheel_diameter_m *= 0.992;
        let m = c.multipliers_for(&p);
        let out = merge_multipliers(FILE, "diff_drive_controller", &m, path).unwrap();
        // Every original line except the one multiplier is still there, in order.
        let kept: Vec<&str> = out.lines().filter(|l| !l.contains("multiplier")).collect();
        let orig: Vec<&str> = FILE.lines().filter(|l| !l.contains("multiplier")).collect();
        assert_eq!(kept, orig);
        assert!(
            out.contains("wheel_separation_multiplier: 0.9760000000  # tuned 2024"),
            "{out}"
        );
        assert!(
            out.contains("    right_wheel_radius_multiplier: 0.9920000000\n"),
            "{out}"
        );
        let back = DiffDriveConfig::parse(&out, "diff_drive_controller", path).unwrap();
        assert!((back.effective().wheelbase_m - p.wheelbase_m).abs() < 1e-12);
        // Calibrating again composes: the new multipliers multiply the written ones.
        let mut p2 = back.effective();
        p2.wheelbase_m *= 1.01;
        let m2 = back.multipliers_for(&p2);
        assert!((m2.wheel_separation_multiplier - 0.976 * 1.01).abs() < 1e-12);
        // Flow style is refused, not mangled.
        let flow = "diff_drive_controller: {ros__parameters: {wheel_separation: 0.39, wheel_radius: 0.075}}\n";
        assert!(matches!(
            merge_multipliers(flow, "diff_drive_controller", &m, path),
            Err(YamlError::FlowStyle { .. })
        ));
    }
}
