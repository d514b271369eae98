//! Online calibration: an augmented extended Kalman filter that estimates the odometry
//! parameters from encoder increments and heading readings — or the poses of an absolute
//! reference (motion capture, a localization) — while the robot drives any path.
//!
//! # State
//! `[x, y, θ, u_L, u_R, k, β, m_x, m_y, m_ψ]`: the pose (m, m, rad; CCW positive), the two combinations a
//! heading sensor can observe — `u = (D_actual / D_configured) / E_b` per wheel, exactly the
//! exact square inversion's `u_L`, `u_R` — the wheel scale `k = E_b` (observable only with
//! absolute position fixes; otherwise it keeps its prior), and an optional constant heading
//! bias `β`. With true wheel travel `k·u·s` for a configured travel `s`:
//!
//! `Δθ = (u_R s_R − u_L s_L) / b_cfg`, `Δs = k (u_R s_R + u_L s_L) / 2`,
//! `x += Δs cos(θ + Δθ/2)`, `y += Δs sin(θ + Δθ/2)`.
//!
//! `m = (m_x, m_y, m_ψ)` is where a pose reference's frame sits in `base_link` (the
//! conventions of [`super::pose_reference`]); it stays at its prior unless poses come. A pose
//! fix of the reference frame in its world frame is `h = (x + m_x cos θ − m_y sin θ,
//! y + m_x sin θ + m_y cos θ, θ + m_ψ)` (yaw innovation wrapped): the filter's world is the
//! reference's, anchored by the first fix ([`OnlineEstimator::update_pose`]). With poses, `k`
//! and so both diameters and the wheelbase in metres are observed ([`ScaleSource::Filter`]).
//! The filter treats the reference as absolute (its errors independent from fix to fix); a
//! reference chained from sample to sample (scan matching) is for the batch fit
//! ([`super::pose_fit`]), and so is the time offset between the streams, which the filter
//! takes as given.
//!
//! # Noise models
//! Each wheel's configured travel per step is uncertain by `σ = slip_fraction·|s| +
//! count_noise·(m per count)` (slip and quantisation), propagated through the motion Jacobian.
//! The parameters may drift as a random walk of `parameter_walk` per √m driven (0 by default:
//! they are constants). Heading readings have standard deviation `heading_sigma_rad`; position
//! fixes `position_sigma_m` per axis. Innovations of heading are wrapped to (−π, π].
//!
//! # Consistency and robustness
//! Every update records its normalised innovation squared (NIS); [`OnlineEstimator::nis_mean`]
//! should be near 1 for heading and 2 for position fixes when the noise models are right.
//! A heading reading whose NIS exceeds the gate (`gate_nis`, χ²₁ at 99.9 % by default: a reading
//! that far off is a sensor glitch, a magnetic disturbance or a bump, not information about the
//! wheels) is rejected and counted, and does not enter the mean. So that a real step in the
//! heading (a compass re-levelled, the robot picked up and put down) cannot lock the filter out
//! for good, `gate_recover_after` rejections in a row re-anchor the heading to the reading,
//! keeping the parameters and counting a reset.
//!
//! # Excitation
//! A path observes a parameter only if it excites it: straight driving observes `E_d` (a
//! diameter difference curves the path), turning observes `E_b`. [`OnlineEstimator::excitation`]
//! compares each parameter's posterior standard deviation with its prior one and gives a verdict,
//! so "± 0.04" on a path with no turns is reported as *not observed*, not as a measurement.

use super::CalibrationError;
use crate::kinematics::{wrap_angle, Correction, SplitConvention, WheelParams};
use nalgebra::{Matrix2, SMatrix, SVector, Vector2};
use serde::{Deserialize, Serialize};

mod estimate;
pub use estimate::*;
mod update;
use update::*;

/// Number of state variables.
pub const N: usize = 10;
type Vector = SVector<f64, N>;
type Matrix = SMatrix<f64, N, N>;

const X: usize = 0;
const Y: usize = 1;
const TH: usize = 2;
const UL: usize = 3;
const UR: usize = 4;
const K: usize = 5;
const BIAS: usize = 6;
const MX: usize = 7;
const MY: usize = 8;
const MPSI: usize = 9;

/// Noise models and priors of the filter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OnlineConfig {
    /// Parameters the encoder counts are converted with (the controller's, during the drive).
    pub configured: WheelParams,
    /// Relative standard deviation of each wheel's travel per step (slip).
    pub slip_fraction: f64,
    /// Standard deviation of each wheel's count per step (quantisation), in counts.
    pub count_noise: f64,
    /// Standard deviation of one heading reading (rad).
    pub heading_sigma_rad: f64,
    /// Standard deviation of a position fix per axis (m).
    pub position_sigma_m: f64,
    /// Prior standard deviation of `u_L`, `u_R` around 1.
    pub ratio_prior_sigma: f64,
    /// Prior standard deviation of the wheel scale `k` around 1.
    pub scale_prior_sigma: f64,
    /// Estimate a constant heading bias (needs position fixes or a known initial heading).
    pub estimate_heading_bias: bool,
    /// Prior standard deviation of the heading bias (rad).
    pub bias_prior_sigma_rad: f64,
    /// Random walk of `u_L`, `u_R`, `k` per √m driven (0: constants).
    pub parameter_walk: f64,
    /// Heading readings with a NIS above this are rejected (`f64::INFINITY`: no gating).
    pub gate_nis: f64,
    /// After this many rejections in a row the heading is re-anchored to the reading.
    pub gate_recover_after: u32,
    /// Prior standard deviation of the pose reference's lever arm `m_x`, `m_y` around 0 (m).
    #[serde(default = "default_mount_prior_m")]
    pub mount_prior_sigma_m: f64,
    /// Prior standard deviation of the pose reference's yaw in `base_link` around 0 (rad).
    #[serde(default = "default_mount_yaw_prior_rad")]
    pub mount_yaw_prior_sigma_rad: f64,
}

fn default_mount_prior_m() -> f64 {
    0.5
}

fn default_mount_yaw_prior_rad() -> f64 {
    0.5
}

/// χ² at 99.9 % with two and three degrees of freedom: the gate of a pose fix without and
/// with yaw.
const CHI2_2_999: f64 = 13.816;
const CHI2_3_999: f64 = 16.266;

/// χ² with one degree of freedom at 99.9 %.
pub const CHI2_1_999: f64 = 10.828;

/// Fewer "counts" per wheel revolution than this mean the wheel is measured as an angle, not
/// counted (a ROS robot's joint states: 2π per revolution).
const ANGLE_UNITS_BELOW: f64 = 100.0;

/// The quantisation assumed for a wheel measured as an angle: a 4096-count encoder's.
const ASSUMED_COUNTS_PER_REV: f64 = 4096.0;

impl OnlineConfig {
    /// Defaults for a robot whose controller is configured with `configured`.
    pub fn new(configured: WheelParams) -> Self {
        // Half a count of quantisation; for a wheel measured as an angle, one count of a
        // 4096-count encoder in its units.
        let count_noise = if configured.counts_per_wheel_rev < ANGLE_UNITS_BELOW {
            configured.counts_per_wheel_rev / ASSUMED_COUNTS_PER_REV
        } else {
            0.5
        };
        OnlineConfig {
            configured,
            slip_fraction: 0.01,
            count_noise,
            heading_sigma_rad: 0.37f64.to_radians(),
            position_sigma_m: 0.01,
            ratio_prior_sigma: 0.05,
            scale_prior_sigma: 0.05,
            estimate_heading_bias: false,
            bias_prior_sigma_rad: 0.1,
            parameter_walk: 0.0,
            gate_nis: CHI2_1_999,
            gate_recover_after: 25,
            mount_prior_sigma_m: default_mount_prior_m(),
            mount_yaw_prior_sigma_rad: default_mount_yaw_prior_rad(),
        }
    }
}

/// The augmented EKF.
#[derive(Debug, Clone)]
pub struct OnlineEstimator {
    cfg: OnlineConfig,
    x: Vector,
    p: Matrix,
    heading_initialized: bool,
    /// Whether a pose fix has put the filter's pose in the reference's world frame.
    anchored: bool,
    fix_noise: FixNoise,
    distance_m: f64,
    nis_heading: (f64, u64),
    nis_position: (f64, u64),
    nis_pose: (f64, u64),
    prior: Matrix,
    gate: GateStats,
    rejected_in_a_row: u32,
}

impl OnlineEstimator {
    /// A filter at the prior: parameters nominal, pose at the origin, heading unknown until the
    /// first reading.
    pub fn new(cfg: OnlineConfig) -> Result<Self, CalibrationError> {
        cfg.configured.validate()?;
        for (name, v) in [
            ("slip_fraction", cfg.slip_fraction),
            ("count_noise", cfg.count_noise),
            ("parameter_walk", cfg.parameter_walk),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(CalibrationError::BadGeometry { name, value: v });
            }
        }
        if cfg.gate_nis.is_nan() || cfg.gate_nis <= 0.0 {
            return Err(CalibrationError::BadGeometry {
                name: "gate_nis",
                value: cfg.gate_nis,
            });
        }
        for (name, v) in [
            ("heading_sigma_rad", cfg.heading_sigma_rad),
            ("position_sigma_m", cfg.position_sigma_m),
            ("ratio_prior_sigma", cfg.ratio_prior_sigma),
            ("scale_prior_sigma", cfg.scale_prior_sigma),
            ("bias_prior_sigma_rad", cfg.bias_prior_sigma_rad),
            ("mount_prior_sigma_m", cfg.mount_prior_sigma_m),
            ("mount_yaw_prior_sigma_rad", cfg.mount_yaw_prior_sigma_rad),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(CalibrationError::BadGeometry { name, value: v });
            }
        }
        let mut x = Vector::zeros();
        x[UL] = 1.0;
        x[UR] = 1.0;
        x[K] = 1.0;
        let mut p = Matrix::zeros();
        p[(UL, UL)] = cfg.ratio_prior_sigma.powi(2);
        p[(UR, UR)] = cfg.ratio_prior_sigma.powi(2);
        p[(K, K)] = cfg.scale_prior_sigma.powi(2);
        if cfg.estimate_heading_bias {
            p[(BIAS, BIAS)] = cfg.bias_prior_sigma_rad.powi(2);
        }
        p[(MX, MX)] = cfg.mount_prior_sigma_m.powi(2);
        p[(MY, MY)] = cfg.mount_prior_sigma_m.powi(2);
        p[(MPSI, MPSI)] = cfg.mount_yaw_prior_sigma_rad.powi(2);
        Ok(OnlineEstimator {
            cfg,
            x,
            p,
            heading_initialized: false,
            anchored: false,
            fix_noise: FixNoise {
                stated_scale: [1.0, 1.0],
                unstated: None,
            },
            distance_m: 0.0,
            nis_heading: (0.0, 0),
            nis_position: (0.0, 0),
            nis_pose: (0.0, 0),
            prior: p,
            gate: GateStats::default(),
            rejected_in_a_row: 0,
        })
    }

    /// What the heading gate did so far.
    pub fn gate_stats(&self) -> GateStats {
        self.gate
    }

    /// The configuration.
    pub fn config(&self) -> &OnlineConfig {
        &self.cfg
    }

    /// The state `[x, y, θ, u_L, u_R, k, β, m_x, m_y, m_ψ]`.
    pub fn state(&self) -> Vector {
        self.x
    }

    /// The state covariance.
    pub fn covariance(&self) -> Matrix {
        self.p
    }

    /// Distance driven (m, by odometry).
    pub fn distance_m(&self) -> f64 {
        self.distance_m
    }

    /// Starts a new run: the pose goes back to the origin (exactly known) and the heading is
    /// taken from the next reading; the parameters and their uncertainty carry over.
    pub fn restart_pose(&mut self) {
        for i in [X, Y, TH] {
            self.x[i] = 0.0;
            for j in 0..N {
                self.p[(i, j)] = 0.0;
                self.p[(j, i)] = 0.0;
            }
        }
        self.heading_initialized = false;
        self.anchored = false;
    }

    /// Predicts with encoder count increments since the last step.
    pub fn predict_counts(&mut self, left_counts: f64, right_counts: f64) {
        let c = &self.cfg.configured;
        self.predict_travel(
            left_counts * c.left_m_per_count(),
            right_counts * c.right_m_per_count(),
        );
    }

    /// Predicts with the wheel travels the configured parameters imply (m).
    pub fn predict_travel(&mut self, s_l: f64, s_r: f64) {
        let b = self.cfg.configured.wheelbase_m;
        let (ul, ur, k, th) = (self.x[UL], self.x[UR], self.x[K], self.x[TH]);
        let step = crate::kinematics::Displacement::of_wheels(ul * s_l, ur * s_r, b);
        let dth = step.turn_rad;
        let ds = k * step.distance_m;
        let phi = th + 0.5 * dth;
        let (sp, cp) = phi.sin_cos();

        // State Jacobian: identity except the pose rows.
        let d_dth = [-s_l / b, s_r / b]; // ∂Δθ/∂(u_L, u_R)
        let d_ds = [0.5 * k * s_l, 0.5 * k * s_r]; // ∂Δs/∂(u_L, u_R)
        let mut f = Matrix::identity();
        f[(X, TH)] = -ds * sp;
        f[(Y, TH)] = ds * cp;
        for (col, i) in [(UL, 0), (UR, 1)] {
            f[(X, col)] = cp * d_ds[i] - 0.5 * ds * sp * d_dth[i];
            f[(Y, col)] = sp * d_ds[i] + 0.5 * ds * cp * d_dth[i];
            f[(TH, col)] = d_dth[i];
        }
        f[(X, K)] = cp * step.distance_m;
        f[(Y, K)] = sp * step.distance_m;

        // Input Jacobian and input noise.
        let g_dth = [-ul / b, ur / b];
        let g_ds = [0.5 * k * ul, 0.5 * k * ur];
        let mpc = [
            self.cfg.configured.left_m_per_count(),
            self.cfg.configured.right_m_per_count(),
        ];
        let mut q = Matrix::zeros();
        for (i, s) in [s_l, s_r].into_iter().enumerate() {
            let sigma = self.cfg.slip_fraction * s.abs() + self.cfg.count_noise * mpc[i];
            let var = sigma * sigma;
            let g = [
                cp * g_ds[i] - 0.5 * ds * sp * g_dth[i],
                sp * g_ds[i] + 0.5 * ds * cp * g_dth[i],
                g_dth[i],
            ];
            for r in 0..3 {
                for c2 in 0..3 {
                    q[(r, c2)] += g[r] * g[c2] * var;
                }
            }
        }
        let travelled = ds.abs().max(0.5 * (s_l.abs() + s_r.abs()) * k);
        if self.cfg.parameter_walk > 0.0 {
            let w = self.cfg.parameter_walk.powi(2) * travelled;
            q[(UL, UL)] += w;
            q[(UR, UR)] += w;
            q[(K, K)] += w;
        }

        self.x[X] += ds * cp;
        self.x[Y] += ds * sp;
        self.x[TH] = wrap_angle(th + dth);
        self.p = f * self.p * f.transpose() + q;
        self.distance_m += ds.abs();
    }

    /// Mean NIS of the pose fixes used, per degree of freedom (≈ 1 for a consistent filter),
    /// and their count.
    pub fn nis_pose_mean(&self) -> (f64, u64) {
        let (s, n) = self.nis_pose;
        (if n > 0 { s / n as f64 } else { f64::NAN }, n)
    }

    /// The pose reference's mounting in `base_link` (x, y in m, yaw in rad) and its standard
    /// deviations.
    pub fn mount(&self) -> ([f64; 3], [f64; 3]) {
        (
            [self.x[MX], self.x[MY], self.x[MPSI]],
            [MX, MY, MPSI].map(|i| self.p[(i, i)].max(0.0).sqrt()),
        )
    }

    /// Mean NIS of heading updates (≈ 1 for a consistent filter) and their count.
    pub fn nis_mean(&self) -> (f64, u64) {
        let (s, n) = self.nis_heading;
        (if n > 0 { s / n as f64 } else { f64::NAN }, n)
    }

    /// Mean NIS of position fixes (≈ 2 for a consistent filter) and their count.
    pub fn nis_position_mean(&self) -> (f64, u64) {
        let (s, n) = self.nis_position;
        (if n > 0 { s / n as f64 } else { f64::NAN }, n)
    }

    /// NEES of `(u_L, u_R)` against known true values (≈ 2 on average when consistent).
    pub fn nees_ratios(&self, true_u_l: f64, true_u_r: f64) -> f64 {
        let e = Vector2::new(self.x[UL] - true_u_l, self.x[UR] - true_u_r);
        let p = Matrix2::new(
            self.p[(UL, UL)],
            self.p[(UL, UR)],
            self.p[(UR, UL)],
            self.p[(UR, UR)],
        );
        p.try_inverse()
            .map_or(f64::INFINITY, |pi| (e.transpose() * pi * e)[(0, 0)])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drift_names_each_parameter_in_use_off_by_more_than_its_uncertainty_allows() {
        let configured = WheelParams::nominal(0.15, 0.39, 4096.0);
        let mut e = OnlineEstimate {
            method: "online",
            e_b: 0.976,
            e_d: 0.99995,
            e_b_std: 1e-4,
            e_d_std: 1e-4,
            correction: Correction {
                left_diameter_scale: 1.0001,
                right_diameter_scale: 0.992,
                wheelbase_scale: 0.976,
            },
            correction_std: Some([1e-4; 3]),
            distance_m: 10.0,
        };
        let d = e.drift(&configured, 3.0);
        let names: Vec<&str> = d.iter().map(|d| d.parameter).collect();
        assert_eq!(names, ["right_wheel_diameter_m", "wheelbase_m"]);
        assert!((d[1].estimate - 0.39 * 0.976).abs() < 1e-12);
        assert!((d[1].std - 0.39e-4).abs() < 1e-12);
        assert!((d[1].sigmas + 240.0).abs() < 1e-6, "{}", d[1].sigmas);
        // Heading only: the ratios, against 1.
        e.correction_std = None;
        let names: Vec<&str> = e
            .drift(&configured, 3.0)
            .iter()
            .map(|d| d.parameter)
            .collect();
        assert_eq!(names, ["E_b"]);
    }

    #[test]
    fn bad_configurations_are_refused() {
        let mut cfg = OnlineConfig::new(WheelParams::nominal(0.15, 0.39, 4096.0));
        cfg.heading_sigma_rad = 0.0;
        assert!(OnlineEstimator::new(cfg).is_err());
        let cfg = OnlineConfig::new(WheelParams::nominal(-0.15, 0.39, 4096.0));
        assert!(OnlineEstimator::new(cfg).is_err());
    }

    #[test]
    fn straight_driving_alone_leaves_the_ratios_at_their_prior_correlation() {
        // Driving straight only observes u_R − u_L (through heading drift), not their mean.
        let mut f =
            OnlineEstimator::new(OnlineConfig::new(WheelParams::nominal(0.15, 0.39, 4096.0)))
                .unwrap();
        f.update_heading(0.0);
        for _ in 0..1000 {
            f.predict_travel(0.01, 0.01);
            f.update_heading(0.0);
        }
        let p = f.covariance();
        let diff_var = p[(UL, UL)] + p[(UR, UR)] - 2.0 * p[(UL, UR)];
        let sum_var = p[(UL, UL)] + p[(UR, UR)] + 2.0 * p[(UL, UR)];
        assert!(diff_var < 1e-6, "u_R − u_L is learned: {diff_var}");
        assert!(sum_var > 1e-3, "u_R + u_L is not: {sum_var}");
    }

    /// Drives `n` steps of `(s_l, s_r)` configured travel on a robot whose true `u` are
    /// `(0.99, 1.01)`, reading the true heading after each step plus `glitch(step number)`,
    /// counting steps from `start`.
    fn drive(
        f: &mut OnlineEstimator,
        heading: &mut f64,
        (start, n): (usize, usize),
        step: (f64, f64),
        glitch: impl Fn(usize) -> f64,
    ) {
        let (ul, ur, b) = (0.99, 1.01, f.config().configured.wheelbase_m);
        for i in start..start + n {
            f.predict_travel(step.0, step.1);
            *heading +=
                crate::kinematics::Displacement::of_wheels(ul * step.0, ur * step.1, b).turn_rad;
            f.update_heading(wrap_angle(*heading + glitch(i)));
        }
    }

    fn filter() -> OnlineEstimator {
        OnlineEstimator::new(OnlineConfig::new(WheelParams::nominal(0.15, 0.39, 4096.0))).unwrap()
    }

    /// Squares' worth of straight stretches and turns both ways.
    fn tour(f: &mut OnlineEstimator, glitch: impl Fn(usize) -> f64 + Copy) {
        let mut heading = 0.0;
        f.update_heading(0.0);
        for k in 0..8 {
            drive(f, &mut heading, (200 * k, 100), (0.01, 0.01), glitch);
            let turn = if k % 2 == 0 { 0.006 } else { -0.006 };
            drive(f, &mut heading, (200 * k + 100, 100), (-turn, turn), glitch);
        }
    }

    #[test]
    fn glitches_are_gated_and_counted_and_a_lasting_step_is_recovered() {
        let mut clean = filter();
        tour(&mut clean, |_| 0.0);
        let mut noisy = filter();
        tour(&mut noisy, |i| if i % 37 == 5 { 0.5 } else { 0.0 });
        let g = noisy.gate_stats();
        // 1600 steps, a glitch every 37th: 44 glitches, every one rejected, nothing else.
        assert_eq!(g.rejected, 44, "{g:?}");
        assert_eq!(g.resets, 0);
        assert_eq!(g.accepted, clean.gate_stats().accepted - 44);
        let (a, b) = (
            clean
                .estimate(ScaleSource::Convention(SplitConvention::LeftNominal))
                .unwrap(),
            noisy
                .estimate(ScaleSource::Convention(SplitConvention::LeftNominal))
                .unwrap(),
        );
        assert!(
            (a.e_b - b.e_b).abs() < 1e-4 && (a.e_d - b.e_d).abs() < 1e-4,
            "{a:?} {b:?}"
        );
        // Without the gate the same glitches pull the estimate and the NIS far off.
        let mut cfg = OnlineConfig::new(WheelParams::nominal(0.15, 0.39, 4096.0));
        cfg.gate_nis = f64::INFINITY;
        let mut ungated = OnlineEstimator::new(cfg).unwrap();
        tour(&mut ungated, |i| if i % 37 == 5 { 0.5 } else { 0.0 });
        assert!(ungated.nis_mean().0 > 100.0 * noisy.nis_mean().0.max(1e-3));

        // A lasting step of 0.3 rad after 500 steps: 25 rejections, one reset, then accepted.
        let mut stepped = filter();
        tour(&mut stepped, |i| if i >= 500 { 0.3 } else { 0.0 });
        let g = stepped.gate_stats();
        assert_eq!((g.rejected, g.resets), (25, 1), "{g:?}");
        let e = stepped
            .estimate(ScaleSource::Convention(SplitConvention::LeftNominal))
            .unwrap();
        assert!((e.e_d - 1.01 / 0.99).abs() < 2e-3, "{e:?}");
    }

    #[test]
    fn the_excitation_verdict_names_what_the_path_did_not_observe() {
        let scale = ScaleSource::Convention(SplitConvention::MeanPreserving);
        let mut heading = 0.0;
        let mut straight = filter();
        straight.update_heading(0.0);
        drive(&mut straight, &mut heading, (0, 500), (0.01, 0.01), |_| 0.0);
        let x = straight.excitation(scale).unwrap();
        assert_eq!((x.e_b, x.e_d), (Observed::No, Observed::Yes), "{x:?}");
        assert!(x.advice().unwrap().contains("turn"));

        let mut heading = 0.0;
        let mut spin = filter();
        spin.update_heading(0.0);
        drive(&mut spin, &mut heading, (0, 500), (-0.006, 0.006), |_| 0.0);
        let x = spin.excitation(scale).unwrap();
        assert_eq!((x.e_b, x.e_d), (Observed::Yes, Observed::No), "{x:?}");
        assert!(x.advice().unwrap().contains("straight"));

        let mut both = filter();
        tour(&mut both, |_| 0.0);
        let x = both.excitation(scale).unwrap();
        assert_eq!((x.e_b, x.e_d), (Observed::Yes, Observed::Yes), "{x:?}");
        assert_eq!(x.advice(), None);
    }
}
