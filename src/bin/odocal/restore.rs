//! `odocal restore BACKUP`: puts the parameters of one of odocal's own backups back into the
//! store they came from (a controller, a robot profile, a controller's YAML) or another one
//! (`--to`), through the same transaction as a calibration: the store is proven writable, the
//! user sees old → new and agrees, what it holds now is backed up first, then the backup's
//! parameters are written, read back, committed and read back.

use crate::device::print_params;
use odocal::base::transaction::{
    check_store, read_backup, BackupError, BackupFile, Rollback, Transaction,
};
use odocal::base::{same_within, ParamStore};
use odocal::spec::{StoreLocation, ODOCAL_BAUD};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::sync::Arc;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Arguments of `odocal restore`.
#[derive(Debug, clap::Args)]
pub struct RestoreArgs {
    /// A backup odocal wrote (`…odocal-backup-<UTC time>.json`).
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
    /// Where the backup of a controller's current parameters goes [default: beside BACKUP];
    /// a file's is always beside the file.
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
    /// Where a device's backup goes.
    pub backup_dir: PathBuf,
    /// Print JSON.
    pub json: bool,
}

/// Runs `odocal restore`.
pub async fn restore(args: RestoreArgs) -> CliResult {
    let backup = read_backup(&args.backup)?;
    let location = match &args.to {
        Some(text) => StoreLocation::parse(text, args.baud)?,
        None => StoreLocation::of_backup(&backup, args.baud)
            .map_err(|e| format!("{}: {e}", args.backup.display()))?,
    };
    if !args.json {
        eprintln!("restoring to {location}");
    }
    let store = location.open().await?;
    let how = Restore {
        from: &args.backup,
        dry_run: args.dry_run,
        yes: args.yes,
        any_device: args.any_device,
        commit: true,
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
    match check_store(backup, how.from, store.as_ref()) {
        Ok(()) => {}
        Err(BackupError::OtherStore { backup_id, .. }) if how.any_device => eprintln!(
            "warning: restoring a backup of {} `{backup_id}` onto `{}`",
            here.kind, here.id
        ),
        Err(e) => return Err(e.into()),
    }
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
    if same_within(&current, &target, &resolution) && committed_holds {
        eprintln!("the store already holds these parameters: nothing to write");
        return print_params(&current, how.json, extra(false));
    }
    if how.dry_run {
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
        if !crate::prompt::yes(&question) {
            return Err("not restored: declined".into());
        }
    }
    let saved = tx.back_up(&how.backup_dir).await?;
    eprintln!("backed up the current parameters to {}", saved.display());
    let written = if how.commit {
        tx.apply(&target).await
    } else {
        tx.write_in_use(&target).await
    };
    let applied = match written {
        Ok(p) => p,
        Err(e) => {
            let undone = match tx.rollback().await {
                Ok(Rollback::NothingWritten) => "nothing was changed".to_string(),
                Ok(Rollback::Restored) => "the earlier parameters are in use again".into(),
                Ok(Rollback::RestoredAndCommitted) => {
                    "the earlier parameters are in use and committed again".into()
                }
                Err(r) => format!("putting the earlier parameters back failed too: {r}"),
            };
            return Err(format!(
                "not restored: {e} ({undone}; the earlier parameters are in {})",
                saved.display()
            )
            .into());
        }
    };
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
