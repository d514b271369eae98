//! `odocal track` without a robot: a recorded session replayed through the online filter — a
//! log of `odocal record` (a session with a pose reference replays as one), a recorded OptiOdom
//! set (its ground-truth heading plays the compass), or `odocal fit`'s wheels and poses files
//! with the configured geometry. Each gives the fed tracker and the parameters the recording's
//! travel was converted with; the checkpoints' estimates go to the caller as they come.

use super::dataset::{DatasetError, OptiOdomSet};
use super::log::{read_log, LogError};
use super::pose_csv::{read_poses, read_wheels, PoseCsvError};
use crate::calibration::online::{OnlineEstimate, ScaleSource};
use crate::calibration::pose_reference::{Geometry, PoseRecording};
use crate::calibration::recording::Recording;
use crate::calibration::tracker::{Tracker, TrackerSettings};
use crate::calibration::CalibrationError;
use crate::kinematics::WheelParams;
use std::path::Path;

/// Why a recording could not be replayed.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The log could not be read.
    #[error(transparent)]
    Log(#[from] LogError),
    /// The data set could not be read.
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    /// A wheels or poses file could not be read.
    #[error(transparent)]
    PoseCsv(#[from] PoseCsvError),
    /// The filter refused its settings.
    #[error(transparent)]
    Calibration(#[from] CalibrationError),
    /// The configured geometry of a wheels and poses pair is missing or out of range.
    #[error("{0}")]
    Geometry(String),
}

/// A replayed recording: the fed tracker and the parameters in use while it was recorded.
pub struct Replayed {
    /// The tracker, every sample fed.
    pub tracker: Tracker,
    /// The parameters the recording's travel was converted with.
    pub configured: WheelParams,
}

/// A recorded OptiOdom set, run after run.
pub fn replay_dataset(
    settings: &TrackerSettings,
    dir: &Path,
    scale: ScaleSource,
    mut on_estimate: impl FnMut(&OnlineEstimate),
) -> Result<Replayed, ReplayError> {
    let set = OptiOdomSet::load(dir)?;
    let mut tracker = settings.tracker(set.configured, scale)?;
    set.feed(&mut tracker).iter().for_each(&mut on_estimate);
    Ok(Replayed {
        tracker,
        configured: set.configured,
    })
}

/// A log of `odocal record` or `track --record`; a log with poses replays against them (the
/// filter's own scale then).
pub fn replay_log(
    settings: &TrackerSettings,
    path: &Path,
    scale: ScaleSource,
    mut on_estimate: impl FnMut(&OnlineEstimate),
) -> Result<Replayed, ReplayError> {
    let (header, recording) = read_log(path)?;
    let scale = if recording.poses.is_empty() {
        scale
    } else {
        ScaleSource::Filter
    };
    let mut tracker = settings.tracker(header.params, scale)?;
    tracker
        .feed_recording("log", &recording)
        .iter()
        .for_each(&mut on_estimate);
    Ok(Replayed {
        tracker,
        configured: header.params,
    })
}

/// `odocal fit`'s wheels (radians) and poses files, for a robot configured with this wheel
/// diameter and wheelbase (m; both needed: the files carry no geometry).
pub fn replay_files(
    settings: &TrackerSettings,
    (poses, wheels): (&Path, &Path),
    (wheel_diameter_m, wheelbase_m): (Option<f64>, Option<f64>),
    scale: ScaleSource,
    mut on_estimate: impl FnMut(&OnlineEstimate),
) -> Result<Replayed, ReplayError> {
    let (Some(d), Some(b)) = (wheel_diameter_m, wheelbase_m) else {
        return Err(ReplayError::Geometry(
            "--poses needs the configured geometry: give --wheel-diameter-m and --wheelbase-m \
             (metres)"
                .into(),
        ));
    };
    crate::ranges::check_geometry(d, b).map_err(ReplayError::Geometry)?;
    // Wheels in radians: a "count" is a radian (see OnlineConfig's angle units).
    let configured = WheelParams::nominal(d, b, std::f64::consts::TAU);
    let drive = PoseRecording {
        wheels: read_wheels(wheels)?,
        poses: read_poses(poses)?,
    };
    let mut tracker = settings.tracker(configured, scale)?;
    let recording = Recording::of_pose_recording(&drive, Geometry::from(&configured));
    tracker
        .feed_recording(&poses.display().to_string(), &recording)
        .iter()
        .for_each(&mut on_estimate);
    Ok(Replayed {
        tracker,
        configured,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn files_without_their_geometry_are_refused_before_they_are_read() {
        let s = TrackerSettings::default();
        let missing = Path::new("/nonexistent/odocal");
        for geometry in [(None, Some(0.4)), (Some(0.1), None)] {
            let e = replay_files(&s, (missing, missing), geometry, s.scale(true), |_| {})
                .err()
                .expect("refused");
            assert!(
                e.to_string()
                    .contains("--wheel-diameter-m and --wheelbase-m"),
                "{e}"
            );
        }
        let e = replay_files(
            &s,
            (missing, missing),
            (Some(9.0), Some(0.4)),
            s.scale(true),
            |_| {},
        )
        .err()
        .expect("refused");
        assert!(e.to_string().contains("--wheel-diameter-m"), "{e}");
        let e = replay_files(
            &s,
            (missing, missing),
            (Some(0.1), Some(0.4)),
            s.scale(true),
            |_| {},
        )
        .err()
        .expect("refused");
        assert!(matches!(e, ReplayError::PoseCsv(_)), "{e}");
    }
}
