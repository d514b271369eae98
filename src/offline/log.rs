//! Recording logs (`odocal record`, `odocal track --record`): what a live session saw, to be
//! replayed by `odocal track --log`.
//!
//! Format (JSON lines): the first line is a [`LogHeader`] (`"type": "header"`); every following
//! line is a wheel travel sample (`"type": "travel"`, a [`TravelSample`]) or a heading reading
//! (`"type": "heading"`, a [`HeadingSample`]) of any base, in the order they arrived. Logs of
//! earlier versions hold our protocol's telemetry instead (`"type": "telemetry"`, a
//! [`TelemetryLine`], counts unwrapped by the host); they read the same way. The log's types
//! are its own: no backend's type is part of the format. Every line is
//! checked as it is read (time goes forward in each stream, no wheel faster than
//! [`MAX_WHEEL_SPEED_M_S`]) and a bad one is named by its line. A log reads as a [`Recording`].

use crate::base::BaseInfo;
use crate::calibration::pose_reference::ReferencePose;
use crate::calibration::recording::{Clocks, Event, HeadingSample, Recording, TravelSample};
use crate::kinematics::{WheelParams, MAX_WHEEL_SPEED_M_S};
use serde::{Deserialize, Serialize};
use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};

/// Errors reading or writing logs.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A line is not what the format says.
    #[error("{path}, line {line}: {reason}")]
    Malformed {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// What is wrong.
        reason: String,
    },
}

/// The first line of a log.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LogHeader {
    /// odocal version that wrote the log.
    pub odocal_version: String,
    /// The device, when it speaks our protocol: its HELLO answer as earlier versions logged it
    /// (kept as written; nothing is read from it).
    #[serde(default)]
    pub device: Option<serde_json::Value>,
    /// Parameters in use while recording (the wheel travel's conversion).
    pub params: WheelParams,
    /// Requested sample period (ms).
    pub period_ms: u64,
    /// The base's components, when the log was written from one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub base: Option<BaseInfo>,
    /// How the travel and heading streams' clocks relate.
    #[serde(default)]
    pub clocks: Clocks,
}

/// One telemetry sample of odocal's protocol, as earlier versions logged it (counts unwrapped
/// by the host). Fields the reading does not use (the motion state, the queue) are ignored.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TelemetryLine {
    /// Device sample index.
    pub sample_index: u32,
    /// Device time since the first sample seen (s), unwrapped.
    pub device_time_s: f64,
    /// Left encoder counts, unwrapped.
    pub left_counts: i64,
    /// Right encoder counts, unwrapped.
    pub right_counts: i64,
    /// Heading (rad), counter-clockwise positive.
    pub heading_rad: f64,
    /// Whether the heading may be used.
    pub heading_valid: bool,
}

impl TelemetryLine {
    /// The heading of this sample, on the device's clock.
    pub fn heading_sample(&self) -> HeadingSample {
        HeadingSample::flagged(self.device_time_s, self.heading_rad, self.heading_valid)
    }
}

#[derive(Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
enum LogLine {
    Header(Box<LogHeader>),
    Telemetry(TelemetryLine),
    Travel(TravelSample),
    Heading(HeadingSample),
    Pose(ReferencePose),
}

/// Writes a telemetry log.
pub struct LogWriter {
    path: PathBuf,
    out: std::io::BufWriter<std::fs::File>,
}

impl LogWriter {
    /// Creates `path` and writes the header.
    pub fn create(path: &Path, header: LogHeader) -> Result<Self, LogError> {
        let io = |source| LogError::Io {
            path: path.to_path_buf(),
            source,
        };
        let file = std::fs::File::create(path).map_err(io)?;
        let mut w = LogWriter {
            path: path.to_path_buf(),
            out: std::io::BufWriter::new(file),
        };
        w.line(&LogLine::Header(Box::new(header)))?;
        Ok(w)
    }

    fn line(&mut self, line: &LogLine) -> Result<(), LogError> {
        let text = serde_json::to_string(line).map_err(|e| LogError::Io {
            path: self.path.clone(),
            source: std::io::Error::other(e),
        })?;
        writeln!(self.out, "{text}").map_err(|source| LogError::Io {
            path: self.path.clone(),
            source,
        })
    }

    /// Appends one telemetry sample of our protocol (the format of earlier versions).
    pub fn sample(&mut self, s: &TelemetryLine) -> Result<(), LogError> {
        self.line(&LogLine::Telemetry(*s))
    }

    /// Appends a travel sample or a heading reading.
    pub fn event(&mut self, e: &Event) -> Result<(), LogError> {
        self.line(&match e {
            Event::Travel(t) => LogLine::Travel(*t),
            Event::Heading(h) => LogLine::Heading(h.clone()),
            Event::Pose(p) => LogLine::Pose(*p),
        })
    }

    /// Flushes to disk.
    pub fn flush(&mut self) -> Result<(), LogError> {
        self.out.flush().map_err(|source| LogError::Io {
            path: self.path.clone(),
            source,
        })
    }
}

/// Checks one logged sample against the one before: time goes forward, the sample index
/// increases, and neither wheel turned further than [`MAX_WHEEL_SPEED_M_S`] allows.
fn check_step(prev: &TelemetryLine, s: &TelemetryLine, params: &WheelParams) -> Result<(), String> {
    let dt = s.device_time_s - prev.device_time_s;
    if !(dt.is_finite() && dt > 0.0) {
        return Err(format!(
            "device time {} s does not follow {} s (time must go forward; a reordered or \
             duplicated line?)",
            s.device_time_s, prev.device_time_s
        ));
    }
    if s.sample_index <= prev.sample_index
        && s.sample_index.wrapping_sub(prev.sample_index) > 1 << 31
    {
        return Err(format!(
            "sample index {} after {} (a reordered or duplicated line?)",
            s.sample_index, prev.sample_index
        ));
    }
    for (wheel, d, per_count) in [
        (
            "left",
            i128::from(s.left_counts) - i128::from(prev.left_counts),
            params.left_m_per_count(),
        ),
        (
            "right",
            i128::from(s.right_counts) - i128::from(prev.right_counts),
            params.right_m_per_count(),
        ),
    ] {
        let limit = MAX_WHEEL_SPEED_M_S * dt / per_count + 2.0;
        if (d as f64).abs() > limit {
            return Err(format!(
                "{wheel} wheel jumped {d} counts in {dt:.3} s, more than a wheel at {MAX_WHEEL_SPEED_M_S} m/s turns ({limit:.0})"
            ));
        }
    }
    Ok(())
}

/// Checks a travel sample against the one before on its stream: time goes forward and
/// neither wheel went further than [`MAX_WHEEL_SPEED_M_S`] allows.
fn check_travel(
    prev: Option<&TravelSample>,
    s: &TravelSample,
    params: &WheelParams,
) -> Result<(), String> {
    if !(s.time_s.is_finite() && s.left_m.is_finite() && s.right_m.is_finite()) {
        return Err(format!("travel sample {s:?} is not finite"));
    }
    let Some(prev) = prev else { return Ok(()) };
    let dt = s.time_s - prev.time_s;
    if dt.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return Err(format!(
            "travel time {} s does not follow {} s (time must go forward; a reordered or \
             duplicated line?)",
            s.time_s, prev.time_s
        ));
    }
    let limit =
        MAX_WHEEL_SPEED_M_S * dt + 2.0 * params.left_m_per_count().max(params.right_m_per_count());
    for (wheel, d) in [("left", s.left_m), ("right", s.right_m)] {
        if d.abs() > limit {
            return Err(format!(
                "{wheel} wheel went {d} m in {dt:.3} s, more than a wheel at \
                 {MAX_WHEEL_SPEED_M_S} m/s goes ({limit:.3} m)"
            ));
        }
    }
    Ok(())
}

/// Checks a heading reading against the one before on its stream: time goes forward (equal
/// stamps are allowed: a sensor may repeat a reading) and a valid heading is a number.
fn check_heading(prev: Option<&HeadingSample>, s: &HeadingSample) -> Result<(), String> {
    if !s.time_s.is_finite() {
        return Err(format!("heading time {} is not a time", s.time_s));
    }
    if s.validity.is_valid() && !s.heading_rad.is_finite() {
        return Err(format!("a valid heading of {} rad", s.heading_rad));
    }
    match prev {
        Some(p) if s.time_s < p.time_s => Err(format!(
            "heading time {} s does not follow {} s (time must go forward)",
            s.time_s, p.time_s
        )),
        _ => Ok(()),
    }
}

/// Reads a log as its header and its [`Recording`].
pub fn read_log(path: &Path) -> Result<(LogHeader, Recording), LogError> {
    let file =
        crate::io::open_bounded(path, crate::io::MAX_DATA_FILE).map_err(|source| LogError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    let mut header: Option<LogHeader> = None;
    let mut recording = Recording::default();
    let mut last_telemetry: Option<TelemetryLine> = None;
    for (i, line) in std::io::BufReader::new(file).lines().enumerate() {
        let bad = |reason: String| LogError::Malformed {
            path: path.to_path_buf(),
            line: i + 1,
            reason,
        };
        let line = line.map_err(|e| bad(e.to_string()))?;
        if line.trim().is_empty() {
            continue;
        }
        let parsed = serde_json::from_str::<LogLine>(&line).map_err(|e| bad(e.to_string()))?;
        let h = match (&parsed, &header) {
            (LogLine::Header(h), None) if i == 0 => {
                h.params
                    .check_physical()
                    .map_err(|e| bad(format!("header parameters: {e}")))?;
                recording.clocks = h.clocks;
                header = Some((**h).clone());
                continue;
            }
            (LogLine::Header(_), _) => return Err(bad("a second header".into())),
            (_, None) => return Err(bad("a sample before the header line".into())),
            (_, Some(h)) => h,
        };
        match parsed {
            LogLine::Header(_) => {}
            LogLine::Telemetry(s) => {
                match &last_telemetry {
                    Some(prev) => check_step(prev, &s, &h.params).map_err(bad)?,
                    None if !s.device_time_s.is_finite() => {
                        return Err(bad(format!(
                            "device time {} is not a time",
                            s.device_time_s
                        )))
                    }
                    None => {}
                }
                let pair = [last_telemetry.unwrap_or(s), s];
                let one = recording_of(h, &pair);
                recording.travel.push(one.travel[1]);
                recording.headings.push(one.headings[1].clone());
                last_telemetry = Some(s);
            }
            LogLine::Travel(t) => {
                check_travel(recording.travel.last(), &t, &h.params).map_err(bad)?;
                recording.travel.push(t);
            }
            LogLine::Heading(r) => {
                check_heading(recording.headings.last(), &r).map_err(bad)?;
                recording.headings.push(r);
            }
            LogLine::Pose(p) => {
                check_pose(recording.poses.last(), &p).map_err(bad)?;
                recording.poses.push(p);
            }
        }
    }
    let header = header.ok_or_else(|| LogError::Malformed {
        path: path.to_path_buf(),
        line: 1,
        reason: "empty log (no header line)".into(),
    })?;
    Ok((header, recording))
}

/// A logged reference pose: finite, and not before the one before it.
fn check_pose(prev: Option<&ReferencePose>, p: &ReferencePose) -> Result<(), String> {
    let finite = p.time_s.is_finite()
        && p.x_m.is_finite()
        && p.y_m.is_finite()
        && p.yaw_rad.is_none_or(f64::is_finite);
    if !finite {
        return Err("a reference pose that is not a number".into());
    }
    if let Some(q) = prev {
        if p.time_s < q.time_s {
            return Err(format!(
                "reference pose at {} s before the one at {} s",
                p.time_s, q.time_s
            ));
        }
    }
    Ok(())
}

/// A telemetry log as a [`Recording`]: the count increments as wheel travel under the
/// header's parameters, the heading of each sample (marked invalid where the device said so),
/// both on the device's clock.
pub fn recording_of(header: &LogHeader, samples: &[TelemetryLine]) -> Recording {
    let mut travel = Vec::with_capacity(samples.len());
    let mut prev: Option<&TelemetryLine> = None;
    for s in samples {
        let (left_m, right_m) = match prev {
            Some(p) => header.params.travel_m(
                (s.left_counts - p.left_counts) as f64,
                (s.right_counts - p.right_counts) as f64,
            ),
            None => (0.0, 0.0),
        };
        travel.push(TravelSample {
            time_s: s.device_time_s,
            left_m,
            right_m,
        });
        prev = Some(s);
    }
    let headings = samples.iter().map(TelemetryLine::heading_sample).collect();
    Recording {
        travel,
        headings,
        clocks: Clocks::Shared,
        poses: Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::recording::Validity;

    /// A log's header for the tests: nominal 0.15 m wheels, 0.39 m wheelbase, 20 ms samples.
    fn test_header() -> LogHeader {
        LogHeader {
            odocal_version: "x".into(),
            device: None,
            params: WheelParams::nominal(0.15, 0.39, 4096.0),
            period_ms: 20,
            base: None,
            clocks: Clocks::Shared,
        }
    }

    #[test]
    fn logs_round_trip_and_bad_lines_are_named() {
        let dir = std::env::temp_dir().join(format!("odocal-log-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.jsonl");
        let header = test_header();
        let sample = TelemetryLine {
            sample_index: 7,
            device_time_s: 0.14,
            left_counts: 5_000_000_000,
            right_counts: -3,
            heading_rad: 0.5,
            heading_valid: true,
        };
        let mut w = LogWriter::create(&path, header.clone()).unwrap();
        w.sample(&sample).unwrap();
        w.flush().unwrap();
        drop(w);
        let (h, rec) = read_log(&path).unwrap();
        assert_eq!(h, header);
        assert_eq!(rec, recording_of(&header, &[sample]));
        let mut text = std::fs::read_to_string(&path).unwrap();
        text.push_str("{\"type\": \"telemetry\", \"sample_index\": \"x\"}\n");
        std::fs::write(&path, text).unwrap();
        match read_log(&path) {
            Err(LogError::Malformed { line, .. }) => assert_eq!(line, 3),
            other => panic!("expected a malformed line 3, got {other:?}"),
        }
        std::fs::write(&path, "").unwrap();
        assert!(matches!(
            read_log(&path),
            Err(LogError::Malformed { line: 1, .. })
        ));
        // Samples of any base: travel and heading lines, as they arrived.
        let mut w = LogWriter::create(&path, header.clone()).unwrap();
        let events = [
            Event::Heading(HeadingSample {
                time_s: 0.1,
                heading_rad: 0.5,
                validity: Validity::Valid,
            }),
            Event::Travel(TravelSample {
                time_s: 0.12,
                left_m: 0.01,
                right_m: 0.011,
            }),
            Event::Heading(HeadingSample {
                time_s: 0.2,
                heading_rad: 0.0,
                validity: Validity::Invalid("magnetic disturbance".into()),
            }),
        ];
        for e in &events {
            w.event(e).unwrap();
        }
        w.flush().unwrap();
        drop(w);
        let (_, rec) = read_log(&path).unwrap();
        assert_eq!(rec.travel.len(), 1);
        assert_eq!(rec.headings.len(), 2);
        assert_eq!(
            rec.headings[1].validity,
            Validity::Invalid("magnetic disturbance".into())
        );
        // A session with a pose reference: its poses come back as they were written, with
        // and without a stated covariance or a yaw; one stamped back in time is named.
        let poses = [
            ReferencePose {
                time_s: 0.1,
                x_m: 5.0,
                y_m: -3.0,
                yaw_rad: Some(1.0),
                stated_std: Some([0.003, 0.003, 0.005]),
            },
            ReferencePose {
                time_s: 0.2,
                x_m: 5.01,
                y_m: -3.0,
                yaw_rad: None,
                stated_std: None,
            },
        ];
        let mut w = LogWriter::create(&path, header.clone()).unwrap();
        for p in &poses {
            w.event(&Event::Pose(*p)).unwrap();
        }
        w.event(&Event::Pose(ReferencePose {
            time_s: 0.15,
            ..poses[0]
        }))
        .unwrap();
        w.flush().unwrap();
        drop(w);
        match read_log(&path) {
            Err(LogError::Malformed { line, reason, .. }) => {
                assert_eq!(line, 4);
                assert!(reason.contains("before the one at 0.2 s"), "{reason}");
            }
            other => panic!("expected a malformed line 4, got {other:?}"),
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let kept: Vec<&str> = text.lines().take(3).collect();
        std::fs::write(&path, kept.join("\n") + "\n").unwrap();
        let (_, rec) = read_log(&path).unwrap();
        assert_eq!(rec.poses, poses.to_vec());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn time_going_backwards_duplicates_and_impossible_jumps_are_named_by_line() {
        let dir = std::env::temp_dir().join(format!("odocal-log-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.jsonl");
        let header = test_header();
        let sample = |i: u32, t: f64, l: i64| TelemetryLine {
            sample_index: i,
            device_time_s: t,
            left_counts: l,
            right_counts: l,
            heading_rad: 0.0,
            heading_valid: true,
        };
        let write = |samples: &[TelemetryLine]| {
            let mut w = LogWriter::create(&path, header.clone()).unwrap();
            for s in samples {
                w.sample(s).unwrap();
            }
            w.flush().unwrap();
        };
        let line_of = |r: Result<(LogHeader, Recording), LogError>| match r {
            Err(LogError::Malformed { line, reason, .. }) => (line, reason),
            other => panic!("expected a malformed line, got {other:?}"),
        };
        // 0.5 m/s for 20 ms is ~87 counts: fine. Then time goes back on line 4.
        write(&[
            sample(1, 0.02, 0),
            sample(2, 0.04, 87),
            sample(3, 0.03, 174),
        ]);
        let (line, reason) = line_of(read_log(&path));
        assert_eq!(line, 4, "{reason}");
        assert!(reason.contains("time must go forward"), "{reason}");
        // A duplicated line.
        write(&[sample(1, 0.02, 0), sample(1, 0.02, 0)]);
        assert_eq!(line_of(read_log(&path)).0, 3);
        // A jump of 10^17 counts in one sample.
        write(&[sample(1, 0.02, 0), sample(2, 0.04, 100_000_000_000_000_000)]);
        let (line, reason) = line_of(read_log(&path));
        assert!(line == 3 && reason.contains("jumped"), "{line}: {reason}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
