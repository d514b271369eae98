//! A seeded simulator of *normal driving* (not squares) of a differential-drive robot watched
//! by an external pose reference: it produces the [`PoseRecording`] a calibration against a
//! pose reference consumes, together with the truth it came from.
//!
//! The robot drives a random sequence of segments (straights, arcs, in-place turns, stops) with
//! smooth speed changes, steered back toward its start when it strays more than
//! [`RETURN_RADIUS_M`] from it. Each wheel interval is one circular arc of the *true* geometry,
//! so the true path is exact and the reference can be sampled anywhere along it. The wheel
//! angles are the rotations the wheels made (their travel over the true radius); wheel slip
//! moves the ground travel away from those rotations. The reference sees a frame mounted on
//! the robot, in a random world frame, with late stamps, noise and outliers, either absolute
//! (each pose on its own) or relative (a chain of noisy increments). Units, signs and frames
//! are those of [`crate::calibration::pose_reference`]; everything random comes from
//! [`DrivingConfig::seed`], so a configuration always gives the same drive.

use super::gaussian;
use crate::calibration::pose_reference::{
    Geometry, Pose2, PoseRecording, ReferenceKind, ReferencePose, WheelAngles,
};
use crate::kinematics::wrap_angle;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::f64::consts::{PI, TAU};

/// Distance from the start (m) beyond which the robot is steered back toward it.
pub const RETURN_RADIUS_M: f64 = 4.0;
/// Distance from the start (m) at which a steer back ends.
const RETURN_DONE_M: f64 = 2.0;
/// Longest steer back (s) before random driving resumes.
const RETURN_MAX_S: f64 = 30.0;
/// Gain of the heading controller steering back (rad/s per rad).
const RETURN_GAIN: f64 = 2.0;
/// Linear acceleration limit (m/s²).
const ACCEL_M_S2: f64 = 0.5;
/// Angular acceleration limit (rad/s²).
const ALPHA_RAD_S2: f64 = 2.0;
/// Most wheel samples a drive may have (guards against absurd durations or rates).
const MAX_WHEEL_SAMPLES: f64 = 1e8;

/// Errors of the driving simulator: a configuration that cannot be simulated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DrivingError {
    /// A true wheel diameter or the wheelbase is not finite and > 0.
    #[error("true geometry {name} must be finite and > 0, got {value}")]
    Geometry {
        /// Which geometry field.
        name: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A noise level (or slip, or outlier size) is negative or not finite.
    #[error("noise level {name} must be finite and >= 0, got {value}")]
    Noise {
        /// Which noise parameter.
        name: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A rate or the duration is not finite and > 0, or they ask for too many samples.
    #[error("{name} must be finite and > 0 (and give at most 1e8 wheel samples), got {value}")]
    Timing {
        /// Which timing parameter.
        name: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A fraction is outside [0, 1].
    #[error("{name} must be within [0, 1], got {value}")]
    Fraction {
        /// Which fraction.
        name: &'static str,
        /// The offending value.
        value: f64,
    },
    /// Another setting is out of range: a speed limit negative or not finite, a mounting or
    /// delay not finite, encoder counts per revolution not finite and > 0.
    #[error("invalid setting {name}: {value}")]
    Setting {
        /// Which setting.
        name: &'static str,
        /// The offending value.
        value: f64,
    },
}

/// What kind of driving the robot does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DrivingPattern {
    /// Everyday driving: arcs both ways, straights, in-place turns, stops, some reversing.
    #[default]
    Normal,
    /// Straight lines only, forward and back: the wheelbase cannot be observed.
    StraightOnly,
    /// Left turns and straights only, never a right turn.
    TurnOneWay,
}

/// How the simulated robot, its drive and its pose reference behave.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct DrivingConfig {
    /// The robot's true geometry (m).
    pub truth: Geometry,
    /// Length of the drive (s).
    pub duration_s: f64,
    /// Rate of the wheel samples (Hz).
    pub wheel_rate_hz: f64,
    /// Rate of the reference poses (Hz).
    pub reference_rate_hz: f64,
    /// Fastest linear speed (m/s).
    pub max_speed_m_s: f64,
    /// Fastest turn rate (rad/s).
    pub max_turn_rad_s: f64,
    /// x of the reference frame in `base_link` (m).
    pub sensor_x_m: f64,
    /// y of the reference frame in `base_link` (m).
    pub sensor_y_m: f64,
    /// Yaw of the reference frame in `base_link` (rad).
    pub sensor_yaw_rad: f64,
    /// How late the reference's stamps are (s): the pose of true time `t` is stamped
    /// `t + delay_s`.
    pub delay_s: f64,
    /// Standard deviation of each position axis of a reference pose, or of a relative
    /// increment (m).
    pub position_sigma_m: f64,
    /// Standard deviation of a reference yaw, or of a relative increment's yaw (rad).
    pub yaw_sigma_rad: f64,
    /// Probability that a reference pose (absolute) or increment (relative) is an outlier.
    pub outlier_fraction: f64,
    /// Typical size of an outlier's position error (m); each is this size ±50% in a random
    /// direction, with a yaw error of up to ±0.3 rad (absolute) or ±0.1 rad (relative).
    pub outlier_size_m: f64,
    /// Whether the reference's errors accumulate.
    pub kind: ReferenceKind,
    /// A position-only reference (GNSS): every yaw is `None`.
    pub position_only: bool,
    /// What kind of driving.
    pub pattern: DrivingPattern,
    /// Relative standard deviation of each wheel's ground travel per wheel interval (slip).
    pub wheel_slip_sigma: f64,
    /// Encoder counts per wheel revolution: the recorded angles are whole counts; `None`
    /// records exact angles.
    pub encoder_counts_per_rev: Option<f64>,
    /// Seed of every random draw.
    pub seed: u64,
}

impl Default for DrivingConfig {
    /// A small robot (nominal wheels 0.1 m, wheelbase 0.3 m; the truth differs) driven for
    /// five minutes under a motion-capture-like absolute reference.
    fn default() -> Self {
        Self {
            truth: Geometry {
                left_diameter_m: 0.1002,
                right_diameter_m: 0.0998,
                wheelbase_m: 0.312,
            },
            duration_s: 300.0,
            wheel_rate_hz: 50.0,
            reference_rate_hz: 10.0,
            max_speed_m_s: 0.4,
            max_turn_rad_s: 1.0,
            sensor_x_m: 0.12,
            sensor_y_m: -0.05,
            sensor_yaw_rad: 0.1,
            delay_s: 0.06,
            position_sigma_m: 0.003,
            yaw_sigma_rad: 0.3_f64.to_radians(),
            outlier_fraction: 0.01,
            outlier_size_m: 0.3,
            kind: ReferenceKind::Absolute,
            position_only: false,
            pattern: DrivingPattern::Normal,
            wheel_slip_sigma: 0.0,
            encoder_counts_per_rev: None,
            seed: 0,
        }
    }
}

impl DrivingConfig {
    /// The default drive under the typical reference of `kind`: motion capture for an
    /// absolute one (the defaults: 3 mm / 0.3°, 1 % outliers of 15–45 cm), chained scan
    /// matching for a relative one (1 mm and 0.1° per increment, 2 % gross failures of
    /// 5–15 cm that stay in the chain). What `simulate --drive`, the coverage study and the
    /// tests drive.
    pub fn with_reference(kind: ReferenceKind) -> Self {
        match kind {
            ReferenceKind::Absolute => Self::default(),
            ReferenceKind::Relative => Self {
                kind,
                position_sigma_m: 0.001,
                yaw_sigma_rad: 0.1f64.to_radians(),
                outlier_fraction: 0.02,
                outlier_size_m: 0.1,
                ..Self::default()
            },
        }
    }

    /// Checks that the configuration can be simulated.
    pub fn validate(&self) -> Result<(), DrivingError> {
        let g = &self.truth;
        for (name, value) in [
            ("left_diameter_m", g.left_diameter_m),
            ("right_diameter_m", g.right_diameter_m),
            ("wheelbase_m", g.wheelbase_m),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(DrivingError::Geometry { name, value });
            }
        }
        for (name, value) in [
            ("duration_s", self.duration_s),
            ("wheel_rate_hz", self.wheel_rate_hz),
            ("reference_rate_hz", self.reference_rate_hz),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(DrivingError::Timing { name, value });
            }
        }
        if self.duration_s * self.wheel_rate_hz > MAX_WHEEL_SAMPLES {
            return Err(DrivingError::Timing {
                name: "duration_s",
                value: self.duration_s,
            });
        }
        for (name, value) in [
            ("position_sigma_m", self.position_sigma_m),
            ("yaw_sigma_rad", self.yaw_sigma_rad),
            ("outlier_size_m", self.outlier_size_m),
            ("wheel_slip_sigma", self.wheel_slip_sigma),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(DrivingError::Noise { name, value });
            }
        }
        if !(0.0..=1.0).contains(&self.outlier_fraction) {
            return Err(DrivingError::Fraction {
                name: "outlier_fraction",
                value: self.outlier_fraction,
            });
        }
        for (name, value) in [
            ("max_speed_m_s", self.max_speed_m_s),
            ("max_turn_rad_s", self.max_turn_rad_s),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(DrivingError::Setting { name, value });
            }
        }
        for (name, value) in [
            ("sensor_x_m", self.sensor_x_m),
            ("sensor_y_m", self.sensor_y_m),
            ("sensor_yaw_rad", self.sensor_yaw_rad),
            ("delay_s", self.delay_s),
        ] {
            if !value.is_finite() {
                return Err(DrivingError::Setting { name, value });
            }
        }
        if let Some(n) = self.encoder_counts_per_rev {
            if !(n.is_finite() && n > 0.0) {
                return Err(DrivingError::Setting {
                    name: "encoder_counts_per_rev",
                    value: n,
                });
            }
        }
        Ok(())
    }

    /// The reference frame's pose in `base_link`.
    pub fn mounting(&self) -> Pose2 {
        Pose2 {
            x: self.sensor_x_m,
            y: self.sensor_y_m,
            theta: self.sensor_yaw_rad,
        }
    }
}

/// A simulated drive: the recording a calibration sees and the truth behind it.
#[derive(Debug, Clone, PartialEq)]
pub struct SimulatedDrive {
    /// The wheel angles (wheel times from 0) and the reference poses (late stamps).
    pub recording: PoseRecording,
    /// The true geometry the wheels moved with.
    pub truth: Geometry,
    /// The true pose of `base_link` at every wheel sample, at its time (s); it starts at the
    /// origin (the reference's world frame is elsewhere).
    pub true_path: Vec<(f64, Pose2)>,
    /// How many reference poses (absolute) or increments (relative) are outliers.
    pub outliers: usize,
}

/// Simulates a drive as `config` says.
pub fn simulate_drive(config: &DrivingConfig) -> Result<SimulatedDrive, DrivingError> {
    config.validate()?;
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let truth = config.truth;
    let dt = 1.0 / config.wheel_rate_hz;
    // Whole wheel intervals that fit the duration (the float product can sit just under it).
    let intervals = (config.duration_s * config.wheel_rate_hz + 1e-9).floor() as usize;

    // The world frame the reference reports in, drawn first so that it depends on the seed
    // alone.
    let world = Pose2 {
        x: uniform(&mut rng, -20.0, 20.0),
        y: uniform(&mut rng, -20.0, 20.0),
        theta: uniform(&mut rng, -PI, PI),
    };
    let phase_s = uniform(&mut rng, 0.0, 1.0) / config.reference_rate_hz;

    let drive = drive_wheels(config, &mut rng, dt, intervals);
    let sensor = sensor_poses(config, &drive, world, phase_s, dt, intervals);
    let (poses, outliers) = report_poses(config, &mut rng, &sensor);

    Ok(SimulatedDrive {
        recording: PoseRecording {
            wheels: drive.wheels,
            poses,
        },
        truth,
        true_path: drive.true_path,
        outliers,
    })
}

/// The wheels' record of a drive and the true motion behind it.
struct WheelDrive {
    /// The wheel angles at every wheel sample.
    wheels: Vec<WheelAngles>,
    /// The true pose of `base_link` at every wheel sample, at its time (s).
    true_path: Vec<(f64, Pose2)>,
    /// Ground travel (left, right) of each interval, for the reference's interpolation.
    travels: Vec<(f64, f64)>,
}

/// Drives `intervals` wheel intervals of `dt` seconds: the wheel angles and the true path.
fn drive_wheels(
    config: &DrivingConfig,
    rng: &mut ChaCha8Rng,
    dt: f64,
    intervals: usize,
) -> WheelDrive {
    let truth = config.truth;
    let b = truth.wheelbase_m;
    let (hl, hr) = (0.5 * truth.left_diameter_m, 0.5 * truth.right_diameter_m);
    let mut driver = Driver::new(config);
    let mut pose = Pose2::default();
    let (mut left_rad, mut right_rad) = (0.0, 0.0);
    let mut wheels = Vec::with_capacity(intervals + 1);
    let mut true_path = Vec::with_capacity(intervals + 1);
    // Ground travel (left, right) of each interval, for the reference's interpolation.
    let mut travels = Vec::with_capacity(intervals);
    let record = |t: f64, l: f64, r: f64| WheelAngles {
        time_s: t,
        left_rad: quantise(l, config.encoder_counts_per_rev),
        right_rad: quantise(r, config.encoder_counts_per_rev),
    };
    wheels.push(record(0.0, 0.0, 0.0));
    true_path.push((0.0, pose));
    for k in 0..intervals {
        let (v, w) = driver.step(&pose, dt, rng);
        let left = (v - 0.5 * w * b) * dt;
        let right = (v + 0.5 * w * b) * dt;
        left_rad += left / hl;
        right_rad += right / hr;
        let ground_left = left * (1.0 + gaussian(rng, config.wheel_slip_sigma));
        let ground_right = right * (1.0 + gaussian(rng, config.wheel_slip_sigma));
        pose = pose.arc(ground_left, ground_right, b);
        travels.push((ground_left, ground_right));
        let t = (k + 1) as f64 * dt;
        wheels.push(record(t, left_rad, right_rad));
        true_path.push((t, pose));
    }
    WheelDrive {
        wheels,
        true_path,
        travels,
    }
}

/// The reference frame's true poses in the world, at true times inside the wheel span.
fn sensor_poses(
    config: &DrivingConfig,
    drive: &WheelDrive,
    world: Pose2,
    phase_s: f64,
    dt: f64,
    intervals: usize,
) -> Vec<(f64, Pose2)> {
    let b = config.truth.wheelbase_m;
    let (true_path, travels) = (&drive.true_path, &drive.travels);
    let end_s = intervals as f64 * dt;
    let mount = config.mounting();
    let mut sensor = Vec::new();
    for j in 0usize.. {
        let t = phase_s + j as f64 / config.reference_rate_hz;
        if t > end_s {
            break;
        }
        let k = ((t / dt).floor() as usize).min(intervals.saturating_sub(1));
        let base = if intervals == 0 {
            true_path[0].1
        } else {
            let f = ((t - true_path[k].0) / dt).clamp(0.0, 1.0);
            let (gl, gr) = travels[k];
            true_path[k].1.arc(f * gl, f * gr, b)
        };
        sensor.push((t, world.compose(&base).compose(&mount)));
    }
    sensor
}

/// What the reference reports of the `sensor` poses, with how many of them are outliers.
fn report_poses(
    config: &DrivingConfig,
    rng: &mut ChaCha8Rng,
    sensor: &[(f64, Pose2)],
) -> (Vec<ReferencePose>, usize) {
    let mut outliers = 0;
    let mut poses = Vec::with_capacity(sensor.len());
    let mut chained = sensor.first().map(|s| s.1).unwrap_or_default();
    for (j, &(t, true_pose)) in sensor.iter().enumerate() {
        let reported = match config.kind {
            ReferenceKind::Absolute => {
                let mut p = Pose2 {
                    x: true_pose.x + gaussian(rng, config.position_sigma_m),
                    y: true_pose.y + gaussian(rng, config.position_sigma_m),
                    theta: true_pose.theta + gaussian(rng, config.yaw_sigma_rad),
                };
                if chance(rng, config.outlier_fraction) {
                    outliers += 1;
                    displace(rng, &mut p, config.outlier_size_m, 0.3);
                }
                p
            }
            ReferenceKind::Relative => {
                if j > 0 {
                    let mut step = sensor[j - 1].1.between(&true_pose);
                    step.x += gaussian(rng, config.position_sigma_m);
                    step.y += gaussian(rng, config.position_sigma_m);
                    step.theta += gaussian(rng, config.yaw_sigma_rad);
                    if chance(rng, config.outlier_fraction) {
                        outliers += 1;
                        displace(rng, &mut step, config.outlier_size_m, 0.1);
                    }
                    chained = chained.compose(&step);
                }
                chained
            }
        };
        poses.push(ReferencePose {
            time_s: t + config.delay_s,
            x_m: reported.x,
            y_m: reported.y,
            yaw_rad: (!config.position_only).then(|| wrap_angle(reported.theta)),
            stated_std: None,
        });
    }
    (poses, outliers)
}

/// The commanded motion: random segments, smoothed by acceleration limits, with a heading
/// controller that steers the robot back when it strays.
struct Driver {
    pattern: DrivingPattern,
    max_speed: f64,
    max_turn: f64,
    /// Speeds now (m/s, rad/s).
    v: f64,
    w: f64,
    /// Targets of the current segment.
    target_v: f64,
    target_w: f64,
    /// Time left in the current segment, or in the steer back (s).
    left_s: f64,
    returning: bool,
}

impl Driver {
    fn new(config: &DrivingConfig) -> Self {
        Self {
            pattern: config.pattern,
            max_speed: config.max_speed_m_s,
            max_turn: config.max_turn_rad_s,
            v: 0.0,
            w: 0.0,
            target_v: 0.0,
            target_w: 0.0,
            left_s: 0.0,
            returning: false,
        }
    }

    /// The speeds `(v, ω)` held over the next interval of `dt` seconds, the robot being at
    /// `pose` (relative to its start).
    fn step(&mut self, pose: &Pose2, dt: f64, rng: &mut ChaCha8Rng) -> (f64, f64) {
        let r = pose.x.hypot(pose.y);
        if self.returning && (r < RETURN_DONE_M || self.left_s <= 0.0) {
            self.returning = false;
            self.left_s = 0.0;
        }
        if !self.returning && r > RETURN_RADIUS_M {
            self.returning = true;
            self.left_s = RETURN_MAX_S;
        }
        if self.returning {
            self.steer_home(pose);
        } else if self.left_s <= 0.0 {
            self.new_segment(rng);
        }
        self.left_s -= dt;
        self.v += (self.target_v - self.v).clamp(-ACCEL_M_S2 * dt, ACCEL_M_S2 * dt);
        self.w += (self.target_w - self.w).clamp(-ALPHA_RAD_S2 * dt, ALPHA_RAD_S2 * dt);
        if self.pattern == DrivingPattern::StraightOnly {
            self.w = 0.0;
        }
        if self.pattern == DrivingPattern::TurnOneWay {
            self.w = self.w.max(0.0);
        }
        (self.v, self.w)
    }

    /// Targets that turn toward the start and drive there.
    fn steer_home(&mut self, pose: &Pose2) {
        let bearing = (-pose.y).atan2(-pose.x);
        let error = wrap_angle(bearing - pose.theta);
        let cruise = 0.6 * self.max_speed;
        match self.pattern {
            DrivingPattern::StraightOnly => {
                // On a straight line through the start: back up or go ahead, whichever leads
                // home.
                self.target_w = 0.0;
                self.target_v = cruise * error.cos().signum();
            }
            DrivingPattern::Normal => {
                self.target_w = (RETURN_GAIN * error).clamp(-self.max_turn, self.max_turn);
                self.target_v = cruise * error.cos().max(0.0);
            }
            DrivingPattern::TurnOneWay => {
                // Only left: the error counter-clockwise in [0, 2π), a small overshoot
                // counting as none rather than a full circle.
                let mut ccw = error.rem_euclid(TAU);
                if ccw > TAU - 0.2 {
                    ccw = 0.0;
                }
                self.target_w = (RETURN_GAIN * ccw).min(self.max_turn);
                self.target_v = cruise * error.cos().max(0.0);
            }
        }
    }

    /// Draws the next random segment.
    fn new_segment(&mut self, rng: &mut ChaCha8Rng) {
        let draw = uniform(rng, 0.0, 1.0);
        let speed = uniform(rng, -0.2, 1.0) * self.max_speed;
        let turn = match self.pattern {
            DrivingPattern::Normal => uniform(rng, -1.0, 1.0) * self.max_turn,
            DrivingPattern::TurnOneWay => uniform(rng, 0.0, 1.0) * self.max_turn,
            DrivingPattern::StraightOnly => 0.0,
        };
        let (v, w, duration) = if draw < 0.05 {
            // A stop.
            (0.0, 0.0, uniform(rng, 1.0, 3.0))
        } else if draw < 0.35 || self.pattern == DrivingPattern::StraightOnly {
            (speed, 0.0, uniform(rng, 2.0, 6.0))
        } else if draw < 0.50 {
            // In place, at least a fifth of the fastest turn so that it does turn.
            let w = turn.signum() * turn.abs().max(0.2 * self.max_turn);
            (0.0, w, uniform(rng, 2.0, 6.0))
        } else {
            (speed, turn, uniform(rng, 2.0, 6.0))
        };
        self.target_v = v;
        self.target_w = w;
        self.left_s = duration;
    }
}

/// A cumulative angle as whole encoder counts, or as it is.
fn quantise(angle_rad: f64, counts_per_rev: Option<f64>) -> f64 {
    match counts_per_rev {
        Some(n) => (angle_rad * n / TAU).round() * TAU / n,
        None => angle_rad,
    }
}

/// Moves `pose` by an outlier: `size_m` ±50% in a random direction, yaw by up to ±`yaw_rad`.
fn displace(rng: &mut ChaCha8Rng, pose: &mut Pose2, size_m: f64, yaw_rad: f64) {
    let size = size_m * uniform(rng, 0.5, 1.5);
    let direction = uniform(rng, 0.0, TAU);
    pose.x += size * direction.cos();
    pose.y += size * direction.sin();
    pose.theta += uniform(rng, -yaw_rad, yaw_rad);
}

/// A uniform draw in `[lo, hi)`; `lo` when the interval is empty (no panic on a zero limit).
fn uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

/// True with probability `p`; no RNG use when `p` is zero, so turning outliers off never shifts
/// the other random streams.
fn chance(rng: &mut ChaCha8Rng, p: f64) -> bool {
    p > 0.0 && rng.random_bool(p.min(1.0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::pose_reference::Odometry;

    fn quiet(kind: ReferenceKind) -> DrivingConfig {
        DrivingConfig {
            delay_s: 0.0,
            position_sigma_m: 0.0,
            yaw_sigma_rad: 0.0,
            outlier_fraction: 0.0,
            kind,
            seed: 11,
            ..DrivingConfig::default()
        }
    }

    fn inverse(p: &Pose2) -> Pose2 {
        p.between(&Pose2::default())
    }

    /// Checks that every reference pose is `W ∘ odometry(t) ∘ M` with the truth's odometry,
    /// `W` aligned from the first sample.
    fn assert_matches_truth(drive: &SimulatedDrive, config: &DrivingConfig, tol: f64) {
        let rec = &drive.recording;
        let odo = Odometry::integrate(&rec.wheels, drive.truth);
        let mount = config.mounting();
        let mut hint = 0;
        let seen = |p: &ReferencePose| Pose2 {
            x: p.x_m,
            y: p.y_m,
            theta: p.yaw_rad.unwrap_or(f64::NAN),
        };
        let first = &rec.poses[0];
        let base0 = odo.at(first.time_s - config.delay_s, &mut hint).unwrap();
        let world = seen(first).compose(&inverse(&base0.compose(&mount)));
        assert!(rec.poses.len() > 1000);
        for p in &rec.poses {
            let base = odo.at(p.time_s - config.delay_s, &mut hint).unwrap();
            let want = world.compose(&base).compose(&mount);
            assert!((p.x_m - want.x).abs() < tol, "x at {}", p.time_s);
            assert!((p.y_m - want.y).abs() < tol, "y at {}", p.time_s);
            let yaw = p.yaw_rad.unwrap();
            assert!(
                wrap_angle(yaw - want.theta).abs() < tol,
                "yaw at {}",
                p.time_s
            );
            assert!(yaw > -PI && yaw <= PI);
        }
    }

    fn turns(drive: &SimulatedDrive) -> impl Iterator<Item = f64> + '_ {
        drive
            .true_path
            .windows(2)
            .map(|w| w[1].1.theta - w[0].1.theta)
    }

    #[test]
    fn a_seed_gives_the_same_drive() {
        let config = DrivingConfig {
            wheel_slip_sigma: 0.01,
            encoder_counts_per_rev: Some(2048.0),
            seed: 5,
            ..DrivingConfig::default()
        };
        let a = simulate_drive(&config).unwrap();
        let b = simulate_drive(&config).unwrap();
        assert_eq!(a, b);
        let c = simulate_drive(&DrivingConfig { seed: 6, ..config }).unwrap();
        assert_ne!(a.recording, c.recording);
        // Spans and rates as configured: wheel times from 0, the reference inside the span.
        assert_eq!(a.recording.wheels.len(), 15_001);
        assert_eq!(a.recording.wheels[0].time_s, 0.0);
        assert!((a.recording.wheels[15_000].time_s - 300.0).abs() < 1e-9);
        let n = a.recording.poses.len();
        assert!((2999..=3001).contains(&n), "{n} reference poses");
        for p in &a.recording.poses {
            let t = p.time_s - 0.06;
            assert!((0.0..=300.0).contains(&t));
            assert!((t * 50.0 - (t * 50.0).round()).abs() > 1e-9 || t == 0.0);
        }
        // Whole counts.
        for w in &a.recording.wheels {
            let counts = w.left_rad * 2048.0 / TAU;
            assert!((counts - counts.round()).abs() < 1e-6);
        }
    }

    #[test]
    fn a_noise_free_absolute_reference_is_the_mounted_truth() {
        for seed in [1, 2, 3] {
            let config = DrivingConfig {
                seed,
                ..quiet(ReferenceKind::Absolute)
            };
            let drive = simulate_drive(&config).unwrap();
            assert_eq!(drive.outliers, 0);
            assert_matches_truth(&drive, &config, 1e-9);
        }
        // A delay only shifts the stamps.
        let config = DrivingConfig {
            delay_s: 0.06,
            ..quiet(ReferenceKind::Absolute)
        };
        assert_matches_truth(&simulate_drive(&config).unwrap(), &config, 1e-9);
    }

    #[test]
    fn a_noise_free_relative_chain_is_the_mounted_truth() {
        let config = quiet(ReferenceKind::Relative);
        let drive = simulate_drive(&config).unwrap();
        assert_matches_truth(&drive, &config, 1e-8);
    }

    #[test]
    fn straight_only_never_turns() {
        let config = DrivingConfig {
            pattern: DrivingPattern::StraightOnly,
            ..DrivingConfig::default()
        };
        let drive = simulate_drive(&config).unwrap();
        assert!(drive.true_path.iter().all(|(_, p)| p.theta == 0.0));
        // It does move, both ways, and stays near its start.
        let xs: Vec<f64> = drive.true_path.iter().map(|(_, p)| p.x).collect();
        let steps = xs.windows(2).map(|w| w[1] - w[0]);
        assert!(steps.clone().filter(|d| *d > 0.0).sum::<f64>() > 10.0);
        assert!(steps.filter(|d| *d < 0.0).sum::<f64>() < -10.0);
        assert!(xs.iter().all(|x| x.abs() < 7.0));
    }

    #[test]
    fn turn_one_way_never_turns_right() {
        for seed in [1, 2, 3] {
            let config = DrivingConfig {
                pattern: DrivingPattern::TurnOneWay,
                seed,
                ..DrivingConfig::default()
            };
            let drive = simulate_drive(&config).unwrap();
            assert!(turns(&drive).all(|d| d >= -1e-12));
            assert!(drive.true_path.last().unwrap().1.theta > 10.0);
            let far = drive.true_path.iter().map(|(_, p)| p.x.hypot(p.y));
            assert!(far.fold(0.0, f64::max) < 8.0);
        }
    }

    #[test]
    fn normal_driving_turns_both_ways_and_stays_in_its_area() {
        for seed in 0..5 {
            let config = DrivingConfig {
                seed,
                ..DrivingConfig::default()
            };
            let drive = simulate_drive(&config).unwrap();
            let left: f64 = turns(&drive).filter(|d| *d > 0.0).sum();
            let right: f64 = turns(&drive).filter(|d| *d < 0.0).sum();
            assert!(left > PI && right < -PI, "seed {seed}: {left} {right}");
            let far = drive
                .true_path
                .iter()
                .map(|(_, p)| p.x.abs().max(p.y.abs()));
            assert!(far.fold(0.0, f64::max) < 6.5, "seed {seed}");
            // Some reversing, some in-place turning.
            let path = &drive.true_path;
            let back = path.windows(2).any(|w| {
                let step = w[0].1.between(&w[1].1);
                step.x < -1e-4
            });
            assert!(back, "seed {seed}");
        }
    }

    #[test]
    fn outliers_are_counted_and_displace() {
        let config = DrivingConfig {
            outlier_fraction: 0.1,
            ..quiet(ReferenceKind::Absolute)
        };
        let drive = simulate_drive(&config).unwrap();
        let n = drive.recording.poses.len() as f64;
        let sd = (n * 0.1 * 0.9).sqrt();
        assert!(
            (drive.outliers as f64 - 0.1 * n).abs() < 5.0 * sd,
            "{}",
            drive.outliers
        );
        // Without noise, exactly the outliers sit far from the truth.
        let clean = simulate_drive(&DrivingConfig {
            outlier_fraction: 0.0,
            ..config.clone()
        })
        .unwrap();
        let moved = drive
            .recording
            .poses
            .iter()
            .zip(&clean.recording.poses)
            .filter(|(a, b)| (a.x_m - b.x_m).hypot(a.y_m - b.y_m) > 0.14)
            .count();
        assert_eq!(moved, drive.outliers);
        // Every sample, or none.
        let all = simulate_drive(&DrivingConfig {
            outlier_fraction: 1.0,
            ..config.clone()
        })
        .unwrap();
        assert_eq!(all.outliers, all.recording.poses.len());
        // Relative: outliers are increments, the first pose has none.
        let rel = simulate_drive(&DrivingConfig {
            outlier_fraction: 1.0,
            kind: ReferenceKind::Relative,
            ..config
        })
        .unwrap();
        assert_eq!(rel.outliers, rel.recording.poses.len() - 1);
    }

    #[test]
    fn noise_slip_and_position_only_behave() {
        let config = DrivingConfig {
            position_only: true,
            ..DrivingConfig::default()
        };
        let drive = simulate_drive(&config).unwrap();
        assert!(!drive.recording.has_yaw());
        assert!(drive.recording.poses.iter().all(|p| p.stated_std.is_none()));
        // Slip: the wheels' odometry with the truth no longer follows the true path.
        let slipping = simulate_drive(&DrivingConfig {
            wheel_slip_sigma: 0.05,
            ..quiet(ReferenceKind::Absolute)
        })
        .unwrap();
        let odo = Odometry::integrate(&slipping.recording.wheels, slipping.truth);
        let end = odo.poses().last().unwrap();
        let truth = slipping.true_path.last().unwrap().1;
        assert!((end.x - truth.x).hypot(end.y - truth.y) > 1e-3);
    }

    #[test]
    fn bad_configurations_are_typed_errors() {
        let ok = DrivingConfig::default();
        assert!(ok.validate().is_ok());
        let cases = [
            DrivingConfig {
                position_sigma_m: f64::NAN,
                ..ok.clone()
            },
            DrivingConfig {
                yaw_sigma_rad: -1.0,
                ..ok.clone()
            },
            DrivingConfig {
                wheel_slip_sigma: f64::INFINITY,
                ..ok.clone()
            },
        ];
        for c in &cases {
            assert!(matches!(simulate_drive(c), Err(DrivingError::Noise { .. })));
        }
        for c in [
            DrivingConfig {
                wheel_rate_hz: 0.0,
                ..ok.clone()
            },
            DrivingConfig {
                reference_rate_hz: -10.0,
                ..ok.clone()
            },
            DrivingConfig {
                duration_s: 0.0,
                ..ok.clone()
            },
            DrivingConfig {
                duration_s: 1e12,
                ..ok.clone()
            },
        ] {
            assert!(matches!(
                simulate_drive(&c),
                Err(DrivingError::Timing { .. })
            ));
        }
        let bad_geometry = DrivingConfig {
            truth: Geometry {
                wheelbase_m: 0.0,
                ..ok.truth
            },
            ..ok.clone()
        };
        assert!(matches!(
            simulate_drive(&bad_geometry),
            Err(DrivingError::Geometry {
                name: "wheelbase_m",
                ..
            })
        ));
        for f in [-0.1, 1.5, f64::NAN] {
            let c = DrivingConfig {
                outlier_fraction: f,
                ..ok.clone()
            };
            assert!(matches!(
                simulate_drive(&c),
                Err(DrivingError::Fraction { .. })
            ));
        }
        let c = DrivingConfig {
            encoder_counts_per_rev: Some(0.0),
            ..ok.clone()
        };
        assert!(matches!(
            simulate_drive(&c),
            Err(DrivingError::Setting { .. })
        ));
        let c = DrivingConfig {
            delay_s: f64::NAN,
            ..ok
        };
        assert!(matches!(
            simulate_drive(&c),
            Err(DrivingError::Setting { .. })
        ));
    }
}
