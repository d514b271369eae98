//! `odocal params`: the command only a controller of odocal's protocol takes.

use crate::out::print_params;
use crate::sensor::PortArgs;
use clap::Subcommand;
use odocal::base::write::{WriteError, Written};
use odocal::hal::params::{self, ParamsError, ParamsPatch};
use odocal::hal::{open_port, Client};
use odocal::protocol::message::ParamSource;
use serde_json::json;
use std::path::PathBuf;
use std::sync::Arc;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// The odocal-protocol controller `--port` names (`PORT` or `odocal:PORT?baud=N`).
async fn connect(port: &PortArgs) -> Result<Client, Box<dyn std::error::Error>> {
    let (path, baud) = port.drive()?.controller_port()?;
    Ok(open_port(&path, baud).await?.0)
}

/// `odocal params` subcommands.
#[derive(Debug, Subcommand)]
pub enum ParamsCommand {
    /// Read parameters.
    Get {
        #[command(flatten)]
        port: PortArgs,
        /// Which copy: active (RAM), stored (non-volatile) or factory.
        #[arg(long, default_value = "active", value_parser = ["active", "stored", "factory"])]
        source: String,
    },
    /// Write the active (RAM) parameters; unspecified fields keep their value. Backs up first.
    Set {
        #[command(flatten)]
        port: PortArgs,
        #[command(flatten)]
        patch: ParamsPatch,
        /// Directory for the backup (a new, uniquely named file; never overwritten).
        #[arg(long, default_value = ".")]
        backup_dir: PathBuf,
    },
    /// Commit the active parameters to non-volatile storage (the stored copy is backed up
    /// first, and read back after).
    Save {
        #[command(flatten)]
        port: PortArgs,
        /// Directory for the backup (a new, uniquely named file; never overwritten).
        #[arg(long, default_value = ".")]
        backup_dir: PathBuf,
    },
    /// Restore factory defaults, or with --from the parameters of a backup file (RAM only, or
    /// also storage with --stored). Shows old → new, asks first (unless --yes), backs up first.
    Restore {
        #[command(flatten)]
        port: PortArgs,
        /// A backup file written by odocal (`odocal-backup-….json`): restore what was in use when
        /// it was taken, instead of the factory defaults.
        #[arg(long)]
        from: Option<PathBuf>,
        /// Restore a backup taken from another device (a different firmware id or serial).
        #[arg(long, requires = "from")]
        any_device: bool,
        /// Do not ask before writing.
        #[arg(long)]
        yes: bool,
        /// Also overwrite the stored copy.
        #[arg(long)]
        stored: bool,
        /// Directory for the backup (a new, uniquely named file; never overwritten).
        #[arg(long, default_value = ".")]
        backup_dir: PathBuf,
    },
}

/// Runs `odocal params ...`.
pub async fn params(cmd: ParamsCommand) -> CliResult {
    match cmd {
        ParamsCommand::Get { port, source } => {
            let client = connect(&port).await?;
            let source = match source.as_str() {
                "stored" => ParamSource::Stored,
                "factory" => ParamSource::Factory,
                _ => ParamSource::Active,
            };
            let p = client.get_params(source).await?;
            print_params(&p, port.json, json!({ "source": source }))
        }
        ParamsCommand::Set {
            port,
            patch,
            backup_dir,
        } => {
            let client = Arc::new(connect(&port).await?);
            let done = written(params::set(&client, &patch, &backup_dir, &mut ui()).await)?;
            eprintln!("written to RAM; run `odocal params save` to keep them across power cycles");
            print_params(&done.applied, port.json, json!({ "backup": done.backup }))
        }
        ParamsCommand::Save { port, backup_dir } => {
            let client = Arc::new(connect(&port).await?);
            let done = written(params::save(&client, &backup_dir, &mut ui()).await)?;
            if !port.json {
                println!("saved: the stored copy holds the parameters in use");
            }
            print_params(&done.applied, port.json, json!({ "backup": done.backup }))
        }
        ParamsCommand::Restore {
            port,
            from: Some(file),
            any_device,
            yes,
            stored,
            backup_dir,
        } => restore_from(&port, &file, any_device, yes, stored, &backup_dir).await,
        ParamsCommand::Restore {
            port,
            stored,
            backup_dir,
            yes,
            ..
        } => {
            let client = Arc::new(connect(&port).await?);
            let how = (stored, yes);
            let done = params::restore_factory(&client, how, &backup_dir, &mut ui()).await;
            let done = written(done)?;
            print_params(&done.applied, port.json, json!({ "backup": done.backup }))
        }
    }
}

/// The terminal's answers to a write's questions.
fn ui() -> crate::prompt::TerminalWriteUi {
    crate::prompt::TerminalWriteUi
}

/// A write's outcome, a failed or declined one said as "not written: …".
fn written(done: Result<Written, ParamsError>) -> Result<Written, Box<dyn std::error::Error>> {
    done.map_err(|e| match e {
        ParamsError::Write(e @ (WriteError::Failed { .. } | WriteError::Declined(_))) => {
            format!("not written: {e}").into()
        }
        e => e.into(),
    })
}

/// `params restore --from FILE`: `odocal restore FILE --to PORT` ([`crate::restore`]), to RAM
/// only unless `--stored`.
async fn restore_from(
    port: &PortArgs,
    file: &std::path::Path,
    any_device: bool,
    yes: bool,
    stored: bool,
    backup_dir: &std::path::Path,
) -> CliResult {
    let backup = odocal::spec::StoreLocation::read_backup(file, None)?;
    let client = connect(port).await?;
    let how = crate::restore::Restore {
        from: file,
        options: odocal::base::restore::RestoreOptions {
            any_device,
            // A device, judged by its serial number alone.
            not_its_file: false,
            commit: stored,
        },
        policy: odocal::base::write::WritePolicy::of_flags(false, yes),
        dir: odocal::base::restore::BackupDir {
            given: Some(backup_dir),
            default: backup_dir,
        },
        json: port.json,
    };
    crate::restore::restore_onto(Arc::new(client), &backup, &how).await
}
