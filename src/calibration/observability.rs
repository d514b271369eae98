//! What a drive with a pose reference can tell, checked before anything is written: how much it
//! turned each way and drove straight, whether the reference turns the way the wheels do, and
//! which fitted parameters are known well enough to write.
//!
//! Two checks, each with what to drive next:
//! - **Before the fit** ([`survey`], [`DriveSurvey::require`]): the wheelbase shows only in
//!   turns and the diameters' difference shows as a turn that grows with distance; the two are
//!   told apart only when the robot turns both ways (the paper's reason for squares both ways),
//!   and the mean diameter only over straight distance. A drive that turns less than half a turn
//!   either way, or drives less than a metre straight, is refused by name.
//! - **Conventions** ([`DriveSurvey::diagnose`]): the reference's turns regressed on the
//!   wheels' (at the nominal geometry). A slope near −1 is swapped wheels (or a mirrored
//!   reference); yaw steps 57 times the wheels' turns are a yaw in degrees; a yaw that turns
//!   against the reference's own path is a yaw of the other sign convention.
//! - **After the fit** ([`judge`]): each parameter's standard deviation against what a
//!   calibration must reach; a diameter or wheelbase worse than [`GEOMETRY_REL_STD_MAX`] is not
//!   observed and is not written.

use super::pool::upper_median;
use super::pose_fit::{Param, PoseFit};
use super::pose_reference::{Geometry, Odometry, Pose2, PoseRecording};
use super::CalibrationError;
use crate::kinematics::wrap_angle;
use serde::Serialize;
use std::f64::consts::PI;

/// Least turning each way (rad): half a turn.
pub const MIN_TURN_EACH_WAY_RAD: f64 = PI;
/// Least straight distance (m).
pub const MIN_STRAIGHT_M: f64 = 1.0;
/// Shortest span over which the drive's turning and straightness are judged (s).
pub const SURVEY_SPAN_S: f64 = 0.5;
/// Curvature below which a span counts as straight (rad/m).
pub const STRAIGHT_CURVATURE_RAD_M: f64 = 0.2;
/// Largest relative standard deviation of a diameter or the wheelbase that is written.
pub const GEOMETRY_REL_STD_MAX: f64 = 0.005;
/// Largest standard deviation of the mounting's position reported as observed (m).
pub const MOUNT_STD_MAX_M: f64 = 0.05;
/// Largest standard deviation of the mounting's yaw reported as observed (rad).
pub const MOUNT_YAW_STD_MAX_RAD: f64 = 0.05;
/// Largest standard deviation of the time offset reported as observed (s).
pub const OFFSET_STD_MAX_S: f64 = 0.05;

/// What the drive did, by the wheels at the nominal geometry, and how the reference followed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DriveSurvey {
    /// Distance driven, forward and back (m).
    pub distance_m: f64,
    /// Distance driven on spans straighter than [`STRAIGHT_CURVATURE_RAD_M`] (m).
    pub straight_m: f64,
    /// Total counter-clockwise turning (rad).
    pub turned_left_rad: f64,
    /// Total clockwise turning (rad, positive).
    pub turned_right_rad: f64,
    /// Duration of the wheel stream (s).
    pub duration_s: f64,
    /// Slope of the reference's yaw changes on the wheels' turns (1 when they agree).
    pub yaw_slope: Option<f64>,
    /// Slope of the direction changes of the reference's path on the wheels' turns.
    pub path_slope: Option<f64>,
    /// Median size of the reference's yaw steps (as given, unwrapped) over that of the wheels'
    /// turns, on intervals where the wheels turn: about 57 for a yaw in degrees.
    pub yaw_step_ratio: Option<f64>,
}

/// Surveys `recording` at the nominal geometry.
pub fn survey(recording: &PoseRecording, nominal: Geometry) -> DriveSurvey {
    let odo = Odometry::integrate(&recording.wheels, nominal);
    let poses = odo.poses();
    let (mut distance, mut straight, mut left, mut right) = (0.0, 0.0, 0.0, 0.0);
    // Turning is counted over spans of at least half a second: per wheel interval, encoder
    // quantisation and wobble add up both ways and would pass any drive as turning both ways.
    let wheels = &recording.wheels;
    let (mut start, mut span_ds) = (0, 0.0);
    for i in 1..poses.len() {
        span_ds += (poses[i].x - poses[i - 1].x).hypot(poses[i].y - poses[i - 1].y);
        if wheels[i].time_s - wheels[start].time_s < SURVEY_SPAN_S && i + 1 < poses.len() {
            continue;
        }
        let dth = poses[i].theta - poses[start].theta;
        distance += span_ds;
        if dth.abs() < STRAIGHT_CURVATURE_RAD_M * span_ds {
            straight += span_ds;
        }
        if dth > 0.0 {
            left += dth;
        } else {
            right -= dth;
        }
        start = i;
        span_ds = 0.0;
    }
    let duration_s = match (recording.wheels.first(), recording.wheels.last()) {
        (Some(a), Some(b)) => b.time_s - a.time_s,
        _ => 0.0,
    };
    // The reference's turns against the wheels', over the reference's intervals.
    let mut hint = 0;
    let odo_at: Vec<Option<Pose2>> = recording
        .poses
        .iter()
        .map(|p| odo.at(p.time_s, &mut hint))
        .collect();
    let (mut syo, mut soo, mut spo, mut spp) = (0.0, 0.0, 0.0, 0.0);
    let (mut yaw_steps, mut odo_steps) = (Vec::new(), Vec::new());
    let mut last_dir: Option<(f64, usize)> = None;
    for j in 1..recording.poses.len() {
        let (Some(a), Some(b)) = (odo_at[j - 1], odo_at[j]) else {
            continue;
        };
        let dodo = b.theta - a.theta;
        let (p0, p1) = (&recording.poses[j - 1], &recording.poses[j]);
        if let (Some(y0), Some(y1)) = (p0.yaw_rad, p1.yaw_rad) {
            syo += wrap_angle(y1 - y0) * dodo;
            soo += dodo * dodo;
            // Only clear turns: on slow ones a noisy yaw's steps dwarf the wheels'.
            if dodo.abs() > 0.05 {
                yaw_steps.push((y1 - y0).abs());
                odo_steps.push(dodo.abs());
            }
        }
        // Direction of the reference's path where it moves clearly.
        let (dx, dy) = (p1.x_m - p0.x_m, p1.y_m - p0.y_m);
        let moved = dx.hypot(dy);
        let odo_moved = (b.x - a.x).hypot(b.y - a.y);
        if moved > 0.01 && odo_moved > 0.5 * moved {
            let dir = dy.atan2(dx);
            if let Some((prev, k)) = last_dir {
                if k + 1 == j {
                    let (Some(c), Some(_)) = (odo_at[j - 2], odo_at[j]) else {
                        last_dir = Some((dir, j));
                        continue;
                    };
                    // The path's direction from interval j−1 to j against the wheels' turn
                    // from the middle of one to the middle of the next (about the same span).
                    let dpath = wrap_angle(dir - prev);
                    let dodo2 = 0.5 * (b.theta - c.theta);
                    spo += dpath * dodo2;
                    spp += dodo2 * dodo2;
                }
            }
            last_dir = Some((dir, j));
        } else {
            last_dir = None;
        }
    }
    let enough = 0.5f64.powi(2);
    DriveSurvey {
        distance_m: distance,
        straight_m: straight,
        turned_left_rad: left,
        turned_right_rad: right,
        duration_s,
        yaw_slope: (soo > enough).then(|| syo / soo),
        path_slope: (spp > enough).then(|| spo / spp),
        yaw_step_ratio: match (median(yaw_steps), median(odo_steps)) {
            (Some(y), Some(o)) if o > 0.0 => Some(y / o),
            _ => None,
        },
    }
}

/// The median of at least ten steps (fewer tell nothing).
fn median(v: Vec<f64>) -> Option<f64> {
    if v.len() < 10 {
        return None;
    }
    upper_median(v)
}

impl DriveSurvey {
    /// Refuses a drive in which the diameters and the wheelbase cannot be told apart.
    pub fn require(&self) -> Result<(), CalibrationError> {
        let mut missing = Vec::new();
        let mut advice = Vec::new();
        let deg = |r: f64| r.to_degrees();
        if self.turned_left_rad < MIN_TURN_EACH_WAY_RAD
            || self.turned_right_rad < MIN_TURN_EACH_WAY_RAD
        {
            missing.push("the wheelbase apart from the diameters' difference");
            advice.push(format!(
                "turn both ways, at least {:.0}° each (this drive turned {:.0}° left and {:.0}° \
                 right)",
                deg(MIN_TURN_EACH_WAY_RAD),
                deg(self.turned_left_rad),
                deg(self.turned_right_rad)
            ));
        }
        if self.straight_m < MIN_STRAIGHT_M {
            missing.push("the mean wheel diameter");
            advice.push(format!(
                "drive straight stretches, {MIN_STRAIGHT_M:.0} m or more in all (this drive \
                 had {:.2} m straight)",
                self.straight_m
            ));
        }
        if missing.is_empty() {
            Ok(())
        } else {
            Err(CalibrationError::NotObserved {
                parameters: missing.join(" and "),
                advice: format!("{}; then record and fit again", advice.join("; ")),
            })
        }
    }

    /// Names a reference or wheels in another convention.
    pub fn diagnose(&self) -> Result<(), CalibrationError> {
        let yaw = self.yaw_slope;
        let path = self.path_slope;
        if let Some(y) = self.yaw_step_ratio {
            if (20.0..120.0).contains(&y) {
                return Err(CalibrationError::PoseInput(format!(
                    "the reference's yaw steps are {y:.1}× the wheels' turns: it is in degrees, \
                     not radians; convert it (yaw_rad = yaw_deg · π/180) and fit again"
                )));
            }
        }
        let reversed = |s: Option<f64>| s.is_some_and(|s| s < -0.5);
        let agrees = |s: Option<f64>| s.is_some_and(|s| s > 0.5);
        if reversed(path) && (yaw.is_none() || reversed(yaw)) {
            return Err(CalibrationError::PoseInput(format!(
                "the wheels turn against the reference (slope {:.2}): the left and right wheels \
                 are swapped (or one wheel's sign is reversed), or the reference is mirrored; \
                 swap the wheel columns (or the joint names) and fit again",
                path.or(yaw).unwrap_or(f64::NAN)
            )));
        }
        if reversed(yaw) && agrees(path) {
            return Err(CalibrationError::PoseInput(format!(
                "the reference's yaw turns against its own path (slope {:.2}) while its path \
                 turns with the wheels: its yaw is clockwise positive (a compass bearing or NED); \
                 negate it and fit again",
                yaw.unwrap_or(f64::NAN)
            )));
        }
        if agrees(yaw) && reversed(path) {
            return Err(CalibrationError::PoseInput(
                "the reference's path is mirrored against its yaw (x and y swapped, or one \
                 negated, e.g. NED against ENU); give the positions in a right-handed frame"
                    .into(),
            ));
        }
        if let Some(y) = yaw.or(path) {
            if y.abs() < 0.2 && self.turned_left_rad + self.turned_right_rad > 2.0 * PI {
                return Err(CalibrationError::PoseInput(format!(
                    "the reference does not turn with the wheels (slope {y:.2}): it is not \
                     this robot's pose, or its stamps are not on the wheels' clock; check the \
                     topic or frame"
                )));
            }
        }
        Ok(())
    }
}

/// Whether each fitted parameter was observed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParameterObservation {
    /// Its name (with unit).
    pub parameter: &'static str,
    /// Its standard deviation.
    pub std: f64,
    /// The largest it may be to count as observed.
    pub limit: f64,
    /// Whether it was observed.
    pub observed: bool,
    /// What to drive to observe it, when it was not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub advice: Option<&'static str>,
}

/// The verdict on a fit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Observability {
    /// Per fitted parameter.
    pub parameters: Vec<ParameterObservation>,
    /// Condition number of the fitted parameters' correlation matrix.
    pub condition: f64,
}

impl Observability {
    /// Refuses when a diameter or the wheelbase was not observed.
    pub fn require_geometry(&self) -> Result<(), CalibrationError> {
        let missing: Vec<&ParameterObservation> = self
            .parameters
            .iter()
            .filter(|p| {
                !p.observed && (p.parameter.contains("diameter") || p.parameter == "wheelbase_m")
            })
            .collect();
        if missing.is_empty() {
            return Ok(());
        }
        let mut advice: Vec<&str> = missing.iter().filter_map(|p| p.advice).collect();
        advice.dedup();
        Err(CalibrationError::NotObserved {
            parameters: missing
                .iter()
                .map(|p| format!("{} (± {:.2e}, needs < {:.2e})", p.parameter, p.std, p.limit))
                .collect::<Vec<_>>()
                .join(", "),
            advice: format!("{}; then record and fit again", advice.join("; ")),
        })
    }
}

/// Judges each fitted parameter of `fit`.
pub fn judge(fit: &PoseFit) -> Observability {
    let mut parameters = Vec::new();
    for p in &fit.free {
        let std = fit.std(*p).unwrap_or(f64::INFINITY);
        let (limit, advice) = match p {
            Param::LeftDiameter | Param::RightDiameter => (
                GEOMETRY_REL_STD_MAX * fit.value(*p),
                "drive longer straight stretches, forward, and turn both ways",
            ),
            Param::Wheelbase => (
                GEOMETRY_REL_STD_MAX * fit.value(*p),
                "turn more, both ways: full turns in place or tight circles",
            ),
            Param::SensorX | Param::SensorY => (
                MOUNT_STD_MAX_M,
                "turn in place or on tight arcs: the reference's lever arm shows only in rotation",
            ),
            Param::SensorYaw => (
                MOUNT_YAW_STD_MAX_RAD,
                "drive straight stretches: the mounting's yaw shows as motion sideways",
            ),
            Param::TimeOffset => (
                OFFSET_STD_MAX_S,
                "change speed more often: start, stop and turn at different speeds",
            ),
        };
        let observed = std.is_finite() && std <= limit;
        parameters.push(ParameterObservation {
            parameter: p.name(),
            std,
            limit,
            observed,
            advice: (!observed).then_some(advice),
        });
    }
    Observability {
        parameters,
        condition: condition(fit),
    }
}

/// Condition number of the fitted parameters' correlation matrix.
fn condition(fit: &PoseFit) -> f64 {
    let n = fit.free.len();
    let mut corr = nalgebra::DMatrix::<f64>::identity(n, n);
    for (a, pa) in fit.free.iter().enumerate() {
        for (b, pb) in fit.free.iter().enumerate() {
            if a != b {
                corr[(a, b)] = fit.correlation(*pa, *pb).unwrap_or(0.0);
            }
        }
    }
    let eig = corr.symmetric_eigen().eigenvalues;
    let (lo, hi) = eig.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
        (lo.min(*v), hi.max(*v))
    });
    if lo > 0.0 {
        hi / lo
    } else {
        f64::INFINITY
    }
}
