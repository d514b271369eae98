//! The mechanism under the one write service: a transaction over a [`ParamStore`].
//!
//! [`Transaction::prepare`] reads what the store holds and proves the store could take a write
//! (a dry run: a file that cannot be rewritten is refused before the robot moves), creating
//! nothing; [`Transaction::back_up`] then writes what it holds to a new backup file (created
//! exclusively: an earlier backup is never overwritten, a symlink never followed), so that a
//! caller can ask its user in between and leave no file behind when the answer is no.
//! [`Transaction::begin`] is both at once. [`Transaction::apply`] (refused until the backup
//! exists) writes, reads back, commits and reads back the committed copy;
//! [`Transaction::rollback`] puts the original back, in use and, if a commit may have
//! happened, committed too. The write service ([`super::write`]) decides *whether* to write
//! (policy, bounds, confirmation) and is the only caller; this file decides *how*.
//!
//! One backup format for every store, a JSON [`BackupFile`]; for a store that is a file it
//! holds the whole file as well, so that `odocal restore` undoes every change odocal made to
//! it. A backup goes into the directory the caller gives (a run's report directory; beside
//! the file for a command that writes one file, [`backup_dir_for`]), named after the file for a
//! store that is a file (`robot.toml.odocal-backup-2026-11-25T14-03-07Z.json`), else after the
//! store (`odocal-backup-<store id>-<UTC time>.json`); a second in the same second gets `-2`.

use super::{same_within, BaseError, ComponentInfo, ParamStore};
use crate::kinematics::WheelParams;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

/// How long a rollback may take before it is reported as failed.
pub const ROLLBACK_TIMEOUT: Duration = Duration::from_secs(5);

/// The content of a backup file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BackupFile {
    /// odocal version that wrote it.
    pub odocal_version: String,
    /// The store the parameters came from.
    pub store: ComponentInfo,
    /// When it was taken (UTC, ISO 8601); absent in older backups.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub taken_utc: Option<String>,
    /// The store's file, as an absolute path, for a store that is a file
    /// ([`ParamStore::file`]): where `odocal restore` finds it again. Absent for a device, and
    /// in older backups (whose `store.details.file` is as it was given).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<PathBuf>,
    /// The parameters in use when the backup was taken.
    pub active: WheelParams,
    /// The committed copy, when the store has one.
    pub committed: Option<WheelParams>,
    /// The store's whole file as it was, for a store that is a file: `odocal restore` puts it
    /// back as it was (every change odocal made to it undone, not only the parameters). Absent
    /// for a device, and in older backups (whose parameters are restored alone).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub text: Option<String>,
}

/// What a rollback achieved (the write service's [`super::write::Undone`] says it to the user).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Rollback {
    /// Nothing had been written: nothing to undo.
    NothingWritten,
    /// The original parameters are in use again (nothing had been committed).
    Restored,
    /// The original parameters are in use and committed again.
    RestoredAndCommitted,
}

/// A write in progress; see the module documentation.
pub struct Transaction {
    store: Arc<dyn ParamStore>,
    original: WheelParams,
    /// The committed copy the backup holds (when the store had one readable): what a rollback
    /// of a commit puts back, which need not be what was in use (`params save`).
    original_committed: Option<WheelParams>,
    backup_path: Option<PathBuf>,
    written: bool,
    committed: bool,
    last_written: Option<WheelParams>,
    /// The store's whole file as the backup holds it, for a store that is a file.
    original_text: Option<String>,
    /// Whether a whole text was written ([`Transaction::apply_text`]): the rollback then puts
    /// the file's original text back, byte for byte.
    text_written: bool,
}

/// What one copy of the parameters was found to hold after a failed rollback.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "state", content = "detail")]
pub enum Holds {
    /// The parameters of the backup.
    Original,
    /// The parameters that were being written.
    New,
    /// Something else (shown).
    Other(Box<WheelParams>),
    /// The copy could not be read (why).
    Unknown(String),
}

impl std::fmt::Display for Holds {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Holds::Original => f.write_str("the original parameters"),
            Holds::New => f.write_str("the new parameters"),
            Holds::Other(p) => write!(f, "other parameters ({p})"),
            Holds::Unknown(why) => write!(f, "unknown ({why})"),
        }
    }
}

impl Transaction {
    /// Reads the store and proves that it could take a write of `params` (of what it holds,
    /// when `None`) ([`ParamStore::check_write`]: a file that cannot be rewritten is refused
    /// here, before anything depends on it). Creates no file and writes nothing: the backup
    /// comes with [`Transaction::back_up`], which [`Transaction::apply`] waits for.
    pub async fn prepare(
        store: Arc<dyn ParamStore>,
        params: Option<&WheelParams>,
    ) -> Result<Transaction, BaseError> {
        let original = store.read().await?;
        store.check_write(params.unwrap_or(&original)).await?;
        Ok(Transaction {
            store,
            original,
            original_committed: None,
            backup_path: None,
            written: false,
            committed: false,
            last_written: None,
            original_text: None,
            text_written: false,
        })
    }

    /// Writes what the store holds now to a new backup file in `dir` (created if needed;
    /// [`backup_store`]). The
    /// original is what the backup holds. Once only: a second call returns the first backup.
    pub async fn back_up(&mut self, dir: &Path) -> Result<PathBuf, BaseError> {
        if let Some(path) = &self.backup_path {
            return Ok(path.clone());
        }
        let (path, backup) = backup_store(self.store.as_ref(), dir).await?;
        self.original = backup.active;
        self.original_committed = backup.committed;
        self.original_text = backup.text;
        self.backup_path = Some(path.clone());
        Ok(path)
    }

    /// [`Transaction::prepare`] and [`Transaction::back_up`] at once: proves the store could
    /// take a write of what it holds, and backs it up. Nothing is written to the store.
    pub async fn begin(
        store: Arc<dyn ParamStore>,
        backup_dir: &Path,
    ) -> Result<Transaction, BaseError> {
        let mut tx = Transaction::prepare(store, None).await?;
        tx.back_up(backup_dir).await?;
        Ok(tx)
    }

    /// The parameters the store held at the start (when backed up: what the backup holds).
    pub fn original(&self) -> &WheelParams {
        &self.original
    }

    /// The committed copy the backup holds, when the store had one it could read.
    pub fn original_committed(&self) -> Option<&WheelParams> {
        self.original_committed.as_ref()
    }

    /// The backup file, once [`Transaction::back_up`] wrote it.
    pub fn backup_path(&self) -> Option<&Path> {
        self.backup_path.as_deref()
    }

    /// The store.
    pub fn store(&self) -> &Arc<dyn ParamStore> {
        &self.store
    }

    /// Continues with `store`, a fresh connection to the same store (after the link to the
    /// first was lost): the backup, the original and what may have been written are kept.
    pub fn reattach(&mut self, store: Arc<dyn ParamStore>) {
        self.store = store;
    }

    /// Whether anything may have been written.
    pub fn written(&self) -> bool {
        self.written
    }

    /// Writes `params` to the copy in use and reads them back, without committing (a device's
    /// RAM; a file store only stages them). Returns them as the store holds them.
    pub async fn write_in_use(&mut self, params: &WheelParams) -> Result<WheelParams, BaseError> {
        self.require_backup()?;
        let resolution = self.store.resolution();
        // Marked before the call: a cancelled or failed write may still have landed.
        let before = (self.written, self.last_written);
        self.written = true;
        self.last_written = Some(*params);
        let applied = match self.store.write(params).await {
            Ok(applied) => applied,
            // These say that nothing was changed: no rollback is owed for this write.
            Err(e @ (BaseError::Unwritable { .. } | BaseError::InvalidArgument { .. })) => {
                (self.written, self.last_written) = before;
                return Err(e);
            }
            Err(e) => return Err(e),
        };
        let read = self.store.read().await?;
        if !same_within(&applied, params, &resolution) || !same_within(&read, params, &resolution) {
            return Err(BaseError::ReadBack {
                copy: "in use",
                written: *params,
                read: Some(read),
            });
        }
        Ok(read)
    }

    /// Writes `params`, reads them back, commits, and reads back the committed copy. Returns
    /// the parameters as the store holds them (rounded to its resolution).
    pub async fn apply(&mut self, params: &WheelParams) -> Result<WheelParams, BaseError> {
        let read = self.write_in_use(params).await?;
        let resolution = self.store.resolution();
        match self.store.commit().await {
            Ok(()) => self.committed = true,
            // A refusal leaves the committed copy as it was (SPEC.md §5 SAVE_PARAMS is atomic;
            // file stores replace atomically, and refuse a text they cannot render before).
            Err(e @ (BaseError::Refused { .. } | BaseError::Unwritable { .. })) => return Err(e),
            // Anything else leaves it unknown whether the commit happened: undo it too.
            Err(e) => {
                self.committed = true;
                return Err(e);
            }
        }
        let stored = self.store.read_committed().await?;
        match stored {
            Some(s) if same_within(&s, params, &resolution) => Ok(read),
            other => Err(BaseError::ReadBack {
                copy: "committed",
                written: *params,
                read: other,
            }),
        }
    }

    /// Puts `text` back as the whole of the store's file (a backup's [`BackupFile::text`]:
    /// every change odocal made to the file is undone, not only the parameters), then reads
    /// the file back: it must hold `expected`. For a store that is a file only; the rollback
    /// puts the file's original text back byte for byte.
    pub async fn apply_text(
        &mut self,
        text: &str,
        expected: &WheelParams,
    ) -> Result<WheelParams, BaseError> {
        self.require_backup()?;
        let Some(file) = self.store.file() else {
            return Err(BaseError::InvalidArgument {
                component: format!("store {}", self.store.info().id),
                reason: "a whole file can only be restored to a store that is a file".into(),
            });
        };
        // Atomic: a failed replacement changed nothing, and no rollback is owed for it.
        crate::io::replace_atomically(&file, text).map_err(|source| BaseError::Unwritable {
            component: format!("store {}", file.display()),
            source: Box::new(source),
        })?;
        self.written = true;
        self.committed = true;
        self.text_written = true;
        self.last_written = Some(*expected);
        let resolution = self.store.resolution();
        let stored = self.store.read_committed().await?;
        match stored {
            Some(s) if same_within(&s, expected, &resolution) => Ok(s),
            other => Err(BaseError::ReadBack {
                copy: "committed",
                written: *expected,
                read: other,
            }),
        }
    }

    /// Nothing is written before the backup exists.
    fn require_backup(&self) -> Result<(), BaseError> {
        match self.backup_path {
            Some(_) => Ok(()),
            None => Err(BaseError::Backup {
                path: PathBuf::new(),
                source: std::io::Error::other("no backup was taken (Transaction::back_up)"),
            }),
        }
    }

    /// Reads what the store holds now, in use and committed, and says for each whether it is the
    /// original, the new parameters, something else, or unknown (after a failed rollback: the
    /// link may have come back, or the file may be readable).
    pub async fn what_the_store_holds(&self) -> (Holds, Holds) {
        let resolution = self.store.resolution();
        let classify_as = |p: &WheelParams, original: &WheelParams| {
            if same_within(p, original, &resolution) {
                Holds::Original
            } else if self
                .last_written
                .is_some_and(|w| same_within(p, &w, &resolution))
            {
                Holds::New
            } else {
                Holds::Other(Box::new(*p))
            }
        };
        let active = match tokio::time::timeout(ROLLBACK_TIMEOUT, self.store.read()).await {
            Ok(Ok(p)) => classify_as(&p, &self.original),
            Ok(Err(e)) => Holds::Unknown(e.to_string()),
            Err(_) => Holds::Unknown(format!(
                "no answer in {}",
                crate::io::seconds(&ROLLBACK_TIMEOUT)
            )),
        };
        let committed =
            match tokio::time::timeout(ROLLBACK_TIMEOUT, self.store.read_committed()).await {
                Ok(Ok(Some(p))) => classify_as(
                    &p,
                    self.original_committed.as_ref().unwrap_or(&self.original),
                ),
                Ok(Ok(None)) => Holds::Unknown("the store has no committed copy".into()),
                Ok(Err(e)) => Holds::Unknown(e.to_string()),
                Err(_) => Holds::Unknown(format!(
                    "no answer in {}",
                    crate::io::seconds(&ROLLBACK_TIMEOUT)
                )),
            };
        (active, committed)
    }

    /// Puts the original parameters back: in use, and committed if a commit may have happened.
    pub async fn rollback(&mut self) -> Result<Rollback, BaseError> {
        if !self.written {
            return Ok(Rollback::NothingWritten);
        }
        if let (true, Some(text), Some(file)) = (
            self.text_written,
            self.original_text.as_deref(),
            self.store.file(),
        ) {
            crate::io::replace_atomically(&file, text).map_err(|source| BaseError::Unwritable {
                component: format!("store {}", file.display()),
                source: Box::new(source),
            })?;
            self.written = false;
            self.committed = false;
            self.text_written = false;
            return Ok(Rollback::RestoredAndCommitted);
        }
        let undo = async {
            if self.committed {
                // The committed copy as the backup holds it, then what was in use (the two
                // differ after a `params save` of parameters never committed before).
                let stored = self.original_committed.unwrap_or(self.original);
                self.store.write(&stored).await?;
                self.store.commit().await?;
                if stored != self.original {
                    self.store.write(&self.original).await?;
                }
            } else {
                self.store.write(&self.original).await?;
            }
            Ok::<_, BaseError>(())
        };
        match tokio::time::timeout(ROLLBACK_TIMEOUT, undo).await {
            Ok(Ok(())) => {
                let outcome = if self.committed {
                    Rollback::RestoredAndCommitted
                } else {
                    Rollback::Restored
                };
                self.written = false;
                self.committed = false;
                Ok(outcome)
            }
            Ok(Err(e)) => Err(e),
            Err(_) => Err(BaseError::MotionTimeout {
                after: ROLLBACK_TIMEOUT,
            }),
        }
    }
}

/// Reads `store` and writes what it holds (and, for a store that is a file, the whole file) to
/// a new backup file in `dir`; returns the file and its content. Used by [`Transaction::back_up`] and by tools that change a store by other means
/// (a device's factory reset).
pub async fn backup_store(
    store: &dyn ParamStore,
    dir: &Path,
) -> Result<(PathBuf, BackupFile), BaseError> {
    let active = store.read().await?;
    // A committed copy that cannot be read (never saved, corrupt) must not block a backup of
    // what is in use; the backup then records none.
    let committed = store.read_committed().await.ok().flatten();
    let file = store.file().map(|f| std::path::absolute(&f).unwrap_or(f));
    let text = match &file {
        Some(f) => Some(
            crate::io::read_bounded(f, crate::io::MAX_TEXT_FILE).map_err(|source| {
                BaseError::Backup {
                    path: f.clone(),
                    source,
                }
            })?,
        ),
        None => None,
    };
    let backup = BackupFile {
        odocal_version: env!("CARGO_PKG_VERSION").into(),
        store: store.info(),
        taken_utc: Some(crate::io::utc_time()),
        file,
        active,
        committed,
        text,
    };
    let path = write_backup(dir, &backup)?;
    Ok((path, backup))
}

/// The start of the names of files of kind `kind` about a store (its backups, a run's partial
/// reports): `robot.toml.<kind>-` for a store that is the file `robot.toml`, else
/// `<alone>-`.
pub fn store_prefix(file: Option<&Path>, kind: &str, alone: &str) -> String {
    match file {
        Some(f) => format!("{}.{kind}-", crate::io::file_name_of(f)),
        None => format!("{alone}-"),
    }
}

/// Where a command that writes one store and has no run directory of its own keeps the
/// backup: beside the store's file for a store that is a file, else `fallback`.
pub fn backup_dir_for(store: &dyn ParamStore, fallback: &Path) -> PathBuf {
    match store.file() {
        Some(f) => crate::io::dir_of(&f).to_path_buf(),
        None => fallback.to_path_buf(),
    }
}

/// A file-name-safe form of a store id.
fn sanitise(id: &str) -> String {
    let s: String = id
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '-' })
        .collect();
    let s = s.trim_matches('-');
    // Only ASCII is left, so byte offsets are character offsets.
    match &s[s.len().saturating_sub(40)..] {
        "" => "store".into(),
        tail => tail.to_string(),
    }
}

/// Creates a new backup file in `dir` ([`store_prefix`]); never replaces an existing file or
/// follows a link, and leaves no empty file when the write fails.
fn write_backup(dir: &Path, backup: &BackupFile) -> Result<PathBuf, BaseError> {
    let prefix = store_prefix(
        backup.file.as_deref(),
        "odocal-backup",
        &format!("odocal-backup-{}", sanitise(&backup.store.id)),
    );
    let err = |path: &Path, source: std::io::Error| BaseError::Backup {
        path: path.to_path_buf(),
        source,
    };
    std::fs::create_dir_all(dir).map_err(|e| err(dir, e))?;
    let text =
        serde_json::to_string_pretty(backup).map_err(|e| err(dir, std::io::Error::other(e)))?;
    crate::io::create_stamped(dir, &prefix, ".json", text.as_bytes()).map_err(|e| err(dir, e))
}

/// The lines that differ between a file as it is `now` and as it was `then` (a backup's
/// text), in order, `-` for a line that goes and `+` for one that comes back: what a restore of
/// the whole file changes. Empty when the texts are equal.
pub fn text_changes(now: &str, then: &str) -> Vec<String> {
    let a: Vec<&str> = now.lines().collect();
    let b: Vec<&str> = then.lines().collect();
    // Common prefix and suffix first: a restore usually changes a few lines of a long file.
    let pre = a.iter().zip(&b).take_while(|(x, y)| x == y).count();
    let suf = a[pre..]
        .iter()
        .rev()
        .zip(b[pre..].iter().rev())
        .take_while(|(x, y)| x == y)
        .count();
    let (a, b) = (&a[pre..a.len() - suf], &b[pre..b.len() - suf]);
    // A longest common subsequence over what is left, when small enough to be cheap; else
    // every line of the middle is shown as changed.
    let mut out = Vec::new();
    if a.len().saturating_mul(b.len()) <= 1 << 20 {
        let mut l = vec![vec![0u32; b.len() + 1]; a.len() + 1];
        for i in (0..a.len()).rev() {
            for j in (0..b.len()).rev() {
                l[i][j] = if a[i] == b[j] {
                    l[i + 1][j + 1] + 1
                } else {
                    l[i + 1][j].max(l[i][j + 1])
                };
            }
        }
        let (mut i, mut j) = (0, 0);
        while i < a.len() || j < b.len() {
            if i < a.len() && j < b.len() && a[i] == b[j] {
                (i, j) = (i + 1, j + 1);
            } else if j == b.len() || (i < a.len() && l[i + 1][j] >= l[i][j + 1]) {
                out.push(format!("- {}", a[i]));
                i += 1;
            } else {
                out.push(format!("+ {}", b[j]));
                j += 1;
            }
        }
    } else {
        out.extend(a.iter().map(|x| format!("- {x}")));
        out.extend(b.iter().map(|x| format!("+ {x}")));
    }
    if now != then && out.is_empty() {
        // Only line endings or a final newline differ.
        out.push("(line endings or the final newline)".into());
    }
    out
}

/// Why a backup file cannot be restored to a store.
#[derive(Debug, thiserror::Error)]
pub enum BackupError {
    /// The file cannot be read (missing, not a regular file, too large).
    #[error("cannot read the backup {path}: {source}")]
    Read {
        /// The backup file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The file is not a backup odocal wrote (not JSON, or fields missing or of the wrong type).
    #[error("{path} is not a backup odocal wrote: {source}")]
    Malformed {
        /// The backup file.
        path: PathBuf,
        /// Where and why it does not parse.
        #[source]
        source: serde_json::Error,
    },
    /// The parameters in it are not a robot's (a zero or negative size, not finite).
    #[error("{path} holds parameters no robot has: {source}")]
    Invalid {
        /// The backup file.
        path: PathBuf,
        /// Which parameter and why.
        #[source]
        source: crate::kinematics::KinematicsError,
    },
    /// It was taken from another kind of store (a controller's backup offered to a robot
    /// profile, say): never restored.
    #[error(
        "{path} was taken from a store of kind `{backup_kind}` (`{backup_id}`), this is \
         `{kind}` (`{id}`): a backup is restored only to the kind of store it came from"
    )]
    OtherKind {
        /// The backup file.
        path: PathBuf,
        /// The kind of store it was taken from.
        backup_kind: String,
        /// Which one.
        backup_id: String,
        /// The kind of store it was offered to.
        kind: String,
        /// Which one.
        id: String,
    },
    /// It names a file it was not taken beside, and that file differs from the one it holds
    /// in more than the parameters: perhaps another robot's file, named by an edit or a copy.
    #[error(
        "{path} names {}, but it was not taken beside that file, and the file differs from the \
         one it holds in {changed} line(s) beyond the parameters (the first: `{first}`): another \
         robot's file? Not restored: give the store with --to to restore onto it anyway \
         (its parameters only, with --any-device)",
        file.display()
    )]
    NotItsFile {
        /// The backup file.
        path: PathBuf,
        /// The file it names.
        file: PathBuf,
        /// Lines that differ beyond the parameters'.
        changed: usize,
        /// The first of them, as `text_changes` shows it.
        first: String,
    },
    /// It was taken from another store of the same kind (another device, file or
    /// controller): restored only when the caller says so.
    #[error(
        "{path} was taken from {kind} `{backup_id}`, this is `{id}`: not restored \
         (--any-device to restore it anyway)"
    )]
    OtherStore {
        /// The backup file.
        path: PathBuf,
        /// The kind of both stores.
        kind: String,
        /// The store it was taken from.
        backup_id: String,
        /// The store it was offered to.
        id: String,
    },
}

/// Whether `store` is the store `backup` (read from `path`) was taken from: the same kind
/// ([`BackupError::OtherKind`] if not) and, for a device, the same id (firmware and serial
/// number); for a file store, the same file (compared as canonical paths: a backup records it
/// absolute, an older one as it was given) and the same section (a YAML's controller)
/// ([`BackupError::OtherStore`] if not).
pub fn check_store(
    backup: &BackupFile,
    path: &Path,
    store: &dyn ParamStore,
) -> Result<(), BackupError> {
    let here = store.info();
    if here.kind != backup.store.kind {
        return Err(BackupError::OtherKind {
            path: path.to_path_buf(),
            backup_kind: backup.store.kind.clone(),
            backup_id: backup.store.id.clone(),
            kind: here.kind,
            id: here.id,
        });
    }
    let same = match store.file() {
        None => here.id == backup.store.id,
        Some(file) => {
            let then = backup.file.clone().or_else(|| {
                backup
                    .store
                    .details
                    .get("file")
                    .and_then(serde_json::Value::as_str)
                    .map(PathBuf::from)
            });
            let canonical = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
            then.is_some_and(|t| canonical(&t) == canonical(&file))
                && here.details.get("controller") == backup.store.details.get("controller")
        }
    };
    if same {
        Ok(())
    } else {
        Err(BackupError::OtherStore {
            path: path.to_path_buf(),
            kind: here.kind,
            backup_id: backup.store.id.clone(),
            id: here.id,
        })
    }
}

/// Whether the file `store` is (when it is one) is the file `backup` (read from `path`) was
/// taken from, judged by more than the path the backup carries (which an edit or a copy
/// changes): the backup lies beside the file, named after it (where odocal writes a file's
/// backups), or the file differs from the text the backup holds only in the lines a write
/// changes ([`ParamStore::written_keys`]: as a calibration whose backup went to a report
/// directory left it). [`BackupError::NotItsFile`] if neither; a device is judged by
/// [`check_store`] alone.
pub fn check_same_file(
    backup: &BackupFile,
    path: &Path,
    store: &dyn ParamStore,
) -> Result<(), BackupError> {
    let Some(file) = store.file() else {
        return Ok(());
    };
    let canonical = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
    let beside = canonical(crate::io::dir_of(path)) == canonical(crate::io::dir_of(&file))
        && path
            .file_name()
            .zip(file.file_name())
            .is_some_and(|(b, f)| {
                b.to_string_lossy()
                    .starts_with(&format!("{}.odocal-", f.to_string_lossy()))
            });
    if beside {
        return Ok(());
    }
    let now = crate::io::read_bounded(&file, crate::io::MAX_TEXT_FILE).unwrap_or_default();
    let keys = store.written_keys();
    let others: Vec<String> = match &backup.text {
        Some(then) => text_changes(&now, then)
            .into_iter()
            .filter(|l| !keys.iter().any(|k| l.contains(k)))
            .collect(),
        // An older backup without the file's text: nothing to judge by but where it lies.
        None => vec!["(the backup holds no text of the file)".into()],
    };
    match others.first() {
        None => Ok(()),
        Some(first) => Err(BackupError::NotItsFile {
            path: path.to_path_buf(),
            file,
            changed: others.len(),
            first: first.clone(),
        }),
    }
}

/// Reads a backup file written by [`Transaction::back_up`] (or [`backup_store`]): bounded,
/// parsed, and its parameters checked.
pub fn read_backup(path: &Path) -> Result<BackupFile, BackupError> {
    let text = crate::io::read_bounded(path, crate::io::MAX_TEXT_FILE).map_err(|source| {
        BackupError::Read {
            path: path.to_path_buf(),
            source,
        }
    })?;
    let backup: BackupFile =
        serde_json::from_str(&text).map_err(|source| BackupError::Malformed {
            path: path.to_path_buf(),
            source,
        })?;
    check_restorable(&backup, path)?;
    Ok(backup)
}

/// Refuses a backup whose parameters no robot has: not finite and positive, or outside the
/// physical ranges odocal accepts from any file ([`WheelParams::check_physical`]: a 1 nm
/// wheel, a 50 m wheelbase). Checked when a backup is read, so a dry run refuses what the real
/// run would, and before anything is backed up or written.
pub fn check_restorable(backup: &BackupFile, path: &Path) -> Result<(), BackupError> {
    let invalid = |source| BackupError::Invalid {
        path: path.to_path_buf(),
        source,
    };
    for params in std::iter::once(&backup.active).chain(backup.committed.as_ref()) {
        params.validate().map_err(invalid)?;
        params.check_physical().map_err(invalid)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::text_changes;

    #[test]
    fn text_changes_lists_only_the_lines_a_restore_changes_in_order() {
        let then = "a: 1\nb: 2\nc: 3\nd: 4\n";
        assert!(text_changes(then, then).is_empty());
        // One value changed in the middle, one line added at the end.
        let now = "a: 1\nb: 2.5\nc: 3\nd: 4\ne: 5\n";
        assert_eq!(
            text_changes(now, then),
            ["- b: 2.5", "+ b: 2", "- e: 5"].map(String::from)
        );
        // A line that moved is one removal and one addition, not a rewrite of the file.
        let moved = "b: 2\na: 1\nc: 3\nd: 4\n";
        let changes = text_changes(moved, then);
        assert_eq!(changes.len(), 2, "{changes:?}");
        // From nothing, and to nothing.
        assert_eq!(text_changes("", "x\n"), ["+ x"].map(String::from));
        assert_eq!(text_changes("x\n", ""), ["- x"].map(String::from));
    }
}
