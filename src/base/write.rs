//! The one write service: *whether* and *how* new parameters reach a store, for every command
//! that changes one (a calibration's rounds, `track --write-back`, `restore`, `export`,
//! `params set`).
//!
//! The policy lives here and nowhere else: the store proves it can take the write before
//! anything is asked ([`WriteSession::prepare`]); the new parameters are checked against
//! [`Bounds`]; the [`WritePolicy`] decides whether to ask, and a [`WriteUi`] asks the question
//! the caller gives; what the store holds is backed up before anything is written; the write
//! is read back (and committed and read back again, by [`Commit`]); any failure puts the
//! backup back ([`WriteSession::undo`]), reconnecting once when the link was lost, and says in
//! one sentence what the store holds then ([`Undone`]). The mechanism underneath is
//! [`Transaction`] (`transaction.rs`); nothing else in the crate writes parameters (a test in
//! `tests/architecture.rs` holds that).
//!
//! A caller with one write uses [`write_once`]; the routine, which backs up before the robot
//! moves and writes once per round, keeps a [`WriteSession`] open for the run.

use super::transaction::{Holds, Rollback, Transaction};
use super::{same_within, BaseError, ParamStore, Reconnect};
use crate::kinematics::{KinematicsError, WheelParams};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

/// How long reopening a store after its link was lost may take (a board that resets when its
/// port opens needs about 2 s, a USB adapter re-enumerating a few more).
pub const RECONNECT_TIMEOUT: Duration = Duration::from_secs(10);

/// Whether new parameters are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WritePolicy {
    /// Estimate and report; write nothing.
    DryRun,
    /// Show old → new and ask before writing.
    Ask,
    /// Write without asking.
    Yes,
}

impl WritePolicy {
    /// The policy of a command's `--dry-run` and `--yes`: a dry run writes nothing (`--yes`
    /// or not); else `--yes` writes without asking, and without it odocal asks.
    pub fn of_flags(dry_run: bool, yes: bool) -> Self {
        match (dry_run, yes) {
            (true, _) => WritePolicy::DryRun,
            (false, true) => WritePolicy::Yes,
            (false, false) => WritePolicy::Ask,
        }
    }

    /// What the policy does, in words for reports.
    pub fn describe(self) -> &'static str {
        match self {
            WritePolicy::DryRun => "none (dry run)",
            WritePolicy::Ask => "after confirmation",
            WritePolicy::Yes => "without asking",
        }
    }
}

/// What new parameters must satisfy before they are written, besides being physically valid
/// ([`WheelParams::validate`]). Changes are measured from what the store held when the
/// session began ([`WriteSession::original`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Bounds {
    /// Physically valid only (a value the user typed, a backup being restored).
    Physical,
    /// Each of the diameters and the wheelbase within ±`fraction` of what the store held
    /// (0.1 = ±10 %); `wider` names the way to allow more, for the refusal's message.
    MaxChange {
        /// The largest relative change allowed.
        fraction: f64,
        /// How the user allows a larger change, when there is a way.
        wider: Option<&'static str>,
    },
}

/// Which copies a write reaches.
#[derive(Debug, Clone, PartialEq)]
pub enum Commit {
    /// The copy in use only (a device's RAM; a file store stages it).
    InUse,
    /// The copy in use, then the committed copy (storage, the file), each read back.
    Both,
    /// The whole of a store's file, put back as this text (a backup of that same file: every
    /// change odocal made to it undone, not only the parameters); read back to hold the new
    /// parameters.
    WholeFile(String),
}

/// How the service talks to the user: the question it is told to ask, and the moments a
/// write must not be interrupted.
pub trait WriteUi: Send {
    /// Asks a yes/no question; `true` to write.
    fn confirm(&mut self, question: &str) -> bool;
    /// `true` from the backup until the write is read back or undone: a Ctrl-C in between
    /// should wait for the end, not cut the write in half.
    fn writing(&mut self, _on: bool) {}
    /// A line worth showing (where the backup went).
    fn note(&mut self, _line: &str) {}
}

/// A [`WriteUi`] that says yes and shows nothing (tests, `--yes --json`).
pub struct Unattended;

impl WriteUi for Unattended {
    fn confirm(&mut self, _question: &str) -> bool {
        true
    }
}

/// What became of the parameters after a write failed and the service put the backup back:
/// the one statement every command makes.
#[derive(Debug)]
pub enum Undone {
    /// Nothing had been written: the store holds what it held.
    NothingWritten,
    /// The backup's parameters are back.
    Restored {
        /// The committed copy was put back too (a commit may have happened).
        committed: bool,
        /// Putting them back took a new connection (the first link was lost).
        reconnected: bool,
    },
    /// Putting them back failed; what each copy holds was read back since.
    Failed {
        /// Why putting them back failed.
        error: Box<BaseError>,
        /// Why reconnecting failed, when the store could try.
        reconnect_error: Option<String>,
        /// The backup to restore from.
        backup: Option<PathBuf>,
        /// What the copy in use holds now.
        active: Holds,
        /// What the committed copy holds now.
        committed: Holds,
    },
}

impl std::fmt::Display for Undone {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Undone::NothingWritten => f.write_str("nothing was changed"),
            Undone::Restored {
                committed,
                reconnected,
            } => write!(
                f,
                "{}{}",
                if *committed {
                    "the earlier parameters are in use and committed again"
                } else {
                    "the earlier parameters are in use again"
                },
                if *reconnected {
                    " (after reconnecting)"
                } else {
                    ""
                }
            ),
            Undone::Failed {
                error,
                reconnect_error,
                backup,
                active,
                committed,
            } => write!(
                f,
                "putting the earlier parameters back failed too: {error}{}. Read back since: in \
                 use {active}, committed {committed}. {}",
                reconnect_error
                    .as_ref()
                    .map(|e| format!("; reconnecting failed: {e}"))
                    .unwrap_or_default(),
                restore_advice(active, committed, backup.as_deref())
            ),
        }
    }
}

/// What to do after a failed rollback, from what the store was found to hold.
pub fn restore_advice(active: &Holds, committed: &Holds, backup: Option<&Path>) -> String {
    match (active, committed) {
        (Holds::Original, Holds::Original) => {
            "The robot holds its original parameters: nothing to restore.".into()
        }
        _ => format!(
            "Restore them with `odocal restore {}` (or by hand).",
            backup.map_or_else(|| "BACKUP".into(), |b| b.display().to_string())
        ),
    }
}

/// Why nothing, or not all, was written.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    /// The new parameters are not physically possible.
    #[error(transparent)]
    Invalid(#[from] KinematicsError),
    /// The new parameters are beyond the [`Bounds`].
    #[error("refusing to write: {0}")]
    OutOfBounds(String),
    /// The user said no.
    #[error("declined by the user: {0}")]
    Declined(String),
    /// The policy is a dry run: everything was checked, nothing written.
    #[error("dry run: nothing written")]
    DryRun,
    /// The store could not be read, proven writable or backed up: nothing was written.
    #[error("{}", nothing_changed(.0))]
    Base(#[from] BaseError),
    /// The write failed after the backup; the backup was put back, or `undone` says why not
    /// (and names the backup to restore from).
    #[error("{source} ({undone}{})", match **undone {
        Undone::Failed { .. } => String::new(),
        _ => format!("; the earlier parameters are in {}", backup.display()),
    })]
    Failed {
        /// Why the write failed.
        source: BaseError,
        /// What the store holds now.
        undone: Box<Undone>,
        /// The backup taken before the write.
        backup: PathBuf,
    },
}

/// An error from before anything was written, saying so (once).
fn nothing_changed(e: &BaseError) -> String {
    let text = e.to_string();
    match text.contains("nothing was changed") {
        true => text,
        false => format!("{text} (nothing was changed)"),
    }
}

/// One change of one store, open for as long as its caller needs: proven writable, backed up,
/// written (perhaps several times), and undone on failure.
pub struct WriteSession {
    tx: Transaction,
    reconnect: Option<Reconnect>,
}

impl WriteSession {
    /// Reads `store` and proves it could take a write of `new` (of what it holds, when
    /// `None`); creates no file and writes nothing. `reconnect` reopens the store when a
    /// rollback finds the link lost.
    pub async fn prepare(
        store: Arc<dyn ParamStore>,
        reconnect: Option<Reconnect>,
        new: Option<&WheelParams>,
    ) -> Result<WriteSession, BaseError> {
        Ok(WriteSession {
            tx: Transaction::prepare(store, new).await?,
            reconnect,
        })
    }

    /// What the store held at the start (once backed up: what the backup holds).
    pub fn original(&self) -> &WheelParams {
        self.tx.original()
    }

    /// The backup, once taken.
    pub fn backup_path(&self) -> Option<&Path> {
        self.tx.backup_path()
    }

    /// Whether anything may have been written.
    pub fn written(&self) -> bool {
        self.tx.written()
    }

    /// The store.
    pub fn store(&self) -> &Arc<dyn ParamStore> {
        self.tx.store()
    }

    /// Backs up what the store holds into a new file in `dir` (once: a second call returns the
    /// first backup). Nothing is written before.
    pub async fn back_up(&mut self, dir: &Path) -> Result<PathBuf, BaseError> {
        self.tx.back_up(dir).await
    }

    /// Checks `new` against `bounds`, measured from [`WriteSession::original`].
    pub fn check(&self, new: &WheelParams, bounds: Bounds) -> Result<(), WriteError> {
        check_bounds(self.original(), new, bounds)
    }

    /// Writes `new` to the copies `commit` names and reads them back; returns the parameters
    /// as the store holds them (rounded to its resolution). Refused before a backup exists. On
    /// an error the caller undoes ([`WriteSession::undo`]).
    pub async fn write(
        &mut self,
        new: &WheelParams,
        commit: &Commit,
    ) -> Result<WheelParams, BaseError> {
        match commit {
            Commit::InUse => self.tx.write_in_use(new).await,
            Commit::Both => self.tx.apply(new).await,
            Commit::WholeFile(text) => self.tx.apply_text(text, new).await,
        }
    }

    /// Puts the backup back after a failure: in use, and committed if a commit may have
    /// happened. When that fails and the store can reconnect, it reconnects once and tries
    /// again; if that fails too, it reads back what each copy holds, so the statement is what
    /// is true rather than what is feared.
    pub async fn undo(&mut self) -> Undone {
        let mut outcome = self.tx.rollback().await;
        let mut reconnected = false;
        let mut reconnect_error = None;
        if outcome.is_err() {
            if let Some(reconnect) = &self.reconnect {
                match tokio::time::timeout(RECONNECT_TIMEOUT, reconnect()).await {
                    Ok(Ok(store)) => {
                        self.tx.reattach(store);
                        reconnected = true;
                        outcome = self.tx.rollback().await;
                    }
                    Ok(Err(e)) => reconnect_error = Some(e.to_string()),
                    Err(_) => {
                        reconnect_error = Some(format!(
                            "no connection within {}",
                            crate::io::seconds(&RECONNECT_TIMEOUT)
                        ))
                    }
                }
            }
        }
        // A rollback the store took is read back like any write: a store that corrupts writes
        // corrupts this one too, and "restored" must be true when it is said.
        let outcome = match outcome {
            Ok(Rollback::NothingWritten) => return Undone::NothingWritten,
            Ok(outcome) => {
                let committed = outcome == Rollback::RestoredAndCommitted;
                self.read_back_original(committed).await.map(|()| committed)
            }
            Err(e) => Err(e),
        };
        match outcome {
            Ok(committed) => Undone::Restored {
                committed,
                reconnected,
            },
            Err(e) => {
                let (active, committed) = self.tx.what_the_store_holds().await;
                Undone::Failed {
                    error: Box::new(e),
                    reconnect_error,
                    backup: self.tx.backup_path().map(Path::to_path_buf),
                    active,
                    committed,
                }
            }
        }
    }
}

impl WriteSession {
    /// Whether the store holds the original again: the copy in use, and the committed copy as
    /// the backup holds it, when `committed` was put back too. A committed copy that was not to
    /// change is compared as well when it can be read (a store that committed without saying
    /// so is found out).
    async fn read_back_original(&self, committed: bool) -> Result<(), BaseError> {
        let store = self.tx.store();
        let original = *self.tx.original();
        let stored_original = self.tx.original_committed().copied();
        let resolution = store.resolution();
        let timeout = super::transaction::ROLLBACK_TIMEOUT;
        let no_answer = || BaseError::MotionTimeout { after: timeout };
        let active = tokio::time::timeout(timeout, store.read())
            .await
            .map_err(|_| no_answer())??;
        if !same_within(&active, &original, &resolution) {
            return Err(BaseError::ReadBack {
                copy: "in use",
                written: original,
                read: Some(active),
            });
        }
        let stored = tokio::time::timeout(timeout, store.read_committed())
            .await
            .map_err(|_| no_answer());
        let (expected, stored) = match (committed, stored_original) {
            (true, expected) => (expected.unwrap_or(original), stored??),
            // Untouched, as far as the store said: checked when it answers.
            (false, Some(expected)) => match stored {
                Ok(Ok(stored)) => (expected, stored),
                _ => return Ok(()),
            },
            (false, None) => return Ok(()),
        };
        match stored {
            Some(s) if same_within(&s, &expected, &resolution) => Ok(()),
            read => Err(BaseError::ReadBack {
                copy: "committed",
                written: expected,
                read,
            }),
        }
    }
}

/// Asks under `policy`: `Ok` to write; [`WriteError::DryRun`] for a dry run;
/// [`WriteError::Declined`] when the user says no to `question`.
pub fn authorise(
    policy: WritePolicy,
    ui: &mut dyn WriteUi,
    question: &str,
) -> Result<(), WriteError> {
    match policy {
        WritePolicy::DryRun => Err(WriteError::DryRun),
        WritePolicy::Yes => Ok(()),
        WritePolicy::Ask => match ui.confirm(question) {
            true => Ok(()),
            false => Err(WriteError::Declined("parameters not written".into())),
        },
    }
}

/// The question asked under [`WritePolicy::Ask`].
#[derive(Debug, Clone, PartialEq)]
pub enum Question {
    /// This line, then the table of what the store holds → the new parameters
    /// ([`params_table`]).
    OldToNew(String),
    /// This question alone (the caller has shown what changes).
    Plain(String),
}

impl Question {
    /// The text asked when the store holds `old`.
    pub fn text(&self, old: &WheelParams, new: &WheelParams) -> String {
        match self {
            Question::OldToNew(line) => format!("{line}\n{}", params_table(old, new)),
            Question::Plain(q) => q.clone(),
        }
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
    // Written too when it changes (a restore may carry another count), so it is shown.
    if old.counts_per_wheel_rev != new.counts_per_wheel_rev {
        let _ = writeln!(
            s,
            "  {:<26} {:>12.3} → {:>12.3}",
            "counts per wheel revolution", old.counts_per_wheel_rev, new.counts_per_wheel_rev
        );
    }
    s
}

/// One write, start to end.
pub struct WriteRequest<'a> {
    /// The parameters to write.
    pub new: WheelParams,
    /// What they must satisfy.
    pub bounds: Bounds,
    /// Whether to ask (or write nothing).
    pub policy: WritePolicy,
    /// Which copies to write.
    pub commit: Commit,
    /// Where the backup of what the store holds goes.
    pub backup_dir: &'a Path,
    /// The question asked under [`WritePolicy::Ask`].
    pub question: Question,
}

/// What [`write_once`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct Written {
    /// What the store held before (what the backup holds).
    pub before: WheelParams,
    /// The parameters as the store holds them now.
    pub applied: WheelParams,
    /// The backup of what it held.
    pub backup: PathBuf,
}

/// Writes `req.new` to `store`: proven writable, checked against the bounds, asked (by the
/// policy), backed up, written and read back; on a failed write the backup is put back and
/// the error says what the store holds ([`WriteError::Failed`]). Declining (or a dry run)
/// leaves no file behind.
pub async fn write_once(
    store: Arc<dyn ParamStore>,
    reconnect: Option<Reconnect>,
    req: WriteRequest<'_>,
    ui: &mut dyn WriteUi,
) -> Result<Written, WriteError> {
    let mut session = WriteSession::prepare(store, reconnect, Some(&req.new)).await?;
    session.check(&req.new, req.bounds)?;
    let question = req.question.text(session.original(), &req.new);
    authorise(req.policy, ui, &question)?;
    ui.writing(true);
    let result = write_backed_up(&mut session, &req, ui).await;
    ui.writing(false);
    result
}

/// The part of [`write_once`] a signal must not cut: the backup, the write, and the undo.
async fn write_backed_up(
    session: &mut WriteSession,
    req: &WriteRequest<'_>,
    ui: &mut dyn WriteUi,
) -> Result<Written, WriteError> {
    let backup = session.back_up(req.backup_dir).await?;
    ui.note(&format!(
        "backed up what the store holds to {}",
        backup.display()
    ));
    let before = *session.original();
    match session.write(&req.new, &req.commit).await {
        Ok(applied) => Ok(Written {
            before,
            applied,
            backup,
        }),
        Err(source) => Err(WriteError::Failed {
            source,
            undone: Box::new(session.undo().await),
            backup,
        }),
    }
}

/// `new` against `bounds`, changes measured from `from`.
fn check_bounds(from: &WheelParams, new: &WheelParams, bounds: Bounds) -> Result<(), WriteError> {
    new.validate()?;
    let Bounds::MaxChange { fraction, wider } = bounds else {
        return Ok(());
    };
    for (name, old, new) in [
        (
            "left wheel diameter",
            from.left_wheel_diameter_m,
            new.left_wheel_diameter_m,
        ),
        (
            "right wheel diameter",
            from.right_wheel_diameter_m,
            new.right_wheel_diameter_m,
        ),
        ("wheelbase", from.wheelbase_m, new.wheelbase_m),
    ] {
        let change = new / old - 1.0;
        if change.abs() > fraction {
            let hint = match wider {
                Some(how) if fraction < 1.0 && change.abs() <= 1.0 => format!(" ({how})"),
                _ => String::new(),
            };
            return Err(WriteError::OutOfBounds(format!(
                "{name} would change by {:+.1} % ({old:.6} → {new:.6} m), more than the \
                 allowed ±{:.1} %{hint}",
                change * 100.0,
                fraction * 100.0,
            )));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(b: f64) -> WheelParams {
        WheelParams::nominal(0.15, b, 4096.0)
    }

    #[test]
    fn a_change_beyond_the_bounds_is_refused_with_the_way_to_allow_it() {
        let bounds = Bounds::MaxChange {
            fraction: 0.1,
            wider: Some("a skid-steer robot needs this: --allow-large-change"),
        };
        assert!(check_bounds(&params(0.4), &params(0.43), bounds).is_ok());
        let err = check_bounds(&params(0.4), &params(0.6), bounds).unwrap_err();
        let text = err.to_string();
        assert!(text.contains("wheelbase would change by +50.0 %"), "{text}");
        assert!(text.contains("--allow-large-change"), "{text}");
        // Physically impossible parameters are refused whatever the bounds.
        assert!(matches!(
            check_bounds(&params(0.4), &params(-0.4), Bounds::Physical),
            Err(WriteError::Invalid(_))
        ));
    }

    #[test]
    fn a_failed_undo_says_what_the_store_holds_and_what_to_do() {
        let undone = Undone::Failed {
            error: Box::new(BaseError::WatchdogTripped),
            reconnect_error: None,
            backup: Some("/tmp/odocal-backup-x.json".into()),
            active: Holds::New,
            committed: Holds::Unknown("no answer".into()),
        };
        let text = undone.to_string();
        assert!(text.contains("in use the new parameters"), "{text}");
        assert!(text.contains("committed unknown (no answer)"), "{text}");
        assert!(
            text.contains("odocal restore /tmp/odocal-backup-x.json"),
            "{text}"
        );
        let held = Undone::Failed {
            error: Box::new(BaseError::WatchdogTripped),
            reconnect_error: Some("no device on the port".into()),
            backup: None,
            active: Holds::Original,
            committed: Holds::Original,
        };
        let text = held.to_string();
        assert!(text.contains("nothing to restore"), "{text}");
        assert!(text.contains("reconnecting failed: no device"), "{text}");
    }

    #[test]
    fn the_policy_decides_before_the_user_is_asked() {
        struct No(usize);
        impl WriteUi for No {
            fn confirm(&mut self, _question: &str) -> bool {
                self.0 += 1;
                false
            }
        }
        let mut ui = No(0);
        assert!(matches!(
            authorise(WritePolicy::DryRun, &mut ui, "?"),
            Err(WriteError::DryRun)
        ));
        assert!(authorise(WritePolicy::Yes, &mut ui, "?").is_ok());
        assert_eq!(ui.0, 0, "neither a dry run nor --yes asks");
        assert!(matches!(
            authorise(WritePolicy::Ask, &mut ui, "?"),
            Err(WriteError::Declined(_))
        ));
        assert_eq!(ui.0, 1);
    }
}

#[cfg(test)]
mod policy_tests {
    use super::*;

    #[test]
    fn a_dry_run_writes_nothing_yes_or_not() {
        assert_eq!(WritePolicy::of_flags(true, true), WritePolicy::DryRun);
        assert_eq!(WritePolicy::of_flags(false, true), WritePolicy::Yes);
        assert_eq!(WritePolicy::of_flags(false, false), WritePolicy::Ask);
    }
}
