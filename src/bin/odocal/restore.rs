//! `odocal restore BACKUP`: puts the parameters of one of odocal's own backups back into the
//! store they came from (a controller, a robot profile, a controller's YAML) or another one
//! (`--to`), through the same transaction as a calibration: the store is proven writable, the
//! user sees old → new and agrees, what it holds now is backed up first, then the backup's
//! parameters are written, read back, committed and read back. A backup of a file restored to
//! that same file puts the whole file back as it was (the lines that change are shown).

use crate::device::print_params;
use odocal::base::transaction::{
    backup_dir_for, check_same_file, check_store, text_changes, BackupError, BackupFile, Rollback,
    Transaction,
};
use odocal::base::{same_within, ParamStore};
use odocal::spec::{StoreLocation, ODOCAL_BAUD};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::sync::Arc;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// How many changed lines of a file a restore shows before asking.
const MAX_SHOWN: usize = 20;

/// Arguments of `odocal restore`.
#[derive(Debug, clap::Args)]
pub struct RestoreArgs {
    /// A backup odocal wrote (`…odocal-backup-<UTC time>.json`, or a copy of a file named
    /// `<file>.odocal-backup-<UTC time>` that earlier versions made beside it).
    backup: PathBuf,
    /// The store to restore to: a controller's port (odocal protocol), `profile:PATH` or
    /// `ros-yaml:PATH[?controller=NAME]` [default: the store the backup was taken from].
    #[arg(long)]
    to: Option<String>,
    /// Baud rate of a controller.
    #[arg(long, default_value_t = ODOCAL_BAUD)]
    baud: u32,
    /// Show old → new and write nothing.
    #[arg(long)]
    dry_run: bool,
    /// Do not ask before writing.
    #[arg(long)]
    yes: bool,
    /// Restore a backup taken from another store (another device, file or controller).
    #[arg(long)]
    any_device: bool,
    /// Where the backup of what the store holds now goes [default: beside the store's file;
    /// for a controller, beside BACKUP].
    #[arg(long)]
    backup_dir: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

/// How a restore goes (shared with `params restore --from`).
pub struct Restore<'a> {
    /// The backup file.
    pub from: &'a Path,
    /// Show, write nothing.
    pub dry_run: bool,
    /// Do not ask.
    pub yes: bool,
    /// Allow a backup of another store.
    pub any_device: bool,
    /// Commit (storage, the file) too; else the copy in use only (a device's RAM).
    pub commit: bool,
    /// Where the backup goes for a store that is not a file (a file's goes beside it), unless
    /// `backup_dir_given`.
    pub backup_dir: PathBuf,
    /// `backup_dir` was asked for: it is used for a file's backup too.
    pub backup_dir_given: bool,
    /// The file the backup names failed [`check_same_file`] (and `any_device` allowed it):
    /// its parameters only, never its whole text.
    pub not_its_file: bool,
    /// Print JSON.
    pub json: bool,
}

/// Runs `odocal restore`.
pub async fn restore(args: RestoreArgs) -> CliResult {
    let to = args
        .to
        .as_deref()
        .map(|text| StoreLocation::parse(text, args.baud))
        .transpose()?;
    let controller = match &to {
        Some(StoreLocation::RosYaml { controller, .. }) => Some(controller.as_str()),
        _ => None,
    };
    let backup = StoreLocation::read_backup(&args.backup, controller)?;
    let named_by_backup = to.is_none();
    let location = match to {
        Some(location) => location,
        None => StoreLocation::of_backup(&backup, args.baud)
            .map_err(|e| format!("{}: {e}", args.backup.display()))?,
    };
    if !args.json {
        eprintln!("restoring to {location}");
    }
    let store = location.open().await?;
    // A file the backup names is trusted only when the backup vouches for it; a store the
    // user chose with --to is theirs to choose, but only a file the backup vouches for gets
    // its whole text back (else its parameters only).
    let not_its_file = match check_same_file(&backup, &args.backup, store.as_ref()) {
        Ok(()) => false,
        Err(e) if named_by_backup && !args.any_device => return Err(e.into()),
        Err(BackupError::NotItsFile { file, changed, .. }) => {
            eprintln!(
                "warning: {} differs from the file this backup holds in {changed} line(s) \
                 beyond the parameters: restoring its parameters only",
                file.display()
            );
            true
        }
        Err(e) => return Err(e.into()),
    };
    let how = Restore {
        from: &args.backup,
        dry_run: args.dry_run,
        yes: args.yes,
        any_device: args.any_device,
        commit: true,
        backup_dir_given: args.backup_dir.is_some(),
        not_its_file,
        backup_dir: args
            .backup_dir
            .unwrap_or_else(|| odocal::io::dir_of(&args.backup).to_path_buf()),
        json: args.json,
    };
    restore_onto(store, &backup, &how).await
}

/// Puts `backup`'s parameters into `store`: refused for another store unless `any_device`;
/// shows old → new; writes nothing when the store holds them already or on a dry run; asks
/// unless `yes` (after proving the store writable, before any file is made); backs up what
/// the store holds; writes (and commits when `commit`), rolling back on failure.
pub async fn restore_onto(
    store: Arc<dyn ParamStore>,
    backup: &BackupFile,
    how: &Restore<'_>,
) -> CliResult {
    let here = store.info();
    let from = how.from.display();
    let same_store = match check_store(backup, how.from, store.as_ref()) {
        Ok(()) => !how.not_its_file,
        Err(BackupError::OtherStore { backup_id, .. }) if how.any_device => {
            eprintln!(
                "warning: restoring a backup of {} `{backup_id}` onto `{}` (its parameters only)",
                here.kind, here.id
            );
            false
        }
        Err(e) => return Err(e.into()),
    };
    let target = backup.active;
    let current = store.read().await?;
    let resolution = store.resolution();
    eprintln!(
        "{from} (taken {}by odocal {}) onto {} `{}`:\n{}",
        backup
            .taken_utc
            .as_ref()
            .map_or(String::new(), |t| format!("{t} ")),
        backup.odocal_version,
        here.kind,
        here.id,
        odocal::routine::report::params_table(&current, &target)
    );
    // The whole file goes back when the backup holds it and this is the file it came from.
    let whole = match (&backup.text, store.file(), same_store) {
        (Some(then), Some(file), true) => Some((
            then.as_str(),
            odocal::io::read_bounded(&file, odocal::io::MAX_TEXT_FILE)
                .map_err(|e| format!("cannot read {}: {e}", file.display()))?,
        )),
        _ => None,
    };
    if let Some((then, now)) = &whole {
        let changes = text_changes(now, then);
        if !changes.is_empty() {
            eprintln!(
                "the whole file goes back as it was: {} line(s) change (- now, + restored)",
                changes.len()
            );
            for line in changes.iter().take(MAX_SHOWN) {
                eprintln!("  {line}");
            }
            if changes.len() > MAX_SHOWN {
                eprintln!("  … and {} more", changes.len() - MAX_SHOWN);
            }
        }
    }
    let committed_holds = !how.commit
        || store
            .read_committed()
            .await
            .ok()
            .flatten()
            .is_some_and(|c| same_within(&c, &target, &resolution));
    let extra = |written: bool| {
        json!({
            "restored_from": how.from,
            "store": here,
            "before": current,
            "written": written,
            "dry_run": how.dry_run,
        })
    };
    let holds_already = match &whole {
        Some((then, now)) => then == now,
        None => same_within(&current, &target, &resolution) && committed_holds,
    };
    if holds_already {
        eprintln!("the store already holds these parameters: nothing to write");
        return print_params(&current, how.json, extra(false));
    }
    if how.dry_run {
        // Every check the real run makes before its question (Transaction::prepare), so a dry
        // run fails where the real run would.
        store.check_write(&target).await?;
        eprintln!("dry run: nothing written");
        return print_params(&current, how.json, extra(false));
    }
    // Proven writable before the question; nothing is made before the answer.
    let mut tx = Transaction::prepare(store, Some(&target)).await?;
    if !how.yes {
        let question = format!(
            "write them to {} `{}`{}?",
            here.kind,
            here.id,
            if how.commit { " and commit them" } else { "" }
        );
        if !tokio::task::block_in_place(|| crate::prompt::yes(&question)) {
            return Err("not restored: declined".into());
        }
    }
    let dir = match how.backup_dir_given {
        true => how.backup_dir.clone(),
        false => backup_dir_for(tx.store().as_ref(), &how.backup_dir),
    };
    // From the backup to the read-back (or the rollback), a signal waits for the end.
    let (saved, applied) = crate::prompt::writing(async {
        let saved = tx.back_up(&dir).await?;
        eprintln!("backed up what the store holds now to {}", saved.display());
        let written = match (&whole, how.commit) {
            (Some((then, _)), _) => tx.apply_text(then, &target).await,
            (None, true) => tx.apply(&target).await,
            (None, false) => tx.write_in_use(&target).await,
        };
        match written {
            Ok(p) => Ok((saved, p)),
            Err(e) => Err(format!(
                "not restored: {e} ({}; the earlier parameters are in {})",
                roll_back(&mut tx).await,
                saved.display()
            )
            .into()),
        }
    })
    .await
    .map_err(|e: Box<dyn std::error::Error>| e)?;
    eprintln!(
        "restored{}",
        if how.commit {
            " and committed"
        } else {
            " to RAM; run `odocal params save` to keep them across power cycles"
        }
    );
    let mut extra = extra(true);
    extra["backup"] = json!(saved);
    print_params(&applied, how.json, extra)
}

/// Rolls `tx` back after a failed write and says what the store holds then.
pub async fn roll_back(tx: &mut Transaction) -> String {
    match tx.rollback().await {
        Ok(r) => r.to_string(),
        Err(r) => Rollback::failed(&r),
    }
}
