//! `odocal restore BACKUP`: puts the parameters of one of odocal's own backups back into the
//! store they came from (a controller, a robot profile, a controller's YAML) or another one
//! (`--to`), through the same transaction as a calibration: the store is proven writable, the
//! user sees old → new and agrees, what it holds now is backed up first, then the backup's
//! parameters are written, read back, committed and read back. A backup of a file restored to
//! that same file puts the whole file back as it was (the lines that change are shown).

use crate::out::print_params;
use odocal::base::restore::{restore, BackupDir, RestoreError, RestoreOptions, Restored};
use odocal::base::transaction::BackupFile;
use odocal::base::write::{WriteError, WritePolicy};
use odocal::base::ParamStore;
use odocal::spec::restore_target::locate;
use odocal::spec::ODOCAL_BAUD;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::sync::Arc;

type CliResult = Result<(), Box<dyn std::error::Error>>;

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
    /// Which store may take it, and what is written.
    pub options: RestoreOptions,
    /// Ask, write without asking, or show and write nothing.
    pub policy: WritePolicy,
    /// Where the backup of what the store holds goes.
    pub dir: BackupDir<'a>,
    /// Print JSON.
    pub json: bool,
}

/// Runs `odocal restore`.
pub async fn run(args: RestoreArgs) -> CliResult {
    let located = locate(&args.backup, args.to.as_deref(), args.baud)?;
    if !args.json {
        eprintln!("restoring to {}", located.location);
    }
    let opened = located.open(&args.backup, args.any_device).await?;
    if let Some(warning) = &opened.not_its_file {
        eprintln!("warning: {warning}");
    }
    let beside_backup = odocal::io::dir_of(&args.backup).to_path_buf();
    let how = Restore {
        from: &args.backup,
        options: RestoreOptions {
            any_device: args.any_device,
            not_its_file: opened.not_its_file.is_some(),
            commit: true,
        },
        policy: WritePolicy::of_flags(args.dry_run, args.yes),
        dir: BackupDir {
            given: args.backup_dir.as_deref(),
            default: &beside_backup,
        },
        json: args.json,
    };
    restore_onto(opened.store, &located.backup, &how).await
}

/// Puts `backup`'s parameters into `store` ([`odocal::base::restore::restore`]) and prints
/// what the store holds after.
pub async fn restore_onto(
    store: Arc<dyn ParamStore>,
    backup: &BackupFile,
    how: &Restore<'_>,
) -> CliResult {
    let mut ui = crate::prompt::TerminalWriteUi;
    let done = restore(
        store,
        (backup, how.from),
        how.options,
        (how.policy, how.dir),
        &mut ui,
    )
    .await;
    let (plan, restored) = done.map_err(|e| match e {
        RestoreError::Write(WriteError::Declined(_)) => "not restored: declined".into(),
        RestoreError::Write(e @ WriteError::Failed { .. }) => format!("not restored: {e}"),
        e => e.to_string(),
    })?;
    let extra = |written: bool| {
        json!({
            "restored_from": how.from,
            "store": plan.store,
            "before": plan.current,
            "written": written,
            "dry_run": how.policy == WritePolicy::DryRun,
        })
    };
    let done = match restored {
        Restored::HoldsAlready => {
            eprintln!("the store already holds these parameters: nothing to write");
            return print_params(&plan.current, how.json, extra(false));
        }
        Restored::DryRun => {
            eprintln!("dry run: nothing written");
            return print_params(&plan.current, how.json, extra(false));
        }
        Restored::Written(done) => done,
    };
    eprintln!(
        "restored{}",
        if how.options.commit {
            " and committed"
        } else {
            " to RAM; run `odocal params save` to keep them across power cycles"
        }
    );
    let mut extra = extra(true);
    extra["backup"] = json!(done.backup);
    print_params(&done.applied, how.json, extra)
}
