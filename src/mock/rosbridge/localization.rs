//! The mock robot's localization: a `geometry_msgs/PoseWithCovarianceStamped` topic (as AMCL's
//! `/amcl_pose`, or a motion-capture bridge's) carrying the pose of a frame mounted on the
//! robot in a world frame of its own, at a slower rate than the wheels, with noise, occasional
//! jumps (a relocalisation, a marker swap) and late stamps — what `odocal track --reference`
//! and `fit` must calibrate through ([`crate::calibration::pose_reference`]'s conventions).

use crate::calibration::pose_reference::Pose2;
use crate::kinematics::Pose;
use crate::ros::msg::{
    Covariance36, Header, PoseWithCovariance, PoseWithCovarianceStamped, Quaternion, Time, Vector3,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// What the localization publishes, and how it errs.
#[derive(Debug, Clone, PartialEq)]
pub struct MockLocalization {
    /// Its topic.
    pub topic: String,
    /// Messages per second of robot time.
    pub rate_hz: f64,
    /// The frame it locates, in `base_link` (x, y in m; yaw in rad): zero for a localization
    /// of `base_link` itself.
    pub mount: Pose2,
    /// Where the robot's start is in the localization's world frame (x, y in m; yaw in rad).
    pub world: Pose2,
    /// Noise of x and y (m; σ).
    pub position_sigma_m: f64,
    /// Noise of the yaw (rad; σ).
    pub yaw_sigma_rad: f64,
    /// Probability that a message is a jump of 15–45 cm.
    pub outlier_fraction: f64,
    /// How late its stamps are (s): the pose stamped `t` is the robot's at `t − delay_s`.
    pub delay_s: f64,
}

impl MockLocalization {
    /// `/amcl_pose` at 10 Hz of `base_link` itself, 3 mm and 0.3° of noise, 1 % jumps, stamps
    /// on time, in a world frame 5 m off with the robot facing 60°.
    pub fn amcl() -> Self {
        MockLocalization {
            topic: "/amcl_pose".into(),
            rate_hz: 10.0,
            mount: Pose2::default(),
            world: Pose2 {
                x: 5.0,
                y: -3.0,
                theta: 60f64.to_radians(),
            },
            position_sigma_m: 0.003,
            yaw_sigma_rad: 0.3f64.to_radians(),
            outlier_fraction: 0.01,
            delay_s: 0.0,
        }
    }
}

/// The localization's state in the mock's physics loop.
pub(super) struct Localizer {
    cfg: MockLocalization,
    rng: ChaCha8Rng,
    next_s: f64,
}

impl Localizer {
    pub(super) fn new(cfg: MockLocalization, seed: u64) -> Self {
        Localizer {
            cfg,
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0x10ca_112e),
            next_s: 0.0,
        }
    }

    /// The message due at robot time `t_s` for the true pose `truth` (in the robot's start
    /// frame), stamped by `stamp` (robot time → header seconds), if one is due.
    pub(super) fn at(
        &mut self,
        t_s: f64,
        truth: &Pose,
        stamp: impl Fn(f64) -> f64,
    ) -> Option<(String, PoseWithCovarianceStamped)> {
        if t_s + 1e-9 < self.next_s || self.cfg.rate_hz.is_nan() || self.cfg.rate_hz <= 0.0 {
            return None;
        }
        // The next stamp due after this one (several periods on when the physics stepped far).
        while self.next_s <= t_s + 1e-9 {
            self.next_s += 1.0 / self.cfg.rate_hz;
        }
        let base = Pose2 {
            x: truth.x_m,
            y: truth.y_m,
            theta: truth.heading_rad,
        };
        let p = self.cfg.world.compose(&base).compose(&self.cfg.mount);
        let c = &self.cfg;
        let (mut x, mut y) = (
            p.x + crate::sim::gaussian(&mut self.rng, c.position_sigma_m),
            p.y + crate::sim::gaussian(&mut self.rng, c.position_sigma_m),
        );
        let yaw = p.theta + crate::sim::gaussian(&mut self.rng, c.yaw_sigma_rad);
        if self.rng.random_bool(c.outlier_fraction.clamp(0.0, 1.0)) {
            let size = 0.3 * self.rng.random_range(0.5..1.5);
            let dir: f64 = self.rng.random_range(0.0..std::f64::consts::TAU);
            x += size * dir.cos();
            y += size * dir.sin();
        }
        let mut covariance = [0.0; 36];
        covariance[0] = c.position_sigma_m.powi(2);
        covariance[7] = c.position_sigma_m.powi(2);
        covariance[35] = c.yaw_sigma_rad.powi(2);
        Some((
            c.topic.clone(),
            PoseWithCovarianceStamped {
                header: Header {
                    stamp: Time::from_seconds(stamp(t_s + c.delay_s)),
                    frame_id: "map".into(),
                },
                pose: PoseWithCovariance {
                    pose: crate::ros::msg::Pose {
                        position: Vector3 { x, y, z: 0.0 },
                        orientation: Quaternion::from_yaw(crate::kinematics::wrap_angle(yaw)),
                    },
                    covariance: Covariance36(covariance),
                },
            },
        ))
    }
}
