//! Safe writes for file-backed parameter stores: a backup copy beside the file, created
//! exclusively, and an atomic replacement that keeps the file's permissions.

use crate::kinematics::WheelParams;
use std::io::Write as _;
use std::path::{Path, PathBuf};

/// Writes `text` to `path` atomically (a temporary file in the same directory, synced, renamed
/// over it), keeping the file's permissions.
pub fn replace_atomically(path: &Path, text: &str) -> std::io::Result<()> {
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.odocal-tmp-{}", std::process::id()));
    let perms = std::fs::metadata(path).ok().map(|m| m.permissions());
    let result = (|| {
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)?;
        f.write_all(text.as_bytes())?;
        f.sync_all()?;
        if let Some(p) = perms {
            std::fs::set_permissions(&tmp, p)?;
        }
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Copies `path` to a new `<path>.odocal-backup-<ms>[-n]` beside it, never overwriting.
pub fn backup_beside(path: &Path) -> std::io::Result<PathBuf> {
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis());
    let text = std::fs::read(path)?;
    for n in 0..1000 {
        let mut name = path.as_os_str().to_owned();
        name.push(if n == 0 {
            format!(".odocal-backup-{stamp}")
        } else {
            format!(".odocal-backup-{stamp}-{n}")
        });
        let candidate = PathBuf::from(name);
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&candidate)
        {
            Ok(mut f) => {
                f.write_all(&text)?;
                f.sync_all()?;
                return Ok(candidate);
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
    Err(std::io::Error::new(
        std::io::ErrorKind::AlreadyExists,
        "1000 backups with one time stamp",
    ))
}

/// Reads a text file of at most `max_bytes` (configuration files are small; a device node or a
/// huge file is refused rather than read until memory runs out).
pub fn read_bounded(path: &Path, max_bytes: u64) -> std::io::Result<String> {
    let len = std::fs::metadata(path)?.len();
    if len > max_bytes {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("{len} bytes is more than the {max_bytes} a configuration file may have"),
        ));
    }
    let mut text = String::new();
    std::io::Read::read_to_string(
        &mut std::io::Read::take(std::fs::File::open(path)?, max_bytes + 1),
        &mut text,
    )?;
    Ok(text)
}

/// What a file store written with odocal's text formats resolves: values are written with
/// at least ten significant decimals, far below a nanometre at robot sizes.
pub const FILE_RESOLUTION: WheelParams = WheelParams {
    left_wheel_diameter_m: 1e-9,
    right_wheel_diameter_m: 1e-9,
    wheelbase_m: 1e-9,
    counts_per_wheel_rev: 1e-9,
};
