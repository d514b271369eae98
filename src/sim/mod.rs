//! Kinematic simulator: a true robot driven open-loop by a controller that believes its own
//! configured parameters, with optional, seeded sensor and wheel noise.
//!
//! The controller turns "straight `L`" and "turn `φ` in place" into wheel-rotation targets
//! computed from its *configured* parameters; the true robot then moves those rotations with
//! its *true* parameters, integrated exactly ([`Pose::advance`]). The mismatch between the two
//! is the systematic odometry error the calibration estimates. Every noise source is off by
//! default, so a default simulator is deterministic and exact. How its heading sensor errs
//! (deviation, a gyro's scale, latency, loss…) is [`sensor`]'s.

pub mod driving;
pub mod options;
pub mod sensor;

pub use crate::kinematics::Direction;
use crate::kinematics::{wrap_angle, Displacement, KinematicsError, Pose, WheelParams};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use sensor::{HeadingModel, HeadingSensor};
use serde::{Deserialize, Serialize};
use std::f64::consts::FRAC_PI_2;

/// Errors of the simulator.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    /// The true or configured parameters are impossible.
    #[error("invalid {which} parameters: {source}")]
    Params {
        /// "true" or "configured".
        which: &'static str,
        /// What is wrong with them.
        source: KinematicsError,
    },
    /// A noise level is negative or not finite.
    #[error("noise level {name} must be finite and >= 0, got {value}")]
    Noise {
        /// Which noise parameter.
        name: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A motion or square command that cannot be executed (non-finite or non-positive size).
    #[error("invalid motion: {0}")]
    Motion(String),
    /// A setting the simulator cannot simulate (the message names the flag and its range).
    #[error("{0}")]
    Setting(String),
}

/// Optional, seeded imperfections. All are off by default.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct NoiseModel {
    /// Standard deviation of each compass reading (rad).
    pub compass_sigma_rad: f64,
    /// Constant compass bias (rad); it cancels in final-minus-start heading errors.
    pub compass_bias_rad: f64,
    /// Round wheel targets to whole encoder counts, as a real controller must.
    pub quantise_encoders: bool,
    /// Relative standard deviation of each wheel's travel per motion (wheel slip).
    pub wheel_slip_sigma: f64,
    /// Standard deviation of each axis of a measured final position (m), e.g. a tape measure
    /// or an external tracker; it only affects the position-based methods.
    #[serde(default)]
    pub position_sigma_m: f64,
}

impl NoiseModel {
    fn validate(&self) -> Result<(), SimError> {
        for (name, value) in [
            ("compass_sigma_rad", self.compass_sigma_rad),
            ("compass_bias_rad", self.compass_bias_rad.abs()),
            ("wheel_slip_sigma", self.wheel_slip_sigma),
            ("position_sigma_m", self.position_sigma_m),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(SimError::Noise { name, value });
            }
        }
        Ok(())
    }
}

/// An open-loop motion primitive as a controller executes it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Motion {
    /// Drive straight this far (m, negative for reverse).
    Straight {
        /// Distance (m).
        distance_m: f64,
    },
    /// Turn in place by this angle (rad, counter-clockwise positive).
    TurnInPlace {
        /// Angle (rad).
        angle_rad: f64,
    },
    /// Turn each wheel by the rotation that moves it this far by the configured parameters
    /// (m; a wheel-speed command run for a while).
    Wheels {
        /// Left wheel travel (m).
        left_m: f64,
        /// Right wheel travel (m).
        right_m: f64,
    },
}

/// One motion as planned: the controller's wheel targets and the true wheel travel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionPlan {
    /// Left wheel target (encoder counts).
    pub left_counts: f64,
    /// Right wheel target (encoder counts).
    pub right_counts: f64,
    /// True left wheel travel (m), slip included.
    pub left_arc_m: f64,
    /// True right wheel travel (m), slip included.
    pub right_arc_m: f64,
}

/// What one executed motion did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionOutcome {
    /// Encoder counts the left wheel turned (whole counts if quantised).
    pub left_counts: f64,
    /// Encoder counts the right wheel turned.
    pub right_counts: f64,
    /// True pose after the motion.
    pub pose: Pose,
}

/// One square run: what was measured and what truly happened.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SquareRun {
    /// Direction driven.
    pub direction: Direction,
    /// Final-minus-start heading error as the compass measured it (rad, CCW positive, wrapped).
    pub measured_heading_error_rad: f64,
    /// True final-minus-start heading error (rad, wrapped).
    pub true_heading_error_rad: f64,
    /// True final pose in the start frame (x along the first leg, y to its left).
    pub final_pose: Pose,
    /// Final position in the start frame as measured (true position plus measurement noise).
    pub measured_final_xy_m: [f64; 2],
    /// True pose after each motion, in the start frame, starting with the origin.
    pub path: Vec<Pose>,
}

/// The simulator: a true robot, a controller's configured parameters, noise, and a seeded RNG.
#[derive(Debug, Clone)]
pub struct Simulator {
    truth: WheelParams,
    configured: WheelParams,
    noise: NoiseModel,
    rng: ChaCha8Rng,
    pose: Pose,
    start_pose: Pose,
    left_counts_total: f64,
    right_counts_total: f64,
    sensor: HeadingSensor,
}

impl Simulator {
    /// A simulator for a robot with `truth` parameters whose controller is configured with
    /// `configured`; `seed` makes every noise draw reproducible.
    pub fn new(
        truth: WheelParams,
        configured: WheelParams,
        noise: NoiseModel,
        seed: u64,
    ) -> Result<Self, SimError> {
        truth.validate().map_err(|source| SimError::Params {
            which: "true",
            source,
        })?;
        configured.validate().map_err(|source| SimError::Params {
            which: "configured",
            source,
        })?;
        noise.validate()?;
        Ok(Self {
            truth,
            configured,
            noise,
            rng: ChaCha8Rng::seed_from_u64(seed),
            pose: Pose::default(),
            start_pose: Pose::default(),
            left_counts_total: 0.0,
            right_counts_total: 0.0,
            sensor: HeadingSensor::new(HeadingModel::default()),
        })
    }

    /// The same simulator whose heading sensor errs as `model` says.
    pub fn with_heading_model(mut self, model: HeadingModel) -> Result<Self, SimError> {
        model
            .validate()
            .map_err(|(name, value)| SimError::Noise { name, value })?;
        self.sensor = HeadingSensor::new(model);
        Ok(self)
    }

    /// How the heading sensor errs.
    pub fn heading_model(&self) -> &HeadingModel {
        self.sensor.model()
    }

    /// The simulation's clock is at `t_s` (s): a gyro's bias integrates, a latency looks back
    /// from here. A mock that runs in time sets it before it reads the heading.
    pub fn set_time(&mut self, t_s: f64) {
        self.sensor.advance_to(t_s, &mut self.rng);
    }

    /// Sets where each square run starts (its heading tests angle wrapping, e.g. −179.9°).
    pub fn with_start_pose(mut self, start: Pose) -> Self {
        self.start_pose = start;
        self.pose = start;
        self
    }

    /// The true parameters.
    pub fn truth(&self) -> &WheelParams {
        &self.truth
    }

    /// The controller's configured parameters.
    pub fn configured(&self) -> &WheelParams {
        &self.configured
    }

    /// Writes new parameters to the controller (what a calibration write-back does).
    pub fn set_configured(&mut self, configured: WheelParams) -> Result<(), SimError> {
        configured.validate().map_err(|source| SimError::Params {
            which: "configured",
            source,
        })?;
        self.configured = configured;
        Ok(())
    }

    /// The noise model in force.
    pub fn noise(&self) -> &NoiseModel {
        &self.noise
    }

    /// The robot's true pose now.
    pub fn pose(&self) -> Pose {
        self.pose
    }

    /// Places the robot at `pose` (a person carrying it back to the start).
    pub fn place(&mut self, pose: Pose) {
        self.pose = pose;
    }

    /// Cumulative encoder counts `(left, right)` since the simulator was made.
    pub fn encoder_counts(&self) -> (f64, f64) {
        (self.left_counts_total, self.right_counts_total)
    }

    /// Zeroes the cumulative encoder counts (the controller's odometry reset).
    pub fn reset_encoders(&mut self) {
        self.left_counts_total = 0.0;
        self.right_counts_total = 0.0;
    }

    /// A reading of the heading sensor now: CCW positive, wrapped, with the noise and bias of
    /// the noise model and the errors of the heading model ([`sensor`]); `None` when the
    /// reading is lost.
    pub fn heading_reading(&mut self) -> Option<f64> {
        let noise = gaussian(&mut self.rng, self.noise.compass_sigma_rad);
        self.heading_reading_with(noise)
    }

    /// [`Simulator::heading_reading`] with noise the caller drew (rad).
    pub fn heading_reading_with(&mut self, noise_rad: f64) -> Option<f64> {
        let seen = self.pose.heading_rad + self.noise.compass_bias_rad;
        self.sensor.read(seen, noise_rad, &mut self.rng)
    }

    /// A reading of the heading sensor that cannot be lost (simulated studies, bags): as
    /// [`Simulator::heading_reading`], a lost reading read again.
    pub fn read_heading(&mut self) -> f64 {
        loop {
            if let Some(h) = self.heading_reading() {
                return wrap_angle(h);
            }
        }
    }

    /// The wheel targets (encoder counts, left and right) the controller computes for `motion`.
    pub fn wheel_targets(&self, motion: &Motion) -> (f64, f64) {
        let c = &self.configured;
        let (left_arc, right_arc) = match *motion {
            Motion::Straight { distance_m } => (distance_m, distance_m),
            Motion::TurnInPlace { angle_rad } => Displacement {
                distance_m: 0.0,
                turn_rad: angle_rad,
            }
            .wheels(c.wheelbase_m),
            Motion::Wheels { left_m, right_m } => (left_m, right_m),
        };
        let mut left = left_arc / c.left_m_per_count();
        let mut right = right_arc / c.right_m_per_count();
        if self.noise.quantise_encoders {
            left = left.round();
            right = right.round();
        }
        (left, right)
    }

    /// Plans one motion open-loop: the wheel targets and the true wheel travel (slip drawn now).
    pub fn plan(&mut self, motion: &Motion) -> Result<MotionPlan, SimError> {
        let size = match *motion {
            Motion::Straight { distance_m } => distance_m,
            Motion::TurnInPlace { angle_rad } => angle_rad,
            Motion::Wheels { left_m, right_m } => left_m + right_m,
        };
        if !size.is_finite() {
            return Err(SimError::Motion(format!("{motion:?} is not finite")));
        }
        let (left_counts, right_counts) = self.wheel_targets(motion);
        let slip = self.noise.wheel_slip_sigma;
        let left_arc_m =
            left_counts * self.truth.left_m_per_count() * (1.0 + gaussian(&mut self.rng, slip));
        let right_arc_m =
            right_counts * self.truth.right_m_per_count() * (1.0 + gaussian(&mut self.rng, slip));
        Ok(MotionPlan {
            left_counts,
            right_counts,
            left_arc_m,
            right_arc_m,
        })
    }

    /// Moves the robot through the part `from..to` (fractions in [0, 1]) of a planned motion.
    ///
    /// Wheel speeds keep a constant ratio within a motion, so its path is one circular arc and
    /// any split into parts lands exactly where the whole motion does.
    pub fn advance_plan(&mut self, plan: &MotionPlan, from: f64, to: f64) -> Pose {
        let f = (to.clamp(0.0, 1.0) - from.clamp(0.0, 1.0)).max(0.0);
        if f > 0.0 && (plan.left_arc_m != 0.0 || plan.right_arc_m != 0.0) {
            let step = Displacement::of_wheels(
                f * plan.left_arc_m,
                f * plan.right_arc_m,
                self.truth.wheelbase_m,
            );
            self.sensor.moved(step.turn_rad);
        }
        self.pose = self.pose.advance(
            f * plan.left_arc_m,
            f * plan.right_arc_m,
            self.truth.wheelbase_m,
        );
        self.left_counts_total += f * plan.left_counts;
        self.right_counts_total += f * plan.right_counts;
        self.pose
    }

    /// Turns the wheels by these encoder counts (a free-path drive step, e.g. 10 ms of a wheel
    /// speed command): the true robot moves by the counts times its true travel per count,
    /// with this step's slip drawn from the noise model. Returns the true pose.
    pub fn step_counts(&mut self, left_counts: f64, right_counts: f64) -> Pose {
        let slip = self.noise.wheel_slip_sigma;
        let plan = MotionPlan {
            left_counts,
            right_counts,
            left_arc_m: left_counts
                * self.truth.left_m_per_count()
                * (1.0 + gaussian(&mut self.rng, slip)),
            right_arc_m: right_counts
                * self.truth.right_m_per_count()
                * (1.0 + gaussian(&mut self.rng, slip)),
        };
        self.advance_plan(&plan, 0.0, 1.0)
    }

    /// Draws the slip of one motion: the factors (left, right) by which each wheel's true
    /// travel differs from its commanded travel, 1 without slip noise.
    pub fn slip_factors(&mut self) -> (f64, f64) {
        let slip = self.noise.wheel_slip_sigma;
        (
            1.0 + gaussian(&mut self.rng, slip),
            1.0 + gaussian(&mut self.rng, slip),
        )
    }

    /// Executes one motion open-loop and moves the true robot.
    pub fn execute(&mut self, motion: &Motion) -> Result<MotionOutcome, SimError> {
        let plan = self.plan(motion)?;
        let pose = self.advance_plan(&plan, 0.0, 1.0);
        Ok(MotionOutcome {
            left_counts: plan.left_counts,
            right_counts: plan.right_counts,
            pose,
        })
    }

    /// The motions of one open-loop square: four times (straight `side_m`, turn ±90°).
    pub fn square_motions(side_m: f64, direction: Direction) -> Vec<Motion> {
        (0..4)
            .flat_map(|_| {
                [
                    Motion::Straight { distance_m: side_m },
                    Motion::TurnInPlace {
                        angle_rad: direction.turn_sign() * FRAC_PI_2,
                    },
                ]
            })
            .collect()
    }

    /// Drives one square from the start pose, reading the compass at rest before and after.
    pub fn run_square(&mut self, side_m: f64, direction: Direction) -> Result<SquareRun, SimError> {
        if !(side_m.is_finite() && side_m > 0.0) {
            return Err(SimError::Motion(format!(
                "square side must be finite and > 0, got {side_m}"
            )));
        }
        let start = self.start_pose;
        self.place(start);
        let heading_before = self.read_heading();
        let mut path = vec![Pose::default()];
        for motion in Self::square_motions(side_m, direction) {
            let out = self.execute(&motion)?;
            path.push(out.pose.relative_to(&start));
        }
        let heading_after = self.read_heading();
        let final_pose = self.pose.relative_to(&start);
        let sigma = self.noise.position_sigma_m;
        let measured_final_xy_m = [
            final_pose.x_m + gaussian(&mut self.rng, sigma),
            final_pose.y_m + gaussian(&mut self.rng, sigma),
        ];
        Ok(SquareRun {
            direction,
            measured_heading_error_rad: wrap_angle(heading_after - heading_before),
            true_heading_error_rad: final_pose.heading_rad,
            final_pose,
            measured_final_xy_m,
            path,
        })
    }

    /// Drives `runs` squares clockwise, then `runs` counter-clockwise.
    pub fn run_square_test(
        &mut self,
        side_m: f64,
        runs: usize,
    ) -> Result<(Vec<SquareRun>, Vec<SquareRun>), SimError> {
        let cw = (0..runs)
            .map(|_| self.run_square(side_m, Direction::Cw))
            .collect::<Result<Vec<_>, _>>()?;
        let ccw = (0..runs)
            .map(|_| self.run_square(side_m, Direction::Ccw))
            .collect::<Result<Vec<_>, _>>()?;
        Ok((cw, ccw))
    }
}

/// One zero-mean normal draw; exactly zero (and no RNG use) when `sigma` is zero, so turning a
/// noise source off never shifts the other sources' random streams.
pub(crate) fn gaussian(rng: &mut ChaCha8Rng, sigma: f64) -> f64 {
    if sigma > 0.0 {
        // sigma was validated finite and positive, so Normal::new cannot fail here.
        Normal::new(0.0, sigma).map_or(0.0, |n| n.sample(rng))
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn nominal() -> WheelParams {
        WheelParams::nominal(0.15, 0.39, 4096.0)
    }

    #[test]
    fn perfect_robot_closes_the_square() {
        let mut sim = Simulator::new(nominal(), nominal(), NoiseModel::default(), 1).unwrap();
        for dir in [Direction::Cw, Direction::Ccw] {
            let run = sim.run_square(4.0, dir).unwrap();
            assert!(run.final_pose.distance_m() < 1e-12);
            assert!(run.measured_heading_error_rad.abs() < 1e-12);
            // First leg runs along +x; the CCW square lies to the left (+y).
            assert_relative_eq!(run.path[1].x_m, 4.0, epsilon = 1e-12);
            let y_corner = run.path[3].y_m;
            assert_relative_eq!(y_corner, 4.0 * dir.turn_sign(), epsilon = 1e-12);
        }
    }

    #[test]
    fn short_wheelbase_overshoots_turns() {
        // b_actual < b_configured: each in-place turn overshoots, so a CCW square ends CCW of
        // its start and a CW square ends CW of it.
        let truth = WheelParams {
            wheelbase_m: 0.38,
            ..nominal()
        };
        let mut sim = Simulator::new(truth, nominal(), NoiseModel::default(), 1).unwrap();
        let ccw = sim.run_square(2.0, Direction::Ccw).unwrap();
        let cw = sim.run_square(2.0, Direction::Cw).unwrap();
        let expected = 2.0 * std::f64::consts::PI * (0.39 / 0.38 - 1.0);
        assert_relative_eq!(ccw.true_heading_error_rad, expected, epsilon = 1e-12);
        assert_relative_eq!(cw.true_heading_error_rad, -expected, epsilon = 1e-12);
    }

    #[test]
    fn compass_bias_cancels_and_wrapping_survives_minus_180() {
        let truth = WheelParams {
            wheelbase_m: 0.38,
            ..nominal()
        };
        let noise = NoiseModel {
            compass_bias_rad: 0.3,
            ..NoiseModel::default()
        };
        let start = Pose::new(0.0, 0.0, (-179.9f64).to_radians());
        let mut sim = Simulator::new(truth, nominal(), noise, 1)
            .unwrap()
            .with_start_pose(start);
        let run = sim.run_square(2.0, Direction::Cw).unwrap();
        assert_relative_eq!(
            run.measured_heading_error_rad,
            run.true_heading_error_rad,
            epsilon = 1e-12
        );
        assert!(run.true_heading_error_rad < 0.0);
    }

    #[test]
    fn quantisation_rounds_targets_and_seeds_reproduce() {
        let noise = NoiseModel {
            quantise_encoders: true,
            compass_sigma_rad: 0.01,
            wheel_slip_sigma: 0.001,
            ..NoiseModel::default()
        };
        let mut a = Simulator::new(nominal(), nominal(), noise, 7).unwrap();
        let mut b = Simulator::new(nominal(), nominal(), noise, 7).unwrap();
        let (l, r) = a.wheel_targets(&Motion::Straight { distance_m: 1.0 });
        assert_eq!(l.fract(), 0.0);
        assert_eq!(r.fract(), 0.0);
        assert_eq!(
            a.run_square(1.0, Direction::Cw).unwrap(),
            b.run_square(1.0, Direction::Cw).unwrap()
        );
    }

    #[test]
    fn a_motion_split_into_parts_ends_where_the_whole_does() {
        let truth = WheelParams {
            right_wheel_diameter_m: 0.149,
            ..nominal()
        };
        let mut whole = Simulator::new(truth, nominal(), NoiseModel::default(), 3).unwrap();
        let mut parts = whole.clone();
        let m = Motion::Straight { distance_m: 2.0 };
        let end = whole.execute(&m).unwrap().pose;
        let plan = parts.plan(&m).unwrap();
        for k in 0..7 {
            parts.advance_plan(&plan, k as f64 / 7.0, (k + 1) as f64 / 7.0);
        }
        assert!((parts.pose().x_m - end.x_m).abs() < 1e-12);
        assert!((parts.pose().y_m - end.y_m).abs() < 1e-12);
        assert!((parts.encoder_counts().1 - whole.encoder_counts().1).abs() < 1e-9);
    }

    #[test]
    fn bad_inputs_are_typed_errors() {
        let bad = WheelParams {
            wheelbase_m: -1.0,
            ..nominal()
        };
        assert!(matches!(
            Simulator::new(bad, nominal(), NoiseModel::default(), 0),
            Err(SimError::Params { which: "true", .. })
        ));
        let noise = NoiseModel {
            compass_sigma_rad: f64::NAN,
            ..NoiseModel::default()
        };
        assert!(matches!(
            Simulator::new(nominal(), nominal(), noise, 0),
            Err(SimError::Noise { .. })
        ));
        let mut sim = Simulator::new(nominal(), nominal(), NoiseModel::default(), 0).unwrap();
        assert!(sim.run_square(0.0, Direction::Cw).is_err());
        assert!(sim
            .execute(&Motion::Straight {
                distance_m: f64::INFINITY
            })
            .is_err());
    }
}
