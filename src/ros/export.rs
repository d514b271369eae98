//! Exporting a calibration for other software: ros2_control's `diff_drive_controller`.
//!
//! Any result odocal prints as JSON can be exported — a routine report (`demo`, `calibrate`,
//! `run`), `estimate`, `track` or `bag` — and either merged into the controller's existing
//! YAML (only the multipliers change; through the write service, [`crate::base::write`]:
//! backed up beside it, as every write odocal makes, then replaced atomically and read back)
//! or written as a new file (never over an existing one).

use crate::base::write::{
    write_once, Bounds, Commit, Question, WriteError, WritePolicy, WriteRequest, WriteUi,
};
use crate::base::ParamStore;
use crate::kinematics::WheelParams;
use crate::ros::yaml::YamlStore;
use serde_json::Value;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// A result that cannot be exported.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The JSON is not an odocal result.
    #[error("not an odocal result: {0}")]
    NotAResult(String),
    /// The method asked for has no estimate in the result.
    #[error("the result has no `{method}` estimate; it has {}", available.join(", "))]
    NoMethod {
        /// The method asked for.
        method: String,
        /// The methods it has.
        available: Vec<String>,
    },
    /// The result file could not be read.
    #[error("cannot read {}: {source}", path.display())]
    Unreadable {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The result file is not JSON.
    #[error("{}: not JSON ({source})", path.display())]
    NotJson {
        /// The file.
        path: PathBuf,
        /// Where it stops being JSON.
        #[source]
        source: serde_json::Error,
    },
    /// The result in this file cannot be exported.
    #[error("{}: {source}", path.display())]
    In {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: Box<ExportError>,
    },
    /// The target exists and merging into it was not asked for.
    #[error(
        "{} exists: not changed. --force merges the {method} calibration's multipliers into it \
         (everything else stays; a backup of it goes beside it, for `odocal restore`)",
        path.display()
    )]
    Exists {
        /// The target.
        path: PathBuf,
        /// The calibration's method.
        method: String,
    },
    /// The parameters are not a robot.
    #[error(transparent)]
    Kinematics(#[from] crate::kinematics::KinematicsError),
    /// The calibration would scale a parameter beyond [`MAX_FACTOR`] either way: not a
    /// calibration (a corrupt result, or the wrong robot).
    #[error("{name} would change by a factor of {factor:.3e}, beyond 1/{MAX_FACTOR}..{MAX_FACTOR}: not exported")]
    Implausible {
        /// The parameter.
        name: &'static str,
        /// calibrated / configured.
        factor: f64,
    },
    /// The target YAML is unusable.
    #[error(transparent)]
    Yaml(#[from] crate::ros::yaml::YamlError),
    /// The target YAML could not be read, backed up, written or read back (what the file holds
    /// then is said).
    #[error(transparent)]
    Write(#[from] WriteError),
    /// Writing failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
}

/// What a result says was configured during the test, and what it calibrated.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// Parameters configured during the test.
    pub configured: WheelParams,
    /// Calibrated parameters.
    pub calibrated: WheelParams,
    /// Which method (or `routine` for a routine report's written parameters).
    pub method: String,
}

fn params(v: &Value, key: &str) -> Result<WheelParams, ExportError> {
    let p: WheelParams = serde_json::from_value(v[key].clone())
        .map_err(|e| ExportError::NotAResult(format!("`{key}`: {e}")))?;
    p.validate()?;
    Ok(p)
}

/// `odocal fit --json`'s geometry (absolute, in metres) over its nominal one; wheel angles in
/// radians (a ROS robot's; a merge keeps the file's own count).
fn pose_fit_calibration(v: &Value) -> Result<Calibration, ExportError> {
    let num = |key: &str| {
        v[key]
            .as_f64()
            .ok_or_else(|| ExportError::NotAResult(format!("a pose fit without `{key}`")))
    };
    let geometry = |l: &str, r: &str, b: &str| -> Result<WheelParams, ExportError> {
        let p = WheelParams {
            left_wheel_diameter_m: num(l)?,
            right_wheel_diameter_m: num(r)?,
            wheelbase_m: num(b)?,
            counts_per_wheel_rev: std::f64::consts::TAU,
        };
        p.validate()?;
        Ok(p)
    };
    Ok(Calibration {
        configured: geometry(
            "nominal_left_wheel_diameter_m",
            "nominal_right_wheel_diameter_m",
            "nominal_wheelbase_m",
        )?,
        calibrated: geometry(
            "left_wheel_diameter_m",
            "right_wheel_diameter_m",
            "wheelbase_m",
        )?,
        method: "pose-fit".into(),
    })
}

/// Reads any odocal result: a routine report's final parameters, or `method`'s estimate
/// (default: the result's `default_method`, else `exact`, else `online`) applied to its
/// `configured` parameters.
pub fn calibration_of(v: &Value, method: Option<&str>) -> Result<Calibration, ExportError> {
    if v.get("reference_kind").is_some() && v.get("left_wheel_diameter_m").is_some() {
        return pose_fit_calibration(v);
    }
    if v.get("final_params").is_some() && v.get("original_params").is_some() && method.is_none() {
        return Ok(Calibration {
            configured: params(v, "original_params")?,
            calibrated: params(v, "final_params")?,
            method: "routine".into(),
        });
    }
    let estimates = v["estimates"]
        .as_array()
        .ok_or_else(|| ExportError::NotAResult("no `estimates` array".into()))?;
    let configured = if v.get("configured").is_some_and(|c| !c.is_null()) {
        params(v, "configured")?
    } else if v.get("original_params").is_some() {
        // A routine report's last round was estimated on its final parameters.
        params(v, "final_params")?
    } else {
        return Err(ExportError::NotAResult(
            "no `configured` parameters (for `estimate`, give --wheel-diameter-m)".into(),
        ));
    };
    let names: Vec<String> = estimates
        .iter()
        .filter_map(|e| e["method"].as_str().map(String::from))
        .collect();
    let wanted = method
        .map(String::from)
        .or_else(|| v["default_method"].as_str().map(String::from))
        .unwrap_or_else(|| {
            if names.iter().any(|n| n == "exact") {
                "exact".into()
            } else {
                names.first().cloned().unwrap_or_default()
            }
        });
    let e = estimates
        .iter()
        .find(|e| e["method"].as_str() == Some(wanted.as_str()))
        .ok_or_else(|| ExportError::NoMethod {
            method: wanted.clone(),
            available: names.clone(),
        })?;
    let correction: crate::kinematics::Correction = serde_json::from_value(e["correction"].clone())
        .map_err(|err| ExportError::NotAResult(format!("`{wanted}` has no correction: {err}")))?;
    Ok(Calibration {
        calibrated: correction.apply(&configured)?,
        configured,
        method: wanted,
    })
}

/// An export as a user asks for it (with the `cli` feature, `odocal export`'s flags).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct ExportSettings {
    /// Any odocal result as JSON: a report.json (demo, calibrate, run), or the --json output of
    /// estimate, track or bag.
    #[cfg_attr(feature = "cli", arg(long, alias = "report"))]
    pub from: PathBuf,
    /// The ros2_control YAML: merged into if it exists (multipliers only, backed up beside it
    /// for `odocal restore`), created otherwise.
    #[cfg_attr(feature = "cli", arg(long))]
    pub ros2: PathBuf,
    /// The controller's name in the YAML.
    #[cfg_attr(
        feature = "cli",
        arg(
            long,
            alias = "controller-name",
            default_value = crate::ros::yaml::DEFAULT_CONTROLLER
        )
    )]
    pub controller: String,
    /// Which estimate to export [default: the result's default method, else exact].
    #[cfg_attr(feature = "cli", arg(long))]
    pub method: Option<String>,
    /// Merge into an existing --ros2 file (its multipliers change; a backup `odocal restore`
    /// takes goes beside it first). Without it an existing file is left alone.
    #[cfg_attr(feature = "cli", arg(long))]
    pub force: bool,
}

impl ExportSettings {
    /// The calibration to export, read from the result file.
    pub fn calibration(&self) -> Result<Calibration, ExportError> {
        let path = || self.from.clone();
        let text =
            crate::io::read_bounded(&self.from, crate::io::MAX_TEXT_FILE).map_err(|source| {
                ExportError::Unreadable {
                    path: path(),
                    source,
                }
            })?;
        let v: Value = serde_json::from_str(&text).map_err(|source| ExportError::NotJson {
            path: path(),
            source,
        })?;
        let cal = calibration_of(&v, self.method.as_deref()).map_err(|e| ExportError::In {
            path: path(),
            source: Box::new(e),
        })?;
        Ok(cal)
    }

    /// What an export of `cal` into [`Self::ros2`] did, in a line: the file written, or the
    /// multipliers merged (through a symbolic link: which file was written) and how to undo it.
    pub fn said(&self, cal: &Calibration, exported: &Exported) -> String {
        let to = self.ros2.display();
        match exported {
            Exported::Created => format!("wrote {to} ({} calibration)", cal.method),
            Exported::Merged { backup } => {
                let target = crate::io::write_target(&self.ros2);
                let link = match target == self.ros2 {
                    true => String::new(),
                    false => format!(" (a link: written to {}, which it names)", target.display()),
                };
                format!(
                    "merged the {} calibration's multipliers into {to}{link} (undo: odocal \
                     restore {})",
                    cal.method,
                    backup.display()
                )
            }
        }
    }
}

/// What [`export`] did.
#[derive(Debug, Clone, PartialEq)]
pub enum Exported {
    /// A new file.
    Created,
    /// Merged into an existing controller YAML; the original is at `backup`.
    Merged {
        /// The backup of the file as it was (`odocal restore` takes it).
        backup: PathBuf,
    },
}

/// Largest factor between a calibrated and a configured parameter an export accepts (skid-steer
/// wheelbase multipliers reach about 2).
pub const MAX_FACTOR: f64 = 10.0;

/// Refuses calibrations that scale a parameter by more than [`MAX_FACTOR`] or by a non-number.
fn check_plausible(cal: &Calibration) -> Result<(), ExportError> {
    cal.calibrated.validate()?;
    cal.configured.validate()?;
    for (name, new, old) in [
        (
            "left wheel diameter",
            cal.calibrated.left_wheel_diameter_m,
            cal.configured.left_wheel_diameter_m,
        ),
        (
            "right wheel diameter",
            cal.calibrated.right_wheel_diameter_m,
            cal.configured.right_wheel_diameter_m,
        ),
        (
            "wheelbase",
            cal.calibrated.wheelbase_m,
            cal.configured.wheelbase_m,
        ),
    ] {
        let factor = new / old;
        if !(factor.is_finite() && (1.0 / MAX_FACTOR..=MAX_FACTOR).contains(&factor)) {
            return Err(ExportError::Implausible { name, factor });
        }
    }
    Ok(())
}

/// Writes `cal` for `controller` into `path`: merged into an existing YAML when `merge`
/// (multipliers only, through the write service: backed up beside the file, replaced
/// atomically, read back, undone on failure; without `merge` an existing file is refused,
/// [`ExportError::Exists`]) or a new file (never replacing anything). A calibration that scales
/// a parameter beyond [`MAX_FACTOR`] is refused.
pub async fn export(
    (path, merge): (&Path, bool),
    controller: &str,
    cal: &Calibration,
    ui: &mut dyn WriteUi,
) -> Result<Exported, ExportError> {
    if path.exists() && !merge {
        return Err(ExportError::Exists {
            path: path.to_path_buf(),
            method: cal.method.clone(),
        });
    }
    check_plausible(cal)?;
    let io = |source| ExportError::Io {
        path: path.to_path_buf(),
        source,
    };
    if path.exists() {
        let store = std::sync::Arc::new(YamlStore::open(path, controller)?);
        let current = store.read().await.map_err(WriteError::Base)?;
        // A ROS robot's wheel angles are radians: the count stays the file's own.
        let new = WheelParams {
            counts_per_wheel_rev: current.counts_per_wheel_rev,
            ..cal.calibrated
        };
        let request = WriteRequest {
            new,
            // Checked against the result's own configuration above ([`check_plausible`]).
            bounds: Bounds::Physical,
            policy: WritePolicy::Yes,
            commit: Commit::Both,
            backup_dir: crate::io::dir_of(path),
            question: Question::Plain(String::new()),
        };
        let done = write_once(store, None, request, ui).await?;
        return Ok(Exported::Merged {
            backup: done.backup,
        });
    }
    let text = ros2_diff_drive_yaml(controller, &cal.configured, &cal.calibrated);
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)
        .map_err(io)?;
    std::io::Write::write_all(&mut f, text.as_bytes()).map_err(io)?;
    Ok(Exported::Created)
}

/// YAML parameters for ros2_control's `diff_drive_controller`.
///
/// The URDF keeps the nominal geometry (`wheel_separation`, `wheel_radius` from `nominal`, the
/// mean of its two wheels); the calibration goes into the controller's multipliers, which is
/// how the controller expects corrections: `wheel_separation_multiplier = b_cal / b_nom` and
/// `left/right_wheel_radius_multiplier = D_cal / D_nom` per wheel.
pub fn ros2_diff_drive_yaml(
    controller_name: &str,
    nominal: &WheelParams,
    calibrated: &WheelParams,
) -> String {
    let radius = 0.25 * (nominal.left_wheel_diameter_m + nominal.right_wheel_diameter_m);
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Written by odocal {}: odometry calibration for diff_drive_controller.",
        env!("CARGO_PKG_VERSION")
    );
    let _ = writeln!(
        s,
        "# Calibrated: left D {:.9} m, right D {:.9} m, wheelbase {:.9} m.",
        calibrated.left_wheel_diameter_m, calibrated.right_wheel_diameter_m, calibrated.wheelbase_m
    );
    // A namespaced name (`ns/ctrl`) is a fully qualified node key.
    let key = match controller_name.contains('/') && !controller_name.starts_with('/') {
        true => format!("/{controller_name}"),
        false => controller_name.to_string(),
    };
    let _ = writeln!(s, "{key}:\n  ros__parameters:");
    let _ = writeln!(s, "    wheel_separation: {:.9}", nominal.wheelbase_m);
    let _ = writeln!(s, "    wheel_radius: {radius:.9}");
    let _ = writeln!(
        s,
        "    wheel_separation_multiplier: {:.9}",
        calibrated.wheelbase_m / nominal.wheelbase_m
    );
    let _ = writeln!(
        s,
        "    left_wheel_radius_multiplier: {:.9}",
        calibrated.left_wheel_diameter_m / (2.0 * radius)
    );
    let _ = writeln!(
        s,
        "    right_wheel_radius_multiplier: {:.9}",
        calibrated.right_wheel_diameter_m / (2.0 * radius)
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(from: &Path, ros2: &Path) -> ExportSettings {
        ExportSettings {
            from: from.to_path_buf(),
            ros2: ros2.to_path_buf(),
            controller: "diff_drive_controller".into(),
            method: None,
            force: false,
        }
    }

    #[tokio::test]
    async fn a_result_that_cannot_be_read_and_a_target_that_exists_are_refused_by_name() {
        let dir = std::env::temp_dir().join(format!("odocal-export-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let (json, yaml) = (dir.join("result.json"), dir.join("robot.yaml"));
        let e = settings(&json, &yaml).calibration().unwrap_err();
        assert!(matches!(e, ExportError::Unreadable { .. }), "{e}");
        std::fs::write(&json, "{ not json").unwrap();
        let e = settings(&json, &yaml).calibration().unwrap_err();
        assert!(matches!(e, ExportError::NotJson { .. }), "{e}");
        std::fs::write(&json, r#"{"unrelated": 1}"#).unwrap();
        let e = settings(&json, &yaml).calibration().unwrap_err();
        assert!(
            matches!(&e, ExportError::In { source, .. } if matches!(**source, ExportError::NotAResult(_))),
            "{e}"
        );
        assert!(
            e.to_string().starts_with(&json.display().to_string()),
            "{e}"
        );

        let nominal = WheelParams::nominal(0.15, 0.39, std::f64::consts::TAU);
        let cal = Calibration {
            configured: nominal,
            calibrated: WheelParams {
                wheelbase_m: 0.38,
                ..nominal
            },
            method: "exact".into(),
        };
        std::fs::write(&yaml, "kept: as it was\n").unwrap();
        let ui = &mut crate::base::write::Unattended;
        let e = export((&yaml, false), "diff_drive_controller", &cal, ui)
            .await
            .unwrap_err();
        assert!(matches!(e, ExportError::Exists { .. }), "{e}");
        assert!(
            e.to_string()
                .contains("--force merges the exact calibration"),
            "{e}"
        );
        assert_eq!(std::fs::read_to_string(&yaml).unwrap(), "kept: as it was\n");
        let new = dir.join("new.yaml");
        let made = export((&new, false), "diff_drive_controller", &cal, ui)
            .await
            .unwrap();
        assert_eq!(made, Exported::Created);
        assert!(std::fs::read_to_string(&new)
            .unwrap()
            .contains("wheel_separation_multiplier"));
    }

    #[test]
    fn multipliers_reproduce_the_calibrated_geometry() {
        let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
        let cal = WheelParams {
            right_wheel_diameter_m: 0.1488,
            wheelbase_m: 0.38064,
            ..nominal
        };
        let y = ros2_diff_drive_yaml("diff_drive_controller", &nominal, &cal);
        let get = |k: &str| -> f64 {
            y.lines()
                .find_map(|l| l.trim().strip_prefix(k)?.strip_prefix(':'))
                .unwrap()
                .trim()
                .parse()
                .unwrap()
        };
        assert!(
            (get("wheel_separation") * get("wheel_separation_multiplier") - 0.38064).abs() < 1e-9
        );
        assert!(
            (2.0 * get("wheel_radius") * get("right_wheel_radius_multiplier") - 0.1488).abs()
                < 1e-9
        );
        assert!((get("left_wheel_radius_multiplier") - 1.0).abs() < 1e-12);
        assert!(y.starts_with("# Written by odocal"));
    }
}
