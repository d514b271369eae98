//! Tracking sessions for the online estimator: feeding it live telemetry, recorded telemetry
//! logs (`odocal record`) or recorded data sets, with periodic checkpoints of its estimate.
//!
//! Recorded input is checked for a constant clock offset between the encoder counts and the
//! heading ([`crate::calibration::time_offset`]) before it is fed, one run at a time; an offset
//! above [`crate::calibration::time_offset::WARN_ABOVE_S`] is corrected (the heading re-read at the shifted time)
//! and reported in [`Tracker::time_offsets`]. Live telemetry cannot be re-read, so a live
//! session checks its whole stream at the end ([`Tracker::check_time_offset`]) and only reports.
//!
//! Log format (JSON lines): the first line is a [`LogHeader`] (`"type": "header"`), every
//! following line one [`TelemetrySample`] (`"type": "telemetry"`), counts unwrapped by the host.

use crate::calibration::online::{OnlineConfig, OnlineEstimate, OnlineEstimator, ScaleSource};
use crate::calibration::time_offset::{estimate_time_offset, shift_heading, TimeOffset};
use crate::calibration::CalibrationError;
use crate::dataset::OptiOdomSet;
use crate::hal::TelemetrySample;
use crate::kinematics::{WheelParams, MAX_WHEEL_SPEED_M_S};
use crate::protocol::message::DeviceInfo;
use serde::{Deserialize, Serialize};
use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};

/// Errors reading or writing telemetry logs.
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

/// The first line of a telemetry log.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LogHeader {
    /// odocal version that wrote the log.
    pub odocal_version: String,
    /// The device.
    pub device: Option<DeviceInfo>,
    /// Parameters active on the controller while recording (the counts' conversion).
    pub params: WheelParams,
    /// Telemetry period (ms).
    pub period_ms: u64,
}

#[derive(Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
enum LogLine {
    Header(LogHeader),
    Telemetry(TelemetrySample),
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
        w.line(&LogLine::Header(header))?;
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

    /// Appends one sample.
    pub fn sample(&mut self, s: &TelemetrySample) -> Result<(), LogError> {
        self.line(&LogLine::Telemetry(*s))
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
fn check_step(
    prev: &TelemetrySample,
    s: &TelemetrySample,
    params: &WheelParams,
) -> Result<(), String> {
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

/// Reads a telemetry log.
pub fn read_log(path: &Path) -> Result<(LogHeader, Vec<TelemetrySample>), LogError> {
    let file = crate::base::files::open_bounded(path, crate::base::files::MAX_DATA_FILE).map_err(
        |source| LogError::Io {
            path: path.to_path_buf(),
            source,
        },
    )?;
    let mut header = None;
    let mut samples = Vec::new();
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
        match serde_json::from_str::<LogLine>(&line).map_err(|e| bad(e.to_string()))? {
            LogLine::Header(h) if i == 0 => {
                h.params
                    .check_physical()
                    .map_err(|e| bad(format!("header parameters: {e}")))?;
                header = Some(h)
            }
            LogLine::Header(_) => return Err(bad("a second header".into())),
            LogLine::Telemetry(_) if header.is_none() => {
                return Err(bad("telemetry before the header line".into()))
            }
            LogLine::Telemetry(s) => {
                if let (Some(prev), Some(h)) = (samples.last(), header.as_ref()) {
                    check_step(prev, &s, &h.params).map_err(bad)?;
                } else if !s.device_time_s.is_finite() {
                    return Err(bad(format!(
                        "device time {} is not a time",
                        s.device_time_s
                    )));
                }
                samples.push(s);
            }
        }
    }
    let header = header.ok_or_else(|| LogError::Malformed {
        path: path.to_path_buf(),
        line: 1,
        reason: "empty log (no header line)".into(),
    })?;
    Ok((header, samples))
}

/// Least driving (m) before the online filter reports an estimate.
pub const MIN_DISTANCE_M: f64 = 0.5;

/// Largest clock offset searched for (s).
pub const MAX_TIME_OFFSET_S: f64 = 1.0;

/// A time offset found in one run of recorded input.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunTimeOffset {
    /// The run (file name, "log", "live").
    pub run: String,
    /// What was found.
    pub offset: TimeOffset,
    /// Whether the heading was re-read at the shifted time before it was fed.
    pub corrected: bool,
}

/// The online estimator with checkpoints every `every_m` metres driven.
pub struct Tracker {
    filter: OnlineEstimator,
    scale: ScaleSource,
    last_counts: Option<(i64, i64)>,
    every_m: f64,
    next_m: f64,
    /// Estimates taken at each checkpoint.
    pub checkpoints: Vec<OnlineEstimate>,
    /// Clock offsets found between the encoder and heading streams, per run checked.
    pub time_offsets: Vec<RunTimeOffset>,
}

impl Tracker {
    /// A tracker over a fresh filter.
    pub fn new(
        cfg: OnlineConfig,
        scale: ScaleSource,
        every_m: f64,
    ) -> Result<Self, CalibrationError> {
        Ok(Tracker {
            filter: OnlineEstimator::new(cfg)?,
            scale,
            last_counts: None,
            every_m: every_m.max(0.01),
            next_m: every_m.max(0.01),
            checkpoints: Vec::new(),
            time_offsets: Vec::new(),
        })
    }

    /// The filter.
    pub fn filter(&self) -> &OnlineEstimator {
        &self.filter
    }

    /// The current estimate.
    ///
    /// Input with no driving or no heading readings has nothing to estimate from: that is
    /// [`CalibrationError::TooLittleData`], not the prior dressed up as a result.
    pub fn estimate(&self) -> Result<OnlineEstimate, CalibrationError> {
        let (_, heading_updates) = self.filter.nis_mean();
        let distance_m = self.filter.distance_m();
        if heading_updates < 2 || distance_m < MIN_DISTANCE_M {
            return Err(CalibrationError::TooLittleData {
                distance_m,
                heading_updates,
            });
        }
        self.filter.estimate(self.scale)
    }

    fn maybe_checkpoint(&mut self) -> Option<OnlineEstimate> {
        if self.filter.distance_m() >= self.next_m {
            // The next multiple of `every_m` past the distance, in one step: a loop adding
            // `every_m` would run for ever once the distance is beyond float resolution.
            let d = self.filter.distance_m();
            self.next_m = ((d / self.every_m).floor() + 1.0) * self.every_m;
            if self.next_m.partial_cmp(&d) != Some(std::cmp::Ordering::Greater) {
                self.next_m = f64::INFINITY;
            }
            if let Ok(e) = self.estimate() {
                self.checkpoints.push(e);
                return Some(e);
            }
        }
        None
    }

    /// Feeds one live or logged telemetry sample; returns a checkpoint when one is due.
    pub fn feed_sample(&mut self, s: &TelemetrySample) -> Option<OnlineEstimate> {
        if let Some((l, r)) = self.last_counts {
            self.filter
                .predict_counts((s.left_counts - l) as f64, (s.right_counts - r) as f64);
        }
        self.last_counts = Some((s.left_counts, s.right_counts));
        if s.heading_valid {
            self.filter.update_heading(s.heading_rad);
        }
        self.maybe_checkpoint()
    }

    /// Feeds a whole recorded telemetry log: checked for a clock offset first, corrected if
    /// it is significant; returns the checkpoints passed.
    pub fn feed_log(&mut self, samples: &[TelemetrySample]) -> Vec<OnlineEstimate> {
        let heading: Vec<Option<f64>> = samples
            .iter()
            .map(|s| s.heading_valid.then_some(s.heading_rad))
            .collect();
        let (times, odo) = self.series(samples);
        let heading = self.correct("log", &times, &odo, heading);
        let mut out = Vec::new();
        for (s, h) in samples.iter().zip(heading) {
            let fed = TelemetrySample {
                heading_rad: h.unwrap_or(f64::NAN),
                heading_valid: h.is_some(),
                ..*s
            };
            out.extend(self.feed_sample(&fed));
        }
        out
    }

    /// Checks a telemetry stream (live, already fed) for a clock offset and records it
    /// uncorrected; returns it when one could be estimated.
    pub fn check_time_offset(
        &mut self,
        run: &str,
        samples: &[TelemetrySample],
    ) -> Option<TimeOffset> {
        let (times, odo) = self.series(samples);
        let heading: Vec<Option<f64>> = samples
            .iter()
            .map(|s| s.heading_valid.then_some(s.heading_rad))
            .collect();
        let offset = estimate_time_offset(&times, &odo, &heading, MAX_TIME_OFFSET_S)?;
        self.time_offsets.push(RunTimeOffset {
            run: run.into(),
            offset,
            corrected: false,
        });
        Some(offset)
    }

    /// Times and odometry turn per sample (configured parameters) of a telemetry stream.
    fn series(&self, samples: &[TelemetrySample]) -> (Vec<f64>, Vec<f64>) {
        let c = &self.filter.config().configured;
        let times = samples.iter().map(|s| s.device_time_s).collect();
        let odo = std::iter::once(0.0)
            .chain(samples.windows(2).map(|w| {
                let dl = (w[1].left_counts - w[0].left_counts) as f64 * c.left_m_per_count();
                let dr = (w[1].right_counts - w[0].right_counts) as f64 * c.right_m_per_count();
                (dr - dl) / c.wheelbase_m
            }))
            .take(samples.len())
            .collect();
        (times, odo)
    }

    fn correct(
        &mut self,
        run: &str,
        times: &[f64],
        odo: &[f64],
        heading: Vec<Option<f64>>,
    ) -> Vec<Option<f64>> {
        let Some(offset) = estimate_time_offset(times, odo, &heading, MAX_TIME_OFFSET_S) else {
            return heading;
        };
        let corrected = offset.significant();
        self.time_offsets.push(RunTimeOffset {
            run: run.into(),
            offset,
            corrected,
        });
        if corrected {
            shift_heading(times, &heading, offset.offset_s)
        } else {
            heading
        }
    }

    /// Feeds every run of a recorded set (ground-truth heading as the compass), restarting the
    /// pose at each run, each run checked for a clock offset first and corrected if it is
    /// significant; returns the checkpoints passed.
    pub fn feed_dataset(&mut self, set: &OptiOdomSet) -> Vec<OnlineEstimate> {
        let mut out = Vec::new();
        let c = self.filter.config().configured;
        for run in &set.runs {
            self.filter.restart_pose();
            self.last_counts = None;
            let times: Vec<f64> = run.samples.iter().map(|s| s.time_s).collect();
            let odo: Vec<f64> = run
                .samples
                .iter()
                .map(|s| {
                    (s.right_counts * c.right_m_per_count() - s.left_counts * c.left_m_per_count())
                        / c.wheelbase_m
                })
                .collect();
            let heading = run
                .samples
                .iter()
                .map(|s| Some(s.truth.heading_rad))
                .collect();
            let heading = self.correct(&run.name, &times, &odo, heading);
            for (s, h) in run.samples.iter().zip(heading) {
                self.filter.predict_counts(s.left_counts, s.right_counts);
                if let Some(h) = h {
                    self.filter.update_heading(h);
                }
                out.extend(self.maybe_checkpoint());
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::message::MotionState;

    #[test]
    fn logs_round_trip_and_bad_lines_are_named() {
        let dir = std::env::temp_dir().join(format!("odocal-log-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.jsonl");
        let header = LogHeader {
            odocal_version: "x".into(),
            device: None,
            params: WheelParams::nominal(0.15, 0.39, 4096.0),
            period_ms: 20,
        };
        let sample = TelemetrySample {
            sample_index: 7,
            device_time_s: 0.14,
            left_counts: 5_000_000_000,
            right_counts: -3,
            heading_rad: 0.5,
            heading_valid: true,
            motion_state: MotionState::Moving,
            queue_depth: 1,
            dropped_before: 0,
        };
        let mut w = LogWriter::create(&path, header.clone()).unwrap();
        w.sample(&sample).unwrap();
        w.flush().unwrap();
        drop(w);
        let (h, s) = read_log(&path).unwrap();
        assert_eq!((h, s), (header, vec![sample]));
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
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn time_going_backwards_duplicates_and_impossible_jumps_are_named_by_line() {
        let dir = std::env::temp_dir().join(format!("odocal-log-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.jsonl");
        let header = LogHeader {
            odocal_version: "x".into(),
            device: None,
            params: WheelParams::nominal(0.15, 0.39, 4096.0),
            period_ms: 20,
        };
        let sample = |i: u32, t: f64, l: i64| TelemetrySample {
            sample_index: i,
            device_time_s: t,
            left_counts: l,
            right_counts: l,
            heading_rad: 0.0,
            heading_valid: true,
            motion_state: MotionState::Moving,
            queue_depth: 0,
            dropped_before: 0,
        };
        let write = |samples: &[TelemetrySample]| {
            let mut w = LogWriter::create(&path, header.clone()).unwrap();
            for s in samples {
                w.sample(s).unwrap();
            }
            w.flush().unwrap();
        };
        let line_of = |r: Result<(LogHeader, Vec<TelemetrySample>), LogError>| match r {
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
