//! The scripted recalibration: from a mis-calibrated base to written, committed and verified
//! parameters, safely, on any [`Base`].
//!
//! [`run`] drives a base through: a backup of its parameters (a [`Transaction`], before
//! anything else), pre-flight checks (drive faults, heading validity and noise at rest, the
//! watchdog), calibration rounds of CW and CCW squares ([`square`]; each checked for
//! plausibility, including the compass's sign convention against the commanded turns),
//! estimation with every method, bounded write-back through the transaction under the
//! configured policy, iteration until converged, and verification squares. Any error or
//! cancellation stops the base and rolls the parameters back. The result is a [`Report`].
//! Nothing here knows which robot, protocol or simulator is behind the base.

pub mod config;
pub mod error;
pub mod heading;
pub mod report;
pub mod square;

pub use error::RoutineError;
pub use report::Report;

use crate::base::transaction::Transaction;
pub use crate::base::GroundTruth;
use crate::base::{Base, BaseError, HeadingSample};
use crate::calibration::uncertainty::{cramer_rao_bound, heading_error_sigma, TestDesign};
use crate::calibration::{
    default_method, estimate_all, Estimate, Method, RunMeasurement, SquareTest,
};
use crate::kinematics::{wrap_angle, Direction, WheelParams};
use config::{RoutineConfig, WritePolicy};
use report::{Phase, RoundReport, RunReport};
use square::{run_square, SquareCommand, SquareRecord};
use std::time::Duration;
use tokio_util::sync::CancellationToken;

/// Something the routine reports while it works.
#[derive(Debug, Clone, PartialEq)]
pub enum RoutineEvent {
    /// A stage starts (human-readable).
    Stage(String),
    /// The number of motions the next phase will drive.
    Plan {
        /// Motions.
        motions: u64,
    },
    /// One motion finished.
    Motion {
        /// "round 1", "verification".
        phase: String,
        /// Run number (1-based).
        run: usize,
        /// Runs in this phase.
        of: usize,
        /// Direction of the run.
        direction: Direction,
        /// Motion within the square (1..=8).
        motion: usize,
    },
    /// A run finished with this heading error (deg).
    RunDone {
        /// Heading error (deg).
        heading_error_deg: f64,
    },
    /// Something looks wrong but the routine goes on.
    Warning(String),
}

/// How the routine talks to its user.
pub trait RoutineUi: Send {
    /// Asks a yes/no question; `true` to go ahead.
    fn confirm(&mut self, question: &str) -> bool;
    /// Reports progress.
    fn event(&mut self, event: &RoutineEvent);
}

/// A UI that says yes to everything and shows nothing (tests, `--yes --json`).
pub struct Unattended;

impl RoutineUi for Unattended {
    fn confirm(&mut self, _question: &str) -> bool {
        true
    }
    fn event(&mut self, _event: &RoutineEvent) {}
}

/// Largest |heading error| a square should produce before the routine warns (45°).
pub const IMPLAUSIBLE_HEADING_RAD: f64 = std::f64::consts::FRAC_PI_4;

async fn cancellable<T, E: Into<RoutineError>>(
    cancel: &CancellationToken,
    fut: impl std::future::Future<Output = Result<T, E>>,
) -> Result<T, RoutineError> {
    tokio::select! {
        r = fut => r.map_err(Into::into),
        () = cancel.cancelled() => Err(RoutineError::Cancelled),
    }
}

/// Runs the whole routine on `base`.
///
/// `truth` (simulation only) adds true final positions, `E_max,sys` and true paths to the
/// report. `cancel` stops the routine at the next await point: the base is stopped and any
/// written parameters are rolled back before this returns.
pub async fn run(
    base: &Base,
    cfg: &RoutineConfig,
    truth: Option<&dyn GroundTruth>,
    ui: &mut dyn RoutineUi,
    cancel: &CancellationToken,
) -> Result<Report, RoutineError> {
    cfg.validate()?;
    // Every place the run will write must take a file before the robot moves or a parameter
    // changes: a report that cannot be written after a write-back would leave the user
    // without the record of what was done.
    check_output_dir(&cfg.backup_dir)?;
    if let Some(dir) = &cfg.report_dir {
        check_output_dir(dir)?;
    }
    ui.event(&RoutineEvent::Stage(
        "reading and backing up the robot's parameters".into(),
    ));
    let mut tx = cancellable(
        cancel,
        Transaction::begin(base.store.clone(), &cfg.backup_dir),
    )
    .await?;
    let mut progress = Progress::default();
    let result = body(base, cfg, truth, ui, cancel, &mut tx, &mut progress).await;
    match result {
        Ok(report) => Ok(report),
        Err(err) => {
            // Stop first (the guard in run_square has already asked for a stop if a square was
            // cut short; this covers everything else), then undo any write.
            let _ = tokio::time::timeout(Duration::from_secs(2), base.drive.stop()).await;
            let err = undo(base, &mut tx, err).await;
            // Nothing measured is thrown away: the squares driven so far, where it stopped
            // and why, beside the backup or in the report directory.
            let dir = cfg.report_dir.as_ref().unwrap_or(&cfg.backup_dir);
            match write_partial(base, cfg, &progress, &err, dir, tx.backup_path()) {
                Ok(path) => ui.event(&RoutineEvent::Warning(format!(
                    "{} square(s) measured before the failure ({}) are in {}",
                    progress.runs.len(),
                    progress.phase,
                    path.display()
                ))),
                Err(e) => ui.event(&RoutineEvent::Warning(format!(
                    "the partial report could not be written to {}: {e}",
                    dir.display()
                ))),
            }
            Err(err)
        }
    }
}

/// Where a run got to: the phase and every square measured so far.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct Progress {
    /// The phase the run was in (pre-flight, round N, write-back, verification).
    pub phase: String,
    /// Every square measured, in order.
    pub runs: Vec<RunReport>,
}

/// Writes `partial-report-<ms>.json` (created new) into `dir`: the phase, the error, what the
/// robot's parameters are now ([`ParamsAfterFailure`]) and the backup, the base (its port) and
/// its link diagnostics (requests, retries, the last request), the settings and every square
/// measured, so the run can be estimated from or understood.
fn write_partial(
    base: &Base,
    cfg: &RoutineConfig,
    progress: &Progress,
    err: &RoutineError,
    dir: &std::path::Path,
    backup: &std::path::Path,
) -> std::io::Result<std::path::PathBuf> {
    let stamp = crate::base::files::stamp_ms();
    let value = serde_json::json!({
        "odocal_version": env!("CARGO_PKG_VERSION"),
        "error": err.to_string(),
        "phase": progress.phase,
        "parameters": ParamsAfterFailure::of(err),
        "backup": backup,
        "base": base.info(),
        "diagnostics": base.drive.diagnostics(),
        "config": cfg,
        "runs": progress.runs,
    });
    let text = serde_json::to_string_pretty(&value).map_err(std::io::Error::other)?;
    std::fs::create_dir_all(dir)?;
    crate::base::files::create_unique(
        |n| {
            dir.join(if n == 0 {
                format!("partial-report-{stamp}.json")
            } else {
                format!("partial-report-{stamp}-{n}.json")
            })
        },
        text.as_bytes(),
    )
}

/// Creates `dir` if needed and proves a new file can be created in it (and removed again).
pub fn check_output_dir(dir: &std::path::Path) -> Result<(), RoutineError> {
    let fail = |reason: String| RoutineError::Output {
        path: dir.to_path_buf(),
        reason,
    };
    if dir.exists() && !dir.is_dir() {
        return Err(fail("it exists and is not a directory".into()));
    }
    std::fs::create_dir_all(dir).map_err(|e| fail(e.to_string()))?;
    let probe = dir.join(format!(".odocal-write-check-{}", std::process::id()));
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .map_err(|e| fail(format!("a new file cannot be created there ({e})")))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// How long reopening a store after its link was lost may take (a board that resets when its
/// port opens needs about 2 s, a USB adapter re-enumerating a few more).
pub const RECONNECT_TIMEOUT: Duration = Duration::from_secs(10);

/// Rolls back `tx` after `err` and says what became of the parameters. When the rollback
/// fails (the device vanished or reset mid-run) and the base can reconnect, it reconnects once
/// and tries again; if that fails too, it reads back what each copy holds, so the error states
/// what is true rather than what is feared.
async fn undo(base: &Base, tx: &mut Transaction, err: RoutineError) -> RoutineError {
    use crate::base::transaction::Rollback;
    let mut outcome = tx.rollback().await;
    let mut reconnected = false;
    let mut reconnect_error = None;
    if outcome.is_err() {
        if let Some(reconnect) = &base.reconnect {
            match tokio::time::timeout(RECONNECT_TIMEOUT, reconnect()).await {
                Ok(Ok(store)) => {
                    tx.reattach(store);
                    reconnected = true;
                    outcome = tx.rollback().await;
                }
                Ok(Err(e)) => reconnect_error = Some(e.to_string().into()),
                Err(_) => {
                    reconnect_error =
                        Some(format!("no connection within {RECONNECT_TIMEOUT:?}").into())
                }
            }
        }
    }
    match outcome {
        Ok(Rollback::NothingWritten) => err,
        Ok(outcome) => RoutineError::Restored {
            source: Box::new(err),
            committed: outcome == Rollback::RestoredAndCommitted,
            reconnected,
        },
        Err(e) => {
            let (active, committed) = tx.what_the_store_holds().await;
            RoutineError::RestoreFailed {
                source: Box::new(err),
                restore_error: Box::new(e),
                reconnect_error,
                backup: tx.backup_path().into(),
                active,
                committed,
            }
        }
    }
}

/// What the host knows of the robot's parameters after a failed run: the statement a partial
/// report makes, read from the error [`run`] returned after its rollback.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case", tag = "outcome")]
pub enum ParamsAfterFailure {
    /// Nothing was written: the robot holds what the backup holds.
    Untouched,
    /// Parameters had been written and the backup was put back.
    Restored {
        /// Whether the committed copy was restored too (a commit may have happened).
        committed: bool,
        /// Whether it took a new connection (the first link was lost).
        reconnected: bool,
    },
    /// Restoring failed; what each copy was read back to hold since.
    RestoreFailed {
        /// The copy in use.
        active: crate::base::transaction::Holds,
        /// The committed copy.
        committed: crate::base::transaction::Holds,
    },
}

impl ParamsAfterFailure {
    /// The statement for an error returned by the routine after its rollback.
    pub fn of(err: &RoutineError) -> Self {
        match err {
            RoutineError::Restored {
                committed,
                reconnected,
                ..
            } => ParamsAfterFailure::Restored {
                committed: *committed,
                reconnected: *reconnected,
            },
            RoutineError::RestoreFailed {
                active, committed, ..
            } => ParamsAfterFailure::RestoreFailed {
                active: active.clone(),
                committed: committed.clone(),
            },
            _ => ParamsAfterFailure::Untouched,
        }
    }
}

async fn body(
    base: &Base,
    cfg: &RoutineConfig,
    truth: Option<&dyn GroundTruth>,
    ui: &mut dyn RoutineUi,
    cancel: &CancellationToken,
    tx: &mut Transaction,
    progress: &mut Progress,
) -> Result<Report, RoutineError> {
    progress.phase = "pre-flight".into();
    let (heading_noise_rad, mut warnings) = preflight(base, cfg, ui, cancel).await?;
    let total_runs = cfg.runs_per_direction * 2;
    if cfg.confirm_motion
        && !ui.confirm(&format!(
        "The robot will drive {total_runs} open-loop squares of {} m at up to {} m/s and {} rad/s. \
         Is the area clear and may it move?",
        cfg.side_m, cfg.max_speed_m_s, cfg.max_rate_rad_s
    )) {
        return Err(RoutineError::Declined("the robot may not move".into()));
    }
    let original = *tx.original();
    let mut current = original;
    let mut rounds = Vec::new();
    let mut converged = false;
    for round in 1..=cfg.max_rounds {
        ui.event(&RoutineEvent::Stage(format!(
            "round {round}: calibration squares"
        )));
        let runs = drive_runs(
            base,
            cfg,
            truth,
            ui,
            cancel,
            Phase::Calibration { round },
            cfg.runs_per_direction,
            &current,
            progress,
        )
        .await?;
        for r in &runs {
            warnings.extend(r.warnings.iter().cloned());
        }
        let test = square_test(cfg, &current, &runs);
        let mut estimates = Vec::new();
        let mut failures = Vec::new();
        for (method, result) in estimate_all(&test, cfg.split_convention())? {
            match result {
                Ok(e) => estimates.push(e),
                Err(e) => failures.push((method, e.to_string())),
            }
        }
        let method = match cfg.method {
            Some(m) => m,
            None => {
                let m = default_method(test.has_leg_headings(), test.has_positions())
                    .unwrap_or(Method::Exact);
                if m != Method::Legs {
                    ui.event(&RoutineEvent::Warning(
                        "the heading along the legs was not streamed in every run: estimating \
                         from the headings at rest (exact), which counts any start transient"
                            .into(),
                    ));
                }
                m
            }
        };
        let chosen = estimates
            .iter()
            .find(|e| e.method == method)
            .cloned()
            .ok_or_else(|| {
                let why = failures.iter().find(|(m, _)| *m == method).map_or(
                    "it needs data this run did not record".to_string(),
                    |(_, e)| e.clone(),
                );
                RoutineError::Implausible(format!("method {method} gave no estimate: {why}"))
            })?;
        let crb = cramer_rao_std(cfg, &chosen, heading_noise_rad, current.wheelbase_m);
        let round_converged =
            (chosen.e_b - 1.0).abs() < cfg.tolerance && (chosen.e_d - 1.0).abs() < cfg.tolerance;
        let mut rr = RoundReport {
            round,
            params_before: current,
            runs,
            estimates,
            failures,
            chosen: chosen.clone(),
            cramer_rao_std: crb,
            converged: round_converged,
            params_after: None,
            written: false,
        };
        if round_converged {
            ui.event(&RoutineEvent::Stage(format!(
                "converged: E_b {:.5}, E_d {:.5} within ±{}",
                chosen.e_b, chosen.e_d, cfg.tolerance
            )));
            converged = true;
            rounds.push(rr);
            break;
        }
        let proposed = chosen.correction.apply(&current)?;
        check_bounds(cfg.max_change, &original, &proposed)?;
        rr.params_after = Some(proposed);
        let write = match cfg.write_back {
            WritePolicy::DryRun => false,
            WritePolicy::Yes => true,
            WritePolicy::Ask => ui.confirm(&format!(
                "Write these parameters and commit them?\n{}",
                report::params_table(&current, &proposed)
            )),
        };
        if !write {
            ui.event(&RoutineEvent::Stage(match cfg.write_back {
                WritePolicy::DryRun => "dry run: nothing written".into(),
                _ => "not written (declined)".into(),
            }));
            rounds.push(rr);
            break;
        }
        // From here on, the parameters are what the store reports (rounded to its resolution).
        progress.phase = format!("write-back after round {round}");
        current = cancellable(cancel, tx.apply(&proposed)).await?;
        rr.written = true;
        rounds.push(rr);
    }
    if !converged && tx.written() {
        let msg = format!(
            "not converged to ±{} after {} round(s); the last estimate was written",
            cfg.tolerance, cfg.max_rounds
        );
        ui.event(&RoutineEvent::Warning(msg.clone()));
        warnings.push(msg);
    }
    let verification = if tx.written() && cfg.verification_runs > 0 {
        ui.event(&RoutineEvent::Stage("verification squares".into()));
        drive_runs(
            base,
            cfg,
            truth,
            ui,
            cancel,
            Phase::Verification,
            cfg.verification_runs,
            &current,
            progress,
        )
        .await?
    } else {
        Vec::new()
    };
    if tx.written() && !verification.is_empty() {
        let abs_deg = |runs: &[RunReport]| -> Vec<f64> {
            runs.iter().map(|r| r.heading_error_deg.abs()).collect()
        };
        let before = rounds.first().map(|r| abs_deg(&r.runs)).unwrap_or_default();
        let distance: Vec<f64> = rounds
            .iter()
            .map(|r| (r.chosen.e_b - 1.0).abs() + (r.chosen.e_d - 1.0).abs())
            .collect();
        if let Err(why) = judge(&before, &abs_deg(&verification), &distance) {
            if !cfg.keep_worse {
                return Err(RoutineError::NotBetter(why));
            }
            ui.event(&RoutineEvent::Warning(format!(
                "{why}; kept because of --keep-worse"
            )));
            warnings.push(why);
        }
    }
    Ok(Report::assemble(
        base,
        cfg,
        original,
        tx.backup_path().to_path_buf(),
        current,
        heading_noise_rad,
        rounds,
        verification,
        converged,
        tx.written(),
        warnings,
    ))
}

/// Whether written parameters clearly helped ("never worse"): `Err` with the numbers when the
/// rounds diverged (the last round's estimate is no nearer 1 than the first's,
/// `round_distance` being `|E_b − 1| + |E_d − 1|` per round) or when the verification's mean
/// |heading error| is not below the first round's by two of its standard errors (the two
/// means' standard errors combined; an error of a run set with fewer than two runs counts its
/// spread as 0).
pub fn judge(before_deg: &[f64], after_deg: &[f64], round_distance: &[f64]) -> Result<(), String> {
    if let (Some(first), Some(last)) = (round_distance.first(), round_distance.last()) {
        if round_distance.len() >= 2 && last >= first {
            return Err(format!(
                "the rounds diverged: |E_b − 1| + |E_d − 1| went from {first:.5} to {last:.5} \
                 over {} rounds",
                round_distance.len()
            ));
        }
    }
    let stats = |v: &[f64]| {
        let n = v.len().max(1) as f64;
        let mean = v.iter().sum::<f64>() / n;
        let var = if v.len() > 1 {
            v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)
        } else {
            0.0
        };
        (mean, (var / n).sqrt())
    };
    let ((b, sb), (a, sa)) = (stats(before_deg), stats(after_deg));
    let margin = 2.0 * sb.hypot(sa);
    if a.is_nan() || b.is_nan() || a >= b - margin {
        return Err(format!(
            "mean |heading error| {b:.3}° before, {a:.3}° after (± {:.3}° at 2σ): no clear \
             improvement; the original parameters were restored",
            margin
        ));
    }
    Ok(())
}

async fn preflight(
    base: &Base,
    cfg: &RoutineConfig,
    ui: &mut dyn RoutineUi,
    cancel: &CancellationToken,
) -> Result<(f64, Vec<String>), RoutineError> {
    ui.event(&RoutineEvent::Stage("pre-flight checks".into()));
    let check = cancellable(cancel, base.drive.preflight()).await?;
    if !check.faults.is_empty() {
        return Err(RoutineError::Preflight(check.faults.join("; ")));
    }
    let mut warnings = check.warnings;
    let readings = match cancellable(cancel, heading::readings(base.heading.as_ref(), 10)).await {
        Err(RoutineError::Base(BaseError::HeadingInvalid { reason })) => {
            return Err(RoutineError::Preflight(format!(
                "the heading sensor reports invalid: {reason}"
            )))
        }
        other => other?,
    };
    let noise = heading::circular_std(&readings);
    ui.event(&RoutineEvent::Stage(format!(
        "heading noise at rest: {:.3}° (σ of 10 readings)",
        noise.to_degrees()
    )));
    let armed = cancellable(
        cancel,
        base.drive
            .arm_watchdog(Duration::from_millis(cfg.watchdog_ms)),
    )
    .await?;
    if armed.is_none() {
        warnings.push(
            "the drive has no watchdog: if this host vanishes mid-motion, only the \
                       drive's own limits stop the robot"
                .into(),
        );
    }
    for w in &warnings {
        ui.event(&RoutineEvent::Warning(w.clone()));
    }
    Ok((noise, warnings))
}

#[allow(clippy::too_many_arguments)]
async fn drive_runs(
    base: &Base,
    cfg: &RoutineConfig,
    truth: Option<&dyn GroundTruth>,
    ui: &mut dyn RoutineUi,
    cancel: &CancellationToken,
    phase: Phase,
    per_direction: usize,
    params: &WheelParams,
    progress: &mut Progress,
) -> Result<Vec<RunReport>, RoutineError> {
    progress.phase = phase.label();
    let of = per_direction * 2;
    ui.event(&RoutineEvent::Plan {
        motions: of as u64 * 8,
    });
    let label = phase.label();
    let mut out = Vec::with_capacity(of);
    let mut index = 0;
    for direction in [Direction::Cw, Direction::Ccw] {
        for _ in 0..per_direction {
            index += 1;
            let cmd = SquareCommand {
                side_m: cfg.side_m,
                direction,
                max_speed_m_s: cfg.max_speed_m_s,
                max_rate_rad_s: cfg.max_rate_rad_s,
                heading_samples: cfg.heading_samples,
                settle: Duration::from_secs_f64(cfg.settle_s),
                stream_period: Duration::from_millis(cfg.telemetry_ms.max(1)),
            };
            let start = truth.map(|t| t.pose());
            let rec = {
                let ui_ref = &mut *ui;
                let label = label.clone();
                let on_motion = move |motion| {
                    ui_ref.event(&RoutineEvent::Motion {
                        phase: label.clone(),
                        run: index,
                        of,
                        direction,
                        motion,
                    })
                };
                cancellable(cancel, run_square(base, &cmd, on_motion)).await?
            };
            let run = RunReport::new(phase, &rec, params, start, truth);
            // Measured is kept, even a square the next check refuses.
            progress.runs.push(run.clone());
            check_plausible(&rec, &run, params, ui)?;
            ui.event(&RoutineEvent::RunDone {
                heading_error_deg: run.heading_error_deg,
            });
            out.push(run);
        }
    }
    Ok(out)
}

/// Total turn of the streamed heading over a run (rad, unwrapped).
fn compass_turn(headings: &[HeadingSample]) -> Option<f64> {
    let valid: Vec<f64> = headings
        .iter()
        .filter(|s| s.validity.is_valid())
        .map(|s| s.heading_rad)
        .collect();
    (valid.len() > 8).then(|| valid.windows(2).map(|w| wrap_angle(w[1] - w[0])).sum())
}

/// Total turn the drive's own odometry saw over a run (rad), from its wheel travel.
fn odometry_turn(rec: &SquareRecord, params: &WheelParams) -> Option<f64> {
    (rec.travel.len() > 8).then(|| {
        rec.travel
            .iter()
            .map(|t| (t.right_m - t.left_m) / params.wheelbase_m)
            .sum()
    })
}

fn check_plausible(
    rec: &SquareRecord,
    run: &RunReport,
    params: &WheelParams,
    ui: &mut dyn RoutineUi,
) -> Result<(), RoutineError> {
    let expected = rec.command.direction.turn_sign() * 2.0 * std::f64::consts::PI;
    let opposite = |turn: f64| (turn + expected).abs() < (turn - expected).abs();
    // The wheels must turn the robot the way the square was commanded; the opposite sign
    // means the encoders or motor channels are swapped or reversed.
    if let Some(turn) = odometry_turn(rec, params).filter(|&t| opposite(t)) {
        return Err(RoutineError::Implausible(format!(
            "the drive's odometry turned {:.0}° during a {} square that should turn {:.0}°: \
             left and right wheels (or encoder directions) are swapped",
            turn.to_degrees(),
            rec.command.direction,
            expected.to_degrees()
        )));
    }
    match compass_turn(&rec.headings) {
        // The heading must turn about ±360° the way the square was commanded; the opposite
        // sign means the sensor reports clockwise-positive azimuth.
        Some(turn) if opposite(turn) => {
            return Err(RoutineError::Implausible(format!(
                "the heading turned {:.0}° during a {} square that should turn {:.0}°: the \
                 heading sensor reports clockwise-positive (negate it) or is mounted upside \
                 down",
                turn.to_degrees(),
                rec.command.direction,
                expected.to_degrees()
            )));
        }
        Some(_) => {}
        None => ui.event(&RoutineEvent::Warning(
            "no heading stream: the heading sensor's sign convention cannot be checked".into(),
        )),
    }
    for w in &run.warnings {
        ui.event(&RoutineEvent::Warning(w.clone()));
    }
    Ok(())
}

fn square_test(cfg: &RoutineConfig, params: &WheelParams, runs: &[RunReport]) -> SquareTest {
    let mut test = SquareTest {
        side_m: cfg.side_m,
        wheelbase_m: params.wheelbase_m,
        cw: Vec::new(),
        ccw: Vec::new(),
    };
    for r in runs {
        let m = RunMeasurement {
            heading_error_rad: r.heading_error_rad,
            final_xy_m: r.true_final_xy_m,
            leg_heading_error_rad: r.leg_heading_error_rad,
        };
        match r.direction {
            Direction::Cw => test.cw.push(m),
            Direction::Ccw => test.ccw.push(m),
        }
    }
    test
}

fn cramer_rao_std(
    cfg: &RoutineConfig,
    e: &Estimate,
    heading_noise_rad: f64,
    wheelbase_m: f64,
) -> Option<[f64; 2]> {
    let design = TestDesign {
        side_m: cfg.side_m,
        wheelbase_m,
        runs_cw: cfg.runs_per_direction,
        runs_ccw: cfg.runs_per_direction,
        heading_error_sigma_rad: heading_error_sigma(heading_noise_rad, cfg.heading_samples),
    };
    cramer_rao_bound(e.e_b, e.e_d, cfg.split_convention(), &design)
        .ok()
        .map(|c| [c[(0, 0)].sqrt(), c[(1, 1)].sqrt()])
}

fn check_bounds(
    max_change: f64,
    original: &WheelParams,
    proposed: &WheelParams,
) -> Result<(), RoutineError> {
    proposed.validate()?;
    for (name, old, new) in [
        (
            "left wheel diameter",
            original.left_wheel_diameter_m,
            proposed.left_wheel_diameter_m,
        ),
        (
            "right wheel diameter",
            original.right_wheel_diameter_m,
            proposed.right_wheel_diameter_m,
        ),
        ("wheelbase", original.wheelbase_m, proposed.wheelbase_m),
    ] {
        let change = new / old - 1.0;
        if change.abs() > max_change {
            return Err(RoutineError::OutOfBounds(format!(
                "{name} would change by {:+.1} % ({old:.6} → {new:.6} m), more than the \
                 allowed ±{:.1} %{}",
                change * 100.0,
                max_change * 100.0,
                if max_change < 1.0 && change.abs() <= 1.0 {
                    " (a skid-steer robot needs this: --allow-large-change)"
                } else {
                    ""
                }
            )));
        }
    }
    Ok(())
}

/// Writes `new` under the routine's safety rules, for callers outside the routine (the online
/// estimator's write-back): a [`Transaction`] backs the store up to `backup_dir` first;
/// changes beyond `max_change` are refused; it asks unless `policy` is `Yes` (and writes
/// nothing for `DryRun`); it writes, reads back, commits, reads back the committed copy, and
/// rolls back on any failure. Returns the parameters as the store holds them and the backup.
pub async fn write_parameters(
    base: &Base,
    new: &WheelParams,
    policy: WritePolicy,
    max_change: f64,
    backup_dir: &std::path::Path,
    ui: &mut dyn RoutineUi,
    cancel: &CancellationToken,
) -> Result<(WheelParams, std::path::PathBuf), RoutineError> {
    let mut tx = cancellable(cancel, Transaction::begin(base.store.clone(), backup_dir)).await?;
    let current = *tx.original();
    check_bounds(max_change, &current, new)?;
    let go = match policy {
        WritePolicy::DryRun => false,
        WritePolicy::Yes => true,
        WritePolicy::Ask => ui.confirm(&format!(
            "Write these parameters and commit them?\n{}",
            report::params_table(&current, new)
        )),
    };
    if !go {
        return Err(RoutineError::Declined("parameters not written".into()));
    }
    match cancellable(cancel, tx.apply(new)).await {
        Ok(applied) => Ok((applied, tx.backup_path().to_path_buf())),
        Err(e) => Err(undo(base, &mut tx, e).await),
    }
}

#[cfg(test)]
mod judge_tests {
    use super::judge;

    #[test]
    fn only_a_clear_improvement_that_converges_passes() {
        // 5° → 0.1°, rounds converging: better.
        assert_eq!(
            judge(&[5.0, 5.2, 4.9], &[0.1, 0.12], &[0.03, 0.0005]),
            Ok(())
        );
        // The rounds oscillate (the last no nearer than the first): refused, with the numbers.
        let e = judge(&[37.7, 37.8], &[38.6, 38.5], &[0.5, 0.2, 0.5]).unwrap_err();
        assert!(e.contains("diverged") && e.contains("0.50000"), "{e}");
        // Worse after than before.
        let e = judge(&[1.0, 1.1], &[1.3, 1.2], &[0.02]).unwrap_err();
        assert!(e.contains("1.050° before, 1.250° after"), "{e}");
        // Better, but within the scatter: not clearly better.
        assert!(judge(&[0.30, 0.10, 0.50], &[0.25, 0.05, 0.45], &[0.001]).is_err());
    }
}
