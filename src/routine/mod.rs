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

pub use error::RoutineError;
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

    /// **Moves the robot**: the compass swing ([`RoutineConfig::swing`]); a deviation it
    /// measures is removed from every reading after. A base that cannot swing, or a fit that
    /// fails its checks (refused, never applied), is a warning and the run goes on: the
    /// default method pairs legs by azimuth and does not need it.
    async fn swing(&mut self, params: &WheelParams) -> Result<(), RoutineError> {
        let kind = self.base.heading.kind();
        if !planning::swings(self.cfg, kind) {
            return Ok(());
        }
        self.progress.stage = Stage::Swing;
        let cmd = SwingCommand {
            turns_per_direction: planning::SWING_TURNS_PER_DIRECTION,
            rate_rad_s: planning::swing_rate_rad_s(self.cfg),
            wheelbase_m: params.wheelbase_m,
            stream_period: Duration::from_millis(self.cfg.telemetry_ms.max(1)),
            noise_std_rad: Some(self.noise.std_rad()).filter(|s| *s > 0.0),
        };
        self.stage(format!(
            "compass swing: two full turns in place each way at {:.2} rad/s (the heading is {kind})",
            cmd.rate_rad_s
        ));
        match cancellable(self.cancel, swing::run_swing(&self.base, &cmd)).await? {
            Ok(fit) => {
                let [a1, b1, a2, b2] = fit.deviation.0.map(f64::to_degrees);
                self.stage(format!(
                    "compass deviation up to {:.2}° (A1 {a1:+.2}°, B1 {b1:+.2}°, A2 {a2:+.2}°, \
                     B2 {b2:+.2}°; residual {:.2}°): removed from every reading from here on \
                     (kept in the report; `odocal swing --save` keeps a curve in a robot profile)",
                    fit.amplitude_rad.to_degrees(),
                    fit.residual_rms_rad.to_degrees()
                ));
                if let Some(advice) = fit.advice() {
                    self.warn(advice);
                }
                self.base.heading = Arc::new(Adjusted::new(
                    self.base.heading.clone(),
                    None,
                    fit.deviation,
                ));
                self.swing = Some(fit);
            }
            Err(swing::NoSwing::Refused(why)) => self.warn(format!(
                "compass swing refused: {why}; going on without a deviation correction"
            )),
            Err(why) => self.warn(format!("no compass swing: {why}")),
        }
        Ok(())
    }

    fn stage(&mut self, s: String) {
        self.ui.event(&RoutineEvent::Stage(s));
    }

    /// A warning for the user now and for the report.
    fn warn(&mut self, w: String) {
        self.ui.event(&RoutineEvent::Warning(w.clone()));
        self.warnings.push(w);
    }

    /// Drive faults, the heading sensor at rest (its validity and noise), the watchdog.
    async fn preflight(&mut self) -> Result<(), RoutineError> {
        self.progress.stage = Stage::PreFlight;
        self.stage("pre-flight checks".into());
        let check = cancellable(self.cancel, self.base.drive.preflight()).await?;
        if !check.faults.is_empty() {
            return Err(RoutineError::Preflight(check.faults.join("; ")));
        }
        let readings = match cancellable(
            self.cancel,
            heading::readings_within(
                self.base.heading.as_ref(),
                PREFLIGHT_READINGS.0,
                PREFLIGHT_READINGS.1,
                PREFLIGHT_BUDGET,
            ),
        )
        .await
        {
            Err(RoutineError::Base(BaseError::HeadingInvalid { reason })) => {
                return Err(RoutineError::Preflight(format!(
                    "the heading sensor reports invalid: {reason}"
                )))
            }
            other => other?,
        };
        self.noise = heading::NoisePool::of(&readings);
        self.preflight_noise = self.noise;
        self.stage(format!(
            "heading noise at rest: {:.3}° (σ of {} readings; refined by every rest that follows)",
            self.noise.std_rad().to_degrees(),
            readings.len()
        ));
        let armed = cancellable(
            self.cancel,
            self.base
                .drive
                .arm_watchdog(Duration::from_millis(self.cfg.watchdog_ms)),
        )
        .await?;
        let mut warnings = check.warnings;
        if let Some(w) = gyro_warning(self.base.heading.kind(), self.cfg.gyro_scale_error) {
            warnings.push(w);
        }
        if armed.is_none() {
            warnings.push(
                "the drive has no watchdog: if this host vanishes mid-motion, only the drive's \
                 own limits stop the robot"
                    .into(),
            );
        }
        for w in warnings {
            self.warn(w);
        }
        Ok(())
    }

    /// Adds a square's readings at rest to the noise estimate, unless their spread shows the
    /// robot was still moving (judged against the pre-flight's σ), which is counted instead.
    fn pool_rest_noise(&mut self, rec: &SquareRecord) {
        if rec.rest_noise.consistent_with(&self.preflight_noise) {
            self.noise = self.noise.plus(rec.rest_noise);
        } else {
            self.moving_rests += 1;
        }
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

    /// A calibration round: its squares, every method's estimate, the chosen one and whether
    /// it is within tolerance.
    async fn round(
        &mut self,
        round: usize,
        current: &WheelParams,
    ) -> Result<RoundReport, RoutineError> {
        self.stage(format!("round {round}: calibration squares"));
        let phase = Phase::Calibration { round };
        let (runs, stopped) = match self.cfg.target() {
            Some(target) => {
                let (runs, why) = self.drive_until(phase, &target, current).await?;
                (runs, Some(why))
            }
            None => (
                self.drive_runs(phase, self.cfg.runs_per_direction, current)
                    .await?,
                None,
            ),
        };
        for r in &runs {
            self.warnings.extend(r.warnings.iter().cloned());
        }
        let test = square_test(self.cfg, current, &runs, self.noise.std_rad());
        let mut estimates = Vec::new();
        let mut failures = Vec::new();
        for (method, result) in estimate_all(&test, self.cfg.split_convention())? {
            match result {
                Ok(e) => estimates.push(e),
                Err(e) => failures.push((method, e.to_string())),
            }
        }
        let (method, chosen_because) = self.choose(&test);
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
        let crb = cramer_rao_std(
            self.cfg,
            &chosen,
            self.noise.std_rad(),
            current.wheelbase_m,
            test.cw.len().min(test.ccw.len()),
        );
        let stopped_because = stopped.map(|why| {
            let text = why.describe(test.cw.len().min(test.ccw.len()));
            match why {
                Stop::Ceiling => self.warn(format!("round {round}: {text}")),
                _ => self.stage(format!("round {round}: {text}")),
            }
            text
        });
        let converged_because = convergence(self.cfg, &chosen, crb, current.wheelbase_m);
        Ok(RoundReport {
            round,
            params_before: *current,
            runs,
            estimates,
            failures,
            chosen,
            chosen_because,
            cramer_rao_std: crb,
            converged: converged_because.is_some(),
            converged_because,
            stopped_because,
            params_after: None,
            written: false,
        })
    }

    /// The method to write and why: the configured one, or the data's default
    /// ([`default_method`]), saying when some runs lacked the heading along the legs.
    fn choose(&mut self, test: &SquareTest) -> (Method, String) {
        let m = self.method_for(test);
        if self.cfg.method.is_some() {
            return (
                m,
                "named in the settings (--method or the routine file)".into(),
            );
        }
        let (without, of) = test.runs_without_leg_headings();
        if !matches!(m, Method::Legs | Method::MatchedLegs) {
            self.warn(
                "the heading along the legs was not recorded in any run of one direction: \
                 estimating from the headings at rest (exact), which counts any start transient"
                    .into(),
            );
        } else if without > 0 {
            self.warn(format!(
                "the heading along the legs was not recorded in {without} of {of} runs \
                 (incomplete streams): the leg method uses the other {}",
                of - without
            ));
        }
        (m, default_method_reason(m).into())
    }

    /// The method to write for `test`, without a word (see [`Calibration::choose`]).
    fn method_for(&self, test: &SquareTest) -> Method {
        self.cfg.method.unwrap_or_else(|| {
            default_method(
                test.has_leg_headings(),
                test.has_positions(),
                self.base.heading.kind(),
            )
            .unwrap_or(Method::Exact)
        })
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

    /// Stops the base, undoes any write and leaves the partial report; returns the error as
    /// it stands after the rollback.
    async fn fail(mut self, err: RoutineError) -> RoutineError {
        // Stop first (the guard in run_square has already asked for a stop if a square was cut
        // short; this covers everything else), then undo any write.
        let robot = match tokio::time::timeout(STOP_TIMEOUT, self.base.drive.stop()).await {
            Ok(Ok(())) => RobotAfterStop::Stopped,
            Ok(Err(e)) => RobotAfterStop::NotReached(e.to_string()),
            Err(_) => RobotAfterStop::NotReached(format!(
                "no answer to the stop within {} s",
                STOP_TIMEOUT.as_secs()
            )),
        };
        let wrote = self.session.written();
        let err = RoutineError::after(err, self.session.undo().await);
        let mut ending = Ending {
            robot,
            parameters: ParamsAfterFailure::of(&err),
            backup: self.session.backup_path().map(std::path::Path::to_path_buf),
        };
        // Nothing driven and nothing written: nothing happened, and nothing is left behind
        // (the backup of a store this run never changed, a report directory it made).
        if self.progress.runs.is_empty() && !wrote {
            if let Some(backup) = ending.backup.take() {
                let _ = std::fs::remove_file(&backup);
            }
            if let Some(dir) = &self.report_dir {
                // Only when empty: an earlier run's files are never touched.
                let _ = std::fs::remove_dir(dir);
            }
            self.ui.event(&RoutineEvent::Ended(ending));
            return err;
        }
        // Nothing measured is thrown away: the squares driven so far, where it stopped and
        // why, in the run's one place for its files ([`run_dir`]).
        let written = match self.claim_report_dir() {
            Ok(claimed) => {
                let file = ParamStore::file(self.base.store.as_ref());
                let dir = run_dir(self.cfg, claimed.as_deref(), file.as_deref(), false);
                let prefix = crate::base::transaction::store_prefix(
                    file.as_deref(),
                    "odocal-partial-report",
                    "partial-report",
                );
                write_partial(
                    &self.base,
                    self.cfg,
                    &self.progress,
                    &err,
                    (&dir, &prefix),
                    self.session.backup_path(),
                )
                .map_err(|e| {
                    format!(
                        "the partial report could not be written to {}: {e}",
                        dir.display()
                    )
                })
            }
            Err(e) => Err(format!("the partial report could not be written: {e}")),
        };
        self.ui.event(&RoutineEvent::Warning(match written {
            Ok(path) => format!(
                "{} square(s) measured before the failure ({}) are in {}",
                self.progress.runs.len(),
                self.progress.stage,
                path.display()
            ),
            Err(e) => e,
        }));
        self.ui.event(&RoutineEvent::Ended(ending));
        err
    }

    /// **Moves the robot**: turns in place back to the heading the first square started at
    /// (by the heading sensor: a deviation is the same at one azimuth, so the same reading is
    /// the same true heading), so that every square's legs point the same four ways. The first
    /// call notes the heading instead.
    async fn realign(&mut self) -> Result<(), RoutineError> {
        if !self.cfg.realign {
            return Ok(());
        }
        let n = self.cfg.heading_samples;
        let now = cancellable(
            self.cancel,
            heading::mean_heading(self.base.heading.as_ref(), n),
        )
        .await?;
        let Some(target) = self.start_heading_rad else {
            self.start_heading_rad = Some(now);
            return Ok(());
        };
        // Twice at most: the second turn takes out what the drive's own error left.
        let mut off = wrap_angle(target - now);
        let mut turned = None;
        let mut turns = 0;
        for _ in 0..2 {
            if off.abs() < REALIGN_WITHIN_RAD {
                break;
            }
            let guard = MotionGuard::new(&self.base.drive);
            cancellable(
                self.cancel,
                self.base.drive.turn_in_place(off, self.cfg.max_rate_rad_s),
            )
            .await?;
            guard.disarm();
            turned = Some(turned.unwrap_or(0.0) + off);
            turns += 1;
            if self.cfg.settle_s > 0.0 {
                tokio::time::sleep(Duration::from_secs_f64(self.cfg.settle_s)).await;
            }
            let now = cancellable(
                self.cancel,
                heading::mean_heading(self.base.heading.as_ref(), n),
            )
            .await?;
            off = wrap_angle(target - now);
        }
        if let Some(turn_rad) = turned {
            self.ui.event(&RoutineEvent::Realigned {
                turn_rad,
                left_rad: off,
                turns,
            });
        }
        Ok(())
    }

    /// **Moves the robot**: `per_direction` squares clockwise, then as many counter-clockwise,
    /// each measured, kept in the progress and checked for plausibility.
    async fn drive_runs(
        &mut self,
        phase: Phase,
        per_direction: usize,
        params: &WheelParams,
    ) -> Result<Vec<RunReport>, RoutineError> {
        self.progress.stage = Stage::of(phase);
        let of = per_direction * 2;
        self.ui.event(&RoutineEvent::Plan {
            motions: of as u64 * 8,
            robot_time_s: of as f64 * square_motion_time_s(self.cfg),
        });
        let mut out = Vec::with_capacity(of);
        for direction in [Direction::Cw, Direction::Ccw] {
            for _ in 0..per_direction {
                let run = self
                    .drive_square(phase, direction, out.len() + 1, of, params)
                    .await?;
                out.push(run);
            }
        }
        Ok(out)
    }

    /// **Moves the robot**: one square (after turning back to the first square's heading),
    /// measured, kept in the progress and checked for plausibility; `index` of `of` in its
    /// phase.
    async fn drive_square(
        &mut self,
        phase: Phase,
        direction: Direction,
        index: usize,
        of: usize,
        params: &WheelParams,
    ) -> Result<RunReport, RoutineError> {
        let cfg = self.cfg;
        let cmd = SquareCommand {
            side_m: cfg.side_m,
            direction,
            max_speed_m_s: cfg.max_speed_m_s,
            max_rate_rad_s: cfg.max_rate_rad_s,
            heading_samples: cfg.heading_samples,
            settle: Duration::from_secs_f64(cfg.settle_s),
            stream_period: Duration::from_millis(cfg.telemetry_ms.max(1)),
        };
        self.realign().await?;
        let start = self.truth.map(|t| t.pose());
        let rec = {
            let ui = &mut *self.ui;
            let on_motion = move |motion| {
                ui.event(&RoutineEvent::Motion {
                    phase,
                    run: index,
                    of,
                    direction,
                    motion,
                    duration_s: motion_time_s(cfg, motion),
                })
            };
            cancellable(self.cancel, run_square(&self.base, &cmd, on_motion)).await?
        };
        self.pool_rest_noise(&rec);
        let mut run = RunReport::new(phase, &rec, params, start, self.truth);
        if let Some(s) = cfg.gyro_scale_error {
            run.remove_gyro_scale(s, cfg.side_m);
        }
        // Measured is kept, even a square the next check refuses.
        self.progress.runs.push(run.clone());
        check_plausible(&rec, &run, params, self.ui)?;
        self.ui.event(&RoutineEvent::RunDone {
            phase,
            run: index,
            of,
            direction,
            heading_error_deg: run.heading_error_deg,
        });
        Ok(run)
    }
}

/// Robot time of motion `motion` (1..=8, legs odd) of a square at the speed limits (s).
fn motion_time_s(cfg: &RoutineConfig, motion: usize) -> f64 {
    if motion % 2 == 1 {
        cfg.side_m / cfg.max_speed_m_s
    } else {
        std::f64::consts::FRAC_PI_2 / cfg.max_rate_rad_s
    }
}

/// Robot time of a square's eight motions at the speed limits (s).
fn square_motion_time_s(cfg: &RoutineConfig) -> f64 {
    (1..=8).map(|k| motion_time_s(cfg, k)).sum()
}

/// What a gyro's scale error does to the estimate, for a heading that is or may be integrated
/// from a gyro whose scale was not given.
pub fn gyro_warning(kind: HeadingKind, scale_error: Option<f64>) -> Option<String> {
    if scale_error.is_some() {
        return None;
    }
    let what = "E_b (the wheelbase) carries the gyro's scale error one to one: a gyro 1 % fast \
                writes a wheelbase 1 % off, and no square can tell; measure it with `odocal spin` \
                and give it with --gyro-scale-error";
    match kind {
        HeadingKind::Gyro => Some(format!("the heading is integrated from a gyro: {what}")),
        HeadingKind::Unknown => Some(format!(
            "the heading sensor's kind is unknown (--heading-kind): if it is integrated from a \
             gyro (an IMU without magnetometer), {what}"
        )),
        HeadingKind::Magnetic | HeadingKind::Reference => None,
    }
}

/// A square starts within this of the first square's heading (rad; 0.5°), or the robot turns
/// back to it ([`RoutineConfig::realign`]).
pub const REALIGN_WITHIN_RAD: f64 = 0.5 * std::f64::consts::PI / 180.0;

/// A correction that changes the heading error of a square by less than this (deg) is not
/// worth a write: it is below what a user can see or a compass can tell.
pub const VISIBLE_DEG: f64 = 0.1;

/// Whether a round's estimate ends the calibration, and why: its correction is within two of
/// its standard errors of no correction (nothing significant to apply), or it would change
/// the heading error of a square by less than [`VISIBLE_DEG`], or (when the user set one) it
/// is within the tolerance. A significant, visible correction is applied whatever its size.
/// Without run-to-run standard errors (one run per direction) the Cramér–Rao bound stands in.
pub fn convergence(
    cfg: &RoutineConfig,
    chosen: &Estimate,
    cramer_rao_std: Option<[f64; 2]>,
    wheelbase_m: f64,
) -> Option<String> {
    let (db, dd) = (chosen.e_b - 1.0, chosen.e_d - 1.0);
    if let Some(t) = cfg.tolerance {
        if db.abs() < t && dd.abs() < t {
            return Some(format!(
                "|E_b − 1| and |E_d − 1| are within the tolerance ±{t}"
            ));
        }
    }
    let sigma = match (chosen.e_b_std_err, chosen.e_d_std_err, cramer_rao_std) {
        (Some(b), Some(d), _) => Some((b, d)),
        (_, _, Some([b, d])) => Some((b, d)),
        _ => None,
    };
    if let Some((sb, sd)) = sigma {
        if db.abs() <= 2.0 * sb && dd.abs() <= 2.0 * sd {
            return Some(format!(
                "the correction is not significant (E_b − 1 = {db:+.5} ± {sb:.5}, E_d − 1 = \
                 {dd:+.5} ± {sd:.5}: within two standard errors)"
            ));
        }
    }
    let (cw, ccw) = crate::calibration::exact::predicted_heading_errors(
        &chosen.correction,
        cfg.side_m,
        wheelbase_m,
    );
    let gain_deg = cw.abs().max(ccw.abs()).to_degrees();
    (gain_deg < VISIBLE_DEG).then(|| {
        format!(
            "the correction would change a square's heading error by {gain_deg:.3}° at most, \
             below the {VISIBLE_DEG}° that can be seen"
        )
    })
}

/// The routine's user as the write service's: the same question, asked the same way.
struct AskRoutineUi<'a>(&'a mut dyn RoutineUi);

impl WriteUi for AskRoutineUi<'_> {
    fn confirm(&mut self, question: &str) -> bool {
        self.0.confirm(question)
    }
}

/// Where a run got to: the stage and every square measured so far.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct Progress {
    /// The stage the run was in.
    pub stage: Stage,
    /// Every square measured, in order.
    pub runs: Vec<RunReport>,
}

/// Writes `<prefix><UTC time>.json` (created new) into `dir` (`place`): the phase, the error,
/// what the robot's parameters are now ([`ParamsAfterFailure`]) and the backup, the base (its
/// port) and its link diagnostics (requests, retries, the last request), the settings and
/// every square measured, so the run can be estimated from or understood.
fn write_partial(
    base: &Base,
    cfg: &RoutineConfig,
    progress: &Progress,
    err: &RoutineError,
    place: (&std::path::Path, &str),
    backup: Option<&std::path::Path>,
) -> std::io::Result<std::path::PathBuf> {
    let (dir, prefix) = place;
    let value = serde_json::json!({
        "odocal_version": env!("CARGO_PKG_VERSION"),
        "error": err.to_string(),
        "phase": progress.stage,
        "parameters": ParamsAfterFailure::of(err),
        "backup": backup,
        "base": base.info(),
        "diagnostics": base.drive.diagnostics(),
        "config": cfg,
        "runs": progress.runs,
    });
    let text = serde_json::to_string_pretty(&value).map_err(std::io::Error::other)?;
    std::fs::create_dir_all(dir)?;
    crate::io::create_stamped(dir, prefix, ".json", text.as_bytes())
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

/// How long the stop after a failure may take before the robot is reported unreachable.
const STOP_TIMEOUT: Duration = Duration::from_secs(2);

/// Where the robot is after a run that stopped.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case", tag = "state", content = "detail")]
pub enum RobotAfterStop {
    /// The drive took the stop.
    Stopped,
    /// The stop could not be sent or was not taken (why).
    NotReached(String),
}

/// How a run that stopped left the robot and its parameters ([`RoutineEvent::Ended`]): the
/// two lines a user reads last, each saying what to do next where there is something to do.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Ending {
    /// Where the robot is.
    pub robot: RobotAfterStop,
    /// What the store holds.
    pub parameters: ParamsAfterFailure,
    /// The backup this run took and kept, if any.
    pub backup: Option<std::path::PathBuf>,
}

impl std::fmt::Display for Ending {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.robot {
            RobotAfterStop::Stopped => f.write_str("robot: stopped")?,
            RobotAfterStop::NotReached(why) => write!(
                f,
                "robot: NOT confirmed stopped ({why}); its own watchdog stops it when the host \
                 goes silent: check that it has, and stop it by hand if not"
            )?,
        }
        let backup = self.backup.as_ref().map(|b| b.display().to_string());
        match (&self.parameters, &backup) {
            (ParamsAfterFailure::Untouched, Some(b)) => write!(
                f,
                "\nparameters: untouched (nothing was written; the backup taken before is {b})"
            ),
            (ParamsAfterFailure::Untouched, None) => {
                f.write_str("\nparameters: untouched (nothing was written)")
            }
            (ParamsAfterFailure::Restored { committed, .. }, _) => write!(
                f,
                "\nparameters: restored to what they were before the run ({})",
                if *committed {
                    "in use and stored"
                } else {
                    "in use; the stored copy was never changed"
                }
            ),
            (ParamsAfterFailure::RestoreFailed { active, committed }, b) => write!(
                f,
                "\nparameters: NOT restored: in use {active}, stored {committed}; put them back \
                 with `odocal restore {}` once the robot answers",
                b.as_deref().unwrap_or("BACKUP")
            ),
        }
    }
}

/// Whether written parameters clearly helped ("never worse"): `Err` with the numbers when the
/// rounds diverged (the last round's estimate is no nearer 1 than the first's,
/// `round_distance` being `|E_b − 1| + |E_d − 1|` per round) or when the verification's mean
/// |heading error| is not below the first round's by two of its standard errors (the two
/// means' standard errors combined; an error of a run set with fewer than two runs counts its
/// spread as 0).
pub fn judge(
    before_deg: &[(Direction, f64)],
    after_deg: &[(Direction, f64)],
    round_distance: &[f64],
) -> Result<(), String> {
    if let (Some(first), Some(last)) = (round_distance.first(), round_distance.last()) {
        if round_distance.len() >= 2 && last >= first {
            return Err(format!(
                "the rounds diverged: |E_b − 1| + |E_d − 1| went from {first:.5} to {last:.5} \
                 over {} rounds",
                round_distance.len()
            ));
        }
    }
    // Per direction: a robot off by 50° one way and 10° the other is not a scatter of 40°.
    let stats = |v: &[(Direction, f64)]| {
        let mut parts = Vec::new();
        for d in [Direction::Cw, Direction::Ccw] {
            let x: Vec<f64> = v.iter().filter(|r| r.0 == d).map(|r| r.1).collect();
            if x.is_empty() {
                continue;
            }
            let n = x.len() as f64;
            let mean = x.iter().sum::<f64>() / n;
            let var = if x.len() > 1 {
                x.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (n - 1.0)
            } else {
                0.0
            };
            parts.push((mean, var / n));
        }
        let k = parts.len().max(1) as f64;
        (
            parts.iter().map(|p| p.0).sum::<f64>() / k,
            parts.iter().map(|p| p.1).sum::<f64>().sqrt() / k,
        )
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

fn check_plausible(
    rec: &SquareRecord,
    run: &RunReport,
    params: &WheelParams,
    ui: &mut dyn RoutineUi,
) -> Result<(), RoutineError> {
    use std::f64::consts::{FRAC_PI_2, PI};
    let sign = rec.command.direction.turn_sign();
    let expected = sign * 2.0 * PI;
    // Reversed means at least half the square's turn the other way: a stream that saw little
    // of the square (lost or late samples) turns near zero, which is no evidence either way.
    let opposite = |turn: f64| turn * sign < -PI;
    // Too few samples to tell a turn's sign (a stream that barely started) are no evidence,
    // nor are headings so far apart that the robot may have turned a quarter between two:
    // their differences cannot be unwrapped.
    let track = rec.recording().track(params.wheelbase_m);
    let turns = track.turns();
    let widest_gap_s = track
        .readings
        .windows(2)
        .map(|w| w[1].0 - w[0].0)
        .fold(0.0, f64::max);
    let unwrappable = widest_gap_s * rec.command.max_rate_rad_s < FRAC_PI_2;
    let odometry_turn = (track.points.len() > 8).then_some(turns.odometry_rad);
    let compass_turn = turns
        .heading_rad
        .filter(|_| track.readings.len() > 8 && unwrappable);
    // The wheels must turn the robot the way the square was commanded; the opposite sign
    // means the encoders or motor channels are swapped or reversed.
    if let Some(turn) = odometry_turn.filter(|&t| opposite(t)) {
        return Err(RoutineError::Implausible(format!(
            "the drive's odometry turned {:.0}° during a {} square that should turn {:.0}°: \
             left and right wheels (or encoder directions) are swapped",
            turn.to_degrees(),
            rec.command.direction,
            expected.to_degrees()
        )));
    }
    match compass_turn {
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
        None if track.readings.len() > 8 => ui.event(&RoutineEvent::Warning(format!(
            "the heading stream has gaps of up to {widest_gap_s:.2} s: the heading sensor's \
             sign convention cannot be checked on this square"
        ))),
        None => ui.event(&RoutineEvent::Warning(
            "no heading stream: the heading sensor's sign convention cannot be checked".into(),
        )),
    }
    for w in &run.warnings {
        ui.event(&RoutineEvent::Warning(w.clone()));
    }
    Ok(())
}

/// The square test of `runs`; each run's heading error at rest carries the variance the
/// heading noise gives it (`heading_noise_rad` per reading, `heading_samples` averaged at each
/// end), the floor under its stated standard error ([`planning`]).
fn square_test(
    cfg: &RoutineConfig,
    params: &WheelParams,
    runs: &[RunReport],
    heading_noise_rad: f64,
) -> SquareTest {
    let noise = (heading_noise_rad > 0.0)
        .then(|| heading_error_sigma(heading_noise_rad, cfg.heading_samples).powi(2));
    SquareTest::from_runs(
        cfg.side_m,
        params.wheelbase_m,
        runs.iter().map(|r| {
            let mut m = r.measurement();
            m.noise_variance_rad2 = noise;
            (r.direction, m)
        }),
    )
}

/// The Cramér–Rao bound's standard errors for `runs` per direction.
fn cramer_rao_std(
    cfg: &RoutineConfig,
    e: &Estimate,
    heading_noise_rad: f64,
    wheelbase_m: f64,
    runs: usize,
) -> Option<[f64; 2]> {
    let design = TestDesign {
        side_m: cfg.side_m,
        wheelbase_m,
        runs_cw: runs,
        runs_ccw: runs,
        heading_error_sigma_rad: heading_error_sigma(heading_noise_rad, cfg.heading_samples),
    };
    cramer_rao_bound(e.e_b, e.e_d, cfg.split_convention(), &design)
        .ok()
        .map(|c| [c[(0, 0)].sqrt(), c[(1, 1)].sqrt()])
}

#[cfg(test)]
mod judge_tests {
    use super::judge;
    use crate::kinematics::Direction;

    fn cw(v: &[f64]) -> Vec<(Direction, f64)> {
        v.iter().map(|&x| (Direction::Cw, x)).collect()
    }

    #[test]
    fn only_a_clear_improvement_that_converges_passes() {
        // 5° → 0.1°, rounds converging: better.
        assert_eq!(
            judge(&cw(&[5.0, 5.2, 4.9]), &cw(&[0.1, 0.12]), &[0.03, 0.0005]),
            Ok(())
        );
        // The rounds oscillate (the last no nearer than the first): refused, with the numbers.
        let e = judge(&cw(&[37.7, 37.8]), &cw(&[38.6, 38.5]), &[0.5, 0.2, 0.5]).unwrap_err();
        assert!(e.contains("diverged") && e.contains("0.50000"), "{e}");
        // Worse after than before.
        let e = judge(&cw(&[1.0, 1.1]), &cw(&[1.3, 1.2]), &[0.02]).unwrap_err();
        assert!(e.contains("1.050° before, 1.250° after"), "{e}");
        // Better, but within the scatter: not clearly better.
        assert!(judge(&cw(&[0.30, 0.10, 0.50]), &cw(&[0.25, 0.05, 0.45]), &[0.001]).is_err());
        // A robot 58° off one way and 3° the other, each repeatable, brought to 0.1°: better
        // (pooled, the two directions would look like a scatter of 30°).
        let both = |a: f64, b: f64| {
            vec![
                (Direction::Cw, a),
                (Direction::Cw, a + 0.1),
                (Direction::Ccw, b),
                (Direction::Ccw, b - 0.1),
            ]
        };
        assert_eq!(
            judge(&both(58.0, 3.0), &both(0.1, 0.15), &[0.06, 0.0001]),
            Ok(())
        );
    }
}

#[cfg(test)]
mod convergence_tests {
    use super::convergence;
    use crate::calibration::{Estimate, Method};
    use crate::kinematics::{Correction, SplitConvention};
    use crate::routine::config::RoutineConfig;

    fn estimate(e_b: f64, e_d: f64, se: (f64, f64)) -> Estimate {
        let correction = Correction {
            left_diameter_scale: 1.0,
            right_diameter_scale: e_d,
            wheelbase_scale: e_b,
        };
        Estimate::of(
            Method::Exact,
            correction,
            Some(se),
            &SplitConvention::LeftNominal,
        )
    }

    #[test]
    fn a_significant_visible_correction_is_applied_however_small() {
        // The round 2: E_d 1.000976 ± 0.00003 on 4 m squares, thirty standard errors
        // from 1 and 0.2° a square: applied, although below the old fixed 0.001.
        let cfg = RoutineConfig::default();
        let e = estimate(1.0, 1.000976, (0.00003, 0.00003));
        assert_eq!(convergence(&cfg, &e, None, 0.39), None);
        // The user's explicit tolerance still ends it.
        let loose = RoutineConfig {
            tolerance: Some(0.001),
            ..RoutineConfig::default()
        };
        let why = convergence(&loose, &e, None, 0.39).unwrap();
        assert!(why.contains("tolerance"), "{why}");
    }

    #[test]
    fn a_correction_within_two_standard_errors_ends_the_rounds() {
        let cfg = RoutineConfig::default();
        let e = estimate(1.003, 0.998, (0.002, 0.0015));
        let why = convergence(&cfg, &e, None, 0.39).unwrap();
        assert!(why.contains("not significant"), "{why}");
        // Without run-to-run errors the Cramér–Rao bound stands in.
        let mut bare = e.clone();
        bare.e_b_std_err = None;
        bare.e_d_std_err = None;
        assert!(convergence(&cfg, &bare, Some([0.002, 0.0015]), 0.39).is_some());
        assert_eq!(convergence(&cfg, &bare, Some([0.0001, 0.0001]), 0.39), None);
    }

    #[test]
    fn a_significant_correction_too_small_to_see_ends_the_rounds() {
        // 20 ppm on E_b, precisely measured: significant, but it changes a 4 m square's
        // heading error by far less than 0.1°.
        let cfg = RoutineConfig::default();
        let e = estimate(1.00002, 1.0, (0.000001, 0.000001));
        let why = convergence(&cfg, &e, None, 0.39).unwrap();
        assert!(why.contains("below the 0.1°"), "{why}");
    }
}
