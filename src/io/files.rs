//! Files: bounded reads (only regular files, never more than a kind's bound), atomic
//! replacement that keeps a file's permissions, files created new (never replacing one, never
//! following a link), and backup copies beside a file.

use std::io::Write as _;
use std::path::{Path, PathBuf};

/// The file a write to `path` changes: what a symbolic link at `path` names, through every
/// link (`colcon build --symlink-install` links installed files to the sources: replacing the
/// link would leave the sources as they were); `path` itself otherwise, or when the link names
/// nothing.
pub fn write_target(path: &Path) -> PathBuf {
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => {
            std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf())
        }
        _ => path.to_path_buf(),
    }
}

/// Proves that `path` can be replaced the way [`replace_atomically`] replaces it, before
/// anything depends on it: a new file can be created (and removed) in the directory of the
/// file written ([`write_target`]), and the file, if it exists, is not one the system forbids
/// changing (immutable or append-only: `chattr +i`, `+a`), which a rename over it would only
/// find at the end.
pub fn probe_replace(path: &Path) -> std::io::Result<()> {
    let target = write_target(path);
    probe_dir(dir_of(&target))?;
    if target.exists() {
        // Opened to write, never written. EPERM (1 on every Unix) is the immutable or
        // append-only file; EACCES, a mode without write permission, does not stop a rename.
        if let Err(e) = std::fs::OpenOptions::new().write(true).open(&target) {
            if e.raw_os_error() == Some(1) {
                return Err(e);
            }
        }
    }
    Ok(())
}

/// `new` with the line endings, final newline and byte-order mark of `old`, the text it
/// replaces: a file written with CRLF on every line stays so (a writer that renders with LF
/// would change every line), one without a final newline keeps none.
pub fn keep_text_form(old: &str, new: &str) -> String {
    let crlf = old.contains("\r\n") && old.matches('\n').count() == old.matches("\r\n").count();
    let mut out = if crlf {
        new.replace("\r\n", "\n").replace('\n', "\r\n")
    } else {
        new.to_string()
    };
    let eol = if crlf { "\r\n" } else { "\n" };
    if !old.is_empty() && !old.ends_with('\n') {
        while out.ends_with('\n') {
            out.truncate(out.len() - 1);
            if out.ends_with('\r') {
                out.truncate(out.len() - 1);
            }
        }
    } else if old.ends_with('\n') && !out.ends_with('\n') {
        out.push_str(eol);
    }
    if old.starts_with('\u{feff}') && !out.starts_with('\u{feff}') {
        out.insert(0, '\u{feff}');
    }
    out
}

/// Writes `text` to `path` atomically (a temporary file in the same directory, synced, renamed
/// over it), keeping the file's permissions. Through a symbolic link, the file it names is
/// replaced and the link stays ([`write_target`]).
pub fn replace_atomically(path: &Path, text: &str) -> std::io::Result<()> {
    let target = write_target(path);
    let path = target.as_path();
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
/// file needs, checked before anything depends on it (for a replacement: [`probe_replace`]).
pub fn probe_dir(dir: &Path) -> std::io::Result<()> {
    // Unique within the process too: threads probe the same directory at once.
    static PROBES: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = PROBES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let probe = dir.join(format!(".odocal-write-check-{}-{n}", std::process::id()));
    create_new(&probe, b"")?;
    std::fs::remove_file(&probe)
}

/// The time now in UTC, ISO 8601 to the second: `2026-11-25T14:03:07Z`.
pub fn utc_time() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    utc_time_of(secs)
}

/// The time now in UTC as a file name may carry it: `2026-11-25T14-03-07Z` ([`utc_time`] with
/// `-` for `:`, which some file systems refuse), so that names sort by time.
pub fn utc_stamp() -> String {
    utc_time().replace(':', "-")
}

/// [`utc_time`] of `secs` seconds after the Unix epoch.
pub fn utc_time_of(secs: u64) -> String {
    let (days, rest) = (secs / 86_400, secs % 86_400);
    // Days to a proleptic Gregorian date: H. Hinnant's `civil_from_days`, for days ≥ 0.
    let z = days + 719_468;
    let era = z / 146_097;
    let doe = z % 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + u64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        rest / 3600,
        rest % 3600 / 60,
        rest % 60
    )
}

/// Creates `path` new with `bytes`, synced: never replaces a file and never follows a link
/// (`O_CREAT | O_EXCL`).
pub fn create_new(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)?;
    let written = f.write_all(bytes).and_then(|()| f.sync_all());
    if written.is_err() {
        // A full disk must not leave an empty or cut-off file that reads as a backup.
        drop(f);
        let _ = std::fs::remove_file(path);
    }
    written
}

/// Creates the first free one of `name(0)`, `name(1)`, … (up to 1000) with `bytes`
/// ([`create_new`]); returns its path. For backups and reports that must never overwrite one
/// another, even when two are made in the same second.
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

/// Creates `<dir>/<prefix><UTC time><suffix>` new with `bytes` ([`utc_stamp`]), or, when a
/// file of that name exists (two in one second), `…<UTC time>-2<suffix>`, `-3`, …; returns
/// its path. Never replaces a file or follows a link.
pub fn create_stamped(
    dir: &Path,
    prefix: &str,
    suffix: &str,
    bytes: &[u8],
) -> std::io::Result<PathBuf> {
    let stamp = utc_stamp();
    create_unique(
        |n| {
            dir.join(match n {
                0 => format!("{prefix}{stamp}{suffix}"),
                n => format!("{prefix}{stamp}-{}{suffix}", n + 1),
            })
        },
        bytes,
    )
}

/// The name of the file `path` names, for names built on it (`robot.toml` →
/// `robot.toml.odocal-backup-…`).
pub fn file_name_of(path: &Path) -> String {
    path.file_name()
        .map_or_else(|| "file".into(), |n| n.to_string_lossy().into_owned())
}

/// Proves, creating nothing that stays, that `dir` could take new files: it is a directory
/// that takes a new file, or it does not exist yet and its nearest existing ancestor is such a
/// directory (where it would be created). Declining a run then leaves no directory behind.
pub fn probe_dir_to_be(dir: &Path) -> std::io::Result<()> {
    let mut at = dir;
    loop {
        match std::fs::metadata(at) {
            Ok(m) if m.is_dir() => return probe_dir(at),
            Ok(_) => {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::NotADirectory,
                    format!("{} exists and is not a directory", at.display()),
                ))
            }
            // Up to the nearest ancestor that exists; a bare name is in `.`.
            Err(e) if e.kind() == std::io::ErrorKind::NotFound && at != Path::new(".") => {
                at = dir_of(at);
            }
            Err(e) => return Err(e),
        }
    }
}

/// A directory for one run's files: `dir` (created if needed) when it holds none of `taken`
/// (not even as a link), else the first of `dir-2`, `dir-3`, … that can be created new. An
/// earlier run's directory is never written into.
pub fn fresh_dir(dir: &Path, taken: &[&str]) -> std::io::Result<PathBuf> {
    let holds = |d: &Path| {
        taken
            .iter()
            .any(|f| std::fs::symlink_metadata(d.join(f)).is_ok())
    };
    if !dir.exists() {
        std::fs::create_dir_all(dir)?;
        return Ok(dir.to_path_buf());
    }
    if dir.is_dir() && !holds(dir) {
        return Ok(dir.to_path_buf());
    }
    let name = dir
        .file_name()
        .map_or_else(|| "report".into(), |n| n.to_string_lossy().into_owned());
    for n in 2..10_000 {
        let candidate = dir.with_file_name(format!("{name}-{n}"));
        match std::fs::create_dir(&candidate) {
            Ok(()) => return Ok(candidate),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
    Err(std::io::Error::new(
        std::io::ErrorKind::AlreadyExists,
        format!("{}: no free directory name", dir.display()),
    ))
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rewritten_text_keeps_its_line_endings_final_newline_and_mark() {
        let new = "a: 1\nb: 2\n";
        assert_eq!(keep_text_form("a: 0\r\nb: 2\r\n", new), "a: 1\r\nb: 2\r\n");
        assert_eq!(keep_text_form("a: 0\r\nb: 2", new), "a: 1\r\nb: 2");
        assert_eq!(keep_text_form("a: 0\nb: 2", new), "a: 1\nb: 2");
        assert_eq!(keep_text_form("a: 0\nb: 2\n", "a: 1\nb: 2"), "a: 1\nb: 2\n");
        assert_eq!(
            keep_text_form("\u{feff}a: 0\n", new),
            "\u{feff}a: 1\nb: 2\n"
        );
        // Mixed endings: the writer's text as it is.
        assert_eq!(keep_text_form("a: 0\r\nb: 2\n", new), new);
        // A spliced text that kept some CRLF comes out CRLF throughout.
        assert_eq!(keep_text_form("a\r\n", "a\r\nb\n"), "a\r\nb\r\n");
    }

    #[test]
    fn a_replacement_through_a_link_changes_what_it_names() {
        let dir = std::env::temp_dir().join(format!("odocal-link-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let target = dir.join("real.yaml");
        std::fs::write(&target, "old").unwrap();
        let link = dir.join("link.yaml");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        assert_eq!(write_target(&link), std::fs::canonicalize(&target).unwrap());
        probe_replace(&link).unwrap();
        replace_atomically(&link, "new").unwrap();
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "new");
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn utc_stamps_are_calendar_dates_that_sort() {
        // Checked against `date -u -d @SECS +%FT%TZ`.
        assert_eq!(utc_time_of(0), "1970-01-01T00:00:00Z");
        assert_eq!(utc_time_of(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(utc_time_of(1_709_251_199), "2024-02-29T23:59:59Z");
        assert_eq!(utc_time_of(1_795_611_787), "2026-11-25T13:03:07Z");
        assert_eq!(utc_time_of(4_102_444_800), "2100-01-01T00:00:00Z");
        assert!(utc_time_of(1_795_611_787) < utc_time_of(1_795_611_788));
        assert!(!utc_stamp().contains(':'), "{}", utc_stamp());
    }

    #[test]
    fn stamped_files_never_replace_one_another() {
        let dir = std::env::temp_dir().join(format!("odocal-stamped-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let a = create_stamped(&dir, "x.", ".json", b"1").unwrap();
        let b = create_stamped(&dir, "x.", ".json", b"2").unwrap();
        assert_ne!(a, b);
        assert_eq!(std::fs::read(&a).unwrap(), b"1");
        let name = file_name_of(&b);
        assert!(name.starts_with("x.") && name.ends_with(".json"), "{name}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_directory_to_be_is_probed_without_being_made() {
        let base = std::env::temp_dir().join(format!("odocal-to-be-{}", std::process::id()));
        std::fs::create_dir_all(&base).unwrap();
        let deep = base.join("a/b/c");
        probe_dir_to_be(&deep).unwrap();
        assert!(!base.join("a").exists(), "nothing was created");
        assert_eq!(std::fs::read_dir(&base).unwrap().count(), 0);
        let file = base.join("f");
        std::fs::write(&file, "x").unwrap();
        assert!(probe_dir_to_be(&file.join("d")).is_err());
        assert!(probe_dir_to_be(&file).is_err());
        std::fs::remove_dir_all(&base).unwrap();
    }
}
