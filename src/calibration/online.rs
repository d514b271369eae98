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

/// How well the path observed one parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Observed {
    /// Posterior standard deviation below a fifth of the prior's.
    Yes,
    /// Between a fifth and 60 % of the prior's: the estimate leans on the prior.
    Weakly,
    /// Above 60 %: the path did not excite it; the value is the prior's.
    No,
}

impl std::fmt::Display for Observed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Observed::Yes => "observed",
            Observed::Weakly => "weakly observed",
            Observed::No => "not observed",
        })
    }
}

impl Observed {
    fn from_ratio(r: f64) -> Self {
        if r < 0.2 {
            Observed::Yes
        } else if r < 0.6 {
            Observed::Weakly
        } else {
            Observed::No
        }
    }
}

/// The excitation verdict: posterior over prior standard deviation per parameter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Excitation {
    /// Verdict on `E_b` (observed by turning).
    pub e_b: Observed,
    /// Verdict on `E_d` (observed by driving straight or along curves).
    pub e_d: Observed,
    /// Posterior/prior standard deviation of `E_b`.
    pub e_b_ratio: f64,
    /// Posterior/prior standard deviation of `E_d`.
    pub e_d_ratio: f64,
}

impl Excitation {
    /// What the user should drive to observe what is not yet observed, if anything.
    pub fn advice(&self) -> Option<&'static str> {
        match (self.e_b, self.e_d) {
            (Observed::Yes, Observed::Yes) => None,
            (Observed::Yes, _) => Some("E_d is not observed: drive straight stretches (a metre or more) while the heading is read"),
            (_, Observed::Yes) => Some("E_b is not observed: turn (in place or tightly), both ways, while the heading is read"),
            _ => Some("neither parameter is observed: drive straight stretches and turns both ways while the heading is read"),
        }
    }
}

/// Counts of the gate (heading readings, or pose fixes when a pose reference is used).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct GateStats {
    /// Readings used.
    pub accepted: u64,
    /// Readings rejected by the gate.
    pub rejected: u64,
    /// Times the heading was re-anchored after `gate_recover_after` rejections in a row.
    pub resets: u64,
}

/// Where the absolute wheel scale comes from when turning the state into parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum ScaleSource {
    /// A split convention (heading-only operation).
    Convention(SplitConvention),
    /// The filter's own scale `k` (meaningful with position fixes).
    Filter,
}

/// The filter's current answer.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct OnlineEstimate {
    /// Always "online".
    pub method: &'static str,
    /// `E_b` under the chosen scale source.
    pub e_b: f64,
    /// `E_d = u_R / u_L`.
    pub e_d: f64,
    /// Standard deviation of `e_b`.
    pub e_b_std: f64,
    /// Standard deviation of `e_d`.
    pub e_d_std: f64,
    /// Factors to apply to the configured parameters.
    pub correction: Correction,
    /// Standard deviations of the factors (left diameter, right diameter, wheelbase) when the
    /// filter observes the absolute scale ([`ScaleSource::Filter`]: pose or position fixes).
    pub correction_std: Option<[f64; 3]>,
    /// Distance driven so far (m, by odometry).
    pub distance_m: f64,
}

/// A parameter's estimate beside the value in use ([`OnlineEstimate::against`]); a drift
/// when they differ by more than the uncertainty allows ([`OnlineEstimate::drift`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Drift {
    /// The parameter (with its unit).
    pub parameter: &'static str,
    /// The value in use (the controller's).
    pub in_use: f64,
    /// The value the drive says.
    pub estimate: f64,
    /// One standard deviation of the estimate.
    pub std: f64,
    /// `(estimate − in_use) / std`.
    pub sigmas: f64,
}

impl OnlineEstimate {
    /// The parameters in use (`configured`) that are off by more than `sigmas` standard
    /// deviations of this estimate ([`OnlineEstimate::against`]).
    pub fn drift(&self, configured: &WheelParams, sigmas: f64) -> Vec<Drift> {
        self.against(configured)
            .into_iter()
            .filter(|d| d.sigmas.abs() > sigmas)
            .collect()
    }

    /// Each parameter's estimate beside its value in use (`configured`): both diameters and
    /// the wheelbase in metres when the scale is observed, else `E_d` and `E_b` (1 in use);
    /// those without a finite positive standard deviation left out.
    pub fn against(&self, configured: &WheelParams) -> Vec<Drift> {
        let c = &self.correction;
        let rows: Vec<(&'static str, f64, f64, f64)> = match self.correction_std {
            Some([sl, sr, sb]) => vec![
                (
                    "left_wheel_diameter_m",
                    configured.left_wheel_diameter_m,
                    c.left_diameter_scale,
                    sl,
                ),
                (
                    "right_wheel_diameter_m",
                    configured.right_wheel_diameter_m,
                    c.right_diameter_scale,
                    sr,
                ),
                ("wheelbase_m", configured.wheelbase_m, c.wheelbase_scale, sb),
            ]
            .into_iter()
            .map(|(name, v, f, sf)| (name, v, v * f, v * sf))
            .collect(),
            None => vec![
                ("E_d", 1.0, self.e_d, self.e_d_std),
                ("E_b", 1.0, self.e_b, self.e_b_std),
            ],
        };
        rows.into_iter()
            .filter(|(_, _, _, std)| *std > 0.0 && std.is_finite())
            .map(|(parameter, in_use, estimate, std)| Drift {
                parameter,
                in_use,
                estimate,
                std,
                sigmas: (estimate - in_use) / std,
            })
            .collect()
    }
}

/// The noise of pose fixes as a batch fit of the drive found it.
#[derive(Debug, Clone, Copy)]
struct FixNoise {
    /// Factors on the standard deviations a fix states (position, yaw).
    stated_scale: [f64; 2],
    /// Standard deviations of fixes that state none (x, y in m; yaw in rad).
    unstated: Option<[f64; 3]>,
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

    /// Updates with a heading reading (rad, counter-clockwise positive). Returns the
    /// normalised innovation squared, or `None` for the first reading (it sets the heading), a
    /// non-finite one, or one rejected by the gate.
    pub fn update_heading(&mut self, heading_rad: f64) -> Option<f64> {
        if !heading_rad.is_finite() {
            return None;
        }
        let r = self.cfg.heading_sigma_rad.powi(2);
        if !self.heading_initialized {
            self.x[TH] = wrap_angle(heading_rad - self.x[BIAS]);
            self.p[(TH, TH)] = r;
            self.heading_initialized = true;
            return None;
        }
        let mut h = SVector::<f64, N>::zeros();
        h[TH] = 1.0;
        if self.cfg.estimate_heading_bias {
            h[BIAS] = 1.0;
        }
        let innovation = wrap_angle(heading_rad - (self.x[TH] + self.x[BIAS]));
        let ph = self.p * h;
        let s = h.dot(&ph) + r;
        let nis = innovation * innovation / s;
        if nis > self.cfg.gate_nis {
            self.gate.rejected += 1;
            self.rejected_in_a_row += 1;
            if self.rejected_in_a_row >= self.cfg.gate_recover_after.max(1) {
                // A lasting step, not a glitch: take the heading from here, keep the parameters.
                for j in 0..N {
                    self.p[(TH, j)] = 0.0;
                    self.p[(j, TH)] = 0.0;
                }
                self.x[TH] = wrap_angle(heading_rad - self.x[BIAS]);
                self.p[(TH, TH)] = r;
                self.gate.resets += 1;
                self.rejected_in_a_row = 0;
            }
            return None;
        }
        self.rejected_in_a_row = 0;
        self.gate.accepted += 1;
        let kgain = ph / s;
        self.x += kgain * innovation;
        self.x[TH] = wrap_angle(self.x[TH]);
        // Joseph form keeps P symmetric and positive over millions of updates.
        let ikh = Matrix::identity() - kgain * h.transpose();
        self.p = ikh * self.p * ikh.transpose() + kgain * kgain.transpose() * r;
        self.nis_heading.0 += nis;
        self.nis_heading.1 += 1;
        Some(nis)
    }

    /// Updates with an absolute position fix (m, in the frame the run started in). Returns the
    /// normalised innovation squared.
    pub fn update_position(&mut self, x_m: f64, y_m: f64) -> Option<f64> {
        if !(x_m.is_finite() && y_m.is_finite()) {
            return None;
        }
        let r = self.cfg.position_sigma_m.powi(2);
        let mut h = SMatrix::<f64, 2, N>::zeros();
        h[(0, X)] = 1.0;
        h[(1, Y)] = 1.0;
        let nu = Vector2::new(x_m - self.x[X], y_m - self.x[Y]);
        let s = h * self.p * h.transpose() + Matrix2::identity() * r;
        let s_inv = s.try_inverse()?;
        let kgain = self.p * h.transpose() * s_inv;
        self.x += kgain * nu;
        let ikh = Matrix::identity() - kgain * h;
        self.p = ikh * self.p * ikh.transpose() + kgain * kgain.transpose() * r;
        let nis = (nu.transpose() * s_inv * nu)[(0, 0)];
        self.nis_position.0 += nis;
        self.nis_position.1 += 1;
        Some(nis)
    }

    /// Updates with a pose of the reference frame in the reference's world frame (m, m and
    /// rad; `yaw_rad` `None` for a position-only reference) with standard deviations
    /// `sigma` (x, y in m, yaw in rad; `None`: the configured `position_sigma_m` and
    /// `heading_sigma_rad`). The first fix of a run anchors the pose (it needs a yaw): the
    /// filter's world becomes the reference's, the pose's uncertainty the mounting's. A fix
    /// whose NIS exceeds χ² at 99.9 % (a relocalisation, a marker swap) is rejected and
    /// counted; `gate_recover_after` rejections in a row re-anchor the pose to the reference,
    /// keeping the parameters. Returns the NIS of an accepted fix.
    pub fn update_pose(
        &mut self,
        x_m: f64,
        y_m: f64,
        yaw_rad: Option<f64>,
        sigma: Option<[f64; 3]>,
    ) -> Option<f64> {
        if !(x_m.is_finite() && y_m.is_finite() && yaw_rad.is_none_or(f64::is_finite)) {
            return None;
        }
        // Stated deviations as the start's batch fit scaled them (a localization's covariance
        // is a weight, seldom a calibrated variance); none stated: the fit's residual scatter,
        // else the configured noise. Only the components used must be stated (a position-only
        // reference states no yaw).
        let usable = |v: f64| v.is_finite() && v > 0.0;
        let stated =
            sigma.filter(|s| usable(s[0]) && usable(s[1]) && (yaw_rad.is_none() || usable(s[2])));
        let noise = self.fix_noise;
        let [sx, sy, syaw] = match stated {
            Some(s) => [
                s[0] * noise.stated_scale[0],
                s[1] * noise.stated_scale[0],
                if usable(s[2]) {
                    s[2] * noise.stated_scale[1]
                } else {
                    self.cfg.heading_sigma_rad
                },
            ],
            None => noise.unstated.unwrap_or([
                self.cfg.position_sigma_m,
                self.cfg.position_sigma_m,
                self.cfg.heading_sigma_rad,
            ]),
        };
        if !self.anchored {
            let Some(yaw) = yaw_rad else {
                // A position-only fix cannot tell which way the robot faces.
                return None;
            };
            self.anchor(x_m, y_m, yaw, [sx * sx, sy * sy, syaw * syaw]);
            return None;
        }
        let dim = if yaw_rad.is_some() { 3 } else { 2 };
        let r = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(
            sx * sx,
            sy * sy,
            if yaw_rad.is_some() { syaw * syaw } else { 1.0 },
        ));
        // The measurement's Jacobian and innovation at state `x` (position only: the yaw row
        // drops out — zero row, unit variance, zero innovation: it neither informs nor counts).
        let linearise = |x: &Vector| {
            let (s, c) = x[TH].sin_cos();
            let (mx, my) = (x[MX], x[MY]);
            let mut h = SMatrix::<f64, 3, N>::zeros();
            h[(0, X)] = 1.0;
            h[(0, TH)] = -s * mx - c * my;
            h[(0, MX)] = c;
            h[(0, MY)] = -s;
            h[(1, Y)] = 1.0;
            h[(1, TH)] = c * mx - s * my;
            h[(1, MX)] = s;
            h[(1, MY)] = c;
            let mut nu = nalgebra::Vector3::new(
                x_m - (x[X] + c * mx - s * my),
                y_m - (x[Y] + s * mx + c * my),
                0.0,
            );
            if let Some(yaw) = yaw_rad {
                h[(2, TH)] = 1.0;
                h[(2, MPSI)] = 1.0;
                nu[2] = wrap_angle(yaw - (x[TH] + x[MPSI]));
            }
            (h, nu)
        };
        let (h0, nu0) = linearise(&self.x);
        let s_inv = (h0 * self.p * h0.transpose() + r).try_inverse()?;
        let nis = (nu0.transpose() * s_inv * nu0)[(0, 0)];
        let gate = if dim == 3 { CHI2_3_999 } else { CHI2_2_999 };
        if nis.is_nan() || nis > gate {
            self.gate.rejected += 1;
            self.rejected_in_a_row += 1;
            if self.rejected_in_a_row >= self.cfg.gate_recover_after.max(1) {
                if let Some(yaw) = yaw_rad {
                    // The reference moved its world (a relocalisation): start from it again.
                    self.anchor(x_m, y_m, yaw, [sx * sx, sy * sy, syaw * syaw]);
                    self.gate.resets += 1;
                }
                self.rejected_in_a_row = 0;
            }
            return None;
        }
        self.rejected_in_a_row = 0;
        self.gate.accepted += 1;
        // Iterated update (Gauss–Newton on the posterior): the lever arm turns with the
        // heading, so a fix linearised where the mounting is still unknown (at first, zero:
        // no lever arm for the heading to turn) misplaces it; relinearising at the updated
        // state, a few times, does not.
        let prior = self.x;
        let (mut h, mut kgain) = (h0, self.p * h0.transpose() * s_inv);
        let mut x = prior + kgain * nu0;
        for _ in 0..4 {
            let (hi, nui) = linearise(&x);
            let Some(si_inv) = (hi * self.p * hi.transpose() + r).try_inverse() else {
                break;
            };
            let ki = self.p * hi.transpose() * si_inv;
            let mut dx = prior - x;
            dx[TH] = wrap_angle(dx[TH]);
            dx[MPSI] = wrap_angle(dx[MPSI]);
            let next = prior + ki * (nui - hi * dx);
            let moved = (next - x).amax();
            (x, h, kgain) = (next, hi, ki);
            if moved < 1e-9 {
                break;
            }
        }
        self.x = x;
        self.x[TH] = wrap_angle(self.x[TH]);
        self.x[MPSI] = wrap_angle(self.x[MPSI]);
        let ikh = Matrix::identity() - kgain * h;
        self.p = ikh * self.p * ikh.transpose() + kgain * r * kgain.transpose();
        self.nis_pose.0 += nis / dim as f64;
        self.nis_pose.1 += 1;
        Some(nis)
    }

    /// Starts the parameters and the pose reference's mounting from a batch fit of the drive so
    /// far ([`super::pose_fit`]): its values, and its covariance carried into the state's
    /// (`u = (D/D_cfg)/E_b`, `k = E_b = b/b_cfg`); the pose waits for the next fix to anchor
    /// it. With fixes alone the filter's first metres are a bilinear problem (the lever arm
    /// turns with a heading the mounting's yaw leaves unknown) that a linearised update
    /// resolves wrongly and then trusts; the batch fit solves it where the drive observed it.
    pub fn start_from_fit(&mut self, fit: &super::pose_fit::PoseFit) {
        let cfg = &self.cfg.configured;
        let [dl, dr, b, mx, my, mpsi, _] = fit.params;
        let k = b / cfg.wheelbase_m;
        let (ul, ur) = (
            dl / cfg.left_wheel_diameter_m / k,
            dr / cfg.right_wheel_diameter_m / k,
        );
        // ∂(u_L, u_R, k, m_x, m_y, m_ψ)/∂(D_L, D_R, b, x, y, ψ).
        let mut j = SMatrix::<f64, 6, 6>::zeros();
        j[(0, 0)] = ul / dl;
        j[(0, 2)] = -ul / b;
        j[(1, 1)] = ur / dr;
        j[(1, 2)] = -ur / b;
        j[(2, 2)] = 1.0 / cfg.wheelbase_m;
        for i in 3..6 {
            j[(i, i)] = 1.0;
        }
        let c = SMatrix::<f64, 6, 6>::from_fn(|a, bb| fit.covariance[a][bb]);
        let cs = j * c * j.transpose();
        let states = [UL, UR, K, MX, MY, MPSI];
        let finite = cs.iter().all(|v| v.is_finite());
        for (a, &i) in states.iter().enumerate() {
            for jj in 0..N {
                self.p[(i, jj)] = 0.0;
                self.p[(jj, i)] = 0.0;
            }
            for (bb, &jj) in states.iter().enumerate() {
                self.p[(i, jj)] = if finite {
                    cs[(a, bb)]
                } else if a == bb {
                    self.prior[(i, i)]
                } else {
                    0.0
                };
            }
        }
        self.x[UL] = ul;
        self.x[UR] = ur;
        self.x[K] = k;
        self.x[MX] = mx;
        self.x[MY] = my;
        self.x[MPSI] = wrap_angle(mpsi);
        let position = fit.residual_std_position_m;
        self.fix_noise = FixNoise {
            stated_scale: [fit.stated_scale, fit.stated_scale_yaw]
                .map(|s| s.filter(|s| s.is_finite() && *s > 0.0).unwrap_or(1.0)),
            unstated: (position.is_finite() && position > 0.0).then(|| {
                [
                    position,
                    position,
                    fit.residual_std_yaw_rad
                        .filter(|s| s.is_finite() && *s > 0.0)
                        .unwrap_or(self.cfg.heading_sigma_rad),
                ]
            }),
        };
        self.restart_pose();
    }

    /// Puts the pose where the reference fix `(x, y, yaw)` (variances `r`) and the current
    /// mounting say, with the uncertainty the mounting's carries into it (its cross-covariance
    /// kept, so that later fixes separate the two).
    fn anchor(&mut self, x_m: f64, y_m: f64, yaw_rad: f64, r: [f64; 3]) {
        let (mx, my, mpsi) = (self.x[MX], self.x[MY], self.x[MPSI]);
        let th = wrap_angle(yaw_rad - mpsi);
        let (s, c) = th.sin_cos();
        // pose = g(fix, m): θ = ψ − m_ψ, (x, y) = p − R(θ)(m_x, m_y); its Jacobian in m.
        let mut jm = SMatrix::<f64, 3, N>::zeros();
        jm[(0, MX)] = -c;
        jm[(0, MY)] = s;
        jm[(0, MPSI)] = -(s * mx + c * my);
        jm[(1, MX)] = -s;
        jm[(1, MY)] = -c;
        jm[(1, MPSI)] = c * mx - s * my;
        jm[(2, MPSI)] = -1.0;
        for i in [X, Y, TH] {
            for j in 0..N {
                self.p[(i, j)] = 0.0;
                self.p[(j, i)] = 0.0;
            }
        }
        let cross = jm * self.p; // 3 × N: the pose's covariance with every state.
        let pose_cov = cross * jm.transpose();
        for (a, i) in [X, Y, TH].into_iter().enumerate() {
            for j in 0..N {
                self.p[(i, j)] = cross[(a, j)];
                self.p[(j, i)] = cross[(a, j)];
            }
        }
        // The fix's own noise, its yaw's through the lever arm too: J_z R J_zᵀ.
        let jz = nalgebra::Matrix3::new(
            1.0,
            0.0,
            s * mx + c * my,
            0.0,
            1.0,
            -(c * mx - s * my),
            0.0,
            0.0,
            1.0,
        );
        let noise =
            jz * nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::from(r)) * jz.transpose();
        for (a, i) in [X, Y, TH].into_iter().enumerate() {
            for (b, j) in [X, Y, TH].into_iter().enumerate() {
                self.p[(i, j)] = pose_cov[(a, b)] + noise[(a, b)];
            }
        }
        self.x[X] = x_m - (c * mx - s * my);
        self.x[Y] = y_m - (s * mx + c * my);
        self.x[TH] = th;
        self.anchored = true;
        self.heading_initialized = true;
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

    /// The parameters' estimate and uncertainty.
    pub fn estimate(&self, scale: ScaleSource) -> Result<OnlineEstimate, CalibrationError> {
        self.estimate_with(scale, &self.p)
    }

    /// Which parameters the path so far observed (see the module).
    pub fn excitation(&self, scale: ScaleSource) -> Result<Excitation, CalibrationError> {
        let post = self.estimate_with(scale, &self.p)?;
        let prior = self.estimate_with(scale, &self.prior)?;
        let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { 0.0 };
        let (rb, rd) = (
            ratio(post.e_b_std, prior.e_b_std),
            ratio(post.e_d_std, prior.e_d_std),
        );
        Ok(Excitation {
            e_b: Observed::from_ratio(rb),
            e_d: Observed::from_ratio(rd),
            e_b_ratio: rb,
            e_d_ratio: rd,
        })
    }

    fn estimate_with(
        &self,
        scale: ScaleSource,
        cov: &Matrix,
    ) -> Result<OnlineEstimate, CalibrationError> {
        let (ul, ur, k) = (self.x[UL], self.x[UR], self.x[K]);
        if !(ul > 0.0 && ur > 0.0 && k > 0.0) {
            return Err(CalibrationError::Unsupported(format!(
                "filter state is not a robot (u_L {ul}, u_R {ur}, k {k})"
            )));
        }
        let e_d = ur / ul;
        // (E_b as a function of u_L, u_R, k) and its gradient.
        let (e_b, grad_b, correction) = match scale {
            ScaleSource::Convention(SplitConvention::MeanPreserving) => {
                let g = 0.5 * (ul + ur);
                let e_b = 1.0 / g;
                (
                    e_b,
                    [-0.5 / (g * g), -0.5 / (g * g), 0.0],
                    SplitConvention::MeanPreserving.split(
                        e_b,
                        e_d,
                        self.cfg.configured.wheelbase_m,
                    )?,
                )
            }
            ScaleSource::Convention(conv) => {
                let e_b = 1.0 / ul;
                (
                    e_b,
                    [-1.0 / (ul * ul), 0.0, 0.0],
                    conv.split(e_b, e_d, self.cfg.configured.wheelbase_m)?,
                )
            }
            ScaleSource::Filter => (
                k,
                [0.0, 0.0, 1.0],
                Correction {
                    left_diameter_scale: k * ul,
                    right_diameter_scale: k * ur,
                    wheelbase_scale: k,
                },
            ),
        };
        let grad_d = [-ur / (ul * ul), 1.0 / ul, 0.0];
        let idx = [UL, UR, K];
        let var = |g: [f64; 3]| {
            let mut v = 0.0;
            for a in 0..3 {
                for b in 0..3 {
                    v += g[a] * cov[(idx[a], idx[b])] * g[b];
                }
            }
            v.max(0.0)
        };
        let correction_std = matches!(scale, ScaleSource::Filter).then(|| {
            [
                var([k, 0.0, ul]).sqrt(),
                var([0.0, k, ur]).sqrt(),
                var([0.0, 0.0, 1.0]).sqrt(),
            ]
        });
        Ok(OnlineEstimate {
            method: "online",
            e_b,
            e_d,
            e_b_std: var(grad_b).sqrt(),
            e_d_std: var(grad_d).sqrt(),
            correction,
            correction_std,
            distance_m: self.distance_m,
        })
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
