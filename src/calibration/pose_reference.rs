//! The input of a calibration against a pose reference: cumulative wheel rotations, the poses
//! of a frame mounted on the robot as an external reference measured them, and the odometry
//! those wheels give for a candidate geometry.
//!
//! Conventions (written once here):
//! - Wheel rotations are cumulative radians, forward positive, each wheel on its own sign
//!   (a wheel turning so that the robot moves forward counts up), at any rate.
//! - A reference pose is the pose of the *reference frame* (a motion-capture body, a lidar
//!   that scan-matches, a GNSS antenna, or `base_link` itself for a localization) in a fixed
//!   world frame with any origin: x, y in metres, yaw counter-clockwise positive in radians.
//!   A position-only reference (GNSS) has no yaw.
//! - The reference frame sits on the robot at `(sensor_x_m, sensor_y_m, sensor_yaw_rad)` in
//!   `base_link` (x forward, y left, the axle's midpoint the origin).
//! - `time_offset_s` is positive when the reference's stamps are late: the pose stamped `t`
//!   was where the robot was at `t − time_offset_s` on the wheels' clock.
//!
//! [`Odometry`] integrates the wheels exactly (each interval a circular arc, as
//! [`crate::kinematics::Pose::advance`]) with the heading kept unwrapped, and interpolates
//! inside an interval along the same arc.

use crate::kinematics::{sinc, Displacement};
use serde::{Deserialize, Serialize};

pub use crate::samples::ReferencePose;

/// Cumulative wheel rotations at one instant (rad, forward positive).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WheelAngles {
    /// Time on the wheels' clock (s).
    pub time_s: f64,
    /// Left wheel's cumulative rotation (rad).
    pub left_rad: f64,
    /// Right wheel's cumulative rotation (rad).
    pub right_rad: f64,
}

impl ReferencePose {
    /// The pose as a [`Pose2`]; a position-only pose faces 0 (its yaw is never compared).
    pub fn pose2(&self) -> Pose2 {
        Pose2 {
            x: self.x_m,
            y: self.y_m,
            theta: self.yaw_rad.unwrap_or(0.0),
        }
    }
}

/// How a reference's errors behave, which decides how it is fitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReferenceKind {
    /// Errors that do not accumulate (motion capture, localization against a map, GNSS): the
    /// trajectory is fitted as a whole, where the odometry's error grows.
    Absolute,
    /// Errors that accumulate (scan matching or visual odometry chained sample to sample):
    /// the motion between consecutive samples is fitted.
    Relative,
}

impl ReferenceKind {
    /// The name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            ReferenceKind::Absolute => "absolute",
            ReferenceKind::Relative => "relative",
        }
    }
}

impl std::str::FromStr for ReferenceKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "absolute" => Ok(ReferenceKind::Absolute),
            "relative" => Ok(ReferenceKind::Relative),
            other => Err(format!(
                "unknown reference kind {other:?}; use absolute (motion capture, a map's \
                 localization, GNSS) or relative (chained scan matching, visual odometry)"
            )),
        }
    }
}

/// A drive with a pose reference: the wheels and the reference, each in time order.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseRecording {
    /// Cumulative wheel rotations, time increasing.
    pub wheels: Vec<WheelAngles>,
    /// Reference poses, time increasing.
    pub poses: Vec<ReferencePose>,
}

impl PoseRecording {
    /// Whether every reference pose carries a yaw.
    pub fn has_yaw(&self) -> bool {
        !self.poses.is_empty() && self.poses.iter().all(|p| p.yaw_rad.is_some())
    }

    /// The first `poses` reference poses and the wheels up to a second past the last of them;
    /// `None` when the recording has no more poses than that.
    pub fn head(&self, poses: usize) -> Option<PoseRecording> {
        if self.poses.len() <= poses || poses == 0 {
            return None;
        }
        let end_s = self.poses[poses - 1].time_s + 1.0;
        Some(PoseRecording {
            wheels: self
                .wheels
                .iter()
                .take_while(|w| w.time_s <= end_s)
                .copied()
                .collect(),
            poses: self.poses[..poses].to_vec(),
        })
    }
}

/// The geometry a fit varies: wheel diameters and the wheelbase (m).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Geometry {
    /// Left wheel diameter (m).
    pub left_diameter_m: f64,
    /// Right wheel diameter (m).
    pub right_diameter_m: f64,
    /// Wheelbase (m).
    pub wheelbase_m: f64,
}

impl From<&crate::kinematics::WheelParams> for Geometry {
    /// The geometry of a controller's parameters (its counts per revolution aside).
    fn from(p: &crate::kinematics::WheelParams) -> Self {
        Geometry {
            left_diameter_m: p.left_wheel_diameter_m,
            right_diameter_m: p.right_wheel_diameter_m,
            wheelbase_m: p.wheelbase_m,
        }
    }
}

/// A planar pose with an unwrapped heading, for integration and interpolation.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pose2 {
    /// x (m).
    pub x: f64,
    /// y (m).
    pub y: f64,
    /// Heading (rad), unwrapped.
    pub theta: f64,
}

impl Pose2 {
    /// The pose after an arc of wheel travels `left_m`, `right_m` on wheelbase `b`.
    #[inline]
    pub fn arc(&self, left_m: f64, right_m: f64, b: f64) -> Pose2 {
        let Displacement {
            distance_m: ds,
            turn_rad: dth,
        } = Displacement::of_wheels(left_m, right_m, b);
        let chord = ds * sinc(0.5 * dth);
        let mid = self.theta + 0.5 * dth;
        let (s, c) = mid.sin_cos();
        Pose2 {
            x: self.x + chord * c,
            y: self.y + chord * s,
            theta: self.theta + dth,
        }
    }

    /// `self ∘ other`: `other` expressed in `self`'s frame, brought to the outer frame.
    #[inline]
    pub fn compose(&self, other: &Pose2) -> Pose2 {
        self.compose_turned(Turn::of(self.theta), other)
    }

    /// [`Pose2::compose`] with `self`'s heading already as a [`Turn`] (`turn` must be
    /// `Turn::of(self.theta)`): no trigonometry per call where one rotation serves many.
    #[inline]
    pub fn compose_turned(&self, turn: Turn, other: &Pose2) -> Pose2 {
        let Turn { cos: c, sin: s } = turn;
        Pose2 {
            x: self.x + c * other.x - s * other.y,
            y: self.y + s * other.x + c * other.y,
            theta: self.theta + other.theta,
        }
    }

    /// `self⁻¹ ∘ other`: `other` in `self`'s frame.
    #[inline]
    pub fn between(&self, other: &Pose2) -> Pose2 {
        self.between_turned(Turn::of(self.theta), other)
    }

    /// [`Pose2::between`] with `self`'s heading already as a [`Turn`].
    #[inline]
    pub fn between_turned(&self, turn: Turn, other: &Pose2) -> Pose2 {
        let Turn { cos: c, sin: s } = turn;
        let dx = other.x - self.x;
        let dy = other.y - self.y;
        Pose2 {
            x: c * dx + s * dy,
            y: -s * dx + c * dy,
            theta: other.theta - self.theta,
        }
    }
}

/// A rotation as its cosine and sine, carried beside an angle so that composing many poses
/// with one rotation, or rotating by small increments, needs no trigonometric call each time
/// (the fit evaluates millions of such products; `sin_cos` was a third of its time).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Turn {
    /// cos of the angle.
    pub cos: f64,
    /// sin of the angle.
    pub sin: f64,
}

impl Turn {
    /// The rotation by `angle_rad`.
    #[inline]
    pub fn of(angle_rad: f64) -> Self {
        let (sin, cos) = angle_rad.sin_cos();
        Turn { cos, sin }
    }

    /// This rotation followed by `other`.
    #[inline]
    pub fn then(self, other: Turn) -> Self {
        Turn {
            cos: self.cos * other.cos - self.sin * other.sin,
            sin: self.sin * other.cos + self.cos * other.sin,
        }
    }
}

/// `(sin h, cos h, sin h / h)` for the half-turn `h` of one wheel interval: by their series
/// for |h| < 0.1 (truncation below 10⁻²⁰ there, so as exact as `sin_cos`), which covers every
/// interval of a wheel stream at tens of hertz, and by `sin_cos` beyond.
#[inline]
pub(crate) fn half_turn(h: f64) -> (f64, f64, f64) {
    if h.abs() < 0.1 {
        let x = h * h;
        let sinc_h = 1.0
            - x / 6.0 * (1.0 - x / 20.0 * (1.0 - x / 42.0 * (1.0 - x / 72.0 * (1.0 - x / 110.0))));
        let cos_h = 1.0
            - x / 2.0
                * (1.0
                    - x / 12.0
                        * (1.0
                            - x / 30.0 * (1.0 - x / 56.0 * (1.0 - x / 90.0 * (1.0 - x / 132.0)))));
        (h * sinc_h, cos_h, sinc_h)
    } else {
        let (sh, ch) = h.sin_cos();
        (sh, ch, sh / h)
    }
}

/// Dead reckoning of a wheel stream for one geometry: the pose of `base_link` at every wheel
/// sample (starting at the origin), and between samples along the same arc.
#[derive(Debug, Clone)]
pub struct Odometry<'a> {
    wheels: &'a [WheelAngles],
    geometry: Geometry,
    poses: Vec<Pose2>,
    /// The heading of each pose as a rotation, carried through the integration.
    turns: Vec<Turn>,
}

impl<'a> Odometry<'a> {
    /// Integrates `wheels` with `geometry`.
    pub fn integrate(wheels: &'a [WheelAngles], geometry: Geometry) -> Self {
        let mut poses = Vec::with_capacity(wheels.len());
        let mut turns = Vec::with_capacity(wheels.len());
        let (hl, hr) = (
            0.5 * geometry.left_diameter_m,
            0.5 * geometry.right_diameter_m,
        );
        let inv_b = 1.0 / geometry.wheelbase_m;
        let (mut x, mut y, mut theta) = (0.0f64, 0.0f64, 0.0f64);
        let mut dir = Turn { cos: 1.0, sin: 0.0 };
        let mut prev: Option<&WheelAngles> = None;
        for (i, w) in wheels.iter().enumerate() {
            if let Some(p) = prev {
                let dl = (w.left_rad - p.left_rad) * hl;
                let dr = (w.right_rad - p.right_rad) * hr;
                let dth = (dr - dl) * inv_b;
                let (sh, ch, sinc_h) = half_turn(0.5 * dth);
                let chord = 0.5 * (dl + dr) * sinc_h;
                let half = Turn { cos: ch, sin: sh };
                // Direction of the chord: the heading turned by half the interval's turn.
                let mid = dir.then(half);
                x += chord * mid.cos;
                y += chord * mid.sin;
                // The heading turned by the whole turn: the half-angle rotation twice; kept a
                // unit vector as rounding accumulates.
                let end = mid.then(half);
                let k = 1.5 - 0.5 * (end.cos * end.cos + end.sin * end.sin);
                dir = Turn {
                    cos: end.cos * k,
                    sin: end.sin * k,
                };
                theta += dth;
            }
            if i % 4096 == 0 {
                // Re-anchor on the summed heading so that the carried direction cannot drift.
                dir = Turn::of(theta);
            }
            poses.push(Pose2 { x, y, theta });
            turns.push(dir);
            prev = Some(w);
        }
        Self {
            wheels,
            geometry,
            poses,
            turns,
        }
    }

    /// The pose at every wheel sample.
    pub fn poses(&self) -> &[Pose2] {
        &self.poses
    }

    /// The time span the wheels cover (s).
    pub fn span_s(&self) -> Option<(f64, f64)> {
        Some((self.wheels.first()?.time_s, self.wheels.last()?.time_s))
    }

    /// The pose at `t_s` (wheels' clock), `None` outside the recorded span. `hint` is a cursor
    /// for queries in increasing time (start at 0).
    pub fn at(&self, t_s: f64, hint: &mut usize) -> Option<Pose2> {
        self.at_turned(t_s, hint).map(|(pose, _)| pose)
    }

    /// [`Odometry::at`] with the pose's heading as a [`Turn`] too.
    pub fn at_turned(&self, t_s: f64, hint: &mut usize) -> Option<(Pose2, Turn)> {
        let n = self.wheels.len();
        if n == 0 || !(t_s >= self.wheels[0].time_s && t_s <= self.wheels[n - 1].time_s) {
            return None;
        }
        let mut k = (*hint).min(n - 1);
        if self.wheels[k].time_s > t_s {
            // Out of order: search from the start.
            k = self
                .wheels
                .partition_point(|w| w.time_s <= t_s)
                .saturating_sub(1);
        }
        while k + 1 < n && self.wheels[k + 1].time_s <= t_s {
            k += 1;
        }
        *hint = k;
        if k + 1 >= n {
            return Some((self.poses[k], self.turns[k]));
        }
        let (a, b) = (&self.wheels[k], &self.wheels[k + 1]);
        let dt = b.time_s - a.time_s;
        let f = if dt > 0.0 { (t_s - a.time_s) / dt } else { 0.0 };
        let g = &self.geometry;
        // Along the interval's arc, as `integrate` steps (the same as `Pose2::arc`).
        let dl = f * (b.left_rad - a.left_rad) * 0.5 * g.left_diameter_m;
        let dr = f * (b.right_rad - a.right_rad) * 0.5 * g.right_diameter_m;
        let Displacement {
            distance_m: ds,
            turn_rad: dth,
        } = Displacement::of_wheels(dl, dr, g.wheelbase_m);
        let (sh, ch, sinc_h) = half_turn(0.5 * dth);
        let chord = ds * sinc_h;
        let half = Turn { cos: ch, sin: sh };
        let (p, mid) = (self.poses[k], self.turns[k].then(half));
        Some((
            Pose2 {
                x: p.x + chord * mid.cos,
                y: p.y + chord * mid.sin,
                theta: p.theta + dth,
            },
            mid.then(half),
        ))
    }
}

/// Dead reckoning checked against the reference: the odometry of `geometry`, started at the
/// reference's first pose (through the mounting `mount` and the time offset `offset_s`), and
/// its distance from the reference's last pose (m). `None` when the streams do not overlap or
/// the reference has no yaw to start from.
pub fn final_position_error_m(
    recording: &PoseRecording,
    geometry: Geometry,
    mount: Pose2,
    offset_s: f64,
) -> Option<f64> {
    let path = reckoned_path(recording, geometry, mount, offset_s)?;
    if path.len() < 2 {
        return None;
    }
    let (i, end) = path.last()?;
    let last = &recording.poses[*i];
    Some((end.x - last.x_m).hypot(end.y - last.y_m))
}

/// Dead reckoning as the reference would have seen it: the reference frame's pose at each
/// reference stamp inside the wheels' span (its index in `recording.poses`, and the pose in
/// the reference's world frame), from the odometry of `geometry` through the mounting `mount`
/// and the time offset `offset_s`, started on the first such reference pose. `None` when the
/// streams do not overlap or that pose has no yaw.
pub fn reckoned_path(
    recording: &PoseRecording,
    geometry: Geometry,
    mount: Pose2,
    offset_s: f64,
) -> Option<Vec<(usize, Pose2)>> {
    let odo = Odometry::integrate(&recording.wheels, geometry);
    let mut hint = 0;
    let inside: Vec<(usize, Pose2)> = recording
        .poses
        .iter()
        .enumerate()
        .filter_map(|(i, p)| Some((i, odo.at(p.time_s - offset_s, &mut hint)?.compose(&mount))))
        .collect();
    let (first, s0) = inside.first()?;
    let f = &recording.poses[*first];
    let r0 = Pose2 {
        x: f.x_m,
        y: f.y_m,
        theta: f.yaw_rad?,
    };
    // The world pose of the odometry's origin, `r0 ∘ s0⁻¹`, puts the sensor on the first pose.
    let origin = r0.compose(&s0.between(&Pose2::default()));
    Some(
        inside
            .into_iter()
            .map(|(i, s)| (i, origin.compose(&s)))
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn a_circle_integrates_exactly_and_interpolates_on_its_arc() {
        // Right wheel twice the left: a circle of known radius.
        let g = Geometry {
            left_diameter_m: 0.1,
            right_diameter_m: 0.1,
            wheelbase_m: 0.4,
        };
        let wheels: Vec<WheelAngles> = (0..=100)
            .map(|i| WheelAngles {
                time_s: i as f64 * 0.1,
                left_rad: i as f64 * 0.2,
                right_rad: i as f64 * 0.4,
            })
            .collect();
        let odo = Odometry::integrate(&wheels, g);
        // Arc lengths: left 0.01 m, right 0.02 m per step; turn 0.025 rad per step.
        let last = odo.poses()[100];
        assert_relative_eq!(last.theta, 2.5, epsilon = 1e-12);
        // Radius of the centre: ds/dθ = 0.015/0.025 = 0.6 m.
        assert_relative_eq!(last.x, 0.6 * 2.5f64.sin(), epsilon = 1e-12);
        assert_relative_eq!(last.y, 0.6 * (1.0 - 2.5f64.cos()), epsilon = 1e-12);
        let mut hint = 0;
        let mid = odo.at(5.05, &mut hint).expect("inside");
        assert_relative_eq!(mid.theta, 50.5 * 0.025, epsilon = 1e-12);
        assert_relative_eq!(mid.x, 0.6 * (50.5f64 * 0.025).sin(), epsilon = 1e-12);
        assert!(odo.at(10.5, &mut hint).is_none());
        // A query before the cursor still finds its interval.
        let early = odo.at(0.5, &mut hint).expect("inside");
        assert_relative_eq!(early.theta, 5.0 * 0.025, epsilon = 1e-12);
    }

    #[test]
    fn compose_and_between_are_inverse() {
        let a = Pose2 {
            x: 1.0,
            y: -2.0,
            theta: 0.7,
        };
        let b = Pose2 {
            x: 0.3,
            y: 0.4,
            theta: -1.9,
        };
        let c = a.compose(&b);
        let back = a.between(&c);
        assert_relative_eq!(back.x, b.x, epsilon = 1e-12);
        assert_relative_eq!(back.y, b.y, epsilon = 1e-12);
        assert_relative_eq!(back.theta, b.theta, epsilon = 1e-12);
    }
}
