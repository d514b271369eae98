//! Tracking sessions for the online estimator: feeding it live telemetry, recorded telemetry
//! logs (`odocal record`) or recorded data sets, with periodic checkpoints of its estimate.
//!
//! Log format (JSON lines): the first line is a [`LogHeader`] (`"type": "header"`), every
//! following line one [`TelemetrySample`] (`"type": "telemetry"`), counts unwrapped by the host.

use crate::calibration::online::{OnlineConfig, OnlineEstimate, OnlineEstimator, ScaleSource};
use crate::calibration::CalibrationError;
use crate::dataset::OptiOdomSet;
use crate::hal::TelemetrySample;
use crate::kinematics::WheelParams;
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

/// Reads a telemetry log.
pub fn read_log(path: &Path) -> Result<(LogHeader, Vec<TelemetrySample>), LogError> {
    let file = std::fs::File::open(path).map_err(|source| LogError::Io {
        path: path.to_path_buf(),
        source,
    })?;
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
            LogLine::Header(h) if i == 0 => header = Some(h),
            LogLine::Header(_) => return Err(bad("a second header".into())),
            LogLine::Telemetry(_) if header.is_none() => {
                return Err(bad("telemetry before the header line".into()))
            }
            LogLine::Telemetry(s) => samples.push(s),
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

/// The online estimator with checkpoints every `every_m` metres driven.
pub struct Tracker {
    filter: OnlineEstimator,
    scale: ScaleSource,
    last_counts: Option<(i64, i64)>,
    every_m: f64,
    next_m: f64,
    /// Estimates taken at each checkpoint.
    pub checkpoints: Vec<OnlineEstimate>,
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
            while self.next_m <= self.filter.distance_m() {
                self.next_m += self.every_m;
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

    /// Feeds every run of a recorded set (ground-truth heading as the compass), restarting the
    /// pose at each run; returns the checkpoints passed.
    pub fn feed_dataset(&mut self, set: &OptiOdomSet) -> Vec<OnlineEstimate> {
        let mut out = Vec::new();
        for run in &set.runs {
            self.filter.restart_pose();
            self.last_counts = None;
            for s in &run.samples {
                self.filter.predict_counts(s.left_counts, s.right_counts);
                self.filter.update_heading(s.truth.heading_rad);
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
}
