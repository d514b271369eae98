//! [`FileStore`]: a parameter store in a file that also holds other things (a controller's
//! YAML, a robot profile), for any format that can read its parameters and write new ones
//! into its text leaving everything else as it is ([`ParamFile`]).
//!
//! `write` stages: it renders the new text in memory, parses it back, and updates the
//! geometry a drive counts with ([`FileStore::shared`]), so the new parameters take effect at
//! once; `check_write` does the same without staging, and probes the directory, so that a file
//! that cannot be written is known before anything depends on it. `commit` renders again from
//! the file as it is then and replaces the file atomically. Nothing is ever half-written: the
//! file is either the old text or the new. The backup is the transaction's
//! ([`super::transaction`]), which holds the whole file: one backup per write.

use super::{BaseError, ComponentInfo, ParamStore};
use crate::kinematics::WheelParams;
use async_trait::async_trait;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, RwLock};

/// What values written with odocal's text formats resolve: at least ten significant decimals,
/// far below a nanometre at robot sizes.
pub const FILE_RESOLUTION: WheelParams = WheelParams {
    left_wheel_diameter_m: 1e-9,
    right_wheel_diameter_m: 1e-9,
    wheelbase_m: 1e-9,
    counts_per_wheel_rev: 1e-9,
};

/// A file format that holds a robot's wheel parameters among other content.
pub trait ParamFile: Send + Sync + 'static {
    /// What the file says, as a drive uses it (the parameters, and anything else it needs).
    type Content: Clone + Send + Sync + 'static;
    /// Why a text is not usable.
    type Error: std::error::Error + Send + Sync + 'static;

    /// The kind of store, for reports and backups (`ros2-control-yaml`, `robot-profile`).
    fn kind(&self) -> &'static str;
    /// Which one: the file, and which part of it.
    fn id(&self, path: &Path) -> String;
    /// More for reports.
    fn details(&self, path: &Path) -> serde_json::Value;
    /// Reads the text (`path` names the file in errors).
    fn parse(&self, text: &str, path: &Path) -> Result<Self::Content, Self::Error>;
    /// The parameters in the content.
    fn params(content: &Self::Content) -> WheelParams;
    /// `text` with the parameters set to `params` and everything else kept.
    fn render(&self, text: &str, params: &WheelParams, path: &Path) -> Result<String, Self::Error>;
    /// Why `params` cannot be written over `current`, if they cannot (a field the format
    /// does not calibrate changed).
    fn refuse(&self, current: &WheelParams, params: &WheelParams) -> Option<String>;
    /// The format's error for a file that cannot be read.
    fn io_error(&self, path: &Path, source: std::io::Error) -> Self::Error;
    /// The keys whose lines `render` changes (or inserts): a file that differs from one of its
    /// backups only in lines naming them is that file, as a calibration left it.
    fn written_keys(&self) -> &'static [&'static str];

    /// What a store of this format at `path` says it is (its kind, id and details), as its
    /// [`FileStore`] and its backups name it.
    fn info(&self, path: &Path) -> ComponentInfo {
        ComponentInfo {
            kind: self.kind().into(),
            id: self.id(path),
            details: self.details(path),
        }
    }
}

/// A [`ParamStore`] in a file of format `F`; see the module.
pub struct FileStore<F: ParamFile> {
    format: F,
    path: PathBuf,
    staged: Mutex<Option<WheelParams>>,
    content: Arc<RwLock<F::Content>>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl<F: ParamFile> FileStore<F> {
    /// Opens `path`, which must read as `format`.
    pub fn with_format(format: F, path: &Path) -> Result<Self, F::Error> {
        let text = crate::io::read_bounded(path, crate::io::MAX_TEXT_FILE)
            .map_err(|e| format.io_error(path, e))?;
        let content = format.parse(&text, path)?;
        Ok(FileStore {
            format,
            path: path.to_path_buf(),
            staged: Mutex::new(None),
            content: Arc::new(RwLock::new(content)),
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The format.
    pub fn format(&self) -> &F {
        &self.format
    }

    /// The content in use (staged parameters included), shared with a drive.
    pub fn shared(&self) -> Arc<RwLock<F::Content>> {
        self.content.clone()
    }

    fn err(&self, e: impl std::error::Error + Send + Sync + 'static) -> BaseError {
        BaseError::backend(format!("store {}", self.path.display()), e)
    }

    fn text(&self) -> Result<String, BaseError> {
        crate::io::read_bounded(&self.path, crate::io::MAX_TEXT_FILE).map_err(|e| self.err(e))
    }

    /// The file's content as it is on disk now.
    pub fn on_disk(&self) -> Result<F::Content, BaseError> {
        self.format
            .parse(&self.text()?, &self.path)
            .map_err(|e| self.err(e))
    }

    /// What the file would hold with `params` written into its current text: the new text and
    /// its content, read back. Changes nothing (a dry run of a write); a text the format
    /// cannot rewrite is [`BaseError::Unwritable`].
    pub fn rendered(&self, params: &WheelParams) -> Result<(String, F::Content), BaseError> {
        let unwritable = |e: F::Error| BaseError::Unwritable {
            component: format!("store {}", self.path.display()),
            source: Box::new(e),
        };
        let old = self.text()?;
        let text = self
            .format
            .render(&old, params, &self.path)
            .map_err(unwritable)?;
        let text = crate::io::keep_text_form(&old, &text);
        let content = self.format.parse(&text, &self.path).map_err(unwritable)?;
        Ok((text, content))
    }

    fn invalid(&self, reason: String) -> BaseError {
        BaseError::InvalidArgument {
            component: format!("store ({})", self.format.kind()),
            reason,
        }
    }

    /// Why `params` cannot be staged: not a robot, or refused by the format.
    fn check_params(&self, params: &WheelParams) -> Result<(), BaseError> {
        params.validate().map_err(|e| self.invalid(e.to_string()))?;
        let current = F::params(&self.content.read().unwrap_or_else(|p| p.into_inner()));
        match self.format.refuse(&current, params) {
            Some(why) => Err(self.invalid(why)),
            None => Ok(()),
        }
    }
}

#[async_trait]
impl<F: ParamFile> ParamStore for FileStore<F> {
    fn info(&self) -> ComponentInfo {
        self.format.info(&self.path)
    }

    async fn read(&self) -> Result<WheelParams, BaseError> {
        if let Some(p) = *lock(&self.staged) {
            return Ok(p);
        }
        Ok(F::params(&self.on_disk()?))
    }

    async fn write(&self, params: &WheelParams) -> Result<WheelParams, BaseError> {
        self.check_params(params)?;
        let (_, content) = self.rendered(params)?;
        let held = F::params(&content);
        *self.content.write().unwrap_or_else(|p| p.into_inner()) = content;
        *lock(&self.staged) = Some(held);
        Ok(held)
    }

    async fn commit(&self) -> Result<(), BaseError> {
        let Some(p) = *lock(&self.staged) else {
            return Ok(());
        };
        let (text, _) = self.rendered(&p)?;
        crate::io::replace_atomically(&self.path, &text).map_err(|e| self.err(e))?;
        *lock(&self.staged) = None;
        Ok(())
    }

    async fn read_committed(&self) -> Result<Option<WheelParams>, BaseError> {
        Ok(Some(F::params(&self.on_disk()?)))
    }

    fn resolution(&self) -> WheelParams {
        FILE_RESOLUTION
    }

    fn file(&self) -> Option<PathBuf> {
        Some(self.path.clone())
    }

    fn written_keys(&self) -> &'static [&'static str] {
        self.format.written_keys()
    }

    /// The dry merge: the file parses, `params` render into it and read back, and it can be
    /// replaced the way `commit` replaces it ([`crate::io::probe_replace`]: a temporary file
    /// in the directory of the file written, through a link its target's; a file the system
    /// forbids changing is found here, not after the robot has driven).
    async fn check_write(&self, params: &WheelParams) -> Result<(), BaseError> {
        self.check_params(params)?;
        self.rendered(params)?;
        let target = crate::io::write_target(&self.path);
        crate::io::probe_replace(&self.path).map_err(|e| BaseError::Unwritable {
            component: format!(
                "store {} (it cannot be replaced: a new file in {}, then a rename over {})",
                self.path.display(),
                crate::io::dir_of(&target).display(),
                target.display()
            ),
            source: Box::new(e),
        })
    }
}
