//! The two CSV files of the `odocal fit` contract, read and written: the wheels
//! (`t_s,left_rad,right_rad`, cumulative wheel rotation in radians, forward positive) and the
//! reference poses (`t_s,x_m,y_m,yaw_rad`, the reference frame's pose in a fixed world frame,
//! with optional `x_std_m,y_std_m,yaw_std_rad`), each at any rate. This module owns the files'
//! format and its checks; what the rows mean is [`crate::calibration::pose_reference`]'s.
//!
//! Reading is lenient about form and strict about content. Columns are found by header name,
//! in any order, unknown columns ignored; fields are trimmed; a UTF-8 byte-order mark, CRLF line
//! ends, blank lines and lines starting with `#` are accepted. Every number must be finite,
//! times must strictly increase, a wheel may not turn faster than
//! [`MAX_WHEEL_RATE_RAD_S`] between rows (a corrupt row), an optional column is filled in every
//! row or in none, and a file needs at least two rows. Every refusal names the file, the
//! 1-based line and, where it applies, the column ([`PoseCsvError`]).
//!
//! The `yaw_rad` column may be absent or empty in every row: a position-only reference (GNSS).
//! The standard deviations `x_std_m`, `y_std_m` come together and fill
//! [`ReferencePose::stated_std`]; `yaw_std_rad` is needed where a yaw is given, and where none
//! is (or its cell is empty) the stated yaw deviation is infinite: there is no yaw to weight.
//!
//! Writing uses Rust's shortest exact formatting of `f64`, so a written file reads back to the
//! same values bit for bit.

use crate::calibration::pose_reference::{ReferencePose, WheelAngles};
use std::io::Read;
use std::path::Path;

/// The header of a wheels file (the required columns, in the order written).
pub const WHEELS_HEADER: &str = "t_s,left_rad,right_rad";

/// The header of a poses file (the columns written; `yaw_rad` may be absent on reading).
pub const POSES_HEADER: &str = "t_s,x_m,y_m,yaw_rad";

/// The header of a poses file with stated standard deviations.
pub const POSES_STD_HEADER: &str = "t_s,x_m,y_m,yaw_rad,x_std_m,y_std_m,yaw_std_rad";

/// Fastest wheel rotation believed between two rows (rad/s): about 19,000 rpm, far beyond any
/// robot wheel, so a faster one is a corrupt row, not motion.
pub const MAX_WHEEL_RATE_RAD_S: f64 = 2000.0;

/// Errors reading a wheels or poses file.
#[derive(Debug, thiserror::Error)]
pub enum PoseCsvError {
    /// The file (or reader) could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file's path, or the name given to a reader.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A required column is not in the header.
    #[error(
        "{path}: no column `{column}` in the header `{found}`; the header must name the \
         columns `{expected}` (any order, other columns ignored)"
    )]
    MissingColumn {
        /// The file's path, or the name given to a reader.
        path: String,
        /// The missing column.
        column: &'static str,
        /// The header line found (the first line that is neither blank nor a comment).
        found: String,
        /// The header expected.
        expected: &'static str,
    },
    /// A field is not a usable number.
    #[error("{path}, line {line}, column {column}: {text:?} is {reason}")]
    Malformed {
        /// The file's path, or the name given to a reader.
        path: String,
        /// 1-based line number.
        line: u64,
        /// The column.
        column: &'static str,
        /// The field's text.
        text: String,
        /// What is wrong: empty, not a number, not finite, not positive.
        reason: &'static str,
    },
    /// A field is not UTF-8 text.
    #[error("{path}, line {line}, column {column}: not UTF-8 text: {source}")]
    NotUtf8 {
        /// The file's path, or the name given to a reader.
        path: String,
        /// 1-based line number.
        line: u64,
        /// The column.
        column: &'static str,
        /// Where the bytes stop being UTF-8.
        source: std::str::Utf8Error,
    },
    /// A row's time does not come after the row before's (equal stamps included).
    #[error(
        "{path}, line {line}: time {time_s} s does not come after {previous_s} s on the row \
         before (times must strictly increase)"
    )]
    TimeNotIncreasing {
        /// The file's path, or the name given to a reader.
        path: String,
        /// 1-based line number of the later row.
        line: u64,
        /// The row before's time (s).
        previous_s: f64,
        /// This row's time (s).
        time_s: f64,
    },
    /// An optional column is empty in some rows and filled in others.
    #[error(
        "{path}, line {line}: column `{column}` is empty here but filled on line \
         {filled_line}; fill it in every row or leave it empty in every row"
    )]
    PartlyEmpty {
        /// The file's path, or the name given to a reader.
        path: String,
        /// The column.
        column: &'static str,
        /// 1-based line number of an empty cell.
        line: u64,
        /// 1-based line number of a filled cell.
        filled_line: u64,
    },
    /// Fewer than two data rows.
    #[error("{path}: {rows} data row(s); at least 2 are needed under the header `{expected}`")]
    TooFewRows {
        /// The file's path, or the name given to a reader.
        path: String,
        /// Data rows found.
        rows: usize,
        /// The header expected.
        expected: &'static str,
    },
    /// A wheel turns implausibly fast between two rows: a corrupt row.
    #[error(
        "{path}, line {line}: the {wheel} wheel turns {rate_rad_s:.6e} rad/s since the row \
         before, more than the {MAX_WHEEL_RATE_RAD_S} rad/s any wheel does (a corrupt row?)"
    )]
    WheelJump {
        /// The file's path, or the name given to a reader.
        path: String,
        /// 1-based line number of the later row.
        line: u64,
        /// `left` or `right`.
        wheel: &'static str,
        /// |Δangle| / Δt (rad/s).
        rate_rad_s: f64,
    },
    /// The CSV reader failed on the text (not expected for the in-memory text it is given).
    #[error("{path}, line {line}: {source}")]
    Csv {
        /// The file's path, or the name given to a reader.
        path: String,
        /// 1-based line number (approximate).
        line: u64,
        /// The CSV error.
        source: csv::Error,
    },
}

/// Reads a wheels file ([`WHEELS_HEADER`]).
pub fn read_wheels(path: &Path) -> Result<Vec<WheelAngles>, PoseCsvError> {
    wheels_from_reader(open(path)?, &path.display().to_string())
}

/// Reads a poses file ([`POSES_HEADER`], optionally with the columns of [`POSES_STD_HEADER`]).
pub fn read_poses(path: &Path) -> Result<Vec<ReferencePose>, PoseCsvError> {
    poses_from_reader(open(path)?, &path.display().to_string())
}

/// [`read_wheels`] from any reader; `name` stands for the file in errors.
pub fn wheels_from_reader(reader: impl Read, name: &str) -> Result<Vec<WheelAngles>, PoseCsvError> {
    let mut table = Table::new(reader, name, WHEELS_HEADER)?;
    let t = table.required("t_s", WHEELS_HEADER)?;
    let l = table.required("left_rad", WHEELS_HEADER)?;
    let r = table.required("right_rad", WHEELS_HEADER)?;
    let mut out: Vec<WheelAngles> = Vec::new();
    while let Some(line) = table.next_row()? {
        let w = WheelAngles {
            time_s: table.number(line, t, "t_s")?,
            left_rad: table.number(line, l, "left_rad")?,
            right_rad: table.number(line, r, "right_rad")?,
        };
        if let Some(prev) = out.last() {
            table.check_time(line, prev.time_s, w.time_s)?;
            let dt = w.time_s - prev.time_s;
            for (wheel, d) in [
                ("left", w.left_rad - prev.left_rad),
                ("right", w.right_rad - prev.right_rad),
            ] {
                let rate = d.abs() / dt;
                // NaN only when Δangle and Δt both overflow: refused too.
                if rate.is_nan() || rate > MAX_WHEEL_RATE_RAD_S {
                    return Err(PoseCsvError::WheelJump {
                        path: table.name.clone(),
                        line,
                        wheel,
                        rate_rad_s: rate,
                    });
                }
            }
        }
        out.push(w);
    }
    table.enough(out.len(), WHEELS_HEADER)?;
    Ok(out)
}

/// [`read_poses`] from any reader; `name` stands for the file in errors.
pub fn poses_from_reader(
    reader: impl Read,
    name: &str,
) -> Result<Vec<ReferencePose>, PoseCsvError> {
    let mut table = Table::new(reader, name, POSES_HEADER)?;
    let t = table.required("t_s", POSES_HEADER)?;
    let x = table.required("x_m", POSES_HEADER)?;
    let y = table.required("y_m", POSES_HEADER)?;
    let yaw = table.optional("yaw_rad");
    let x_std = table.optional("x_std_m");
    let y_std = table.optional("y_std_m");
    let yaw_std = table.optional("yaw_std_rad");
    // The position deviations come together; a yaw deviation alone fills nothing.
    let std_xy = match (x_std, y_std, yaw_std) {
        (Some(a), Some(b), _) => Some((a, b)),
        (None, None, None) => None,
        (None, _, _) => return Err(table.missing("x_std_m", POSES_STD_HEADER)),
        (Some(_), None, _) => return Err(table.missing("y_std_m", POSES_STD_HEADER)),
    };
    let mut out: Vec<ReferencePose> = Vec::new();
    let mut yaw_filled = Filled::new("yaw_rad");
    let mut std_filled = Filled::new("x_std_m");
    while let Some(line) = table.next_row()? {
        let time_s = table.number(line, t, "t_s")?;
        let yaw_rad = table.optional_number(line, yaw, "yaw_rad")?;
        yaw_filled.check(&table.name, line, yaw_rad.is_some())?;
        let stated_std = match std_xy {
            None => None,
            Some((a, b)) => {
                let sx = table.optional_std(line, Some(a), "x_std_m")?;
                std_filled.check(&table.name, line, sx.is_some())?;
                match sx {
                    None => None,
                    Some(sx) => {
                        let sy = table.std(line, b, "y_std_m")?;
                        let syaw = match (yaw_rad, yaw_std) {
                            (None, col) => table
                                .optional_std(line, col, "yaw_std_rad")?
                                .unwrap_or(f64::INFINITY),
                            (Some(_), Some(col)) => table.std(line, col, "yaw_std_rad")?,
                            (Some(_), None) => {
                                return Err(table.missing("yaw_std_rad", POSES_STD_HEADER))
                            }
                        };
                        Some([sx, sy, syaw])
                    }
                }
            }
        };
        let pose = ReferencePose {
            time_s,
            x_m: table.number(line, x, "x_m")?,
            y_m: table.number(line, y, "y_m")?,
            yaw_rad,
            stated_std,
        };
        if let Some(prev) = out.last() {
            table.check_time(line, prev.time_s, pose.time_s)?;
        }
        out.push(pose);
    }
    table.enough(out.len(), POSES_HEADER)?;
    Ok(out)
}

/// Writes a wheels file ([`wheels_to_csv`]), replacing any file at `path` atomically.
pub fn write_wheels(path: &Path, wheels: &[WheelAngles]) -> std::io::Result<()> {
    crate::io::replace_atomically(path, &wheels_to_csv(wheels))
}

/// Writes a poses file ([`poses_to_csv`]), replacing any file at `path` atomically.
pub fn write_poses(path: &Path, poses: &[ReferencePose]) -> std::io::Result<()> {
    crate::io::replace_atomically(path, &poses_to_csv(poses))
}

/// Writes a drive as `wheels.csv` and `poses.csv` (what `odocal fit --wheels --poses` reads)
/// into `dir`, which must not exist yet (it is created).
pub fn write_new_dir(
    dir: &Path,
    drive: &crate::calibration::pose_reference::PoseRecording,
) -> std::io::Result<()> {
    if dir.exists() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::AlreadyExists,
            format!(
                "{} exists; --write-csv writes a new directory (give another path)",
                dir.display()
            ),
        ));
    }
    std::fs::create_dir_all(dir)?;
    write_wheels(&dir.join("wheels.csv"), &drive.wheels)?;
    write_poses(&dir.join("poses.csv"), &drive.poses)
}

/// The text of a wheels file: [`WHEELS_HEADER`] and one row per sample, each number in
/// Rust's shortest exact form.
pub fn wheels_to_csv(wheels: &[WheelAngles]) -> String {
    let mut out = String::with_capacity(32 * (wheels.len() + 1));
    out.push_str(WHEELS_HEADER);
    out.push('\n');
    for w in wheels {
        out.push_str(&format!("{},{},{}\n", w.time_s, w.left_rad, w.right_rad));
    }
    out
}

/// The text of a poses file: [`POSES_HEADER`], or [`POSES_STD_HEADER`] when any pose states
/// deviations, and one row per pose, each number in Rust's shortest exact form. An absent yaw,
/// absent deviations and a yaw deviation that is not finite are written as empty cells. (A
/// reader refuses a column empty in some rows only: give every pose a yaw or none, and
/// deviations or none.)
pub fn poses_to_csv(poses: &[ReferencePose]) -> String {
    let with_std = poses.iter().any(|p| p.stated_std.is_some());
    let mut out = String::with_capacity(48 * (poses.len() + 1));
    out.push_str(if with_std {
        POSES_STD_HEADER
    } else {
        POSES_HEADER
    });
    out.push('\n');
    let cell = |v: Option<f64>| v.map(|v| v.to_string()).unwrap_or_default();
    for p in poses {
        out.push_str(&format!(
            "{},{},{},{}",
            p.time_s,
            p.x_m,
            p.y_m,
            cell(p.yaw_rad)
        ));
        if with_std {
            match p.stated_std {
                Some([sx, sy, syaw]) => out.push_str(&format!(
                    ",{sx},{sy},{}",
                    cell(Some(syaw).filter(|s| s.is_finite()))
                )),
                None => out.push_str(",,,"),
            }
        }
        out.push('\n');
    }
    out
}

fn open(path: &Path) -> Result<std::io::Take<std::fs::File>, PoseCsvError> {
    crate::io::open_bounded(path, crate::io::MAX_DATA_FILE).map_err(|source| PoseCsvError::Io {
        path: path.display().to_string(),
        source,
    })
}

/// Whether an optional column has been filled so far, to refuse one filled in some rows only.
struct Filled {
    column: &'static str,
    first: Option<(u64, bool)>,
}

impl Filled {
    fn new(column: &'static str) -> Self {
        Self {
            column,
            first: None,
        }
    }

    fn check(&mut self, path: &str, line: u64, filled: bool) -> Result<(), PoseCsvError> {
        match self.first {
            None => {
                self.first = Some((line, filled));
                Ok(())
            }
            Some((_, f)) if f == filled => Ok(()),
            Some((first, f)) => {
                let (line, filled_line) = if f { (line, first) } else { (first, line) };
                Err(PoseCsvError::PartlyEmpty {
                    path: path.to_string(),
                    column: self.column,
                    line,
                    filled_line,
                })
            }
        }
    }
}

/// A CSV text with its blank and comment lines removed, read row by row with each row's line
/// number in the original.
struct Table {
    name: String,
    reader: csv::Reader<std::io::Cursor<Vec<u8>>>,
    /// `(byte offset in the kept text, 1-based line in the original)` of every kept line.
    lines: Vec<(u64, u64)>,
    /// The header's names (lossily decoded, trimmed).
    names: Vec<String>,
    /// The header line as found, for messages.
    header: String,
    record: csv::ByteRecord,
}

impl Table {
    /// Reads all of `reader` and its header line; no header line is no rows under `expected`.
    fn new(
        mut reader: impl Read,
        name: &str,
        expected: &'static str,
    ) -> Result<Self, PoseCsvError> {
        let mut bytes = Vec::new();
        reader
            .read_to_end(&mut bytes)
            .map_err(|source| PoseCsvError::Io {
                path: name.to_string(),
                source,
            })?;
        let (text, lines) = kept_lines(bytes);
        let reader = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(std::io::Cursor::new(text));
        let mut table = Table {
            name: name.to_string(),
            reader,
            lines,
            names: Vec::new(),
            header: String::new(),
            record: csv::ByteRecord::new(),
        };
        if table.next_row()?.is_none() {
            return Err(PoseCsvError::TooFewRows {
                path: table.name,
                rows: 0,
                expected,
            });
        }
        table.names = table
            .record
            .iter()
            .map(|f| String::from_utf8_lossy(f).trim().to_string())
            .collect();
        table.header = table.names.join(",");
        Ok(table)
    }

    fn missing(&self, column: &'static str, expected: &'static str) -> PoseCsvError {
        PoseCsvError::MissingColumn {
            path: self.name.clone(),
            column,
            found: self.header.clone(),
            expected,
        }
    }

    fn optional(&self, column: &str) -> Option<usize> {
        self.names.iter().position(|n| n == column)
    }

    fn required(
        &self,
        column: &'static str,
        expected: &'static str,
    ) -> Result<usize, PoseCsvError> {
        self.optional(column)
            .ok_or_else(|| self.missing(column, expected))
    }

    /// Reads the next row; its line number, `None` at the end.
    fn next_row(&mut self) -> Result<Option<u64>, PoseCsvError> {
        let more = self.reader.read_byte_record(&mut self.record);
        let byte = self.record.position().map_or(0, |p| p.byte());
        let k = self.lines.partition_point(|(offset, _)| *offset <= byte);
        let line = self.lines[..k].last().map_or(1, |(_, line)| *line);
        match more {
            Ok(true) => Ok(Some(line)),
            Ok(false) => Ok(None),
            Err(source) => Err(PoseCsvError::Csv {
                path: self.name.clone(),
                line,
                source,
            }),
        }
    }

    /// The field of this row in column `index` (empty when the row is short), as text.
    fn text(&self, line: u64, index: usize, column: &'static str) -> Result<&str, PoseCsvError> {
        let bytes = self.record.get(index).unwrap_or(b"");
        std::str::from_utf8(bytes)
            .map(str::trim)
            .map_err(|source| PoseCsvError::NotUtf8 {
                path: self.name.clone(),
                line,
                column,
                source,
            })
    }

    fn malformed(
        &self,
        line: u64,
        column: &'static str,
        text: &str,
        reason: &'static str,
    ) -> PoseCsvError {
        PoseCsvError::Malformed {
            path: self.name.clone(),
            line,
            column,
            text: text.to_string(),
            reason,
        }
    }

    /// The finite number in column `index`, `None` when the cell is empty or the column absent.
    fn optional_number(
        &self,
        line: u64,
        index: Option<usize>,
        column: &'static str,
    ) -> Result<Option<f64>, PoseCsvError> {
        let Some(index) = index else { return Ok(None) };
        let text = self.text(line, index, column)?;
        if text.is_empty() {
            return Ok(None);
        }
        match text.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(Some(v)),
            Ok(_) => Err(self.malformed(line, column, text, "not finite")),
            Err(_) => Err(self.malformed(line, column, text, "not a number")),
        }
    }

    /// The finite number in column `index`, which must not be empty.
    fn number(&self, line: u64, index: usize, column: &'static str) -> Result<f64, PoseCsvError> {
        self.optional_number(line, Some(index), column)?
            .ok_or_else(|| self.malformed(line, column, "", "empty"))
    }

    /// A standard deviation (finite and positive), `None` when empty or absent.
    fn optional_std(
        &self,
        line: u64,
        index: Option<usize>,
        column: &'static str,
    ) -> Result<Option<f64>, PoseCsvError> {
        match self.optional_number(line, index, column)? {
            Some(v) if v <= 0.0 => {
                Err(self.malformed(line, column, &v.to_string(), "not positive"))
            }
            v => Ok(v),
        }
    }

    /// A standard deviation (finite and positive), which must not be empty.
    fn std(&self, line: u64, index: usize, column: &'static str) -> Result<f64, PoseCsvError> {
        self.optional_std(line, Some(index), column)?
            .ok_or_else(|| self.malformed(line, column, "", "empty"))
    }

    fn check_time(&self, line: u64, previous_s: f64, time_s: f64) -> Result<(), PoseCsvError> {
        if time_s > previous_s {
            Ok(())
        } else {
            Err(PoseCsvError::TimeNotIncreasing {
                path: self.name.clone(),
                line,
                previous_s,
                time_s,
            })
        }
    }

    fn enough(&self, rows: usize, expected: &'static str) -> Result<(), PoseCsvError> {
        if rows >= 2 {
            Ok(())
        } else {
            Err(PoseCsvError::TooFewRows {
                path: self.name.clone(),
                rows,
                expected,
            })
        }
    }
}

/// `bytes` without a leading UTF-8 byte-order mark, carriage returns at line ends, blank lines
/// and `#` comment lines (compacted in place), and where each kept line starts in the result
/// with its 1-based line number in the original.
fn kept_lines(mut bytes: Vec<u8>) -> (Vec<u8>, Vec<(u64, u64)>) {
    let mut read = if bytes.starts_with(b"\xef\xbb\xbf") {
        3
    } else {
        0
    };
    let mut write = 0;
    let mut line = 0u64;
    let mut lines = Vec::new();
    while read < bytes.len() {
        line += 1;
        let end = bytes[read..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |k| read + k);
        let next = (end + 1).min(bytes.len());
        let content_end = if end > read && bytes[end - 1] == b'\r' {
            end - 1
        } else {
            end
        };
        let trimmed = bytes[read..content_end].trim_ascii();
        if !(trimmed.is_empty() || trimmed.starts_with(b"#")) {
            lines.push((write as u64, line));
            bytes.copy_within(read..content_end, write);
            write += content_end - read;
            // `write` never passes `read`: the byte here was read already (or is past the end).
            if write < bytes.len() {
                bytes[write] = b'\n';
                write += 1;
            }
        }
        read = next;
    }
    bytes.truncate(write);
    (bytes, lines)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wheels(text: &[u8]) -> Result<Vec<WheelAngles>, PoseCsvError> {
        wheels_from_reader(text, "wheels.csv")
    }

    fn poses(text: &[u8]) -> Result<Vec<ReferencePose>, PoseCsvError> {
        poses_from_reader(text, "poses.csv")
    }

    fn pose(time_s: f64, x_m: f64, y_m: f64, yaw_rad: Option<f64>) -> ReferencePose {
        ReferencePose {
            time_s,
            x_m,
            y_m,
            yaw_rad,
            stated_std: None,
        }
    }

    #[test]
    fn wheels_and_poses_round_trip_exactly() {
        let w: Vec<WheelAngles> = (0..50)
            .map(|i| {
                let t = 1.7e9 + i as f64 * 0.010_000_000_3;
                WheelAngles {
                    time_s: t,
                    left_rad: (i as f64 * 0.1).sin() * 3.0 + 1e-17,
                    right_rad: -(i as f64 / 7.0),
                }
            })
            .collect();
        assert_eq!(wheels(wheels_to_csv(&w).as_bytes()).unwrap(), w);
        for yaw in [true, false] {
            let p: Vec<ReferencePose> = (0..20)
                .map(|i| {
                    let f = i as f64;
                    pose(
                        f / 3.0,
                        f.cos() * 1e3,
                        -f / 11.0,
                        yaw.then(|| f.sin() * 3.1),
                    )
                })
                .collect();
            assert_eq!(poses(poses_to_csv(&p).as_bytes()).unwrap(), p);
            let with_std: Vec<ReferencePose> = p
                .iter()
                .map(|p| ReferencePose {
                    stated_std: Some([0.01, 0.02, if yaw { 0.003 } else { f64::INFINITY }]),
                    ..*p
                })
                .collect();
            assert_eq!(poses(poses_to_csv(&with_std).as_bytes()).unwrap(), with_std);
        }
    }

    #[test]
    fn files_round_trip_through_the_file_functions() {
        let dir = std::env::temp_dir().join(format!("odocal-pose-csv-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let w = vec![
            WheelAngles {
                time_s: 0.0,
                left_rad: 0.0,
                right_rad: 0.0,
            },
            WheelAngles {
                time_s: 0.1,
                left_rad: 0.3,
                right_rad: 0.30000000000000004,
            },
        ];
        let p = vec![
            pose(0.0, 1.0, 2.0, Some(0.5)),
            pose(0.2, 1.1, 2.2, Some(-3.0)),
        ];
        write_wheels(&dir.join("w.csv"), &w).unwrap();
        write_poses(&dir.join("p.csv"), &p).unwrap();
        assert_eq!(read_wheels(&dir.join("w.csv")).unwrap(), w);
        assert_eq!(read_poses(&dir.join("p.csv")).unwrap(), p);
        let err = read_wheels(&dir.join("absent.csv")).unwrap_err();
        assert!(matches!(err, PoseCsvError::Io { .. }), "{err}");
        assert!(err.to_string().contains("absent.csv"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn columns_are_found_by_name_and_an_absent_or_empty_yaw_is_none() {
        let p = poses(b"y_m, note ,t_s,x_m\n2,a,0,1\n3,b,1,4\n").unwrap();
        assert_eq!(
            p,
            vec![pose(0.0, 1.0, 2.0, None), pose(1.0, 4.0, 3.0, None)]
        );
        let p = poses(b"t_s,x_m,y_m,yaw_rad\n0,1,2,\n1,4,3, \n").unwrap();
        assert_eq!(
            p,
            vec![pose(0.0, 1.0, 2.0, None), pose(1.0, 4.0, 3.0, None)]
        );
        let w = wheels(b"right_rad,t_s,left_rad,extra\n1,0,2\n3,0.5,4,x\n").unwrap();
        assert_eq!(
            w[1],
            WheelAngles {
                time_s: 0.5,
                left_rad: 4.0,
                right_rad: 3.0
            }
        );
    }

    #[test]
    fn std_columns_fill_stated_std() {
        let text = b"t_s,x_m,y_m,yaw_rad,x_std_m,y_std_m,yaw_std_rad\n\
                     0,0,0,0.1,0.01,0.02,0.03\n1,1,0,0.2,0.1,0.2,0.3\n";
        let p = poses(text).unwrap();
        assert_eq!(p[0].stated_std, Some([0.01, 0.02, 0.03]));
        assert_eq!(p[1].stated_std, Some([0.1, 0.2, 0.3]));
        // Position only (GNSS): no yaw, so no yaw deviation.
        let p = poses(b"t_s,x_m,y_m,x_std_m,y_std_m\n0,0,0,0.5,0.6\n1,1,0,0.5,0.7\n").unwrap();
        assert_eq!(p[1].stated_std, Some([0.5, 0.7, f64::INFINITY]));
        assert_eq!(p[1].yaw_rad, None);
        // A yaw needs its deviation.
        let err =
            poses(b"t_s,x_m,y_m,yaw_rad,x_std_m,y_std_m\n0,0,0,0,1,1\n1,1,0,0,1,1\n").unwrap_err();
        assert!(
            matches!(
                err,
                PoseCsvError::MissingColumn {
                    column: "yaw_std_rad",
                    ..
                }
            ),
            "{err}"
        );
        let err = poses(b"t_s,x_m,y_m,x_std_m\n0,0,0,1\n1,1,0,1\n").unwrap_err();
        assert!(
            matches!(
                err,
                PoseCsvError::MissingColumn {
                    column: "y_std_m",
                    ..
                }
            ),
            "{err}"
        );
        let err = poses(b"t_s,x_m,y_m,x_std_m,y_std_m\n0,0,0,1,1\n1,1,0,0,1\n").unwrap_err();
        assert!(
            matches!(
                err,
                PoseCsvError::Malformed {
                    line: 3,
                    column: "x_std_m",
                    reason: "not positive",
                    ..
                }
            ),
            "{err}"
        );
        let err = poses(b"t_s,x_m,y_m,x_std_m,y_std_m\n0,0,0,1,1\n1,1,0,,\n").unwrap_err();
        assert!(
            matches!(
                err,
                PoseCsvError::PartlyEmpty {
                    line: 3,
                    filled_line: 2,
                    column: "x_std_m",
                    ..
                }
            ),
            "{err}"
        );
    }

    #[test]
    fn a_missing_column_names_it_the_header_found_and_the_header_expected() {
        let err = wheels(b"t_s,left_rad,rigth_rad\n0,0,0\n1,0,0\n").unwrap_err();
        assert!(
            matches!(
                err,
                PoseCsvError::MissingColumn {
                    column: "right_rad",
                    ..
                }
            ),
            "{err}"
        );
        let msg = err.to_string();
        assert!(msg.contains("t_s,left_rad,rigth_rad"), "{msg}");
        assert!(msg.contains(WHEELS_HEADER), "{msg}");
        // No header at all: the first row is taken as one and lacks the names.
        let err = poses(b"0,1,2,3\n1,1,2,3\n").unwrap_err();
        assert!(
            matches!(err, PoseCsvError::MissingColumn { column: "t_s", .. }),
            "{err}"
        );
        assert!(err.to_string().contains(POSES_HEADER), "{err}");
    }

    #[test]
    fn a_malformed_field_names_line_column_text_and_reason() {
        let err = wheels(b"t_s,left_rad,right_rad\n0,0,0\n# note\n\n1,abc,0\n").unwrap_err();
        match &err {
            PoseCsvError::Malformed {
                line,
                column,
                text,
                reason,
                path,
            } => {
                assert_eq!(
                    (*line, *column, text.as_str(), *reason),
                    (5, "left_rad", "abc", "not a number")
                );
                assert_eq!(path, "wheels.csv");
            }
            other => panic!("{other}"),
        }
        assert!(err.to_string().contains("line 5"), "{err}");
        let err = wheels(b"t_s,left_rad,right_rad\n0,0,0\n1,0,inf\n").unwrap_err();
        assert!(
            matches!(
                err,
                PoseCsvError::Malformed {
                    line: 3,
                    column: "right_rad",
                    reason: "not finite",
                    ..
                }
            ),
            "{err}"
        );
        let err = poses(b"t_s,x_m,y_m\n0,0,0\n1,NaN,0\n").unwrap_err();
        assert!(
            matches!(
                err,
                PoseCsvError::Malformed {
                    line: 3,
                    reason: "not finite",
                    ..
                }
            ),
            "{err}"
        );
        // A short row: the missing field is empty.
        let err = wheels(b"t_s,left_rad,right_rad\n0,0,0\n1,0\n").unwrap_err();
        assert!(
            matches!(
                err,
                PoseCsvError::Malformed {
                    line: 3,
                    column: "right_rad",
                    reason: "empty",
                    ..
                }
            ),
            "{err}"
        );
    }

    #[test]
    fn time_must_strictly_increase() {
        let err = wheels(b"t_s,left_rad,right_rad\n0,0,0\n1,0,0\n0.5,0,0\n").unwrap_err();
        assert!(
            matches!(err, PoseCsvError::TimeNotIncreasing { line: 4, previous_s, time_s, .. }
                if previous_s == 1.0 && time_s == 0.5),
            "{err}"
        );
        let err = poses(b"t_s,x_m,y_m\n0,0,0\n1,0,0\n\n1,0,0\n").unwrap_err();
        assert!(
            matches!(err, PoseCsvError::TimeNotIncreasing { line: 5, .. }),
            "{err}"
        );
        assert!(err.to_string().contains("line 5"), "{err}");
    }

    #[test]
    fn a_yaw_column_partly_empty_is_refused_with_its_lines() {
        let err = poses(b"t_s,x_m,y_m,yaw_rad\n0,0,0,0.1\n1,0,0,0.2\n2,0,0,\n").unwrap_err();
        assert!(
            matches!(
                err,
                PoseCsvError::PartlyEmpty {
                    column: "yaw_rad",
                    line: 4,
                    filled_line: 2,
                    ..
                }
            ),
            "{err}"
        );
        let err = poses(b"t_s,x_m,y_m,yaw_rad\n0,0,0,\n1,0,0,0.2\n").unwrap_err();
        assert!(
            matches!(
                err,
                PoseCsvError::PartlyEmpty {
                    column: "yaw_rad",
                    line: 2,
                    filled_line: 3,
                    ..
                }
            ),
            "{err}"
        );
    }

    #[test]
    fn fewer_than_two_rows_are_refused() {
        for text in [
            &b""[..],
            b"t_s,left_rad,right_rad\n",
            b"t_s,left_rad,right_rad\n0,0,0\n# x\n",
        ] {
            let err = wheels(text).unwrap_err();
            assert!(matches!(err, PoseCsvError::TooFewRows { .. }), "{err}");
        }
        let err = poses(b"t_s,x_m,y_m\n0,0,0\n").unwrap_err();
        assert!(
            matches!(err, PoseCsvError::TooFewRows { rows: 1, .. }),
            "{err}"
        );
    }

    #[test]
    fn an_implausible_wheel_jump_is_a_corrupt_row() {
        // 2000 rad/s exactly passes; more does not.
        assert!(wheels(b"t_s,left_rad,right_rad\n0,0,0\n0.5,1000,-1000\n").is_ok());
        let err = wheels(b"t_s,left_rad,right_rad\n0,0,0\n0.01,0.1,0\n0.02,0.2,300\n").unwrap_err();
        match err {
            PoseCsvError::WheelJump {
                line,
                wheel,
                rate_rad_s,
                ..
            } => {
                assert_eq!((line, wheel), (4, "right"));
                assert!((rate_rad_s - 30_000.0).abs() < 1e-6, "{rate_rad_s}");
            }
            other => panic!("{other}"),
        }
    }

    #[test]
    fn bom_crlf_comments_blank_lines_and_whitespace_are_tolerated() {
        let text = b"\xef\xbb\xbf# recorded 2024\r\n t_s , left_rad , right_rad \r\n\r\n\
                     0, 1 ,2\r\n   \r\n# pause\r\n1,\t3,4\r\n2,5,6";
        let w = wheels(text).unwrap();
        assert_eq!(w.len(), 3);
        assert_eq!(
            w[2],
            WheelAngles {
                time_s: 2.0,
                left_rad: 5.0,
                right_rad: 6.0
            }
        );
        // Line numbers count the skipped lines.
        let mut bad = text.to_vec();
        bad.extend_from_slice(b"\r\n2,7,8\r\n");
        let err = wheels(&bad).unwrap_err();
        assert!(
            matches!(err, PoseCsvError::TimeNotIncreasing { line: 9, .. }),
            "{err}"
        );
    }

    #[test]
    fn a_byte_that_is_not_utf8_is_an_error_with_its_line() {
        let err = wheels(b"t_s,left_rad,right_rad\n0,0,0\n1,0\xff,0\n").unwrap_err();
        assert!(
            matches!(
                err,
                PoseCsvError::NotUtf8 {
                    line: 3,
                    column: "left_rad",
                    ..
                }
            ),
            "{err}"
        );
        // In a column nobody reads, or in a comment, it does no harm.
        let w = wheels(b"# \xfe\nt_s,left_rad,right_rad,note\n0,0,0,\xff\n1,0,0,x\n").unwrap();
        assert_eq!(w.len(), 2);
        // Garbage never panics.
        let junk: Vec<u8> = (0..=255u8).cycle().take(3000).collect();
        assert!(wheels(&junk).is_err());
        assert!(poses(&junk).is_err());
    }
}
