//! Whether a pose reference measures the robot independently of the wheels it is to calibrate.
//!
//! The references a ROS robot already carries are often made from its own wheels: the
//! controller's `/odom`, the TF chain `odom → base_link` (or `map → odom → base_link` while no
//! localization corrects `map → odom`), or a filter that fuses the wheels with a gyro
//! (`robot_localization`'s `/odometry/filtered`: positions from the wheels, heading from the
//! gyro). A fit against such a reference gives back the geometry the controller integrated with,
//! with a residual of nothing and a standard deviation of nothing: a confident wrong answer.
//!
//! The test rests on the data, not on names. Over consecutive reference samples, the
//! reference's motion is compared with the odometry's over the same interval, at the nominal
//! geometry (the reference frame at `base_link` and on time before the fit, with the fitted
//! mounting and time offset after it):
//! - the *length* of each position increment against the odometry's, as a ratio: a reference
//!   made from the wheels moves the odometry's distance, to a part in 10⁵ or better; any real
//!   sensor's noise scatters the ratio by a part in a hundred or more (3 mm of noise on a 3 cm
//!   increment is 14 %; motion capture's 0.1 mm on its 3 mm steps, 5 %);
//! - the *turn* of each increment against the odometry's, the same way: a heading made from the
//!   wheels turns with them; a gyro's or a scan matcher's does not.
//!
//! Either follows the wheels when its ratios' robust relative scatter is under
//! [`FOLLOWS_WHEELS_SCATTER`] and their median within [`FOLLOWS_WHEELS_RATIO`] of one.
//!
//! Lengths are compared rather than positions because a fused reference puts the wheels'
//! distances along another heading: its positions depart from the odometry's while its
//! increments keep their lengths. Each scatter is a median absolute deviation (scaled to a
//! Gaussian σ) about the median, so that outliers, stops and the odd relocalisation do not hide
//! a reference that follows the wheels everywhere else.

use super::pool::upper_median;
use super::pose_reference::{Geometry, Odometry, Pose2, PoseRecording};
use crate::kinematics::wrap_angle;
use serde::Serialize;

/// Largest robust relative scatter of the increments' length (or turn) ratio at which a
/// reference follows the wheels: two parts in 10⁴, ten times what the integration schemes of
/// controllers and filters differ by (an arc against a Runge–Kutta step, 10⁻⁵) and fifty times
/// below the noise of the most precise motion capture on its shortest steps.
pub const FOLLOWS_WHEELS_SCATTER: f64 = 2e-4;
/// Largest departure of the median ratio from 1 at which a reference follows the wheels *at the
/// nominal geometry* (a reference that moves 3 % further than the nominal odometry, however
/// smoothly, has measured something the wheels did not say).
pub const FOLLOWS_WHEELS_RATIO: f64 = 2e-3;
/// Fewest increments a comparison needs.
const MIN_INCREMENTS: usize = 20;

/// What a reference is made of, as its motion against the wheels' tells.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ReferenceSource {
    /// Neither its positions nor its heading follow the wheels: a sensor of its own.
    Independent,
    /// Positions and heading (or positions alone, without a heading) follow the wheels: the
    /// controller's own odometry. It can give back only the geometry it was integrated with.
    WheelOdometry,
    /// Positions follow the wheels while the heading departs: the wheels fused with a gyro (or
    /// a compass). Only its heading measures the robot.
    WheelPositionsOwnHeading,
    /// The heading follows the wheels while the positions do not (wheels fused with GNSS):
    /// only its positions measure the robot.
    WheelHeadingOwnPositions,
}

/// How one quantity of the reference's increments (their lengths, their turns) compares with
/// the odometry's over the same intervals.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RatioSpread {
    /// Increments compared (those where the odometry moved, or turned, clearly).
    pub increments: usize,
    /// Median of the reference's over the odometry's (1: the same).
    pub median_ratio: f64,
    /// Robust (MAD) standard deviation of the ratio over its median (dimensionless).
    pub relative_scatter: f64,
}

impl RatioSpread {
    /// Whether the reference follows the odometry in this quantity.
    pub fn follows(&self) -> bool {
        self.relative_scatter < FOLLOWS_WHEELS_SCATTER
            && (self.median_ratio - 1.0).abs() < FOLLOWS_WHEELS_RATIO
    }

    fn text(&self, what: &str) -> String {
        format!(
            "its {what} are the wheels' odometry's × {:.5} with a relative scatter of {:.1e} \
             over {} samples",
            self.median_ratio, self.relative_scatter, self.increments
        )
    }
}

/// The comparison of a reference's motion with the wheels' odometry at the nominal geometry.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Independence {
    /// What the reference is made of.
    pub source: ReferenceSource,
    /// The increments' lengths against the odometry's; `None`: too few moving increments.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lengths: Option<RatioSpread>,
    /// The increments' turns against the odometry's; `None` without a heading or turns.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub turns: Option<RatioSpread>,
}

impl Independence {
    /// Whether the positions follow the wheels.
    pub fn positions_follow(&self) -> bool {
        self.lengths.is_some_and(|l| l.follows())
    }

    /// Whether the heading follows the wheels.
    pub fn heading_follows(&self) -> bool {
        self.turns.is_some_and(|t| t.follows())
    }

    /// The sentence a refusal or a note gives: what the reference is, the figures that say so,
    /// and what to give instead.
    pub fn explanation(&self) -> String {
        let lengths = self
            .lengths
            .map_or(String::new(), |l| l.text("increments' lengths"));
        let turns = self.turns.map_or(String::new(), |t| t.text("turns"));
        let both = [lengths.as_str(), turns.as_str()]
            .into_iter()
            .filter(|s| !s.is_empty())
            .collect::<Vec<_>>()
            .join("; ");
        let instead = "give a reference that measures the robot by itself: a localization \
                       against a map (/amcl_pose, or tf:map while it corrects map → odom), \
                       motion capture, GNSS or laser scan matching";
        match self.source {
            ReferenceSource::Independent => format!("an independent reference ({both})"),
            ReferenceSource::WheelOdometry => format!(
                "the reference is the wheels' own odometry at the nominal geometry ({both}; any \
                 sensor's noise scatters them by 10⁻² or more): it can only give back the \
                 nominal geometry (it is the controller's /odom, tf:odom, or tf:map while no \
                 localization moves map → odom); {instead}"
            ),
            ReferenceSource::WheelPositionsOwnHeading => format!(
                "the reference's positions are the wheels' own odometry at the nominal geometry \
                 ({lengths}) while its heading is not ({turns}): a filter that fuses the wheels \
                 with a gyro (robot_localization's /odometry/filtered). It cannot observe the \
                 wheel diameters in metres, and its heading tells only E_d and E_b, with the \
                 gyro's own scale error (odocal calibrate with that IMU as the heading source \
                 measures those); {instead}"
            ),
            ReferenceSource::WheelHeadingOwnPositions => format!(
                "the reference's heading is the wheels' own odometry ({turns}) while its \
                 positions are not: its yaw is left out and its positions alone are fitted"
            ),
        }
    }
}

/// Compares `recording`'s reference with the odometry of the `nominal` geometry, the reference
/// frame at `mount` and its stamps `offset_s` late.
pub fn compare(
    recording: &PoseRecording,
    nominal: Geometry,
    mount: Pose2,
    offset_s: f64,
) -> Independence {
    let odo = Odometry::integrate(&recording.wheels, nominal);
    let mut hint = 0;
    let predicted: Vec<Option<Pose2>> = recording
        .poses
        .iter()
        .map(|p| Some(odo.at(p.time_s - offset_s, &mut hint)?.compose(&mount)))
        .collect();
    // (reference, odometry) per increment.
    let (mut lengths, mut turns) = (Vec::new(), Vec::new());
    for j in 1..recording.poses.len() {
        let (Some(a), Some(b)) = (predicted[j - 1], predicted[j]) else {
            continue;
        };
        let (r0, r1) = (&recording.poses[j - 1], &recording.poses[j]);
        lengths.push((
            (r1.x_m - r0.x_m).hypot(r1.y_m - r0.y_m),
            (b.x - a.x).hypot(b.y - a.y),
        ));
        if let (Some(y0), Some(y1)) = (r0.yaw_rad, r1.yaw_rad) {
            turns.push((wrap_angle(y1 - y0), b.theta - a.theta));
        }
    }
    let lengths = ratio_spread(&lengths, 0.0);
    // Turns of a thousandth of a radian or less are the encoders' quantisation.
    let turns = ratio_spread(&turns, 1e-3);
    let source = match (
        lengths.is_some_and(|l| l.follows()),
        turns.map(|t| t.follows()),
    ) {
        (true, None | Some(true)) => ReferenceSource::WheelOdometry,
        (true, Some(false)) => ReferenceSource::WheelPositionsOwnHeading,
        (false, Some(true)) => ReferenceSource::WheelHeadingOwnPositions,
        (false, _) => ReferenceSource::Independent,
    };
    Independence {
        source,
        lengths,
        turns,
    }
}

/// The ratio of the reference's to the odometry's on the increments where the odometry's is
/// a quarter of its typical size or more (and above `least`): stops and straight stretches say
/// nothing of a scale.
fn ratio_spread(pairs: &[(f64, f64)], least: f64) -> Option<RatioSpread> {
    let typical = upper_median(
        pairs
            .iter()
            .map(|p| p.1.abs())
            .filter(|v| *v > least)
            .collect(),
    )?;
    let ratios: Vec<f64> = pairs
        .iter()
        .filter(|(_, o)| o.abs() > (0.25 * typical).max(least))
        .map(|(r, o)| r / o)
        .collect();
    if ratios.len() < MIN_INCREMENTS {
        return None;
    }
    let m = upper_median(ratios.clone())?;
    let mad = upper_median(ratios.iter().map(|x| (x - m).abs()).collect())?;
    (m != 0.0).then(|| RatioSpread {
        increments: ratios.len(),
        median_ratio: m,
        relative_scatter: 1.4826 * mad / m.abs(),
    })
}

/// The more wheel-like of two comparisons (the one whose lengths scatter least): a reference
/// that follows the wheels with the nominal or with the fitted mounting and time offset follows
/// them.
pub fn more_wheel_like(a: Independence, b: Independence) -> Independence {
    let key = |i: &Independence| {
        (
            i.source == ReferenceSource::Independent,
            i.lengths.map_or(f64::INFINITY, |l| l.relative_scatter),
        )
    };
    if key(&a) <= key(&b) {
        a
    } else {
        b
    }
}
