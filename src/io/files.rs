//! Files: bounded reads (only regular files, never more than a kind's bound), atomic
//! replacement that keeps a file's permissions, files created new (never replacing one, never
//! following a link), and backup copies beside a file.

use std::io::Write as _;
use std::path::{Path, PathBuf};

/// Writes `text` to `path` atomically (a temporary file in the same directory, synced, renamed
/// over it), keeping the file's permissions.
pub fn replace_atomically(path: &Path, text: &str) -> std::io::Result<()> {
    let dir = dir_of(path);
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

/// The directory a file is in (`.` for a bare name).
pub fn dir_of(path: &Path) -> &Path {
    path.parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// Proves that a new file can be created in `dir` (and removed again): what a backup beside a
/// file and an atomic replacement need, checked before anything depends on it.
pub fn probe_dir(dir: &Path) -> std::io::Result<()> {
    let probe = dir.join(format!(".odocal-write-check-{}", std::process::id()));
    create_new(&probe, b"")?;
    std::fs::remove_file(&probe)
}

/// Milliseconds since the Unix epoch, for file names that sort by time.
pub fn stamp_ms() -> u128 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis())
}

/// Creates `path` new with `bytes`, synced: never replaces a file and never follows a link
/// (`O_CREAT | O_EXCL`).
pub fn create_new(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)?;
    f.write_all(bytes)?;
    f.sync_all()
}

/// Creates the first free one of `name(0)`, `name(1)`, … (up to 1000) with `bytes`
/// ([`create_new`]); returns its path. For backups and reports that must never overwrite one
/// another, even when two are made in the same millisecond.
pub fn create_unique(name: impl Fn(u32) -> PathBuf, bytes: &[u8]) -> std::io::Result<PathBuf> {
    for n in 0..1000 {
        let candidate = name(n);
        match create_new(&candidate, bytes) {
            Ok(()) => return Ok(candidate),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
    Err(std::io::Error::new(
        std::io::ErrorKind::AlreadyExists,
        "1000 files with one time stamp",
    ))
}

/// Copies `path` to a new `<path>.odocal-backup-<ms>[-n]` beside it, never overwriting.
pub fn backup_beside(path: &Path) -> std::io::Result<PathBuf> {
    let stamp = stamp_ms();
    let text = read_bounded_bytes(path, super::MAX_TEXT_FILE)?;
    create_unique(
        |n| {
            let mut name = path.as_os_str().to_owned();
            name.push(if n == 0 {
                format!(".odocal-backup-{stamp}")
            } else {
                format!(".odocal-backup-{stamp}-{n}")
            });
            PathBuf::from(name)
        },
        &text,
    )
}

/// Opens a file to read at most `max_bytes` of it: only a regular file (a device node such as
/// `/dev/zero`, or a pipe, never ends; a symlink is followed to what it names and judged by
/// that) no larger than the bound, and reading stops at the bound even if the file grows.
pub fn open_bounded(path: &Path, max_bytes: u64) -> std::io::Result<std::io::Take<std::fs::File>> {
    // Judged before opening: opening a FIFO would block until a writer came.
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a regular file (a device or a pipe may never end)",
        ));
    }
    if meta.len() > max_bytes {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "{} bytes is more than the {max_bytes} this file may have",
                meta.len()
            ),
        ));
    }
    Ok(std::io::Read::take(std::fs::File::open(path)?, max_bytes))
}

/// Reads a file of at most `max_bytes` ([`open_bounded`]): a device node or a huge file is
/// refused rather than read until memory runs out.
pub fn read_bounded_bytes(path: &Path, max_bytes: u64) -> std::io::Result<Vec<u8>> {
    let mut bytes = Vec::new();
    std::io::Read::read_to_end(&mut open_bounded(path, max_bytes)?, &mut bytes)?;
    Ok(bytes)
}

/// [`read_bounded_bytes`] for a text file (configuration files, backups and reports are
/// small); text that is not UTF-8 is an `InvalidData` error.
pub fn read_bounded(path: &Path, max_bytes: u64) -> std::io::Result<String> {
    String::from_utf8(read_bounded_bytes(path, max_bytes)?)
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))
}
