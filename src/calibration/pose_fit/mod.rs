//! Maximum-likelihood calibration against a pose reference: both wheel diameters and the
//! wheelbase in metres, the reference frame's mounting on the robot and the time offset between
//! the streams, from any driving.
//!
//! **Model.** The odometry integrates the wheels exactly for a candidate geometry
//! `(D_L, D_R, b)` ([`Odometry`]); the reference frame sits at `M = (x_s, y_s, ψ_s)` in
//! `base_link`; a pose stamped `t` is compared with the odometry at `t − δ`
//! ([`super::pose_reference`] states the conventions). The parameters are
//! `p = (D_L, D_R, b, x_s, y_s, ψ_s, δ)`.
//!
//! **Two kinds of reference, two likelihoods** (Censi, Marchionni & Oriolo 2013 fit the motion
//! between scan-matching samples; a localization or motion capture is fitted as a trajectory):
//! - *absolute* — `r_j = A_w ∘ O(t_j − δ) ∘ M ⊕ ε_j` with independent `ε_j`; the world-to-odom
//!   alignment `A_w` (one per window, the whole trajectory by default) is a nuisance solved in
//!   closed form at every evaluation (weighted 2-D Procrustes on the positions, refined by the
//!   yaws), so the Jacobian is that of the projected residual (variable projection, Golub &
//!   Pereyra 1973) and its covariance is the marginal one.
//! - *relative* — `r_{j-1}⁻¹ ∘ r_j = M⁻¹ ∘ O(t_{j-1} − δ)⁻¹ ∘ O(t_j − δ) ∘ M ⊕ ε_j`: errors of a
//!   chained reference are independent per increment, and a gross failure is one bad
//!   increment instead of a permanent step.
//!
//! Residuals are `(Δx, Δy, Δψ)` per sample (or increment); positions and yaws have one noise
//! scale each, estimated from the residuals, times the standard deviation a message states for
//! its sample where it states one. Against an absolute reference a real robot's residuals also
//! wander: wheel slip accumulates between the alignment and each sample. Each component is then
//! modelled as white noise plus a random walk (variance `q` per second), the residuals are
//! whitened by a scalar Kalman filter per component (its innovations), and `σ`, `q` are found by
//! maximum likelihood; a walk is kept only when the likelihood ratio says it is there. With no
//! walk this is exactly the white model. The solver is Levenberg–Marquardt on a numeric Jacobian,
//! inside iteratively reweighted least squares: Huber weights first, to find the basin, then
//! samples whose `χ²` exceeds its 99.9 % quantile are left out (a relocalisation jump, a
//! scan-matching failure) and the scales re-estimated from the rest.
//!
//! **Covariance.** `(Jᵀ W J)⁻¹` over the inliers at the solution, inflated by
//! `(1 + ρ)/(1 − ρ)` when the residuals are positively correlated from one sample to the next
//! (`ρ` their lag-one correlation): wheel slip and unmodelled dynamics make neighbouring
//! residuals alike, and a covariance that ignored it would claim information the drive does not
//! hold. The inflation is reported.
//!
//! **Which kind.** When not told, the reference is fitted as relative first (consistent for
//! both kinds), and the residual of the motion over ten samples is compared with the residual of
//! one: an absolute reference's errors do not grow with the span (ratio ≈ 1), a chained one's do
//! (ratio ≈ 10). Below `√10` it is called absolute and fitted again that way.

use super::pool::upper_median;
use super::pose_reference::{Geometry, Odometry, Pose2, PoseRecording, ReferenceKind, Turn};
use super::CalibrationError;
use crate::kinematics::wrap_angle;
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

mod clock_rate;
mod problem;
use problem::*;
mod solver;
use solver::*;
mod scales;
use scales::*;
mod stages;
use stages::*;

/// Number of parameters of the full model.
pub const PARAMS: usize = 7;

/// One parameter of the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Param {
    /// Left wheel diameter (m).
    LeftDiameter,
    /// Right wheel diameter (m).
    RightDiameter,
    /// Wheelbase (m).
    Wheelbase,
    /// The reference frame's x in `base_link` (m).
    SensorX,
    /// The reference frame's y in `base_link` (m).
    SensorY,
    /// The reference frame's yaw in `base_link` (rad).
    SensorYaw,
    /// Lateness of the reference's stamps (s).
    TimeOffset,
}

impl Param {
    /// Every parameter, in the order of the parameter vector.
    pub const ALL: [Param; PARAMS] = [
        Param::LeftDiameter,
        Param::RightDiameter,
        Param::Wheelbase,
        Param::SensorX,
        Param::SensorY,
        Param::SensorYaw,
        Param::TimeOffset,
    ];

    /// Its name in reports and JSON (with its unit).
    pub fn name(self) -> &'static str {
        match self {
            Param::LeftDiameter => "left_wheel_diameter_m",
            Param::RightDiameter => "right_wheel_diameter_m",
            Param::Wheelbase => "wheelbase_m",
            Param::SensorX => "sensor_x_m",
            Param::SensorY => "sensor_y_m",
            Param::SensorYaw => "sensor_yaw_rad",
            Param::TimeOffset => "time_offset_s",
        }
    }

    /// Its index in the parameter vector.
    pub fn index(self) -> usize {
        self as usize
    }

    fn is_geometry(self) -> bool {
        matches!(
            self,
            Param::LeftDiameter | Param::RightDiameter | Param::Wheelbase
        )
    }
}

/// How the residuals are weighted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Weighting {
    /// Scales of position and yaw estimated from the residuals (maximum likelihood).
    Estimated,
    /// Metres and radians summed as they are, as the ROS calibration scripts do.
    Unit,
}

/// What to fit and how.
#[derive(Debug, Clone, PartialEq)]
pub struct FitConfig {
    /// The geometry the fit starts from, and the wheelbase `E_b` is relative to.
    pub nominal: Geometry,
    /// The reference's kind; `None`: decided from the data.
    pub kind: Option<ReferenceKind>,
    /// Fit the reference frame's mounting (else it is `base_link` itself).
    pub fit_mounting: bool,
    /// Fit the time offset (else 0).
    pub fit_time_offset: bool,
    /// Largest time offset searched (s).
    pub max_time_offset_s: f64,
    /// Absolute references: align each window of this length separately (s); `None`: the
    /// whole trajectory is one window.
    pub window_s: Option<f64>,
    /// Down-weight and then leave out outliers.
    pub robust: bool,
    /// One diameter for both wheels (the two-multiplier baseline).
    pub tie_diameters: bool,
    /// How the residuals are weighted.
    pub weighting: Weighting,
}

impl FitConfig {
    /// The full maximum-likelihood fit from `nominal`: everything free, robust, kind decided
    /// from the data.
    pub fn full(nominal: Geometry) -> Self {
        Self {
            nominal,
            kind: None,
            fit_mounting: true,
            fit_time_offset: true,
            max_time_offset_s: 0.5,
            window_s: None,
            robust: true,
            tie_diameters: false,
            weighting: Weighting::Estimated,
        }
    }
}

/// How the reference's kind was settled.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct KindDecision {
    /// The kind used.
    pub kind: ReferenceKind,
    /// `"user"` or `"data"`.
    pub decided_by: &'static str,
    /// Variance of the motion residual over ten samples over that of one (data only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub variance_ratio_10_to_1: Option<f64>,
    /// One sentence on why.
    pub reason: String,
}

/// The fitted parameters with their uncertainty.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PoseFit {
    /// The fitted geometry (m).
    pub geometry: Geometry,
    /// The parameter vector `(D_L, D_R, b, x_s, y_s, ψ_s, δ)` (m, m, m, m, m, rad, s).
    pub params: [f64; PARAMS],
    /// Its covariance (inflated, see the module's notes); rows and columns of parameters that
    /// were not fitted are zero.
    pub covariance: [[f64; PARAMS]; PARAMS],
    /// The parameters that were fitted.
    pub free: Vec<Param>,
    /// How the kind was settled.
    pub kind: KindDecision,
    /// Standard deviation of one position residual (m), inliers (with stated standard
    /// deviations: their root mean square times [`Self::stated_scale`]).
    pub residual_std_position_m: f64,
    /// When the messages' own standard deviations weighted the samples: the factor the
    /// residuals say they are off by (1: the messages state their noise right; the stated
    /// covariance's scale is not trusted, only its shape).
    pub stated_scale: Option<f64>,
    /// The same for the stated yaw deviations (`None` without yaw or stated deviations).
    pub stated_scale_yaw: Option<f64>,
    /// Standard deviation of one yaw residual (rad), inliers; `None` without yaw.
    pub residual_std_yaw_rad: Option<f64>,
    /// Variance per second of the positions' random walk between reference and odometry
    /// (m²/s; absolute references; 0: none found).
    pub walk_position_m2_s: f64,
    /// Variance per second of the yaw's random walk (rad²/s); `None` without yaw.
    pub walk_yaw_rad2_s: Option<f64>,
    /// Samples (absolute) or increments (relative) compared.
    pub compared: usize,
    /// Of them, left out as outliers.
    pub outliers: usize,
    /// Windows aligned separately (absolute).
    pub windows: usize,
    /// Lag-one correlation of the normalised residuals.
    pub lag_one_correlation: f64,
    /// Factor the covariance was multiplied by for it.
    pub variance_inflation: f64,
    /// Levenberg–Marquardt iterations, all stages.
    pub iterations: usize,
    /// Time span compared (s, reference clock).
    pub span_s: f64,
    /// The nominal wheelbase `E_b` refers to (m).
    pub nominal_wheelbase_m: f64,
    /// What the user should know about this fit (a time offset at its limit).
    pub warnings: Vec<String>,
}

impl PoseFit {
    /// A parameter's value.
    pub fn value(&self, p: Param) -> f64 {
        self.params[p.index()]
    }

    /// A parameter's standard deviation; `None` when it was not fitted.
    pub fn std(&self, p: Param) -> Option<f64> {
        self.free
            .contains(&p)
            .then(|| finite_sqrt(self.covariance[p.index()][p.index()]))
    }

    /// `E_d = D_R / D_L`.
    pub fn e_d(&self) -> f64 {
        self.geometry.right_diameter_m / self.geometry.left_diameter_m
    }

    /// Standard deviation of `E_d` (first order).
    pub fn e_d_std(&self) -> f64 {
        let (l, r) = (
            self.geometry.left_diameter_m,
            self.geometry.right_diameter_m,
        );
        let g = [-r / (l * l), 1.0 / l];
        let c = &self.covariance;
        finite_sqrt(g[0] * g[0] * c[0][0] + 2.0 * g[0] * g[1] * c[0][1] + g[1] * g[1] * c[1][1])
    }

    /// `E_b = b / b_nominal`.
    pub fn e_b(&self) -> f64 {
        self.geometry.wheelbase_m / self.nominal_wheelbase_m
    }

    /// Standard deviation of `E_b`.
    pub fn e_b_std(&self) -> f64 {
        finite_sqrt(self.covariance[2][2]) / self.nominal_wheelbase_m
    }

    /// The correlation of two fitted parameters.
    pub fn correlation(&self, a: Param, b: Param) -> Option<f64> {
        let (sa, sb) = (self.std(a)?, self.std(b)?);
        (sa > 0.0 && sb > 0.0).then(|| self.covariance[a.index()][b.index()] / (sa * sb))
    }
}

/// The square root of a variance; infinite when the variance is not a finite number (an
/// unobserved parameter must never read as a zero standard deviation).
fn finite_sqrt(v: f64) -> f64 {
    if v.is_finite() {
        v.max(0.0).sqrt()
    } else {
        f64::INFINITY
    }
}

/// Fits `recording` by `config`.
pub fn fit_poses(
    recording: &PoseRecording,
    config: &FitConfig,
) -> Result<PoseFit, CalibrationError> {
    check_input(recording, config)?;
    if config.fit_time_offset {
        clock_rate::delay_beyond_search(recording, config.nominal, config.max_time_offset_s)?;
    }
    if config.kind.is_none() && !recording.has_yaw() {
        let decision = KindDecision {
            kind: ReferenceKind::Absolute,
            decided_by: "data",
            variance_ratio_10_to_1: None,
            reason: "a reference without yaw (GNSS) has no frame of its own to chain motion \
                     in: absolute"
                .into(),
        };
        return fit_kind(recording, config, ReferenceKind::Absolute, None, decision);
    }
    match config.kind {
        Some(kind) => {
            let decision = KindDecision {
                kind,
                decided_by: "user",
                variance_ratio_10_to_1: None,
                reason: format!("given as {}", kind.name()),
            };
            let mut fit = fit_kind(recording, config, kind, None, decision)?;
            fit.warnings
                .extend(contradicted_kind(recording, config, &fit));
            Ok(fit)
        }
        None => fit_deciding_kind(recording, config),
    }
}

/// Fits `recording` as the kind its relative fit's residuals tell, from that fit.
fn fit_deciding_kind(
    recording: &PoseRecording,
    config: &FitConfig,
) -> Result<PoseFit, CalibrationError> {
    let (head, relative) = decision_fit(recording, config)?;
    // The spread of the residuals on the samples that were fitted.
    let ratio = span_variance_ratio(
        head.as_ref().unwrap_or(recording),
        config,
        &relative.params,
        10,
    );
    let decision = kind_from_ratio(ratio);
    match (decision.kind, head) {
        (ReferenceKind::Relative, None) => Ok(PoseFit {
            kind: decision,
            ..relative
        }),
        (kind, _) => fit_kind(recording, config, kind, Some(relative.params), decision),
    }
}

/// The relative fit that tells the kind, with the head it was made on (`None`: the whole
/// recording).
fn decision_fit(
    recording: &PoseRecording,
    config: &FitConfig,
) -> Result<(Option<PoseRecording>, PoseFit), CalibrationError> {
    // The kind is told by a relative fit; on a long drive, of its first part only (the
    // fit for the kind decided then starts from it): the decision needs the motion
    // residuals' spread, not the last digit of the geometry.
    let undecided = || KindDecision {
        kind: ReferenceKind::Relative,
        decided_by: "data",
        variance_ratio_10_to_1: None,
        reason: String::new(),
    };
    // A head that cannot be fitted (the robot idle, poses before the wheels) leaves
    // the decision to the whole recording.
    let head_fit = recording.head(DECISION_POSES).and_then(|h| {
        let fit = fit_kind(&h, config, ReferenceKind::Relative, None, undecided()).ok()?;
        Some((h, fit))
    });
    Ok(match head_fit {
        Some((h, fit)) => (Some(h), fit),
        None => (
            None,
            fit_kind(
                recording,
                config,
                ReferenceKind::Relative,
                None,
                undecided(),
            )?,
        ),
    })
}

/// A warning when the data's own test contradicts the kind the user gave, clearly (outside the
/// band where the odometry's drift can tip it): a chained reference fitted as absolute biases
/// the diameters and the mounting, an absolute one fitted as relative shrinks the scale.
fn contradicted_kind(
    recording: &PoseRecording,
    config: &FitConfig,
    fit: &PoseFit,
) -> Option<String> {
    if !recording.has_yaw() {
        return None;
    }
    let head = recording.head(DECISION_POSES);
    let ratio = span_variance_ratio(head.as_ref().unwrap_or(recording), config, &fit.params, 10);
    let threshold = 10f64.sqrt();
    let data = if ratio >= 2.0 * threshold {
        ReferenceKind::Relative
    } else if ratio < 0.5 * threshold {
        ReferenceKind::Absolute
    } else {
        return None;
    };
    (data != fit.kind.kind).then(|| {
        format!(
            "the reference was given as {}, but its motion residual over ten samples has \
             {ratio:.2}× the variance of one (√10 = {threshold:.2} separates the kinds): the \
             data say {} ({}); the diameters and the mounting are biased when the kind is \
             wrong: fit again without --reference-kind to let the data decide",
            fit.kind.kind.name(),
            data.name(),
            match data {
                ReferenceKind::Relative => "chained from sample to sample",
                ReferenceKind::Absolute => "errors that do not grow with the span",
            }
        )
    })
}

/// The kind a variance ratio of the motion residuals over ten samples to one tells, and why.
fn kind_from_ratio(ratio: f64) -> KindDecision {
    let threshold = 10f64.sqrt();
    let (kind, why) = if !ratio.is_finite() {
        (
            ReferenceKind::Absolute,
            "the motion residuals could not be compared (too few samples or none moving): \
             taken as absolute, the safer fit",
        )
    } else if ratio < threshold {
        (
            ReferenceKind::Absolute,
            "its errors do not grow with the span: the reference does not accumulate error",
        )
    } else {
        (
            ReferenceKind::Relative,
            "its errors grow with the span: the reference is chained from sample to sample",
        )
    };
    // Near the threshold the odometry's own random walk (slip, a jittering encoder
    // clock) may be what grows: say so, and how to settle it.
    let doubt = if (0.5 * threshold..2.0 * threshold).contains(&ratio) {
        "; close to the threshold, where the odometry's own drift can tip it: give \
         --reference-kind if you know the reference"
    } else {
        ""
    };
    KindDecision {
        kind,
        decided_by: "data",
        variance_ratio_10_to_1: Some(ratio),
        reason: format!(
            "the motion residual over ten samples has {ratio:.2}× the variance of one \
             (√10 = {threshold:.2} separates the kinds): {why}; fitted as {}{doubt}",
            kind.name()
        ),
    }
}

fn check_input(recording: &PoseRecording, config: &FitConfig) -> Result<(), CalibrationError> {
    let g = &config.nominal;
    for (name, v) in [
        ("nominal left wheel diameter", g.left_diameter_m),
        ("nominal right wheel diameter", g.right_diameter_m),
        ("nominal wheelbase", g.wheelbase_m),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(CalibrationError::PoseInput(format!(
                "the {name} must be a positive length in metres, got {v}"
            )));
        }
    }
    if !(config.max_time_offset_s.is_finite() && config.max_time_offset_s >= 0.0) {
        return Err(CalibrationError::PoseInput(format!(
            "the largest time offset must be finite and ≥ 0 s, got {}",
            config.max_time_offset_s
        )));
    }
    if let Some(w) = config.window_s {
        if !(w.is_finite() && w > 0.0) {
            return Err(CalibrationError::PoseInput(format!(
                "the alignment window must be a positive time in seconds, got {w}"
            )));
        }
    }
    if recording.wheels.len() < 2 || recording.poses.len() < 3 {
        return Err(CalibrationError::PoseInput(format!(
            "{} wheel sample(s) and {} reference pose(s): a fit needs a drive, at least two \
             wheel samples and three poses",
            recording.wheels.len(),
            recording.poses.len()
        )));
    }
    let finite_w = recording
        .wheels
        .iter()
        .all(|w| w.time_s.is_finite() && w.left_rad.is_finite() && w.right_rad.is_finite());
    let finite_p = recording.poses.iter().all(|p| {
        p.time_s.is_finite()
            && p.x_m.is_finite()
            && p.y_m.is_finite()
            && p.yaw_rad.is_none_or(f64::is_finite)
            && p.stated_std.is_none_or(|s| {
                let positive = |v: f64| v.is_finite() && v > 0.0;
                positive(s[0]) && positive(s[1]) && (p.yaw_rad.is_none() || positive(s[2]))
            })
    });
    if !finite_w || !finite_p {
        return Err(CalibrationError::PoseInput(
            "a wheel sample or a reference pose holds a value that is not finite (or a stated \
             standard deviation that is not positive); read the inputs through odocal's readers"
                .into(),
        ));
    }
    let increasing = |t: &mut dyn Iterator<Item = f64>| {
        let v: Vec<f64> = t.collect();
        v.windows(2).all(|w| w[1] > w[0])
    };
    if !increasing(&mut recording.wheels.iter().map(|w| w.time_s))
        || !increasing(&mut recording.poses.iter().map(|p| p.time_s))
    {
        return Err(CalibrationError::PoseInput(
            "the wheel or the reference stamps do not increase; sort the samples by time".into(),
        ));
    }
    let has_yaw = recording.poses.iter().any(|p| p.yaw_rad.is_some());
    if has_yaw && !recording.has_yaw() {
        return Err(CalibrationError::PoseInput(
            "some reference poses have a yaw and some do not; give yaw for every pose or none"
                .into(),
        ));
    }
    if !has_yaw && config.kind == Some(ReferenceKind::Relative) {
        return Err(CalibrationError::PoseInput(
            "a relative reference needs a yaw with every pose (its motion is measured in its \
             own frame); a position-only reference such as GNSS is absolute"
                .into(),
        ));
    }
    Ok(())
}

/// The robust variance of the motion residual over `k` reference samples over that over one,
/// at parameters `p` (position components).
fn span_variance_ratio(
    recording: &PoseRecording,
    config: &FitConfig,
    p: &[f64; PARAMS],
    k: usize,
) -> f64 {
    let Ok(problem) = Problem::new(recording, config, ReferenceKind::Relative) else {
        return f64::NAN;
    };
    let odo = Odometry::integrate(&recording.wheels, Problem::geometry(p));
    let (pred, turns) = problem.predicted(&odo, p);
    let poses = &recording.poses;
    let ref_pose = |i: usize| poses[problem.selected[i]].pose2();
    let spread = |lag: usize| {
        mad_std((lag..problem.selected.len()).flat_map(|j| {
            let rd = ref_pose(j - lag).between(&ref_pose(j));
            let pd = pred[j - lag].between_turned(turns[j - lag], &pred[j]);
            [rd.x - pd.x, rd.y - pd.y]
        }))
    };
    let (one, many) = (spread(1), spread(k));
    if one > 0.0 {
        (many / one).powi(2)
    } else {
        f64::NAN
    }
}

/// Reference samples the kind decision's relative fit uses at most (ten minutes at 10 Hz).
const DECISION_POSES: usize = 6000;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::pose_reference::{ReferencePose, WheelAngles};

    /// A noise-free drive: a figure eight of arcs and straights, wheels at 50 Hz.
    fn drive(truth: Geometry, mount: Pose2, delay: f64, noise: f64) -> PoseRecording {
        let dt = 0.02;
        let mut wheels = Vec::new();
        let mut poses = Vec::new();
        let (mut l, mut r) = (0.0, 0.0);
        let mut base = Pose2::default();
        let mut state: u64 = 12345;
        let mut gauss = || {
            // Box–Muller on a small LCG: enough for a unit test.
            let mut u = || {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
            };
            let (a, b) = (u(), u());
            (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        };
        for i in 0..6000 {
            let t = i as f64 * dt;
            let phase = (t / 8.0) as i64 % 4;
            let (v, w) = match phase {
                0 => (0.3, 0.0),
                1 => (0.2, 0.8),
                2 => (0.3, 0.0),
                _ => (0.15, -1.0),
            };
            wheels.push(WheelAngles {
                time_s: t,
                left_rad: l,
                right_rad: r,
            });
            if i % 5 == 0 {
                let s = base.compose(&mount);
                poses.push(ReferencePose {
                    time_s: t + delay,
                    x_m: 2.0 + s.x + noise * gauss(),
                    y_m: -1.0 + s.y + noise * gauss(),
                    yaw_rad: Some(wrap_angle(s.theta + noise * gauss())),
                    stated_std: None,
                });
            }
            let dl = (v - w * truth.wheelbase_m / 2.0) * dt;
            let dr = (v + w * truth.wheelbase_m / 2.0) * dt;
            l += dl / (truth.left_diameter_m / 2.0);
            r += dr / (truth.right_diameter_m / 2.0);
            base = base.arc(dl, dr, truth.wheelbase_m);
        }
        PoseRecording { wheels, poses }
    }

    fn nominal() -> Geometry {
        Geometry {
            left_diameter_m: 0.1,
            right_diameter_m: 0.1,
            wheelbase_m: 0.3,
        }
    }

    const TRUTH: Geometry = Geometry {
        left_diameter_m: 0.1004,
        right_diameter_m: 0.0997,
        wheelbase_m: 0.309,
    };

    #[test]
    fn a_noise_free_absolute_drive_gives_the_truth_back() {
        let mount = Pose2 {
            x: 0.1,
            y: -0.04,
            theta: 0.2,
        };
        let rec = drive(TRUTH, mount, 0.05, 0.0);
        let mut config = FitConfig::full(nominal());
        config.kind = Some(ReferenceKind::Absolute);
        let fit = fit_poses(&rec, &config).expect("fits");
        let g = fit.geometry;
        assert!(
            (g.left_diameter_m / TRUTH.left_diameter_m - 1.0).abs() < 1e-6,
            "{g:?}"
        );
        assert!(
            (g.right_diameter_m / TRUTH.right_diameter_m - 1.0).abs() < 1e-6,
            "{g:?}"
        );
        assert!(
            (g.wheelbase_m / TRUTH.wheelbase_m - 1.0).abs() < 1e-6,
            "{g:?}"
        );
        assert!((fit.value(Param::SensorX) - 0.1).abs() < 1e-5);
        assert!((fit.value(Param::SensorY) + 0.04).abs() < 1e-5);
        assert!((fit.value(Param::SensorYaw) - 0.2).abs() < 1e-5);
        assert!((fit.value(Param::TimeOffset) - 0.05).abs() < 1e-4);
    }

    #[test]
    fn a_noisy_drive_is_fitted_within_its_stated_errors_either_kind() {
        let mount = Pose2 {
            x: 0.15,
            y: 0.02,
            theta: -0.1,
        };
        let rec = drive(TRUTH, mount, 0.03, 0.003);
        for kind in [ReferenceKind::Absolute, ReferenceKind::Relative] {
            let mut config = FitConfig::full(nominal());
            config.kind = Some(kind);
            let fit = fit_poses(&rec, &config).expect("fits");
            for (param, truth) in [
                (Param::LeftDiameter, TRUTH.left_diameter_m),
                (Param::RightDiameter, TRUTH.right_diameter_m),
                (Param::Wheelbase, TRUTH.wheelbase_m),
                (Param::SensorX, 0.15),
                (Param::SensorY, 0.02),
                (Param::TimeOffset, 0.03),
            ] {
                let (v, s) = (fit.value(param), fit.std(param).expect("fitted"));
                assert!(
                    (v - truth).abs() < 4.0 * s,
                    "{kind:?} {}: {v} vs {truth} ± {s}",
                    param.name()
                );
                assert!(s > 0.0 && s.is_finite());
            }
            assert!(
                (fit.residual_std_position_m / 0.003 - 1.0).abs() < 0.3
                    || kind == ReferenceKind::Relative
            );
        }
    }

    #[test]
    fn the_kind_is_told_from_the_data() {
        let rec = drive(TRUTH, Pose2::default(), 0.0, 0.003);
        let fit = fit_poses(&rec, &FitConfig::full(nominal())).expect("fits");
        assert_eq!(
            fit.kind.kind,
            ReferenceKind::Absolute,
            "{}",
            fit.kind.reason
        );
    }

    #[test]
    fn a_zero_offset_limit_fits_no_offset_and_an_offset_at_its_limit_is_warned_of() {
        let rec = drive(TRUTH, Pose2::default(), 0.2, 0.001);
        let mut config = FitConfig::full(nominal());
        config.kind = Some(ReferenceKind::Absolute);
        config.max_time_offset_s = 0.0;
        let fit = fit_poses(&rec, &config).expect("fits");
        assert!(!fit.free.contains(&Param::TimeOffset));
        assert!(fit.std(Param::LeftDiameter).is_some_and(f64::is_finite));
        config.max_time_offset_s = 0.1;
        let fit = fit_poses(&rec, &config).expect("fits");
        assert!(
            (fit.value(Param::TimeOffset) - 0.1).abs() < 1e-3,
            "{}",
            fit.value(Param::TimeOffset)
        );
        assert!(
            fit.warnings
                .iter()
                .any(|w| w.contains("--max-time-offset-s")),
            "{:?}",
            fit.warnings
        );
        config.max_time_offset_s = 0.5;
        let fit = fit_poses(&rec, &config).expect("fits");
        assert!(fit.warnings.is_empty(), "{:?}", fit.warnings);
    }

    #[test]
    fn short_alignment_windows_join_their_neighbours() {
        let rec = drive(TRUTH, Pose2::default(), 0.0, 0.002);
        let mut config = FitConfig::full(nominal());
        config.kind = Some(ReferenceKind::Absolute);
        // Ten-second windows hold 100 poses at 10 Hz; half-second ones would hold 5 and are
        // merged up to at least ten.
        config.window_s = Some(10.0);
        let long = fit_poses(&rec, &config).expect("fits");
        config.window_s = Some(0.5);
        let short = fit_poses(&rec, &config).expect("fits");
        assert!(long.windows >= 10, "{}", long.windows);
        // Pairs of half-second windows: about a tenth as many windows as poses.
        let n = rec.poses.len();
        assert!(
            (n / 12..=n / 10).contains(&short.windows),
            "{} of {n}",
            short.windows
        );
        assert!(short.std(Param::Wheelbase).is_some_and(f64::is_finite));
    }

    #[test]
    fn bad_input_is_refused_by_name() {
        let rec = drive(TRUTH, Pose2::default(), 0.0, 0.0);
        let mut shifted = rec.clone();
        for p in &mut shifted.poses {
            p.time_s += 1e4;
        }
        let err = fit_poses(&shifted, &FitConfig::full(nominal())).unwrap_err();
        assert!(err.to_string().contains("same clock"), "{err}");
        let mut nan = rec.clone();
        nan.poses[3].x_m = f64::NAN;
        assert!(matches!(
            fit_poses(&nan, &FitConfig::full(nominal())),
            Err(CalibrationError::PoseInput(_))
        ));
    }
}
