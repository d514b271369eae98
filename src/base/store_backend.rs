//! A parameter store on its own, as a backend module offers it: its text form, how a backup
//! names it, how it is shown and how it opens into a [`ParamStore`] without a drive (what
//! `odocal restore` writes to).
//!
//! Each store module exports one [`StoreBackend`]; [`crate::spec::registry::STORE_BACKENDS`]
//! lists them, so a new store is its module plus one line there.

use super::drive_backend::BackendError;
use super::port_spec::PortSpec;
use super::transaction::BackupFile;
use super::ParamStore;
use futures_util::future::BoxFuture;
use std::path::PathBuf;
use std::sync::Arc;

/// The future a [`StoreBackend::open`] returns.
pub type OpenStore = BoxFuture<'static, Result<Arc<dyn ParamStore>, BackendError>>;

/// A parameter store on its own.
pub struct StoreBackend {
    /// The store kind its backups record (`ComponentInfo::kind`).
    pub kind: &'static str,
    /// What it is, for messages (`a robot profile`).
    pub what: &'static str,
    /// The scheme of its text form (`profile` in `profile:robot.toml`).
    pub scheme: &'static str,
    /// Its text form with defaults, for help and errors.
    pub form: &'static str,
    /// The option keys its text form takes.
    pub options: &'static [&'static str],
    /// It takes a bare port (a controller's `/dev/ttyUSB0`, no scheme).
    pub bare_port: bool,
    /// Fills in the options' defaults and checks them, before anything opens (a store
    /// parsed and printed reads back the same).
    pub complete: fn(&mut PortSpec) -> Result<(), String>,
    /// Where a backup of this kind says its store is: from the file it records (absolute, or
    /// in older backups as given) and its details; an error says what the backup does not say.
    pub of_backup: fn(&BackupFile, Option<PathBuf>) -> Result<PortSpec, &'static str>,
    /// The text form, shortest that reads back the same.
    pub show: fn(&PortSpec) -> String,
    /// **Connects to the store** (a controller: the handshake; a file: read and parsed).
    pub open: fn(PortSpec) -> OpenStore,
}

impl StoreBackend {
    /// `key` of a backup's store details, as text.
    pub fn detail<'a>(backup: &'a BackupFile, key: &str) -> Option<&'a str> {
        backup
            .store
            .details
            .get(key)
            .and_then(serde_json::Value::as_str)
    }
}

impl std::fmt::Debug for StoreBackend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StoreBackend")
            .field("scheme", &self.scheme)
            .finish_non_exhaustive()
    }
}

impl PartialEq for StoreBackend {
    fn eq(&self, other: &Self) -> bool {
        self.scheme == other.scheme
    }
}
