//! Several bags of one robot analysed as one session (`odocal bag`): each bag read and its
//! squares estimated against the controller's YAML (or the geometry inferred from its own
//! odometry), the estimates pooled onto the first bag's configuration, the IMU's kind decided
//! once; and the text and JSON a person reads of it.

use super::analyse::{heading_kind, pool, BagReport, GeometrySource, PooledBags};
use super::{infer_geometry, read_bag, BagError, BagOptions, RosTopics};
use crate::calibration::stated::{
    default_line, disagreement_lines, pm, pm_b, pm_d, within_session_legend, Basis,
};
use crate::calibration::{HeadingKind, Method};
use crate::ros::yaml::DiffDriveConfig;
use serde_json::json;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// What the bags of one session gave.
#[derive(Debug, Clone)]
pub struct BagSession {
    /// Each bag's analysis, in the order given.
    pub reports: Vec<BagReport>,
    /// Their estimates pooled onto the first bag's configuration.
    pub pooled: PooledBags,
    /// What the IMU's yaw is.
    pub kind: HeadingKind,
    /// Where that comes from.
    pub kind_from: &'static str,
}

/// Where a ROS robot's geometry and data are.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct RosSource {
    /// The controller's ros2_control YAML (its `ros__parameters:` at any nesting: `/**:`,
    /// namespaced keys, several documents).
    #[cfg_attr(feature = "cli", arg(long))]
    pub ros_yaml: Option<PathBuf>,
    /// The diff_drive_controller's name (`ns/name` to pick one namespace's).
    #[cfg_attr(feature = "cli", arg(long, default_value = crate::ros::yaml::DEFAULT_CONTROLLER))]
    pub controller: String,
    /// Wheel joint states topic (sensor_msgs/JointState).
    #[cfg_attr(feature = "cli", arg(long, default_value = "/joint_states"))]
    pub joint_states_topic: String,
    /// IMU topic (sensor_msgs/Imu with an orientation).
    #[cfg_attr(feature = "cli", arg(long, default_value = "/imu"))]
    pub imu_topic: String,
    /// The controller's odometry topic (nav_msgs/Odometry).
    #[cfg_attr(feature = "cli", arg(long, default_value = "/odom"))]
    pub odom_topic: String,
    /// Left wheel joint name [default: the YAML's first left_wheel_names, else the one name
    /// with "left"].
    #[cfg_attr(feature = "cli", arg(long))]
    pub left_joint: Option<String>,
    /// Right wheel joint name [default: the YAML's first right_wheel_names, else the one name
    /// with "right"].
    #[cfg_attr(feature = "cli", arg(long))]
    pub right_joint: Option<String>,
}

impl RosSource {
    /// The topics.
    pub fn topics(&self) -> RosTopics {
        RosTopics {
            joint_states: self.joint_states_topic.clone(),
            imu: self.imu_topic.clone(),
            odom: self.odom_topic.clone(),
        }
    }

    /// The YAML section, if a file was given.
    pub fn config(&self) -> Result<Option<DiffDriveConfig>, BagError> {
        Ok(match &self.ros_yaml {
            Some(p) => Some(DiffDriveConfig::load(p, &self.controller)?),
            None => None,
        })
    }
}

/// A bag session as a user sets it (with the `cli` feature, `odocal bag`'s flags).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct BagSettings {
    /// Where the robot's geometry and data are.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub ros: RosSource,
    /// Explicit runs instead of finding them: START:END seconds from the bag's first message;
    /// repeatable.
    #[cfg_attr(feature = "cli", arg(long = "range"))]
    pub ranges: Vec<String>,
    /// Square side (m) [default: the bag's metadata, else the mean leg length by odometry].
    #[cfg_attr(feature = "cli", arg(long))]
    pub side_m: Option<f64>,
    /// Shortest rest (s) that separates one run from the next.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.5))]
    pub min_rest_s: f64,
    /// Diameter split: left-nominal, mean-preserving or measured-scale:COMMANDED_M,MEASURED_M.
    #[cfg_attr(feature = "cli", arg(long, default_value = "left-nominal"))]
    pub convention: crate::kinematics::SplitConvention,
    /// What the IMU's yaw is: magnetic (a compass or a 9-axis fusion: it may deviate), gyro
    /// (integrated), reference (ground truth) or unknown. It decides the default method
    /// [default: what the bag's `odocal` metadata says (bags odocal wrote), else unknown].
    #[cfg_attr(feature = "cli", arg(long))]
    pub heading_kind: Option<HeadingKind>,
}

/// `START:END` seconds, as `--range` gives it.
fn parse_range(s: &str) -> Result<(f64, f64), BagError> {
    let bad = |why: String| BagError::Setting(format!("--range {s}: {why}"));
    let (a, b) = s
        .split_once(':')
        .ok_or_else(|| bad("expected START:END in seconds".into()))?;
    let num = |v: &str| {
        v.trim()
            .parse::<f64>()
            .map_err(|_| bad(format!("{v:?} is not a number of seconds")))
    };
    Ok((num(a)?, num(b)?))
}

impl BagSettings {
    /// Reads and analyses `files` as bags of one robot with these settings
    /// ([`analyse_files`]); the wheel joints default to the YAML's first of each side.
    pub fn analyse(&self, files: &[PathBuf]) -> Result<BagSession, BagError> {
        let cfg = self.ros.config()?;
        let first = |names: fn(&DiffDriveConfig) -> &Vec<String>| {
            cfg.as_ref().and_then(|c| names(c).first().cloned())
        };
        let opts = BagOptions {
            topics: self.ros.topics(),
            left_joint: self
                .ros
                .left_joint
                .clone()
                .or_else(|| first(|c| &c.left_wheel_names)),
            right_joint: (self.ros.right_joint.clone()).or_else(|| first(|c| &c.right_wheel_names)),
            min_rest_s: self.min_rest_s,
            ranges: self
                .ranges
                .iter()
                .map(|r| parse_range(r))
                .collect::<Result<_, _>>()?,
            side_m: self.side_m,
            convention: self.convention,
        };
        if let Some(s) = opts
            .side_m
            .filter(|s| !(s.is_finite() && *s > 0.0 && *s <= 100.0))
        {
            return Err(BagError::Setting(format!(
                "--side-m must be in (0, 100] m, got {s}"
            )));
        }
        let yaml = match (&cfg, &self.ros.ros_yaml) {
            (Some(c), Some(path)) => Some((path.as_path(), c)),
            _ => None,
        };
        analyse_files(files, &opts, yaml, self.heading_kind)
    }
}

/// Reads and analyses `files` as bags of one robot: geometry from `yaml` (the controller's
/// file and its section) when given, else inferred from each bag; the IMU's kind `given`, else
/// from the bags' metadata.
pub fn analyse_files(
    files: &[PathBuf],
    opts: &BagOptions,
    yaml: Option<(&Path, &DiffDriveConfig)>,
    given: Option<HeadingKind>,
) -> Result<BagSession, BagError> {
    let mut reports = Vec::new();
    let mut nominal_of_first = None;
    let mut kinds = Vec::new();
    for file in files {
        let data = read_bag(file, opts)?;
        kinds.push(data.heading_kind);
        let (configured, geometry, nominal) = match yaml {
            Some((path, c)) => (
                c.effective(),
                GeometrySource::Yaml {
                    file: path.to_path_buf(),
                    controller: c.controller.clone(),
                },
                (c.wheel_radius_m, c.wheel_separation_m),
            ),
            None => {
                let g = infer_geometry(&data)?;
                (
                    g.params(),
                    GeometrySource::Inferred(g),
                    (g.wheel_radius_m, g.wheel_separation_m),
                )
            }
        };
        nominal_of_first.get_or_insert(nominal);
        reports.push(super::analyse(
            file, &data, configured, geometry, nominal, opts,
        )?);
    }
    let nominal = nominal_of_first.unwrap_or((f64::NAN, f64::NAN));
    let (kind, kind_from) = heading_kind(given, &kinds);
    let pooled = pool(&reports, nominal, opts.convention, kind)?;
    Ok(BagSession {
        reports,
        pooled,
        kind,
        kind_from,
    })
}

impl BagSession {
    /// The session as stdout's JSON: one bag's report, or every bag's and the pooled values.
    pub fn json(&self) -> serde_json::Result<serde_json::Value> {
        if let [report] = self.reports.as_slice() {
            let mut v = serde_json::to_value(report)?;
            v["default_method"] = json!(self.pooled.default_method);
            return Ok(v);
        }
        Ok(json!({
            "bags": self.reports,
            "pooled": self.pooled.methods,
            "estimates": self.pooled.estimates,
            "uncertainty": self.pooled.methods.uncertainty,
            "default_method": self.pooled.default_method,
        }))
    }

    /// The session as the terminal shows it: each bag, then the pooled estimates when there
    /// are several, the default method and any disagreement. `topics` names where an inferred
    /// geometry came from.
    pub fn text(&self, topics: &RosTopics) -> String {
        let mut out = String::new();
        let default = self.pooled.default_method;
        for report in &self.reports {
            bag_text(&mut out, report, topics, default);
        }
        let _ = writeln!(out, "IMU yaw: {} ({})", self.kind, self.kind_from);
        if self.reports.len() > 1 {
            self.pooled_text(&mut out);
        }
        if let Some(m) = default {
            let _ = writeln!(out, "{}", default_line(m));
        }
        if self.reports.len() > 1 {
            let estimates: Vec<_> = self
                .pooled
                .estimates
                .iter()
                .map(|e| e.estimate.clone())
                .collect();
            for line in disagreement_lines(default, "the default", Basis::Pooled, &estimates) {
                let _ = writeln!(out, "{line}");
            }
        }
        out
    }

    /// The pooled table, with what its ± is.
    fn pooled_text(&self, out: &mut String) {
        let _ = writeln!(
            out,
            "\npooled over {} bags, against {}'s configuration; ± is one standard deviation of \
             what the next bag of this robot will read (a prediction: the pooled value's \
             standard error, the bag-to-bag spread and one bag's own scatter; --json has each \
             quantity's std_err and prediction_std)",
            self.reports.len(),
            self.reports[0].file.display()
        );
        let _ = writeln!(
            out,
            "{:<14}{:>11}{:>11}{:>11}{:>11}   {:>12}{:>12}{:>12}",
            "method", "E_b", "±", "E_d", "±", "sep_mult", "left_mult", "right_mult"
        );
        for e in &self.pooled.estimates {
            let mark = if self.pooled.default_method == Some(e.estimate.method) {
                "  (default)"
            } else {
                ""
            };
            let (b, d) = self
                .pooled
                .methods
                .pooled
                .iter()
                .find(|p| p.method == e.estimate.method)
                .map_or((None, None), |p| p.prediction_std(&e.estimate));
            let _ = writeln!(
                out,
                "{:<14}{:>11.6}{:>11}{:>11.6}{:>11}   {:>12.6}{:>12.6}{:>12.6}{mark}",
                e.estimate.method.name(),
                e.estimate.e_b,
                pm(b),
                e.estimate.e_d,
                pm(d),
                e.multipliers.wheel_separation_multiplier,
                e.multipliers.left_wheel_radius_multiplier,
                e.multipliers.right_wheel_radius_multiplier
            );
        }
        for (m, bags) in &self.pooled.methods.missing {
            let _ = writeln!(
                out,
                "{:<14}– not estimated on {}",
                m.name(),
                bags.join(", ")
            );
        }
    }
}

/// One bag: where its geometry came from, its squares, every method's estimate with its ±,
/// the online filter's, and what to look at.
fn bag_text(out: &mut String, report: &BagReport, topics: &RosTopics, default: Option<Method>) {
    let _ = writeln!(out, "== {}", report.file.display());
    let _ = match &report.geometry {
        GeometrySource::Yaml { file, controller } => writeln!(
            out,
            "configured geometry from {} ({controller}): wheel radius {:.6} m, separation {:.6} m",
            file.display(),
            0.5 * report.configured.left_wheel_diameter_m,
            report.configured.wheelbase_m
        ),
        GeometrySource::Inferred(g) => writeln!(
            out,
            "configured geometry INFERRED from {} against {} (no --ros-yaml given): wheel radius \
             {:.6} m, separation {:.6} m over {} intervals",
            topics.odom, topics.joint_states, g.wheel_radius_m, g.wheel_separation_m, g.intervals
        ),
    };
    let _ = writeln!(
        out,
        "{} messages; {} square run(s), side {:.3} m (from {})",
        report.messages,
        report.runs.len(),
        report.side_m,
        report.side_source
    );
    for r in &report.runs {
        let _ = writeln!(
            out,
            "  {:>7.1}–{:<7.1} s  {:<3}  heading error {:+.3}°",
            r.start_s,
            r.end_s,
            r.direction,
            r.heading_error_rad.to_degrees()
        );
    }
    for s in &report.skipped {
        let _ = writeln!(out, "  skipped: {s}");
    }
    for n in &report.notes {
        let _ = writeln!(out, "note: {n}");
    }
    let _ = writeln!(
        out,
        "\n{:<14}{:>11}{:>11}{:>11}{:>11}   {:>12}{:>12}{:>12}",
        "method", "E_b", "±", "E_d", "±", "sep_mult", "left_mult", "right_mult"
    );
    for e in &report.estimates {
        let _ = writeln!(
            out,
            "{:<14}{:>11.6}{:>11}{:>11.6}{:>11}   {:>12.6}{:>12.6}{:>12.6}{}",
            e.estimate.method.name(),
            e.estimate.e_b,
            pm_b(&e.estimate),
            e.estimate.e_d,
            pm_d(&e.estimate),
            e.multipliers.wheel_separation_multiplier,
            e.multipliers.left_wheel_radius_multiplier,
            e.multipliers.right_wheel_radius_multiplier,
            if default == Some(e.estimate.method) {
                "  (default)"
            } else {
                ""
            }
        );
    }
    let estimates: Vec<_> = report
        .estimates
        .iter()
        .map(|e| e.estimate.clone())
        .collect();
    for line in within_session_legend(&estimates) {
        let _ = writeln!(out, "{line}");
    }
    for line in disagreement_lines(default, "the default", Basis::Session, &estimates) {
        let _ = writeln!(out, "{line}");
    }
    for (m, why) in &report.failures {
        let _ = writeln!(out, "{:<14}– {why}", m.name());
    }
    online_text(out, report);
}

/// What the online filter made of the whole bag, and the IMU's delay when it matters.
fn online_text(out: &mut String, report: &BagReport) {
    if let Some(o) = &report.online {
        let _ = writeln!(
            out,
            "{:<14}{:>11.6}{:>11}{:>11.6}{:>11}   (± is 1σ of the online filter over the whole \
             bag, {:.1} m driven, mean NIS {:.2})",
            "online",
            o.e_b,
            pm(Some(o.e_b_std)),
            o.e_d,
            pm(Some(o.e_d_std)),
            o.distance_m,
            report.online_nis.unwrap_or(f64::NAN)
        );
    }
    if let Some(g) = report.online_gate.as_ref().filter(|g| g.rejected > 0) {
        let _ = writeln!(
            out,
            "online: {} IMU reading(s) rejected by the gate, {} re-anchor(s)",
            g.rejected, g.resets
        );
    }
    if let Some(advice) = report.online_excitation.as_ref().and_then(|x| x.advice()) {
        let _ = writeln!(out, "online: {advice}");
    }
    if let Some(o) = report.time_offset.as_ref().filter(|o| o.significant()) {
        let _ = writeln!(
            out,
            "warning: the IMU {} the joint states by {:.3} s (rate correlation {:.2}, {:.2} at \
             0 s); corrected for the online filter",
            if o.offset_s >= 0.0 { "lags" } else { "leads" },
            o.offset_s.abs(),
            o.correlation,
            o.correlation_at_zero
        );
    }
}

#[cfg(test)]
mod settings_tests {
    use super::*;

    fn settings() -> BagSettings {
        BagSettings {
            ros: RosSource {
                ros_yaml: None,
                controller: "diff_drive_controller".into(),
                joint_states_topic: "/joint_states".into(),
                imu_topic: "/imu".into(),
                odom_topic: "/odom".into(),
                left_joint: None,
                right_joint: None,
            },
            ranges: Vec::new(),
            side_m: None,
            min_rest_s: 0.5,
            convention: crate::kinematics::SplitConvention::LeftNominal,
            heading_kind: None,
        }
    }

    #[test]
    fn ranges_are_start_end_seconds_and_a_side_is_checked_before_any_bag_is_read() {
        assert_eq!(parse_range(" 1.5 : 20").unwrap(), (1.5, 20.0));
        for bad in ["12", "a:3", "1:"] {
            let e = parse_range(bad).unwrap_err();
            assert!(
                matches!(&e, BagError::Setting(m) if m.starts_with("--range")),
                "{e}"
            );
        }
        let s = BagSettings {
            side_m: Some(-4.0),
            ..settings()
        };
        let none: [PathBuf; 0] = [];
        let e = s.analyse(&none).unwrap_err();
        assert!(e.to_string().contains("--side-m"), "{e}");
        assert!(matches!(settings().analyse(&none), Err(BagError::NoBags)));
    }
}
