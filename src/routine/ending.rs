//! How a run ends when it does not succeed: the base stopped, the parameters rolled back
//! through the write service, what the robot holds now ([`ParamsAfterFailure`], [`Ending`]) and
//! the partial report written where the run was told to keep it.

use super::*;

impl Calibration<'_> {
    /// Stops the base, undoes any write and leaves the partial report; returns the error as
    /// it stands after the rollback.
    pub(super) async fn fail(mut self, err: RoutineError) -> RoutineError {
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
pub(super) fn write_partial(
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
pub(super) const STOP_TIMEOUT: Duration = Duration::from_secs(2);

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
