//! Where `odocal restore` puts a backup: the store named with `--to`, else the one the backup
//! was taken from; and whether a file there may get its whole text back. A file the backup
//! names is trusted only when the backup vouches for it ([`check_same_file`]); a store the
//! user chose is theirs to choose, but only a file the backup vouches for gets its whole text
//! back (else its parameters only).

use super::{SpecError, StoreLocation};
use crate::base::transaction::{check_same_file, BackupError, BackupFile};
use crate::base::ParamStore;
use std::path::Path;
use std::sync::Arc;

/// A backup read and the store it goes to, not yet opened.
#[derive(Debug)]
pub struct Located {
    /// The backup.
    pub backup: BackupFile,
    /// The store it goes to.
    pub location: StoreLocation,
    /// The store is the one the backup names (no `--to`).
    pub named_by_backup: bool,
}

/// The store opened, and whether its file must keep its text.
pub struct Opened {
    /// The store.
    pub store: Arc<dyn ParamStore>,
    /// Said when the file differs from the backup's beyond the parameters and the restore
    /// goes on with its parameters only (`any_device`, or a store chosen with `--to`).
    pub not_its_file: Option<String>,
}

/// Reads the backup at `path` and finds its store: `to` (a store spec) when given, else the
/// store the backup was taken from; controllers at `baud`.
pub fn locate(path: &Path, to: Option<&str>, baud: u32) -> Result<Located, SpecError> {
    let to = to
        .map(|text| StoreLocation::parse(text, baud))
        .transpose()?;
    let controller = to.as_ref().and_then(|l| l.option("controller"));
    let backup = StoreLocation::read_backup(path, controller)?;
    let named_by_backup = to.is_none();
    let location = match to {
        Some(location) => location,
        None => StoreLocation::of_backup(&backup, baud).map_err(|e| SpecError::InBackup {
            path: path.to_path_buf(),
            source: Box::new(e),
        })?,
    };
    Ok(Located {
        backup,
        location,
        named_by_backup,
    })
}

impl Located {
    /// Opens the store and judges its file against the backup (read from `path`): a file the
    /// backup names but does not vouch for is refused unless `any_device`.
    pub async fn open(&self, path: &Path, any_device: bool) -> Result<Opened, SpecError> {
        let store = self.location.open().await?;
        let not_its_file = match check_same_file(&self.backup, path, store.as_ref()) {
            Ok(()) => None,
            Err(e) if self.named_by_backup && !any_device => return Err(e.into()),
            Err(BackupError::NotItsFile { file, changed, .. }) => Some(format!(
                "{} differs from the file this backup holds in {changed} line(s) beyond the \
                 parameters: restoring its parameters only",
                file.display()
            )),
            Err(e) => return Err(e.into()),
        };
        Ok(Opened {
            store,
            not_its_file,
        })
    }
}
