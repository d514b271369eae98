//! What the routine measured and did: the report's data, its Markdown form, and the report
//! directory (`report.json`, `report.md`, SVG plots).

use super::config::RoutineConfig;
use super::{plots, GroundTruth};
use crate::calibration::{Estimate, Method};
use crate::hal::motion::SquareRecord;
use crate::hal::{Client, LinkStatsSnapshot, TelemetrySample};
use crate::kinematics::{Direction, Pose, WheelParams};
use crate::protocol::message::DeviceInfo;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Which part of the routine a run belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case", tag = "phase")]
pub enum Phase {
    /// A calibration round.
    Calibration {
        /// Round number (1-based).
        round: usize,
    },
    /// Verification after writing.
    Verification,
}

impl Phase {
    /// "round 2" or "verification".
    pub fn label(&self) -> String {
        match self {
            Phase::Calibration { round } => format!("round {round}"),
            Phase::Verification => "verification".into(),
        }
    }
}

/// Most points kept per path in the report.
const PATH_POINTS: usize = 400;

/// One square as the report keeps it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunReport {
    /// Phase.
    #[serde(flatten)]
    pub phase: Phase,
    /// Direction.
    pub direction: Direction,
    /// Final-minus-start heading error (rad).
    pub heading_error_rad: f64,
    /// The same in degrees.
    pub heading_error_deg: f64,
    /// Mean heading at rest before (rad).
    pub heading_before_rad: f64,
    /// Mean heading at rest after (rad).
    pub heading_after_rad: f64,
    /// Parameters configured during the run.
    pub params: WheelParams,
    /// True final position in the start frame (simulation only).
    pub true_final_xy_m: Option<[f64; 2]>,
    /// Odometry path from telemetry (start frame, decimated).
    pub odometry_path: Vec<[f64; 2]>,
    /// True path (simulation only): the same wheel counts with the true parameters.
    pub true_path: Option<Vec<[f64; 2]>>,
    /// Telemetry samples received.
    pub telemetry_samples: usize,
    /// Plausibility warnings.
    pub warnings: Vec<String>,
}

/// Integrates a telemetry trace's encoder counts with `params`, from the origin.
fn integrate(trace: &[TelemetrySample], params: &WheelParams) -> Vec<[f64; 2]> {
    let mut pose = Pose::default();
    let mut out = vec![[0.0, 0.0]];
    for w in trace.windows(2) {
        pose = params.odometry_step(
            &pose,
            (w[1].left_counts - w[0].left_counts) as f64,
            (w[1].right_counts - w[0].right_counts) as f64,
        );
        out.push([pose.x_m, pose.y_m]);
    }
    let step = out.len().div_ceil(PATH_POINTS).max(1);
    let last = out.last().copied();
    let mut kept: Vec<[f64; 2]> = out.into_iter().step_by(step).collect();
    if let (Some(l), Some(k)) = (last, kept.last()) {
        if *k != l {
            kept.push(l);
        }
    }
    kept
}

impl RunReport {
    /// The report of one measured square.
    pub fn new(
        phase: Phase,
        rec: &SquareRecord,
        params: &WheelParams,
        start: Option<Pose>,
        truth: Option<&dyn GroundTruth>,
    ) -> Self {
        let true_final_xy_m = match (start, truth) {
            (Some(s), Some(t)) => {
                let p = t.pose().relative_to(&s);
                Some([p.x_m, p.y_m])
            }
            _ => None,
        };
        let mut warnings = Vec::new();
        if rec.heading_error_rad.abs() > super::IMPLAUSIBLE_HEADING_RAD {
            warnings.push(format!(
                "{} {} run: heading error {:.1}° exceeds 45°: check the square size, wheel \
                 slip and the heading sensor",
                phase.label(),
                rec.command.direction,
                rec.heading_error_rad.to_degrees()
            ));
        }
        RunReport {
            phase,
            direction: rec.command.direction,
            heading_error_rad: rec.heading_error_rad,
            heading_error_deg: rec.heading_error_rad.to_degrees(),
            heading_before_rad: rec.heading_before_rad,
            heading_after_rad: rec.heading_after_rad,
            params: *params,
            true_final_xy_m,
            odometry_path: integrate(&rec.trace, params),
            true_path: truth.map(|t| integrate(&rec.trace, &t.true_params())),
            telemetry_samples: rec.trace.len(),
            warnings,
        }
    }
}

/// One calibration round.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RoundReport {
    /// Round number (1-based).
    pub round: usize,
    /// Parameters configured during the round.
    pub params_before: WheelParams,
    /// The squares.
    pub runs: Vec<RunReport>,
    /// Every method's estimate.
    pub estimates: Vec<Estimate>,
    /// Methods without an estimate, and why.
    pub failures: Vec<(Method, String)>,
    /// The configured method's estimate.
    pub chosen: Estimate,
    /// Cramér–Rao bound on the std of (E_b, E_d) for the measured heading noise.
    pub cramer_rao_std: Option<[f64; 2]>,
    /// Whether this round's estimate was within tolerance of 1.
    pub converged: bool,
    /// Parameters proposed from this round (absent when converged).
    pub params_after: Option<WheelParams>,
    /// Whether they were written.
    pub written: bool,
}

/// Everything one routine run measured and did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Report {
    /// odocal version.
    pub odocal_version: String,
    /// The device.
    pub device: DeviceInfo,
    /// The settings.
    pub config: RoutineConfig,
    /// Parameters found on the controller (backed up).
    pub original_params: WheelParams,
    /// Where the backup was written.
    pub backup_path: PathBuf,
    /// Parameters on the controller at the end.
    pub final_params: WheelParams,
    /// Heading noise at rest (σ of single readings, rad).
    pub heading_noise_rad: f64,
    /// Calibration rounds.
    pub rounds: Vec<RoundReport>,
    /// Verification squares (after writing).
    pub verification: Vec<RunReport>,
    /// Whether the routine converged.
    pub converged: bool,
    /// Whether parameters were written.
    pub written: bool,
    /// The last round's estimates (every method), for tools that read `estimates`.
    pub estimates: Vec<Estimate>,
    /// `E_max,sys` of the first round (simulation only; m).
    pub e_max_sys_before_m: Option<f64>,
    /// `E_max,sys` of the verification (simulation only; m).
    pub e_max_sys_after_m: Option<f64>,
    /// Mean |final heading error| of the first round (deg).
    pub mean_abs_heading_error_before_deg: f64,
    /// Mean |final heading error| of the verification (deg).
    pub mean_abs_heading_error_after_deg: Option<f64>,
    /// Link health.
    pub link: LinkStatsSnapshot,
    /// Warnings raised on the way.
    pub warnings: Vec<String>,
}

/// `E_max,sys` of runs with true final positions (simulation only), see
/// [`crate::calibration::e_max_sys`].
pub fn e_max_sys(runs: &[RunReport]) -> Option<f64> {
    let ends = |d: Direction| -> Option<Vec<[f64; 2]>> {
        runs.iter()
            .filter(|r| r.direction == d)
            .map(|r| r.true_final_xy_m)
            .collect()
    };
    crate::calibration::e_max_sys(&ends(Direction::Cw)?, &ends(Direction::Ccw)?)
}

fn mean_abs_heading_deg(runs: &[RunReport]) -> Option<f64> {
    (!runs.is_empty())
        .then(|| runs.iter().map(|r| r.heading_error_deg.abs()).sum::<f64>() / runs.len() as f64)
}

impl Report {
    #[allow(clippy::too_many_arguments)]
    pub(super) fn assemble(
        client: &Client,
        cfg: &RoutineConfig,
        original_params: WheelParams,
        backup_path: PathBuf,
        final_params: WheelParams,
        heading_noise_rad: f64,
        rounds: Vec<RoundReport>,
        verification: Vec<RunReport>,
        converged: bool,
        written: bool,
        warnings: Vec<String>,
    ) -> Self {
        let first = rounds.first().map(|r| r.runs.as_slice()).unwrap_or(&[]);
        Report {
            odocal_version: env!("CARGO_PKG_VERSION").into(),
            device: client.device_info().clone(),
            config: cfg.clone(),
            original_params,
            backup_path,
            final_params,
            heading_noise_rad,
            e_max_sys_before_m: e_max_sys(first),
            e_max_sys_after_m: e_max_sys(&verification),
            mean_abs_heading_error_before_deg: mean_abs_heading_deg(first).unwrap_or(0.0),
            mean_abs_heading_error_after_deg: mean_abs_heading_deg(&verification),
            estimates: rounds
                .last()
                .map(|r| r.estimates.clone())
                .unwrap_or_default(),
            rounds,
            verification,
            converged,
            written,
            link: client.stats(),
            warnings,
        }
    }

    /// The before/after summary as a plain-text table.
    pub fn summary_table(&self) -> String {
        let mut s = String::new();
        let opt =
            |v: Option<f64>, unit: &str| v.map_or("–".to_string(), |v| format!("{v:.4} {unit}"));
        let _ = writeln!(s, "{:<34} {:>14} {:>14}", "", "before", "after");
        let _ = writeln!(
            s,
            "{:<34} {:>14} {:>14}",
            "E_max,sys (true end points)",
            opt(self.e_max_sys_before_m, "m"),
            opt(self.e_max_sys_after_m, "m")
        );
        let _ = writeln!(
            s,
            "{:<34} {:>14} {:>14}",
            "mean |final heading error|",
            format!("{:.3}°", self.mean_abs_heading_error_before_deg),
            self.mean_abs_heading_error_after_deg
                .map_or("–".to_string(), |v| format!("{v:.3}°"))
        );
        s.push('\n');
        s.push_str(&params_table(&self.original_params, &self.final_params));
        s
    }

    /// The report as Markdown.
    pub fn to_markdown(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "# odocal recalibration report\n");
        let _ = writeln!(
            s,
            "Device `{}` (serial {:#x}, protocol {}.{}), odocal {}.\n",
            self.device.firmware_id,
            self.device.serial_number,
            self.device.major,
            self.device.minor,
            self.odocal_version
        );
        let _ = writeln!(
            s,
            "Squares of {} m, {} per direction per round, method `{}`, convention `{}`, \
             write-back `{:?}`. Backup of the original parameters: `{}`.\n",
            self.config.side_m,
            self.config.runs_per_direction,
            self.config.method,
            self.config.split_convention().name(),
            self.config.write_back,
            self.backup_path.display()
        );
        let _ = writeln!(
            s,
            "Heading noise at rest: {:.3}°. Converged: {}. Written: {}.\n",
            self.heading_noise_rad.to_degrees(),
            self.converged,
            self.written
        );
        let _ = writeln!(
            s,
            "## Before and after\n\n```text\n{}```\n",
            self.summary_table()
        );
        for r in &self.rounds {
            let _ = writeln!(s, "## Round {}\n", r.round);
            let _ = writeln!(s, "| run | direction | heading error (°) |\n|---|---|---|");
            for (i, run) in r.runs.iter().enumerate() {
                let _ = writeln!(
                    s,
                    "| {} | {} | {:+.3} |",
                    i + 1,
                    run.direction,
                    run.heading_error_deg
                );
            }
            let _ = writeln!(s, "\n| method | E_b | ± | E_d | ± |\n|---|---|---|---|---|");
            for e in &r.estimates {
                let f = |v: Option<f64>| v.map_or("–".into(), |v| format!("{v:.5}"));
                let _ = writeln!(
                    s,
                    "| {}{} | {:.6} | {} | {:.6} | {} |",
                    e.method,
                    if e.method == r.chosen.method {
                        " (chosen)"
                    } else {
                        ""
                    },
                    e.e_b,
                    f(e.e_b_std_err),
                    e.e_d,
                    f(e.e_d_std_err)
                );
            }
            if let Some([b, d]) = r.cramer_rao_std {
                let _ = writeln!(s, "\nCramér–Rao bound (std): E_b {b:.5}, E_d {d:.5}.");
            }
            let _ = writeln!(
                s,
                "\n{}\n",
                if r.converged {
                    "Within tolerance: nothing to write.".to_string()
                } else if r.written {
                    "Written and saved.".to_string()
                } else {
                    "Not written.".to_string()
                }
            );
        }
        if !self.verification.is_empty() {
            let _ = writeln!(
                s,
                "## Verification\n\n| run | direction | heading error (°) |\n|---|---|---|"
            );
            for (i, run) in self.verification.iter().enumerate() {
                let _ = writeln!(
                    s,
                    "| {} | {} | {:+.3} |",
                    i + 1,
                    run.direction,
                    run.heading_error_deg
                );
            }
            s.push('\n');
        }
        if !self.warnings.is_empty() {
            let _ = writeln!(s, "## Warnings\n");
            for w in &self.warnings {
                let _ = writeln!(s, "- {w}");
            }
            s.push('\n');
        }
        let _ = writeln!(
            s,
            "## Plots\n\n![paths](paths.svg)\n\n![heading errors](heading_errors.svg)\n\n\
             ![end points](end_points.svg)\n"
        );
        s
    }

    /// Writes `report.json`, `report.md` and the SVG plots into `dir` (created if needed).
    pub fn write_dir(&self, dir: &Path) -> std::io::Result<Vec<PathBuf>> {
        std::fs::create_dir_all(dir)?;
        let json = dir.join("report.json");
        std::fs::write(
            &json,
            serde_json::to_string_pretty(self).map_err(std::io::Error::other)?,
        )?;
        let md = dir.join("report.md");
        std::fs::write(&md, self.to_markdown())?;
        let mut written = vec![json, md];
        written.extend(plots::write_all(self, dir)?);
        Ok(written)
    }
}

/// Old → new parameters, one per line, with the relative change.
pub fn params_table(old: &WheelParams, new: &WheelParams) -> String {
    let mut s = String::new();
    for (name, a, b) in [
        (
            "left wheel diameter (m)",
            old.left_wheel_diameter_m,
            new.left_wheel_diameter_m,
        ),
        (
            "right wheel diameter (m)",
            old.right_wheel_diameter_m,
            new.right_wheel_diameter_m,
        ),
        ("wheelbase (m)", old.wheelbase_m, new.wheelbase_m),
    ] {
        let _ = writeln!(
            s,
            "  {name:<26} {a:>12.6} → {b:>12.6}  ({:+.3} %)",
            (b / a - 1.0) * 100.0
        );
    }
    s
}
