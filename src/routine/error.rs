//! Errors of the routine. Whatever the error, the base was told to stop and any parameters
//! written were rolled back, or the error says that this failed and where the backup is.

use super::config::ConfigError;
use crate::base::transaction::Holds;
use crate::base::write::{Undone, WriteError};
use crate::base::BaseError;
use crate::calibration::CalibrationError;
use crate::kinematics::KinematicsError;
use std::path::PathBuf;

/// Errors of the routine.
#[derive(Debug, thiserror::Error)]
pub enum RoutineError {
    /// The settings are unusable.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A component of the base failed.
    #[error(transparent)]
    Base(#[from] BaseError),
    /// The measurements could not be calibrated.
    #[error(transparent)]
    Calibration(#[from] CalibrationError),
    /// New parameters would be impossible.
    #[error(transparent)]
    Kinematics(#[from] KinematicsError),
    /// The pre-flight checks failed.
    #[error("pre-flight check failed: {0}")]
    Preflight(String),
    /// The measurements are implausible (e.g. the compass turns the wrong way).
    #[error("implausible measurement: {0}")]
    Implausible(String),
    /// The estimate asks for a change beyond the configured bounds.
    #[error("refusing to write: {0}")]
    OutOfBounds(String),
    /// The user declined (to move or to write).
    #[error("declined by the user: {0}")]
    Declined(String),
    /// Ctrl-C or the caller cancelled.
    #[error("cancelled")]
    Cancelled,
    /// An output location (report or backup directory) cannot be written; checked before the
    /// robot moves or anything is written.
    #[error("cannot write to {}: {reason}", path.display())]
    Output {
        /// The location.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The written parameters did not clearly help (or the rounds diverged).
    #[error("the new parameters are not clearly better: {0} (--keep-worse keeps them anyway)")]
    NotBetter(String),
    /// An error happened after parameters were written; the backup was put back.
    #[error("{source} (the original parameters were restored{}{})", if *.committed { " and committed" } else { "" }, if *.reconnected { " after reconnecting" } else { "" })]
    Restored {
        /// The error.
        source: Box<RoutineError>,
        /// Whether the committed copy was restored too.
        committed: bool,
        /// Whether restoring needed a new connection (the first link was lost).
        reconnected: bool,
    },
    /// An error happened after parameters were written and restoring them failed too; what
    /// the store holds was read back afterwards.
    #[error("{source}; restoring the backup failed ({restore_error}{}). Read back since: in use {active}, committed {committed}. {}", reconnect_error.as_ref().map(|e| format!("; reconnecting failed: {e}")).unwrap_or_default(), restore_advice(active, committed, backup))]
    RestoreFailed {
        /// The error.
        source: Box<RoutineError>,
        /// Why restoring failed.
        restore_error: Box<BaseError>,
        /// Why reconnecting failed, when the base could try.
        reconnect_error: Option<Box<str>>,
        /// The backup file to restore from.
        backup: Box<std::path::Path>,
        /// What the copy in use holds now.
        active: Holds,
        /// What the committed copy holds now.
        committed: Holds,
    },
}

impl RoutineError {
    /// `err` as it stands after the write service undid the run's writes ([`Undone`]).
    pub fn after(err: RoutineError, undone: Undone) -> RoutineError {
        match undone {
            Undone::NothingWritten => err,
            Undone::Restored {
                committed,
                reconnected,
            } => RoutineError::Restored {
                source: Box::new(err),
                committed,
                reconnected,
            },
            Undone::Failed {
                error,
                reconnect_error,
                backup,
                active,
                committed,
            } => RoutineError::RestoreFailed {
                source: Box::new(err),
                restore_error: error,
                reconnect_error: reconnect_error.map(Into::into),
                backup: backup.unwrap_or_default().into(),
                active,
                committed,
            },
        }
    }
}

/// A refusal of the write service is the routine's refusal; a write that failed after the
/// backup is the store's error as it stands after the undo.
impl From<WriteError> for RoutineError {
    fn from(e: WriteError) -> Self {
        match e {
            WriteError::Invalid(e) => RoutineError::Kinematics(e),
            WriteError::OutOfBounds(why) => RoutineError::OutOfBounds(why),
            WriteError::Declined(why) => RoutineError::Declined(why),
            WriteError::DryRun => RoutineError::Declined("a dry run writes nothing".into()),
            WriteError::Base(e) => RoutineError::Base(e),
            WriteError::Failed { source, undone, .. } => {
                RoutineError::after(RoutineError::Base(source), *undone)
            }
        }
    }
}

/// What to do after a failed rollback, from what the store was found to hold.
fn restore_advice(active: &Holds, committed: &Holds, backup: &std::path::Path) -> String {
    crate::base::write::restore_advice(active, committed, Some(backup))
}
