//! What the routine measured and did, as data: every square, round and verification, the
//! parameters before and after, and the summary figures. Rendering it (Markdown, plots, files,
//! exports) is [`crate::report`]'s job.

use super::config::RoutineConfig;
use super::square::SquareRecord;
use super::GroundTruth;
use crate::base::{Base, BaseInfo, TravelSample};
use crate::calibration::legs::LegMeasurement;
use crate::calibration::recording::{coverage, Coverage, Track};
use crate::calibration::{Estimate, Method};
use crate::kinematics::{Direction, Displacement, Pose, WheelParams};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

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
        self.to_string()
    }
}

impl std::fmt::Display for Phase {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        Stage::of(*self).fmt(f)
    }
}

/// Where a run of the routine is, for its progress and a partial report: shown (and written
/// to JSON) as `pre-flight`, `round N`, `write-back after round N`, `verification`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Stage {
    /// Checking the drive and the heading sensor (nothing has moved).
    #[default]
    PreFlight,
    /// Turning in place to measure the compass's deviation.
    Swing,
    /// Driving and estimating a calibration round.
    Round(usize),
    /// Writing the parameters a round proposed.
    WriteBack {
        /// The round.
        round: usize,
    },
    /// Driving the verification squares.
    Verification,
}

impl Stage {
    /// The stage of driving a phase's squares.
    pub fn of(phase: Phase) -> Self {
        match phase {
            Phase::Calibration { round } => Stage::Round(round),
            Phase::Verification => Stage::Verification,
        }
    }
}

impl std::fmt::Display for Stage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Stage::PreFlight => f.write_str("pre-flight"),
            Stage::Swing => f.write_str("compass swing"),
            Stage::Round(round) => write!(f, "round {round}"),
            Stage::WriteBack { round } => write!(f, "write-back after round {round}"),
            Stage::Verification => f.write_str("verification"),
        }
    }
}

impl Serialize for Stage {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
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
    /// Heading error along the legs, middle of the first to the middle of the last (rad),
    /// when both streams ran ([`Track::leg_measurement`]).
    pub leg_heading_error_rad: Option<f64>,
    /// The drive's odometry over the run (turn and distance), when it reported it.
    pub odometry: Option<Displacement>,
    /// The heading along the legs, leg by leg (mean error and odometry at each leg's middle).
    pub legs: Option<LegMeasurement>,
    /// Parameters configured during the run.
    pub params: WheelParams,
    /// True final position in the start frame (simulation only).
    pub true_final_xy_m: Option<[f64; 2]>,
    /// Odometry path from the streamed wheel travel (start frame, decimated).
    pub odometry_path: Vec<[f64; 2]>,
    /// True path (simulation only): the same wheel rotations with the true parameters.
    pub true_path: Option<Vec<[f64; 2]>>,
    /// Wheel-travel samples streamed during the run.
    pub travel_samples: usize,
    /// Heading samples streamed during the run.
    pub heading_samples: usize,
    /// The run as streamed, decimated to at most 400 samples (as the paths are): what the
    /// report's plots re-integrate with other parameters and read the heading along the legs
    /// from. Empty in reports written before it existed, and when the drive did not stream.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub samples: Vec<RunSample>,
    /// How completely the heading stream covered the run (a stream that lost or delayed
    /// readings says by how much), when it streamed.
    pub heading_coverage: Option<Coverage>,
    /// Plausibility warnings.
    pub warnings: Vec<String>,
}

/// One sample of a run as the report keeps it ([`RunReport::samples`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RunSample {
    /// Time on the wheel travel's clock (s).
    pub time_s: f64,
    /// Left wheel's travel since the run's start (m), as the run's configured parameters
    /// measured it: another set of parameters rescales it by its metres per count.
    pub left_m: f64,
    /// Right wheel's travel since the run's start (m), as `left_m`.
    pub right_m: f64,
    /// The heading read at this time (rad, counter-clockwise positive, unwrapped along the run;
    /// as read, before any gyro scale is removed), or `None` where there was no valid reading.
    #[serde(default)]
    pub heading_rad: Option<f64>,
}

/// The run's samples from its aligned streams ([`Recording::track`]): cumulative wheel travel
/// and the heading at every travel sample, decimated to [`PATH_POINTS`] keeping the last.
/// Cumulative travel decimates without loss of the total, unlike increments.
fn run_samples(track: &Track, wheelbase_m: f64) -> Vec<RunSample> {
    let (mut left, mut right) = (0.0, 0.0);
    let all: Vec<RunSample> = track
        .points
        .iter()
        .map(|p| {
            let (l, r) = p.step.wheels(wheelbase_m);
            left += l;
            right += r;
            RunSample {
                time_s: p.time_s,
                left_m: left,
                right_m: right,
                heading_rad: p.heading_rad,
            }
        })
        .collect();
    let step = all.len().div_ceil(PATH_POINTS).max(1);
    let last = all.last().copied();
    let mut kept: Vec<RunSample> = all.into_iter().step_by(step).collect();
    if let (Some(l), Some(k)) = (last, kept.last()) {
        if *k != l {
            kept.push(l);
        }
    }
    kept
}

/// A heading stream that covered less of a run than this is reported as incomplete.
pub const INCOMPLETE: f64 = 0.9;

/// Integrates wheel travel reported with `configured` parameters as a robot with `actual`
/// parameters would move, from the origin; decimated to [`PATH_POINTS`].
fn integrate(
    travel: &[TravelSample],
    configured: &WheelParams,
    actual: &WheelParams,
) -> Vec<[f64; 2]> {
    let left = actual.left_m_per_count() / configured.left_m_per_count();
    let right = actual.right_m_per_count() / configured.right_m_per_count();
    let mut pose = Pose::default();
    let mut out = vec![[0.0, 0.0]];
    for t in travel {
        pose = pose.advance(t.left_m * left, t.right_m * right, actual.wheelbase_m);
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
        // The streams aligned once: the heading along the legs and the kept samples.
        let track = rec.recording().track(params.wheelbase_m);
        let legs = track.leg_measurement(params.wheelbase_m);
        let times: Vec<f64> = rec.headings.iter().map(|h| h.time_s).collect();
        let heading_coverage = coverage(&times);
        if let Some(c) = heading_coverage.filter(|c| c.fraction < INCOMPLETE) {
            warnings.push(format!(
                "{} {} run: the heading stream missed {:.1} s of {:.1} s ({:.0} % covered): \
                 readings lost or late",
                phase.label(),
                rec.command.direction,
                c.missing_s,
                c.span_s,
                100.0 * c.fraction
            ));
        }
        RunReport {
            phase,
            direction: rec.command.direction,
            heading_error_rad: rec.heading_error_rad,
            heading_error_deg: rec.heading_error_rad.to_degrees(),
            heading_before_rad: rec.heading_before_rad,
            heading_after_rad: rec.heading_after_rad,
            leg_heading_error_rad: legs.map(|l| l.heading_error_rad()),
            odometry: rec.odometry,
            legs,
            params: *params,
            true_final_xy_m,
            odometry_path: integrate(&rec.travel, params, params),
            true_path: truth.map(|t| integrate(&rec.travel, params, &t.true_params())),
            travel_samples: rec.travel.len(),
            heading_samples: rec.headings.len(),
            samples: run_samples(&track, params.wheelbase_m),
            heading_coverage,
            warnings,
        }
    }
}

impl RunReport {
    /// What the estimators take of this run (its final position where a ground truth gave
    /// one).
    pub fn measurement(&self) -> crate::calibration::RunMeasurement {
        crate::calibration::RunMeasurement {
            heading_error_rad: self.heading_error_rad,
            final_xy_m: self.true_final_xy_m,
            odometry: self.odometry,
            legs: self.legs,
            noise_variance_rad2: None,
        }
    }
    /// The run as a gyro of scale error `s` would have measured it without the error: every
    /// heading change divided by `1 + s` ([`crate::calibration::gyro`]), against the
    /// odometry's turn (the commanded ±2π when the drive did not report one).
    pub fn remove_gyro_scale(&mut self, s: f64, side_m: f64) {
        let mut m = self.measurement();
        crate::calibration::gyro::remove_scale_from_run(&mut m, self.direction, side_m, s);
        self.heading_error_rad = m.heading_error_rad;
        self.heading_error_deg = m.heading_error_rad.to_degrees();
        self.legs = m.legs;
        self.leg_heading_error_rad = m.legs.map(|l| l.heading_error_rad());
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
    /// Why that method: named in the settings, or the default for the data and the sensor
    /// ([`crate::calibration::default_method_reason`]).
    pub chosen_because: String,
    /// Cramér–Rao bound on the std of (E_b, E_d) for the measured heading noise.
    pub cramer_rao_std: Option<[f64; 2]>,
    /// Whether this round ended the calibration ([`super::convergence`]).
    pub converged: bool,
    /// Why it did.
    pub converged_because: Option<String>,
    /// Why its squares stopped, when they stop at a target precision
    /// ([`super::planning::stop`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stopped_because: Option<String>,
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
    /// The drive, heading source and parameter store.
    pub base: BaseInfo,
    /// The settings.
    pub config: RoutineConfig,
    /// Parameters found in the store (backed up).
    pub original_params: WheelParams,
    /// Where the backup was written.
    pub backup_path: PathBuf,
    /// Parameters in the store at the end.
    pub final_params: WheelParams,
    /// Heading noise at rest (σ of single readings, rad), pooled over the pre-flight's
    /// readings and every rest's.
    pub heading_noise_rad: f64,
    /// Heading noise the pre-flight measured before anything moved (σ of single readings at
    /// rest, rad; what it printed).
    #[serde(default)]
    pub preflight_heading_noise_rad: f64,
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
    /// The drive's link or device health at the end.
    pub diagnostics: serde_json::Value,
    /// Warnings raised on the way.
    pub warnings: Vec<String>,
    /// What the compass swing measured (removed from every reading after it), when it ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub swing: Option<crate::calibration::swing::SwingFit>,
    /// The plan shown before the robot moved ([`super::planning`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub plan: Option<crate::calibration::plan::Plan>,
    /// The directory this run's report goes to: the configured one, or `dir-N` when an
    /// earlier report holds it (claimed before the robot moved, so that this run's backup is
    /// there too).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub report_dir: Option<PathBuf>,
}

/// Every file a report directory receives.
pub const REPORT_FILES: [&str; 9] = [
    "report.json",
    "report.md",
    "report.html",
    "paths.svg",
    "heading_errors.svg",
    "end_points.svg",
    "estimates.svg",
    "swing.svg",
    "heading_along_legs.svg",
];

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

/// What a calibration ended with, for [`Report::assemble`].
pub(super) struct Outcome {
    pub original_params: WheelParams,
    pub backup_path: PathBuf,
    pub final_params: WheelParams,
    pub heading_noise_rad: f64,
    pub preflight_heading_noise_rad: f64,
    pub rounds: Vec<RoundReport>,
    pub verification: Vec<RunReport>,
    pub converged: bool,
    pub written: bool,
    pub warnings: Vec<String>,
}

impl Report {
    pub(super) fn assemble(base: &Base, cfg: &RoutineConfig, o: Outcome) -> Self {
        let first = o.rounds.first().map(|r| r.runs.as_slice()).unwrap_or(&[]);
        Report {
            odocal_version: env!("CARGO_PKG_VERSION").into(),
            base: base.info(),
            config: cfg.clone(),
            original_params: o.original_params,
            backup_path: o.backup_path,
            final_params: o.final_params,
            heading_noise_rad: o.heading_noise_rad,
            preflight_heading_noise_rad: o.preflight_heading_noise_rad,
            e_max_sys_before_m: e_max_sys(first),
            e_max_sys_after_m: e_max_sys(&o.verification),
            mean_abs_heading_error_before_deg: mean_abs_heading_deg(first).unwrap_or(0.0),
            mean_abs_heading_error_after_deg: mean_abs_heading_deg(&o.verification),
            estimates: o
                .rounds
                .last()
                .map(|r| r.estimates.clone())
                .unwrap_or_default(),
            rounds: o.rounds,
            verification: o.verification,
            converged: o.converged,
            written: o.written,
            diagnostics: base.drive.diagnostics(),
            warnings: o.warnings,
            swing: None,
            plan: None,
            report_dir: None,
        }
    }
}

pub use crate::base::write::params_table;
