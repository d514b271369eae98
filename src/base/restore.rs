//! Putting one of odocal's backups back: everything decided before anything is written.
//!
//! [`plan_restore`] checks that the backup belongs to the store it is offered to (or that
//! the caller allows another), reads what the store holds, and works out what would change:
//! the parameters, and for a backup of that same file the whole file as it was (every change
//! odocal made to it undone). The write itself is the write service's
//! ([`crate::base::write::write_once`], with [`RestorePlan::request`]): proven writable,
//! asked, backed up, written, read back, undone on failure.

use super::transaction::{backup_dir_for, check_store, text_changes, BackupError, BackupFile};
use super::write::{
    write_once, Bounds, Commit, Question, WriteError, WritePolicy, WriteRequest, WriteUi, Written,
};
use super::{same_within, BaseError, ComponentInfo, ParamStore};
use crate::kinematics::WheelParams;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// How a restore may go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RestoreOptions {
    /// A backup of another store of the same kind is restored (its parameters only).
    pub any_device: bool,
    /// The file the backup names is not the file it was taken from
    /// ([`super::transaction::check_same_file`]): its parameters only, never its whole text.
    pub not_its_file: bool,
    /// Commit (storage, the file) too; else the copy in use only (a device's RAM).
    pub commit: bool,
}

/// Why a restore cannot be planned.
#[derive(Debug, thiserror::Error)]
pub enum RestoreError {
    /// The backup does not belong to this store.
    #[error(transparent)]
    Backup(#[from] BackupError),
    /// The store could not be read.
    #[error(transparent)]
    Base(#[from] BaseError),
    /// The write was refused, declined or failed (what the store holds then is said).
    #[error(transparent)]
    Write(#[from] WriteError),
    /// The store's file could not be read.
    #[error("cannot read {}: {source}", path.display())]
    File {
        /// The store's file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
}

/// What a restore would do, worked out before anything is written.
#[derive(Debug, Clone, PartialEq)]
pub struct RestorePlan {
    /// The store restored to.
    pub store: ComponentInfo,
    /// What it holds in use now.
    pub current: WheelParams,
    /// The backup's parameters.
    pub target: WheelParams,
    /// Said before anything else: a backup of another store restored by its parameters.
    pub warning: Option<String>,
    /// The backup's whole file, when it goes back as it was (a backup of this same file).
    pub whole_file: Option<String>,
    /// The lines of the file that change (`- now`, `+ restored`), for a whole file.
    pub changes: Vec<String>,
    /// The store holds the backup's parameters already (every copy the restore would write;
    /// for a whole file, the same text): nothing to write.
    pub holds_already: bool,
    /// Whether the committed copy is written too.
    pub commit: bool,
}

/// Works out what restoring `backup` (read from `from`) onto `store` would do; refuses a
/// backup of another store unless `options.any_device`.
pub async fn plan_restore(
    store: &dyn ParamStore,
    backup: &BackupFile,
    from: &Path,
    options: RestoreOptions,
) -> Result<RestorePlan, RestoreError> {
    let here = store.info();
    let (same_store, warning) = match check_store(backup, from, store) {
        Ok(()) => (!options.not_its_file, None),
        Err(BackupError::OtherStore { backup_id, .. }) if options.any_device => (
            false,
            Some(format!(
                "restoring a backup of {} `{backup_id}` onto `{}` (its parameters only)",
                here.kind, here.id
            )),
        ),
        Err(e) => return Err(e.into()),
    };
    let target = backup.active;
    let current = store.read().await?;
    let resolution = store.resolution();
    // The whole file goes back when the backup holds it and this is the file it came from.
    let whole = match (&backup.text, store.file(), same_store) {
        (Some(then), Some(file), true) => {
            let now = crate::io::read_bounded(&file, crate::io::MAX_TEXT_FILE)
                .map_err(|source| RestoreError::File { path: file, source })?;
            Some((then.clone(), now))
        }
        _ => None,
    };
    let committed_holds = !options.commit
        || store
            .read_committed()
            .await
            .ok()
            .flatten()
            .is_some_and(|c| same_within(&c, &target, &resolution));
    let (holds_already, changes) = match &whole {
        Some((then, now)) => (then == now, text_changes(now, then)),
        None => (
            same_within(&current, &target, &resolution) && committed_holds,
            Vec::new(),
        ),
    };
    Ok(RestorePlan {
        store: here,
        current,
        target,
        warning,
        whole_file: whole.map(|(then, _)| then),
        changes,
        holds_already,
        commit: options.commit,
    })
}

/// What [`restore`] did.
#[derive(Debug)]
pub enum Restored {
    /// The store held the backup's parameters already: nothing written.
    HoldsAlready,
    /// A dry run: every check the real run makes before its question was made; nothing written.
    DryRun,
    /// Written (and committed when asked), read back.
    Written(Written),
}

/// Where a restore puts the backup of what the store holds now: `given`, else beside the
/// store's file, else `default` (beside the backup restored).
#[derive(Debug, Clone, Copy)]
pub struct BackupDir<'a> {
    /// The directory asked for.
    pub given: Option<&'a Path>,
    /// Where it goes for a store that is not a file, when none was asked for.
    pub default: &'a Path,
}

/// Puts `backup` (read from `from`) into `store`: plans it ([`plan_restore`]; refused for
/// another store unless `options.any_device`), shows the plan (`ui.note`), and unless the store
/// holds it already writes it through the write service with `policy` (asks, backs up what
/// the store holds, writes and commits, reads back, undoes on failure).
pub async fn restore(
    store: Arc<dyn ParamStore>,
    (backup, from): (&BackupFile, &Path),
    options: RestoreOptions,
    (policy, dir): (WritePolicy, BackupDir<'_>),
    ui: &mut dyn WriteUi,
) -> Result<(RestorePlan, Restored), RestoreError> {
    let plan = plan_restore(store.as_ref(), backup, from, options).await?;
    // The note's line end is the text's last one.
    let text = plan.text(from, backup);
    ui.note(text.strip_suffix('\n').unwrap_or(&text));
    if plan.holds_already {
        return Ok((plan, Restored::HoldsAlready));
    }
    let dir = match dir.given {
        Some(d) => d.to_path_buf(),
        None => backup_dir_for(store.as_ref(), dir.default),
    };
    match write_once(store, None, plan.request(policy, &dir), ui).await {
        Ok(done) => Ok((plan, Restored::Written(done))),
        Err(WriteError::DryRun) => Ok((plan, Restored::DryRun)),
        Err(e) => Err(e.into()),
    }
}

/// How many changed lines of a file a restore shows before asking.
const MAX_SHOWN: usize = 20;

impl RestorePlan {
    /// What the restore of `backup` (read from `from`) will do, as shown before the question:
    /// a warning if any, old → new, and the lines of the file that change.
    pub fn text(&self, from: &Path, backup: &BackupFile) -> String {
        use std::fmt::Write as _;
        let mut out = String::new();
        if let Some(warning) = &self.warning {
            let _ = writeln!(out, "warning: {warning}");
        }
        let _ = writeln!(
            out,
            "{} (taken {}by odocal {}) onto {} `{}`:\n{}",
            from.display(),
            backup
                .taken_utc
                .as_ref()
                .map_or(String::new(), |t| format!("{t} ")),
            backup.odocal_version,
            self.store.kind,
            self.store.id,
            super::write::params_table(&self.current, &self.target)
        );
        if !self.changes.is_empty() {
            let _ = writeln!(
                out,
                "the whole file goes back as it was: {} line(s) change (- now, + restored)",
                self.changes.len()
            );
            for line in self.changes.iter().take(MAX_SHOWN) {
                let _ = writeln!(out, "  {line}");
            }
            if self.changes.len() > MAX_SHOWN {
                let _ = writeln!(out, "  … and {} more", self.changes.len() - MAX_SHOWN);
            }
        }
        out
    }

    /// The write that carries the plan out, under `policy`, backing up into `backup_dir`.
    pub fn request<'a>(&self, policy: WritePolicy, backup_dir: &'a Path) -> WriteRequest<'a> {
        WriteRequest {
            new: self.target,
            // A backup odocal wrote holds a robot's parameters, however far from today's.
            bounds: Bounds::Physical,
            policy,
            commit: match (&self.whole_file, self.commit) {
                (Some(text), _) => Commit::WholeFile(text.clone()),
                (None, true) => Commit::Both,
                (None, false) => Commit::InUse,
            },
            backup_dir,
            question: Question::Plain(format!(
                "write them to {} `{}`{}?",
                self.store.kind,
                self.store.id,
                if self.commit { " and commit them" } else { "" }
            )),
        }
    }
}
