//! The scripted recalibration: from a mis-calibrated base to written, committed and verified
//! parameters, safely, on any [`Base`].
//!
//! [`run`] drives a base through: proof that the store can take a write (a [`WriteSession`],
//! before anything else), pre-flight checks (drive faults, heading validity and noise at rest,
//! the watchdog), the user's leave to move, a backup of the parameters (before the robot first
//! moves; declining leaves no file behind), calibration rounds of CW and CCW squares ([`square`]; each checked for
//! plausibility, including the compass's sign convention against the commanded turns),
//! estimation with every method, bounded write-back through the write service under the
//! configured policy, iteration until converged, and verification squares. Any error or
//! cancellation stops the base and rolls the parameters back. The result is a [`Report`].
//! Nothing here knows which robot, protocol or simulator is behind the base.

pub mod config;
pub mod error;
pub mod heading;
pub mod overrides;
pub mod plan_answer;
pub mod planning;
pub mod progress;
pub mod report;
pub mod spin;
pub mod square;
pub mod swing;
pub mod track;

mod ending;
mod judge;
mod steps;

pub use ending::*;
pub use error::RoutineError;
pub use judge::*;
pub use report::Report;

use crate::base::adjusted::Adjusted;
use crate::base::write::{self as write_service, Bounds, Commit, WriteSession, WriteUi};
pub use crate::base::GroundTruth;
use crate::base::{Base, BaseError, HeadingKind, MotionGuard, ParamStore};
use crate::calibration::plan::Plan;
use crate::calibration::swing::SwingFit;
use crate::calibration::uncertainty::{cramer_rao_bound, heading_error_sigma, TestDesign};
use crate::calibration::{
    default_method, default_method_reason, estimate_all, Estimate, Method, SquareTest,
};
use crate::kinematics::{wrap_angle, Direction, WheelParams};
use config::RoutineConfig;
use planning::Stop;
use report::{Outcome, Phase, RoundReport, RunReport, Stage};
use square::{run_square, SquareCommand, SquareRecord};
use std::sync::Arc;
use std::time::Duration;
use swing::SwingCommand;
use tokio_util::sync::CancellationToken;

/// Something the routine reports while it works.
#[derive(Debug, Clone, PartialEq)]
pub enum RoutineEvent {
    /// A stage starts (human-readable).
    Stage(String),
    /// The motions the next phase will drive.
    Plan {
        /// Motions.
        motions: u64,
        /// Their robot time at the speed limits (s).
        robot_time_s: f64,
    },
    /// The phase drives more than it planned (a round whose target is not reached yet).
    Extend {
        /// More motions.
        motions: u64,
        /// Their robot time at the speed limits (s).
        robot_time_s: f64,
    },
    /// One motion finished.
    Motion {
        /// The phase (shown as `round 1`, `verification`).
        phase: Phase,
        /// Run number (1-based).
        run: usize,
        /// Runs in this phase.
        of: usize,
        /// Direction of the run.
        direction: Direction,
        /// Motion within the square (1..=8).
        motion: usize,
        /// Its robot time at the speed limits (s).
        duration_s: f64,
    },
    /// A run finished with this heading error (deg).
    RunDone {
        /// The phase (`round 1`, `verification`).
        phase: Phase,
        /// Run number in its phase (1-based).
        run: usize,
        /// Runs in this phase.
        of: usize,
        /// Its direction.
        direction: Direction,
        /// Heading error (deg).
        heading_error_deg: f64,
    },
    /// The robot turned in place back to the first square's heading before a square
    /// ([`RoutineConfig::realign`]).
    Realigned {
        /// The turns commanded, summed (rad, counter-clockwise positive as
        /// [`crate::base::Drive::turn_in_place`]).
        turn_rad: f64,
        /// How far from the first square's heading the robot is left (rad, by the sensor).
        left_rad: f64,
        /// Turns commanded (1, or 2 when the first left more than the tolerance).
        turns: u32,
    },
    /// Something looks wrong but the routine goes on.
    Warning(String),
    /// The run stopped before it finished (an error, Ctrl-C, a refusal): where the robot and
    /// its parameters are now. The last thing the routine reports.
    Ended(Ending),
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

/// Readings the pre-flight takes at rest: at least the first, up to the second while
/// [`PREFLIGHT_BUDGET`] lasts (fifty state σ within ±30 % 997 times in 1000; ten, 8 in 10).
pub const PREFLIGHT_READINGS: (usize, usize) = (10, 50);

/// How long the pre-flight goes on reading at rest once it has the least number.
pub const PREFLIGHT_BUDGET: Duration = Duration::from_secs(5);

async fn cancellable<T, E: Into<RoutineError>>(
    cancel: &CancellationToken,
    fut: impl std::future::Future<Output = Result<T, E>>,
) -> Result<T, RoutineError> {
    tokio::select! {
        // Cancellation first, and a fixed order: the same run twice takes the same turns.
        biased;
        () = cancel.cancelled() => Err(RoutineError::Cancelled),
        r = fut => r.map_err(Into::into),
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
    // without the record of what was done. Nothing is created yet: a run declined at the
    // first question leaves no file and no directory behind.
    check_output_dir(&run_dir(
        cfg,
        None,
        ParamStore::file(base.store.as_ref()).as_deref(),
        true,
    ))?;
    if let Some(dir) = &cfg.report_dir {
        check_output_dir(dir)?;
    }
    ui.event(&RoutineEvent::Stage(
        "reading the robot's parameters and proving they can be written back".into(),
    ));
    let session = cancellable(
        cancel,
        WriteSession::prepare(base.store.clone(), base.reconnect.clone(), None),
    )
    .await?;
    let base = base.clone();
    let mut run = Calibration {
        base,
        cfg,
        truth,
        ui,
        cancel,
        session,
        report_dir: None,
        progress: Progress::default(),
        noise: heading::NoisePool::default(),
        preflight_noise: heading::NoisePool::default(),
        moving_rests: 0,
        warnings: Vec::new(),
        start_heading_rad: None,
        swing: None,
        plan: None,
    };
    match run.body().await {
        Ok(report) => Ok(report),
        Err(err) => Err(run.fail(err).await),
    }
}

/// Where a run's own files go: its backup into the configured backup directory, else the
/// report directory (`claimed`: this run's), else beside the store's file (`file`), else `.`;
/// its partial report (`backup` false) into the report directory first. A calibration from
/// the command line always has a report directory, so nothing lands in the user's
/// configuration folder unless asked to.
fn run_dir(
    cfg: &RoutineConfig,
    claimed: Option<&std::path::Path>,
    file: Option<&std::path::Path>,
    backup: bool,
) -> std::path::PathBuf {
    let report = claimed.or(cfg.report_dir.as_deref());
    let first = match backup {
        true => cfg.backup_dir.as_deref().or(report),
        false => report.or(cfg.backup_dir.as_deref()),
    };
    first
        .or(file.map(crate::io::dir_of))
        .unwrap_or(std::path::Path::new("."))
        .to_path_buf()
}

/// One calibration run on a base: the steps of the procedure, each a method of its own.
struct Calibration<'a> {
    /// The caller's base; its heading source wrapped once a swing measured a deviation.
    base: Base,
    cfg: &'a RoutineConfig,
    truth: Option<&'a dyn GroundTruth>,
    ui: &'a mut dyn RoutineUi,
    cancel: &'a CancellationToken,
    /// The one write path ([`crate::base::write`]): proven writable before anything else,
    /// backed up before the robot first moves, undone on failure.
    session: WriteSession,
    /// This run's report directory, once claimed ([`Calibration::claim_report_dir`]).
    report_dir: Option<std::path::PathBuf>,
    progress: Progress,
    /// The spread of every rest's readings so far: the heading sensor's noise.
    noise: heading::NoisePool,
    /// The pre-flight's readings' spread, which every rest after is judged against.
    preflight_noise: heading::NoisePool,
    /// Rests whose readings spread beyond the sensor's noise: the robot had not settled.
    moving_rests: usize,
    warnings: Vec<String>,
    /// The heading every square starts at (the first square's), once known.
    start_heading_rad: Option<f64>,
    /// What the compass swing measured.
    swing: Option<SwingFit>,
    /// The plan shown before the robot moved ([`planning`]).
    plan: Option<Plan>,
}

/// What the rounds left: each round's report, the parameters in use now, whether the last
/// round converged.
struct Rounds {
    reports: Vec<RoundReport>,
    current: WheelParams,
    converged: bool,
}

impl Calibration<'_> {
    /// The procedure: pre-flight, rounds (each written when allowed) until converged,
    /// verification, judgement.
    async fn body(&mut self) -> Result<Report, RoutineError> {
        self.preflight().await?;
        self.make_plan();
        self.confirm_motion()?;
        self.back_up().await?;
        let original = *self.session.original();
        self.swing(&original).await?;
        let rounds = self.rounds(&original).await?;
        let verification = self.verification(&rounds).await?;
        if self.moving_rests > 0 {
            self.warn(format!(
                "{} rest(s) spread beyond the heading sensor's noise (the robot had not settled): \
                 left out of the noise estimate; a longer settle_s measures such squares better",
                self.moving_rests
            ));
        }
        let mut report = Report::assemble(
            &self.base,
            self.cfg,
            Outcome {
                original_params: original,
                backup_path: self
                    .session
                    .backup_path()
                    .map(std::path::Path::to_path_buf)
                    .unwrap_or_default(),
                final_params: rounds.current,
                heading_noise_rad: self.noise.std_rad(),
                preflight_heading_noise_rad: self.preflight_noise.std_rad(),
                rounds: rounds.reports,
                verification,
                converged: rounds.converged,
                written: self.session.written(),
                warnings: std::mem::take(&mut self.warnings),
            },
        );
        report.swing = self.swing.take();
        report.plan = self.plan.take();
        report.report_dir = self.report_dir.clone();
        Ok(report)
    }

    /// The rounds from `original`: each measured, then written when its correction is
    /// significant and allowed, until one converges (or the user declines, or
    /// `max_rounds`).
    async fn rounds(&mut self, original: &WheelParams) -> Result<Rounds, RoutineError> {
        let mut current = *original;
        let mut reports = Vec::new();
        let mut converged = false;
        for round in 1..=self.cfg.max_rounds {
            let mut rr = self.round(round, &current).await?;
            if let Some(why) = &rr.converged_because {
                self.stage(format!(
                    "converged: E_b {:.5}, E_d {:.5}: {why}",
                    rr.chosen.e_b, rr.chosen.e_d
                ));
                converged = true;
                reports.push(rr);
                break;
            }
            let proposed = rr.chosen.correction.apply(&current)?;
            self.session.check(
                &proposed,
                Bounds::MaxChange {
                    fraction: self.cfg.max_change,
                    wider: Some("a skid-steer robot needs this: --allow-large-change"),
                },
            )?;
            rr.params_after = Some(proposed);
            if !self.authorise_write(&current, &proposed) {
                reports.push(rr);
                break;
            }
            self.progress.stage = Stage::WriteBack { round };
            // From here on, the parameters are what the store reports (rounded to its
            // resolution).
            current =
                cancellable(self.cancel, self.session.write(&proposed, &Commit::Both)).await?;
            rr.written = true;
            reports.push(rr);
        }
        if !converged && self.session.written() {
            self.warn(format!(
                "not converged after {} round(s) (the last correction was still significant); \
                 the last estimate was written",
                self.cfg.max_rounds
            ));
        }
        Ok(Rounds {
            reports,
            current,
            converged,
        })
    }

    /// The verification squares, judged: a sequential run's confirming round when it was
    /// driven with the parameters that stay, otherwise squares driven now.
    async fn verification(&mut self, rounds: &Rounds) -> Result<Vec<RunReport>, RoutineError> {
        let confirming = rounds.reports.last().filter(|r| {
            self.cfg.target().is_some()
                && rounds.converged
                && r.round > 1
                && r.params_before == rounds.current
        });
        match confirming {
            Some(last) => {
                self.stage(
                    "verification: the confirming round's squares, driven with the written \
                     parameters"
                        .into(),
                );
                self.judged(&rounds.reports, last.runs.clone())
            }
            None => self.verify(&rounds.current, &rounds.reports).await,
        }
    }

    fn stage(&mut self, s: String) {
        self.ui.event(&RoutineEvent::Stage(s));
    }

    /// A warning for the user now and for the report.
    fn warn(&mut self, w: String) {
        self.ui.event(&RoutineEvent::Warning(w.clone()));
        self.warnings.push(w);
    }

    /// The report directory this run writes to: the configured one when no earlier report
    /// holds it, else `dir-2`, `dir-3`, … (created now; `None` without one). Claimed before
    /// the backup, so that a second run's backup never lands in the first one's directory.
    fn claim_report_dir(&mut self) -> Result<Option<std::path::PathBuf>, RoutineError> {
        if self.report_dir.is_none() {
            if let Some(dir) = &self.cfg.report_dir {
                let claimed = crate::io::fresh_dir(dir, &report::REPORT_FILES).map_err(|e| {
                    RoutineError::Output {
                        path: dir.clone(),
                        reason: e.to_string(),
                    }
                })?;
                self.report_dir = Some(claimed);
            }
        }
        Ok(self.report_dir.clone())
    }

    /// Backs the parameters up, once the robot may move and before it does, into the run's
    /// one place for its files ([`run_dir`]).
    async fn back_up(&mut self) -> Result<(), RoutineError> {
        let claimed = self.claim_report_dir()?;
        let file = ParamStore::file(self.base.store.as_ref());
        let dir = run_dir(self.cfg, claimed.as_deref(), file.as_deref(), true);
        let path = cancellable(self.cancel, self.session.back_up(&dir)).await?;
        self.stage(format!(
            "backed up the robot's parameters to {}",
            path.display()
        ));
        Ok(())
    }

    /// Asks before the robot first moves (unless the settings say not to).
    fn confirm_motion(&mut self) -> Result<(), RoutineError> {
        let cfg = self.cfg;
        let question = planning::motion_question(cfg, self.plan.as_ref());
        if cfg.confirm_motion && !self.ui.confirm(&question) {
            return Err(RoutineError::Declined("the robot may not move".into()));
        }
        Ok(())
    }

    /// Whether the new parameters may be written: the policy, and the user's answer to the
    /// table of old → new when it asks ([`write_service::authorise`]).
    fn authorise_write(&mut self, current: &WheelParams, proposed: &WheelParams) -> bool {
        let question =
            write_service::Question::OldToNew("Write these parameters and commit them?".into())
                .text(current, proposed);
        let answer = write_service::authorise(
            self.cfg.write_back,
            &mut AskRoutineUi(&mut *self.ui),
            &question,
        );
        if let Err(refusal) = &answer {
            self.stage(match refusal {
                write_service::WriteError::DryRun => "dry run: nothing written".into(),
                _ => "not written (declined)".into(),
            });
        }
        answer.is_ok()
    }

    /// The verification squares after a write, judged against the first round ([`judge`]).
    async fn verify(
        &mut self,
        current: &WheelParams,
        rounds: &[RoundReport],
    ) -> Result<Vec<RunReport>, RoutineError> {
        if !self.session.written() || self.cfg.verification_runs == 0 {
            return Ok(Vec::new());
        }
        self.stage("verification squares".into());
        let verification = self
            .drive_runs(Phase::Verification, self.cfg.verification_runs, current)
            .await?;
        self.judged(rounds, verification)
    }

    /// `verification` once [`judge`] finds it clearly better than the first round (or the
    /// settings keep worse parameters, with a warning).
    fn judged(
        &mut self,
        rounds: &[RoundReport],
        verification: Vec<RunReport>,
    ) -> Result<Vec<RunReport>, RoutineError> {
        let abs_deg = |runs: &[RunReport]| -> Vec<(Direction, f64)> {
            runs.iter()
                .map(|r| (r.direction, r.heading_error_deg.abs()))
                .collect()
        };
        let before = rounds.first().map(|r| abs_deg(&r.runs)).unwrap_or_default();
        let distance: Vec<f64> = rounds
            .iter()
            .map(|r| (r.chosen.e_b - 1.0).abs() + (r.chosen.e_d - 1.0).abs())
            .collect();
        if let Err(why) = judge(&before, &abs_deg(&verification), &distance) {
            if !self.cfg.keep_worse {
                return Err(RoutineError::NotBetter(why));
            }
            self.warn(format!("{why}; kept because of --keep-worse"));
        }
        Ok(verification)
    }
}

/// The routine's user as the write service's: the same question, asked the same way.
struct AskRoutineUi<'a>(&'a mut dyn RoutineUi);

impl WriteUi for AskRoutineUi<'_> {
    fn confirm(&mut self, question: &str) -> bool {
        self.0.confirm(question)
    }
}

/// Proves that a new file could be created in `dir`, creating nothing that stays: it is a
/// directory that takes one, or does not exist yet and would be created where one can be
/// ([`crate::io::probe_dir_to_be`]).
pub fn check_output_dir(dir: &std::path::Path) -> Result<(), RoutineError> {
    let fail = |reason: String| RoutineError::Output {
        path: dir.to_path_buf(),
        reason,
    };
    if dir.exists() && !dir.is_dir() {
        return Err(fail("it exists and is not a directory".into()));
    }
    crate::io::probe_dir_to_be(dir)
        .map_err(|e| fail(format!("a new file cannot be created there ({e})")))
}
