//! The scripted recalibration: from a mis-calibrated base to written, saved and verified
//! parameters, safely.
//!
//! [`run`] drives a connected [`Client`] through: backup of the controller's parameters (before
//! anything else), pre-flight checks (encoders, heading validity, heading noise at rest),
//! calibration rounds of CW and CCW squares (each checked for plausibility, including the
//! compass's sign convention against the commanded turns), estimation with every method,
//! bounded write-back (set, read back, save, read back the stored copy) under the configured
//! policy, iteration until converged, and verification squares. Any error or cancellation stops
//! the base and restores the backed-up parameters. The result is a [`report::Report`].

pub mod config;
pub mod demo;
pub mod export;
pub mod plots;
pub mod report;

use crate::calibration::uncertainty::{cramer_rao_bound, heading_error_sigma, TestDesign};
use crate::calibration::{estimate_all, CalibrationError, Estimate, RunMeasurement, SquareTest};
use crate::hal::motion::{run_square_with_progress, SquareCommand, SquareRecord};
use crate::hal::{Client, HalError, LinkError, TelemetrySample};
use crate::kinematics::{wrap_angle, Direction, KinematicsError, Pose, WheelParams};
use crate::protocol::message::ParamSource;
use config::{RoutineConfig, WritePolicy};
use report::{Phase, Report, RoundReport, RunReport};
use std::path::PathBuf;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

/// Errors of the routine. Whatever the error, the base was told to stop and the parameters
/// were restored if any had been written (see [`RoutineError::Restored`]).
#[derive(Debug, thiserror::Error)]
pub enum RoutineError {
    /// The settings are unusable.
    #[error(transparent)]
    Config(#[from] config::ConfigError),
    /// The link or the device failed.
    #[error(transparent)]
    Hal(#[from] HalError),
    /// The measurements could not be calibrated.
    #[error(transparent)]
    Calibration(#[from] CalibrationError),
    /// New parameters would be impossible.
    #[error(transparent)]
    Kinematics(#[from] KinematicsError),
    /// The backup could not be written: nothing was changed.
    #[error("cannot write the parameter backup {path}: {reason}; nothing was changed")]
    Backup {
        /// Backup path.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The pre-flight checks failed.
    #[error("pre-flight check failed: {0}")]
    Preflight(String),
    /// The measurements are implausible (e.g. the compass turns the wrong way).
    #[error("implausible measurement: {0}")]
    Implausible(String),
    /// The estimate asks for a change beyond the configured bounds.
    #[error("refusing to write: {0}")]
    OutOfBounds(String),
    /// What was written did not read back.
    #[error("read-back mismatch: wrote {written:?}, device reports {read:?}")]
    ReadBack {
        /// What was sent.
        written: WheelParams,
        /// What came back.
        read: WheelParams,
    },
    /// The user declined (to move or to write).
    #[error("declined by the user: {0}")]
    Declined(String),
    /// Ctrl-C or the caller cancelled.
    #[error("cancelled")]
    Cancelled,
    /// An error happened after parameters were written; the backup was put back.
    #[error("{source} (the original parameters were restored{})", if *.saved { " and saved" } else { "" })]
    Restored {
        /// The error.
        source: Box<RoutineError>,
        /// Whether the stored copy was restored too.
        saved: bool,
    },
    /// An error happened after parameters were written and restoring them failed too.
    #[error("{source}; RESTORING THE BACKUP FAILED ({restore_error}): restore {backup} by hand")]
    RestoreFailed {
        /// The error.
        source: Box<RoutineError>,
        /// Why restoring failed.
        restore_error: String,
        /// The backup file to restore from.
        backup: PathBuf,
    },
}

/// Where the robot truly is: available in simulation, used for `E_max,sys` and true paths.
pub trait GroundTruth: Send + Sync {
    /// The robot's true pose now.
    fn pose(&self) -> Pose;
    /// The robot's true parameters.
    fn true_params(&self) -> WheelParams;
}

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

/// What has been changed on the controller, so a failure can undo it.
struct Changes {
    backup: WheelParams,
    backup_path: PathBuf,
    written: bool,
    saved: bool,
}

async fn cancellable<T, E: Into<RoutineError>>(
    cancel: &CancellationToken,
    fut: impl std::future::Future<Output = Result<T, E>>,
) -> Result<T, RoutineError> {
    tokio::select! {
        r = fut => r.map_err(Into::into),
        () = cancel.cancelled() => Err(RoutineError::Cancelled),
    }
}

/// Runs the whole routine on a connected client.
///
/// `truth` (simulation only) adds true final positions, `E_max,sys` and true paths to the
/// report. `cancel` stops the routine at the next await point: the base is stopped and any
/// written parameters are restored before this returns.
pub async fn run(
    client: &Client,
    cfg: &RoutineConfig,
    truth: Option<&dyn GroundTruth>,
    ui: &mut dyn RoutineUi,
    cancel: &CancellationToken,
) -> Result<Report, RoutineError> {
    cfg.validate()?;
    ui.event(&RoutineEvent::Stage(
        "reading and backing up the controller's parameters".into(),
    ));
    let backup = cancellable(cancel, client.get_params(ParamSource::Active)).await?;
    let backup_path = write_backup(client, &cfg.backup_dir, &backup)?;
    let mut changes = Changes {
        backup,
        backup_path,
        written: false,
        saved: false,
    };
    let result = body(client, cfg, truth, ui, cancel, &mut changes).await;
    match result {
        Ok(report) => Ok(report),
        Err(err) => {
            // Stop first (the guard in run_square has already sent STOP if a square was cut
            // short; this covers everything else), then undo any write.
            let _ = tokio::time::timeout(Duration::from_secs(2), client.stop()).await;
            Err(undo(client, &changes, err).await)
        }
    }
}

async fn undo(client: &Client, changes: &Changes, err: RoutineError) -> RoutineError {
    if !changes.written {
        return err;
    }
    let restore = async {
        let read = client.set_params(&changes.backup).await?;
        if changes.saved {
            client.save_params().await?;
        }
        Ok::<_, HalError>(read)
    };
    match tokio::time::timeout(Duration::from_secs(5), restore).await {
        Ok(Ok(_)) => RoutineError::Restored {
            source: Box::new(err),
            saved: changes.saved,
        },
        Ok(Err(e)) => RoutineError::RestoreFailed {
            source: Box::new(err),
            restore_error: e.to_string(),
            backup: changes.backup_path.clone(),
        },
        Err(_) => RoutineError::RestoreFailed {
            source: Box::new(err),
            restore_error: "timed out".into(),
            backup: changes.backup_path.clone(),
        },
    }
}

fn write_backup(
    client: &Client,
    backup_dir: &std::path::Path,
    params: &WheelParams,
) -> Result<PathBuf, RoutineError> {
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis());
    let path = backup_dir.join(format!(
        "odocal-backup-{}-{stamp}.json",
        client.device_info().serial_number
    ));
    let err = |reason: String| RoutineError::Backup {
        path: path.clone(),
        reason,
    };
    std::fs::create_dir_all(backup_dir).map_err(|e| err(e.to_string()))?;
    let text = serde_json::to_string_pretty(&serde_json::json!({
        "device": client.device_info(),
        "active": params,
    }))
    .map_err(|e| err(e.to_string()))?;
    std::fs::write(&path, text).map_err(|e| err(e.to_string()))?;
    Ok(path)
}

async fn body(
    client: &Client,
    cfg: &RoutineConfig,
    truth: Option<&dyn GroundTruth>,
    ui: &mut dyn RoutineUi,
    cancel: &CancellationToken,
    changes: &mut Changes,
) -> Result<Report, RoutineError> {
    let heading_noise_rad = preflight(client, cfg, ui, cancel).await?;
    let total_runs = cfg.runs_per_direction * 2;
    if cfg.confirm_motion
        && !ui.confirm(&format!(
        "The robot will drive {total_runs} open-loop squares of {} m at up to {} m/s and {} rad/s. \
         Is the area clear and may it move?",
        cfg.side_m, cfg.max_speed_m_s, cfg.max_rate_rad_s
    )) {
        return Err(RoutineError::Declined("the robot may not move".into()));
    }
    let mut current = changes.backup;
    let mut rounds = Vec::new();
    let mut converged = false;
    let mut warnings = Vec::new();
    for round in 1..=cfg.max_rounds {
        ui.event(&RoutineEvent::Stage(format!(
            "round {round}: calibration squares"
        )));
        let runs = drive_runs(
            client,
            cfg,
            truth,
            ui,
            cancel,
            Phase::Calibration { round },
            cfg.runs_per_direction,
            &current,
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
        let chosen = estimates
            .iter()
            .find(|e| e.method == cfg.method)
            .cloned()
            .ok_or_else(|| {
                let why = failures
                    .iter()
                    .find(|(m, _)| *m == cfg.method)
                    .map_or("it needs final positions".to_string(), |(_, e)| e.clone());
                RoutineError::Implausible(format!("method {} gave no estimate: {why}", cfg.method))
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
        check_bounds(cfg.max_change, &changes.backup, &proposed)?;
        rr.params_after = Some(proposed);
        let write = match cfg.write_back {
            WritePolicy::DryRun => false,
            WritePolicy::Yes => true,
            WritePolicy::Ask => ui.confirm(&format!(
                "Write these parameters to the controller and save them?\n{}",
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
        // From here on, the parameters are what the device reports (rounded to the wire).
        current = write_params(client, cancel, changes, &proposed).await?;
        rr.written = true;
        rounds.push(rr);
    }
    if !converged && changes.written {
        let msg = format!(
            "not converged to ±{} after {} round(s); the last estimate was written",
            cfg.tolerance, cfg.max_rounds
        );
        ui.event(&RoutineEvent::Warning(msg.clone()));
        warnings.push(msg);
    }
    let verification = if changes.written && cfg.verification_runs > 0 {
        ui.event(&RoutineEvent::Stage("verification squares".into()));
        drive_runs(
            client,
            cfg,
            truth,
            ui,
            cancel,
            Phase::Verification,
            cfg.verification_runs,
            &current,
        )
        .await?
    } else {
        Vec::new()
    };
    Ok(Report::assemble(
        client,
        cfg,
        changes.backup,
        changes.backup_path.clone(),
        current,
        heading_noise_rad,
        rounds,
        verification,
        converged,
        changes.written,
        warnings,
    ))
}

async fn preflight(
    client: &Client,
    cfg: &RoutineConfig,
    ui: &mut dyn RoutineUi,
    cancel: &CancellationToken,
) -> Result<f64, RoutineError> {
    ui.event(&RoutineEvent::Stage("pre-flight checks".into()));
    let status = cancellable(cancel, client.status()).await?;
    if status.fault_flags != 0 {
        return Err(RoutineError::Preflight(format!(
            "device reports faults {:#06x}",
            status.fault_flags
        )));
    }
    cancellable(cancel, client.read_encoders()).await?;
    let mut readings = Vec::new();
    for _ in 0..10 {
        let h = cancellable(cancel, client.read_heading()).await?;
        if !h.valid {
            return Err(RoutineError::Preflight(
                "the heading sensor reports invalid".into(),
            ));
        }
        readings.push(h.heading_rad);
    }
    let mean = circular_mean(&readings);
    let noise = (readings
        .iter()
        .map(|h| wrap_angle(h - mean).powi(2))
        .sum::<f64>()
        / (readings.len() - 1) as f64)
        .sqrt();
    ui.event(&RoutineEvent::Stage(format!(
        "heading noise at rest: {:.3}° (σ of 10 readings)",
        noise.to_degrees()
    )));
    cancellable(
        cancel,
        client.configure_watchdog(Some(Duration::from_millis(cfg.watchdog_ms))),
    )
    .await?;
    let period = (cfg.telemetry_ms > 0).then(|| Duration::from_millis(cfg.telemetry_ms));
    cancellable(cancel, client.configure_telemetry(period)).await?;
    Ok(noise)
}

fn circular_mean(angles: &[f64]) -> f64 {
    let (s, c) = angles
        .iter()
        .fold((0.0, 0.0), |(s, c), a| (s + a.sin(), c + a.cos()));
    s.atan2(c)
}

#[allow(clippy::too_many_arguments)]
async fn drive_runs(
    client: &Client,
    cfg: &RoutineConfig,
    truth: Option<&dyn GroundTruth>,
    ui: &mut dyn RoutineUi,
    cancel: &CancellationToken,
    phase: Phase,
    per_direction: usize,
    params: &WheelParams,
) -> Result<Vec<RunReport>, RoutineError> {
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
                cancellable(cancel, run_square_with_progress(client, &cmd, on_motion)).await?
            };
            let run = RunReport::new(phase, &rec, params, start, truth);
            check_plausible(&rec, &run, ui)?;
            ui.event(&RoutineEvent::RunDone {
                heading_error_deg: run.heading_error_deg,
            });
            out.push(run);
        }
    }
    Ok(out)
}

/// Total turn of the compass heading over a run's telemetry (rad, unwrapped).
fn compass_turn(trace: &[TelemetrySample]) -> Option<f64> {
    let valid: Vec<f64> = trace
        .iter()
        .filter(|s| s.heading_valid)
        .map(|s| s.heading_rad)
        .collect();
    (valid.len() > 8).then(|| valid.windows(2).map(|w| wrap_angle(w[1] - w[0])).sum())
}

fn check_plausible(
    rec: &SquareRecord,
    run: &RunReport,
    ui: &mut dyn RoutineUi,
) -> Result<(), RoutineError> {
    let expected = rec.command.direction.turn_sign() * 2.0 * std::f64::consts::PI;
    match compass_turn(&rec.trace) {
        // The compass must turn about ±360° the way the square was commanded; the opposite
        // sign means it reports clockwise-positive azimuth (or left/right are swapped).
        Some(turn) if (turn + expected).abs() < (turn - expected).abs() => {
            return Err(RoutineError::Implausible(format!(
                "the heading turned {:.0}° during a {} square that should turn {:.0}°: the \
                 heading sensor reports clockwise-positive (negate it in firmware) or the \
                 wheels are swapped",
                turn.to_degrees(),
                rec.command.direction,
                expected.to_degrees()
            )));
        }
        Some(_) => {}
        None => ui.event(&RoutineEvent::Warning(
            "no telemetry: the heading sensor's sign convention cannot be checked".into(),
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
                 allowed ±{:.1} %",
                change * 100.0,
                max_change * 100.0
            )));
        }
    }
    Ok(())
}

/// Writes `new` to the controller under the routine's safety rules, for callers outside the
/// routine (the online estimator's write-back): backs up the active parameters to `backup_dir`
/// first, refuses changes beyond `max_change`, asks unless `policy` is `Yes` (and writes
/// nothing for `DryRun`), writes, reads back, saves, reads back the stored copy, and restores
/// the backup on any failure. Returns the parameters as the device holds them and the backup.
pub async fn write_parameters(
    client: &Client,
    new: &WheelParams,
    policy: WritePolicy,
    max_change: f64,
    backup_dir: &std::path::Path,
    ui: &mut dyn RoutineUi,
    cancel: &CancellationToken,
) -> Result<(WheelParams, PathBuf), RoutineError> {
    let current = cancellable(cancel, client.get_params(ParamSource::Active)).await?;
    let backup_path = write_backup(client, backup_dir, &current)?;
    check_bounds(max_change, &current, new)?;
    let go = match policy {
        WritePolicy::DryRun => false,
        WritePolicy::Yes => true,
        WritePolicy::Ask => ui.confirm(&format!(
            "Write these parameters to the controller and save them?\n{}",
            report::params_table(&current, new)
        )),
    };
    if !go {
        return Err(RoutineError::Declined("parameters not written".into()));
    }
    let mut changes = Changes {
        backup: current,
        backup_path: backup_path.clone(),
        written: false,
        saved: false,
    };
    match write_params(client, cancel, &mut changes, new).await {
        Ok(applied) => Ok((applied, backup_path)),
        Err(e) => Err(undo(client, &changes, e).await),
    }
}

/// Writes to RAM, reads back, saves, reads back the stored copy; returns the parameters as the
/// device holds them.
async fn write_params(
    client: &Client,
    cancel: &CancellationToken,
    changes: &mut Changes,
    params: &WheelParams,
) -> Result<WheelParams, RoutineError> {
    changes.written = true;
    let applied = cancellable(cancel, client.set_params(params)).await?;
    let read = cancellable(cancel, client.get_params(ParamSource::Active)).await?;
    if !same_on_wire(&applied, params) || !same_on_wire(&read, params) {
        return Err(RoutineError::ReadBack {
            written: *params,
            read,
        });
    }
    match cancellable(cancel, client.save_params()).await {
        Ok(_) => changes.saved = true,
        // A NACK means the device kept its stored copy (SPEC.md: SAVE_PARAMS is atomic).
        Err(e @ RoutineError::Hal(HalError::Nack { .. })) => return Err(e),
        // Anything else leaves it unknown whether the save happened: restore it too.
        Err(e) => {
            changes.saved = true;
            return Err(e);
        }
    }
    let stored = cancellable(cancel, client.get_params(ParamSource::Stored)).await?;
    if !same_on_wire(&stored, params) {
        return Err(RoutineError::ReadBack {
            written: *params,
            read: stored,
        });
    }
    Ok(read)
}

/// Equal within the wire's resolution (1 nm, 1e-6 count).
fn same_on_wire(a: &WheelParams, b: &WheelParams) -> bool {
    (a.left_wheel_diameter_m - b.left_wheel_diameter_m).abs() < 1e-9
        && (a.right_wheel_diameter_m - b.right_wheel_diameter_m).abs() < 1e-9
        && (a.wheelbase_m - b.wheelbase_m).abs() < 1e-9
        && (a.counts_per_wheel_rev - b.counts_per_wheel_rev).abs() < 1e-6
}

impl From<LinkError> for RoutineError {
    fn from(e: LinkError) -> Self {
        RoutineError::Hal(HalError::Link(e))
    }
}
