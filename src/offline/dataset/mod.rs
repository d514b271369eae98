//! Recorded runs with ground truth: the OptiOdom data set's reader, its conversion to a
//! calibration input, and replay evaluation of parameter sets against the ground truth.
//!
//! Format (see the data set's README): `<id>_metadata.csv` holds `key,values…` rows (`ngear`,
//! `encRes`, `Li` wheelbase, `Di` wheel diameters, `L` square side); each `<id>_run-NN.csv` has
//! no header and one row per 0.05 s: `time_s, x_m, y_m, theta_rad, ticks_right, ticks_left`,
//! the pose relative to the run's start and the ticks as per-cycle increments.
//!
//! A recorded square becomes calibration input like this: the ground-truth heading plays the
//! compass, and a run's heading error is `wrap(Δθ_truth − Δθ_odometry)`, the odometry being the
//! recorded encoder increments integrated with the set's configured parameters. For a perfect
//! open-loop controller `Δθ_odometry` is exactly ±2π and this is the plain final heading error;
//! a real controller misses its wheel targets slightly, and subtracting what the wheels really
//! did removes that execution error from the calibration. Final positions likewise are ground
//! truth minus odometry, in the start frame.

use crate::calibration::legs::LegMeasurement;
use crate::calibration::online::OnlineEstimate;
use crate::calibration::pool::{
    pool_methods, Pooled, PooledMethods, RecordingEstimates, UncertaintyKind,
};
use crate::calibration::pose_reference::{Geometry, PoseRecording, ReferencePose, WheelAngles};
use crate::calibration::recording::{Clocks, HeadingSample, Recording, TravelSample, Validity};
use crate::calibration::tracker::Tracker;
use crate::calibration::{self, Estimate, Method, RunMeasurement, SquareTest};
use crate::kinematics::{
    wrap_angle, Direction, Pose, SplitConvention, WheelParams, MAX_WHEEL_SPEED_M_S,
};
use serde::Serialize;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

mod evaluation;
mod read;

pub use evaluation::*;
use read::*;

/// Errors reading or using a recorded data set.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A file or directory could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A CSV row is malformed.
    #[error("{path}, line {line}: {reason}")]
    Malformed {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// What is wrong.
        reason: String,
    },
    /// The metadata lacks a key or has an unusable value for it.
    #[error("{path}: metadata key {key}: {reason}")]
    Metadata {
        /// The metadata file.
        path: PathBuf,
        /// The key.
        key: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The directory holds no metadata file or no runs.
    #[error("{0}: not an OptiOdom set (needs one *_metadata.csv and *_run-NN.csv files)")]
    NotASet(PathBuf),
    /// A set pooled with others was recorded with another nominal geometry than the first.
    #[error(
        "{0} was recorded with another nominal geometry than the first set; pool sets recorded \
         with one configuration"
    )]
    OtherGeometry(String),
    /// Sets were to be pooled, but none was given.
    #[error("no data set given")]
    NoSets,
    /// Square calibration was asked of a set without a side length.
    #[error("{0}: no square side `L` in the metadata; not a square set")]
    NotASquareSet(String),
    /// A run's direction cannot be told from its ground truth.
    #[error(
        "{set} run {run}: ground truth turns {turn_deg:.1}°, not about ±360°; not a square run"
    )]
    NotASquareRun {
        /// The set id.
        set: String,
        /// The run's file name.
        run: String,
        /// Total ground-truth turn.
        turn_deg: f64,
    },
    /// The runs cannot be calibrated.
    #[error(transparent)]
    Calibration(#[from] calibration::CalibrationError),
    /// Parameters written back would be impossible.
    #[error(transparent)]
    Kinematics(#[from] crate::kinematics::KinematicsError),
}

/// One recorded sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Time since the run started (s).
    pub time_s: f64,
    /// Ground-truth pose relative to the run's start.
    pub truth: Pose,
    /// Right encoder counts during this cycle.
    pub right_counts: f64,
    /// Left encoder counts during this cycle.
    pub left_counts: f64,
}

/// One recorded run.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedRun {
    /// File name, e.g. `231220200040_run-01.csv`.
    pub name: String,
    /// Samples in time order.
    pub samples: Vec<Sample>,
}

/// Where a run ended by ground truth and by odometry, both relative to its start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunEnd {
    /// Ground-truth final pose.
    pub truth: Pose,
    /// Unwrapped ground-truth total turn (rad).
    pub truth_turn_rad: f64,
    /// Odometry final pose.
    pub odometry: Pose,
    /// Unwrapped odometry total turn (rad).
    pub odometry_turn_rad: f64,
}

impl RecordedRun {
    /// The run as a [`Recording`]: the encoder increments as wheel travel under `params` (the
    /// first row's, from before the run started, left out) and the ground-truth heading as the
    /// heading stream, both on the run's clock.
    pub fn recording(&self, params: &WheelParams) -> Recording {
        let travel = self
            .samples
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let (left_m, right_m) = if i == 0 {
                    (0.0, 0.0)
                } else {
                    params.travel_m(s.left_counts, s.right_counts)
                };
                TravelSample {
                    time_s: s.time_s,
                    left_m,
                    right_m,
                }
            })
            .collect();
        let headings = self
            .samples
            .iter()
            .map(|s| HeadingSample {
                time_s: s.time_s,
                heading_rad: s.truth.heading_rad,
                validity: Validity::Valid,
            })
            .collect();
        Recording {
            travel,
            headings,
            clocks: Clocks::Shared,
            poses: Vec::new(),
        }
    }

    /// The heading along the legs ([`crate::calibration::legs`]): ground-truth heading minus
    /// odometry heading (configured `params`), middle of the first leg to the middle of the
    /// last; `None` unless the odometry finds exactly four legs.
    pub fn leg_measurement(&self, params: &WheelParams) -> Option<LegMeasurement> {
        self.recording(params)
            .track(params.wheelbase_m)
            .leg_measurement(params.wheelbase_m)
    }

    /// The run as a drive with a pose reference: the encoder increments summed into cumulative
    /// wheel rotations (`ticks · 2π / counts_per_wheel_rev`, starting at 0 on the first row,
    /// whose increment from before the run started is left out as in [`Self::recording`]) and
    /// the ground-truth poses (yaw as recorded, wrapped), both at every row's time.
    pub fn pose_recording(&self, counts_per_wheel_rev: f64) -> PoseRecording {
        let rad_per_count = 2.0 * PI / counts_per_wheel_rev;
        // Counts are summed before scaling: whole numbers add exactly.
        let (mut left, mut right) = (0.0, 0.0);
        let wheels = self
            .samples
            .iter()
            .enumerate()
            .map(|(i, s)| {
                if i > 0 {
                    left += s.left_counts;
                    right += s.right_counts;
                }
                WheelAngles {
                    time_s: s.time_s,
                    left_rad: left * rad_per_count,
                    right_rad: right * rad_per_count,
                }
            })
            .collect();
        let poses = self
            .samples
            .iter()
            .map(|s| ReferencePose {
                time_s: s.time_s,
                x_m: s.truth.x_m,
                y_m: s.truth.y_m,
                yaw_rad: Some(s.truth.heading_rad),
                stated_std: None,
            })
            .collect();
        PoseRecording { wheels, poses }
    }

    /// Integrates the run's encoder increments with `params` and reports both final poses.
    pub fn replay(&self, params: &WheelParams) -> RunEnd {
        let mut odo = Pose::default();
        let mut odo_turn = 0.0;
        let mut truth_turn = 0.0;
        let mut prev_heading = self.samples.first().map_or(0.0, |s| s.truth.heading_rad);
        for s in self.samples.iter().skip(1) {
            let next = params.odometry_step(&odo, s.left_counts, s.right_counts);
            odo_turn += wrap_angle(next.heading_rad - odo.heading_rad);
            odo = next;
            truth_turn += wrap_angle(s.truth.heading_rad - prev_heading);
            prev_heading = s.truth.heading_rad;
        }
        let start = self.samples.first().map_or(Pose::default(), |s| s.truth);
        let truth = self
            .samples
            .last()
            .map_or(Pose::default(), |s| s.truth.relative_to(&start));
        RunEnd {
            truth,
            truth_turn_rad: truth_turn,
            odometry: odo,
            odometry_turn_rad: odo_turn,
        }
    }
}

/// One OptiOdom set: configured parameters, optional square side, runs.
#[derive(Debug, Clone, PartialEq)]
pub struct OptiOdomSet {
    /// The set's id (its directory name).
    pub id: String,
    /// Parameters the robot's controller used (the metadata's nominal values).
    pub configured: WheelParams,
    /// Square side (m) for square sets.
    pub side_m: Option<f64>,
    /// The runs, in file-name order.
    pub runs: Vec<RecordedRun>,
}

impl OptiOdomSet {
    /// The set's runs as one continuous recording on one clock, one sample per control cycle:
    /// the wheel travel the controller counted (under [`Self::configured`]) and the
    /// motion-capture heading, with `rest_s` of stillness before and after every run. Each
    /// run's ground truth starts at its own origin: the heading continues from where the
    /// previous run ended, so the headings are one continuous sensor's.
    pub fn to_recording(&self, rest_s: f64) -> Recording {
        let mut rec = Recording {
            clocks: Clocks::Shared,
            ..Recording::default()
        };
        let mut t = 0.0;
        let push = |rec: &mut Recording, t: f64, (left_m, right_m): (f64, f64), yaw: f64| {
            rec.travel.push(TravelSample {
                time_s: t,
                left_m,
                right_m,
            });
            rec.headings.push(HeadingSample {
                time_s: t,
                heading_rad: wrap_angle(yaw),
                validity: Validity::Valid,
            });
        };
        let still = (rest_s / CYCLE_S).round() as u64;
        let mut heading_offset = 0.0;
        for run in &self.runs {
            let first = run.samples.first().map_or(0.0, |s| s.truth.heading_rad);
            let mut yaw = heading_offset + first;
            for _ in 0..still {
                t += CYCLE_S;
                push(&mut rec, t, (0.0, 0.0), yaw);
            }
            let mut prev = first;
            for s in run.samples.iter().skip(1) {
                yaw += wrap_angle(s.truth.heading_rad - prev);
                prev = s.truth.heading_rad;
                t += CYCLE_S;
                let travel = self.configured.travel_m(s.left_counts, s.right_counts);
                push(&mut rec, t, travel, yaw);
            }
            heading_offset = yaw - first;
            for _ in 0..still {
                t += CYCLE_S;
                push(&mut rec, t, (0.0, 0.0), yaw);
            }
        }
        rec
    }
}

impl OptiOdomSet {
    /// Every run as a drive with a pose reference ([`RecordedRun::pose_recording`] with the
    /// set's counts per wheel revolution), in run order, each named `<set id> <run file>`.
    pub fn pose_recordings(&self) -> Vec<(String, PoseRecording)> {
        self.runs
            .iter()
            .map(|run| {
                (
                    format!("{} {}", self.id, run.name),
                    run.pose_recording(self.configured.counts_per_wheel_rev),
                )
            })
            .collect()
    }

    /// Feeds every run to `tracker`, each as a run of its own (the ground-truth heading plays
    /// the compass); returns the checkpoints passed.
    pub fn feed(&self, tracker: &mut Tracker) -> Vec<OnlineEstimate> {
        self.runs
            .iter()
            .flat_map(|run| tracker.feed_recording(&run.name, &run.recording(&self.configured)))
            .collect()
    }

    /// The set as a bi-directional square test (direction told from the ground-truth turn).
    pub fn square_test(&self) -> Result<SquareTest, DatasetError> {
        let side_m = self
            .side_m
            .ok_or_else(|| DatasetError::NotASquareSet(self.id.clone()))?;
        let mut runs = Vec::with_capacity(self.runs.len());
        for run in &self.runs {
            let end = run.replay(&self.configured);
            let Some(direction) = Direction::of_square_turn(end.truth_turn_rad, 0.5 * PI) else {
                return Err(DatasetError::NotASquareRun {
                    set: self.id.clone(),
                    run: run.name.clone(),
                    turn_deg: end.truth_turn_rad.to_degrees(),
                });
            };
            let track = run
                .recording(&self.configured)
                .track(self.configured.wheelbase_m);
            let odometry = track.odometry_in(0..track.points.len());
            let legs = track.leg_measurement(self.configured.wheelbase_m);
            let m = RunMeasurement {
                heading_error_rad: wrap_angle(end.truth_turn_rad - end.odometry_turn_rad),
                final_xy_m: Some([
                    end.truth.x_m - end.odometry.x_m,
                    end.truth.y_m - end.odometry.y_m,
                ]),
                odometry: Some(odometry),
                legs,
                noise_variance_rad2: None,
            };
            runs.push((direction, m));
        }
        let test = SquareTest::from_runs(side_m, self.configured.wheelbase_m, runs);
        Ok(test)
    }
}

/// The drives of data sets of one robot in one configuration, pooled, and that configuration's
/// geometry (the sets' metadata; sets recorded with another are refused).
pub fn pool_pose_recordings(
    dirs: &[PathBuf],
) -> Result<(Vec<(String, PoseRecording)>, Geometry), DatasetError> {
    let mut recordings = Vec::new();
    let mut nominal = None;
    for dir in dirs {
        let set = OptiOdomSet::load(dir)?;
        let g = Geometry::from(&set.configured);
        if nominal.is_some_and(|n| n != g) {
            return Err(DatasetError::OtherGeometry(set.id));
        }
        nominal = Some(g);
        recordings.extend(set.pose_recordings());
    }
    let nominal = nominal.ok_or(DatasetError::NoSets)?;
    Ok((recordings, nominal))
}

/// Where the OptiOdom data set lives: `$ODOCAL_OPTIODOM`, else `../shared/datasets/optiodom`
/// beside this crate.
pub fn default_optiodom_root() -> PathBuf {
    std::env::var_os("ODOCAL_OPTIODOM")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/datasets/optiodom")
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::pose_reference::{Geometry, Odometry};

    /// The free-path set, or `None` (with a notice) when the data is missing outside CI.
    fn free_set() -> Option<OptiOdomSet> {
        let dir = default_optiodom_root().join("free/030120210001");
        if !dir.is_dir() {
            assert!(
                std::env::var_os("CI").is_none(),
                "OptiOdom data set missing at {} (set ODOCAL_OPTIODOM); CI must have ../shared",
                dir.display()
            );
            eprintln!(
                "NOTICE: skipping, OptiOdom data not found at {}",
                dir.display()
            );
            return None;
        }
        Some(OptiOdomSet::load(&dir).expect("the free-path set loads"))
    }

    fn path_length(points: impl Iterator<Item = (f64, f64)>) -> f64 {
        let mut points = points.peekable();
        let mut length = 0.0;
        while let (Some(a), Some(b)) = (points.next(), points.peek()) {
            length += (b.0 - a.0).hypot(b.1 - a.1);
        }
        length
    }

    #[test]
    fn a_free_run_becomes_a_pose_recording_whose_dead_reckoning_matches_the_path_length() {
        let Some(set) = free_set() else { return };
        let recordings = set.pose_recordings();
        assert_eq!(recordings.len(), set.runs.len());
        let rec = &recordings[0].1;
        assert_eq!(rec.wheels.len(), rec.poses.len());
        assert_eq!(rec.wheels.len(), set.runs[0].samples.len());
        assert!(rec.wheels.windows(2).all(|w| w[1].time_s > w[0].time_s));
        assert!(rec.has_yaw());
        let c = &set.configured;
        let odometry = Odometry::integrate(
            &rec.wheels,
            Geometry {
                left_diameter_m: c.left_wheel_diameter_m,
                right_diameter_m: c.right_wheel_diameter_m,
                wheelbase_m: c.wheelbase_m,
            },
        );
        let odo_len = path_length(odometry.poses().iter().map(|p| (p.x, p.y)));
        let truth_len = path_length(rec.poses.iter().map(|p| (p.x_m, p.y_m)));
        assert!(truth_len > 1.0, "ground-truth path {truth_len} m");
        let ratio = odo_len / truth_len;
        assert!(
            (0.9..=1.1).contains(&ratio),
            "odometry {odo_len:.3} m against ground truth {truth_len:.3} m"
        );
        // The same travel as the existing conversion to wheel travel.
        let travel = set.runs[0].recording(c).travel;
        let left_m: f64 = travel.iter().map(|t| t.left_m).sum();
        let last = rec.wheels[rec.wheels.len() - 1].left_rad * 0.5 * c.left_wheel_diameter_m;
        assert!(
            (left_m - last).abs() < 1e-9 * left_m.abs().max(1.0),
            "{left_m} vs {last}"
        );
    }
}
