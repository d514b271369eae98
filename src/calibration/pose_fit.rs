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
            fit_kind(recording, config, kind, None, decision)
        }
        None => {
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
            let (head, relative) = match head_fit {
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
            };
            // The spread of the residuals on the samples that were fitted.
            let ratio = span_variance_ratio(
                head.as_ref().unwrap_or(recording),
                config,
                &relative.params,
                10,
            );
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
            let decision = KindDecision {
                kind,
                decided_by: "data",
                variance_ratio_10_to_1: Some(ratio),
                reason: format!(
                    "the motion residual over ten samples has {ratio:.2}× the variance of one \
                     (√10 = {threshold:.2} separates the kinds): {why}; fitted as {}{doubt}",
                    kind.name()
                ),
            };
            match (kind, head) {
                (ReferenceKind::Relative, None) => Ok(PoseFit {
                    kind: decision,
                    ..relative
                }),
                _ => fit_kind(recording, config, kind, Some(relative.params), decision),
            }
        }
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

/// Noise of the residuals: white noise of one position component and of the yaw (the
/// reference's own, and the odometry's per interval), and, for an absolute reference, the
/// variance per second of a random walk (the odometry's slip accumulating between alignments).
#[derive(Debug, Clone, Copy)]
struct Scales {
    position: f64,
    yaw: f64,
    walk_position: f64,
    walk_yaw: f64,
}

impl Scales {
    fn white(position: f64, yaw: f64) -> Self {
        Self {
            position,
            yaw,
            walk_position: 0.0,
            walk_yaw: 0.0,
        }
    }

    fn walks(&self) -> bool {
        self.walk_position > 0.0 || self.walk_yaw > 0.0
    }

    /// White σ and walk variance rate of component `c`.
    fn of(&self, c: usize) -> (f64, f64) {
        if c < 2 {
            (self.position, self.walk_position)
        } else {
            (self.yaw, self.walk_yaw)
        }
    }
}

/// The least-squares problem for one kind.
struct Problem<'a> {
    recording: &'a PoseRecording,
    /// Indices of the reference poses compared.
    selected: Vec<usize>,
    kind: ReferenceKind,
    dim: usize,
    /// Windows over `selected` (absolute): `[start, end)`.
    windows: Vec<(usize, usize)>,
    free: Vec<Param>,
    tie: bool,
    fixed: [f64; PARAMS],
    max_offset: f64,
    /// Whether the stated standard deviations weight the samples: only for an absolute
    /// reference (a pose's σ is not its increment's) whose every sample states one (a mix
    /// would weigh the two kinds of sample by unrelated units).
    use_stated: bool,
    /// The reference's motion between consecutive selected samples (relative), computed once.
    reference_steps: Vec<Pose2>,
}

impl<'a> Problem<'a> {
    fn new(
        recording: &'a PoseRecording,
        config: &FitConfig,
        kind: ReferenceKind,
    ) -> Result<Self, CalibrationError> {
        let has_yaw = recording.has_yaw();
        // A largest offset of zero is no offset to fit (its column would be zero).
        let fit_offset = config.fit_time_offset && config.max_time_offset_s > 0.0;
        let margin = if fit_offset {
            config.max_time_offset_s
        } else {
            0.0
        };
        let (w0, w1) = (
            recording.wheels[0].time_s,
            recording.wheels[recording.wheels.len() - 1].time_s,
        );
        let selected: Vec<usize> = recording
            .poses
            .iter()
            .enumerate()
            .filter(|(_, p)| p.time_s - margin >= w0 && p.time_s + margin <= w1)
            .map(|(i, _)| i)
            .collect();
        let blocks = match kind {
            ReferenceKind::Absolute => selected.len(),
            ReferenceKind::Relative => selected.len().saturating_sub(1),
        };
        if blocks < 10 {
            return Err(CalibrationError::PoseInput(format!(
                "only {} reference pose(s) fall inside the wheels' time span ({w0:.3}–{w1:.3} s, \
                 less {margin:.2} s each side for the time offset; at least 10 are needed): \
                 check that both streams are stamped on the same clock (seconds) and that the \
                 reference covers the drive{}",
                selected.len(),
                if margin > 0.0 {
                    ", or lower --max-time-offset-s"
                } else {
                    ""
                },
            )));
        }
        let mut free = vec![Param::LeftDiameter];
        if !config.tie_diameters {
            free.push(Param::RightDiameter);
        }
        free.push(Param::Wheelbase);
        if config.fit_mounting {
            free.push(Param::SensorX);
            free.push(Param::SensorY);
            if has_yaw {
                free.push(Param::SensorYaw);
            }
        }
        if fit_offset {
            free.push(Param::TimeOffset);
        }
        let windows = match (kind, config.window_s) {
            (ReferenceKind::Relative, _) | (_, None) => vec![(0, selected.len())],
            (ReferenceKind::Absolute, Some(w)) => {
                let mut out = Vec::new();
                let mut start = 0;
                for i in 1..=selected.len() {
                    let done = i == selected.len()
                        || recording.poses[selected[i]].time_s
                            - recording.poses[selected[start]].time_s
                            >= w;
                    if done {
                        out.push((start, i));
                        start = i;
                    }
                }
                // A window grows by the next until it holds ten samples, and a short last one
                // joins the window before it: an alignment of a few samples would absorb
                // everything they hold.
                let mut merged: Vec<(usize, usize)> = Vec::new();
                for w in out {
                    match merged.last_mut() {
                        Some(last) if last.1 - last.0 < 10 => last.1 = w.1,
                        _ => merged.push(w),
                    }
                }
                if merged.len() > 1 && merged[merged.len() - 1].1 - merged[merged.len() - 1].0 < 10
                {
                    let tail = merged.pop().map_or(0, |t| t.1);
                    if let Some(last) = merged.last_mut() {
                        last.1 = tail;
                    }
                }
                merged
            }
        };
        let g = config.nominal;
        let use_stated = kind == ReferenceKind::Absolute
            && selected
                .iter()
                .all(|&i| recording.poses[i].stated_std.is_some());
        Ok(Self {
            recording,
            kind,
            dim: if has_yaw { 3 } else { 2 },
            windows,
            free,
            tie: config.tie_diameters,
            fixed: [
                g.left_diameter_m,
                g.right_diameter_m,
                g.wheelbase_m,
                0.0,
                0.0,
                0.0,
                0.0,
            ],
            max_offset: margin,
            use_stated,
            reference_steps: match kind {
                ReferenceKind::Relative => selected
                    .windows(2)
                    .map(|k| {
                        let (r0, r1) = (&recording.poses[k[0]], &recording.poses[k[1]]);
                        r0.pose2().between(&r1.pose2())
                    })
                    .collect(),
                ReferenceKind::Absolute => Vec::new(),
            },
            selected,
        })
    }

    fn blocks(&self) -> usize {
        match self.kind {
            ReferenceKind::Absolute => self.selected.len(),
            ReferenceKind::Relative => self.selected.len() - 1,
        }
    }

    /// The full parameter vector from the free values.
    fn full(&self, x: &[f64]) -> [f64; PARAMS] {
        let mut p = self.fixed;
        for (v, param) in x.iter().zip(&self.free) {
            p[param.index()] = *v;
        }
        if self.tie {
            p[1] = p[0];
        }
        p
    }

    fn free_values(&self, p: &[f64; PARAMS]) -> Vec<f64> {
        self.free.iter().map(|q| p[q.index()]).collect()
    }

    fn geometry(p: &[f64; PARAMS]) -> Geometry {
        Geometry {
            left_diameter_m: p[0],
            right_diameter_m: p[1],
            wheelbase_m: p[2],
        }
    }

    /// The stated standard deviation of component `c` of block `b` (1 when none is stated).
    fn stated(&self, block: usize, c: usize) -> f64 {
        let i = match self.kind {
            ReferenceKind::Absolute => self.selected[block],
            ReferenceKind::Relative => self.selected[block + 1],
        };
        if !self.use_stated {
            return 1.0;
        }
        self.recording.poses[i].stated_std.map_or(1.0, |s| s[c])
    }

    /// Root mean square of the stated standard deviation of component `c` (1 when the
    /// samples are not weighted by what they state).
    fn stated_rms(&self, c: usize) -> f64 {
        if !self.use_stated || self.blocks() == 0 {
            return 1.0;
        }
        let sum: f64 = (0..self.blocks()).map(|b| self.stated(b, c).powi(2)).sum();
        (sum / self.blocks() as f64).sqrt()
    }

    /// The predicted reference-frame poses at the selected stamps, before any alignment.
    fn predicted(&self, odo: &Odometry<'_>, p: &[f64; PARAMS]) -> (Vec<Pose2>, Vec<Turn>) {
        let mount = Pose2 {
            x: p[3],
            y: p[4],
            theta: p[5],
        };
        let mount_turn = Turn::of(mount.theta);
        let delta = p[6].clamp(-self.max_offset, self.max_offset);
        let mut hint = 0;
        let last = odo
            .poses()
            .last()
            .map(|q| (*q, Turn::of(q.theta)))
            .unwrap_or((Pose2::default(), Turn::of(0.0)));
        self.selected
            .iter()
            .map(|&i| {
                let t = self.recording.poses[i].time_s - delta;
                let (base, turn) = odo.at_turned(t, &mut hint).unwrap_or(last);
                (base.compose_turned(turn, &mount), turn.then(mount_turn))
            })
            .unzip()
    }

    /// Residuals (reference minus prediction) for parameters `p`, block after block, `dim`
    /// components each; `weights` and `scales` set the alignment's weights.
    fn residuals(
        &self,
        odo: &Odometry<'_>,
        p: &[f64; PARAMS],
        weights: &[f64],
        scales: Scales,
    ) -> Vec<f64> {
        let (pred, turns) = self.predicted(odo, p);
        let dim = self.dim;
        let mut out = Vec::with_capacity(self.blocks() * dim);
        match self.kind {
            ReferenceKind::Absolute => {
                for &(a, b) in &self.windows {
                    let mut align = self.align(&pred[a..b], a, weights, scales);
                    if scales.walks() {
                        align = self.align_whitened(&pred, a, b, align, weights, scales);
                    }
                    out.extend(self.window_residuals(&pred, a, b, &align));
                }
            }
            ReferenceKind::Relative => {
                for (k, rd) in self.reference_steps.iter().enumerate() {
                    let pd = pred[k].between_turned(turns[k], &pred[k + 1]);
                    out.push(rd.x - pd.x);
                    out.push(rd.y - pd.y);
                    if dim == 3 {
                        out.push(wrap_angle(rd.theta - pd.theta));
                    }
                }
            }
        }
        out
    }

    /// The world-from-odometry alignment of one window: weighted Procrustes on the positions,
    /// refined by the yaws.
    fn align(&self, pred: &[Pose2], first: usize, weights: &[f64], scales: Scales) -> Pose2 {
        let poses = &self.recording.poses;
        let (mut sw, mut cq, mut cr) = (0.0, [0.0; 2], [0.0; 2]);
        for (k, q) in pred.iter().enumerate() {
            let b = first + k;
            let w = weights[b] / (0.5 * (self.stated(b, 0).powi(2) + self.stated(b, 1).powi(2)));
            let r = &poses[self.selected[b]];
            sw += w;
            cq[0] += w * q.x;
            cq[1] += w * q.y;
            cr[0] += w * r.x_m;
            cr[1] += w * r.y_m;
        }
        if sw <= 0.0 {
            return Pose2::default();
        }
        for c in cq.iter_mut().chain(cr.iter_mut()) {
            *c /= sw;
        }
        let (mut sc, mut ss) = (0.0, 0.0);
        for (k, q) in pred.iter().enumerate() {
            let b = first + k;
            let w = weights[b] / (0.5 * (self.stated(b, 0).powi(2) + self.stated(b, 1).powi(2)));
            let r = &poses[self.selected[b]];
            let (qx, qy) = (q.x - cq[0], q.y - cq[1]);
            let (rx, ry) = (r.x_m - cr[0], r.y_m - cr[1]);
            sc += w * (qx * rx + qy * ry);
            ss += w * (qx * ry - qy * rx);
        }
        let mut phi = ss.atan2(sc);
        if self.dim == 3 {
            // The position cost is −2A·cos(φ − φ_p) (curvature 2A/σ_p²); the yaw cost is
            // quadratic (curvature 2Σw/σ_ψ²): one Newton step on their sum, twice.
            let k_pos = sc.hypot(ss) / scales.position.powi(2);
            for _ in 0..2 {
                let (mut wy, mut off) = (0.0, 0.0);
                for (k, q) in pred.iter().enumerate() {
                    let b = first + k;
                    let w = weights[b] / self.stated(b, 2).powi(2);
                    if let Some(yaw) = poses[self.selected[b]].yaw_rad {
                        wy += w;
                        off += w * wrap_angle(yaw - q.theta - phi);
                    }
                }
                if wy <= 0.0 {
                    break;
                }
                let k_yaw = wy / scales.yaw.powi(2);
                let pos_pull = {
                    let (s, c) = (ss, sc);
                    // d/dφ of −(c·cosφ + s·sinφ) at φ, over its curvature: the position
                    // cost's own Newton step.
                    (s * phi.cos() - c * phi.sin()) / scales.position.powi(2)
                };
                phi += (pos_pull + k_yaw * off / wy) / (k_pos + k_yaw);
            }
        }
        let (s, c) = phi.sin_cos();
        Pose2 {
            x: cr[0] - (c * cq[0] - s * cq[1]),
            y: cr[1] - (s * cq[0] + c * cq[1]),
            theta: phi,
        }
    }

    /// The time of block `b` (s, reference clock).
    fn block_time(&self, b: usize) -> f64 {
        let i = match self.kind {
            ReferenceKind::Absolute => self.selected[b],
            ReferenceKind::Relative => self.selected[b + 1],
        };
        self.recording.poses[i].time_s
    }

    /// The residuals of one window for an alignment.
    fn window_residuals(&self, pred: &[Pose2], a: usize, b: usize, align: &Pose2) -> Vec<f64> {
        let poses = &self.recording.poses;
        let mut out = Vec::with_capacity((b - a) * self.dim);
        let turn = Turn::of(align.theta);
        for k in a..b {
            let q = align.compose_turned(turn, &pred[k]);
            let r = &poses[self.selected[k]];
            out.push(r.x_m - q.x);
            out.push(r.y_m - q.y);
            if let Some(yaw) = r.yaw_rad {
                out.push(wrap_angle(yaw - q.theta));
            }
        }
        out
    }

    /// Under a random walk the Procrustes alignment is no longer the likelihood's: two
    /// Gauss–Newton steps on the whitened residuals of the window, over `(t_x, t_y, φ)`.
    fn align_whitened(
        &self,
        pred: &[Pose2],
        a: usize,
        b: usize,
        mut align: Pose2,
        weights: &[f64],
        scales: Scales,
    ) -> Pose2 {
        let dim = self.dim;
        for _ in 0..2 {
            let e = self.window_residuals(pred, a, b, &align);
            // ∂e/∂t_x = (−1, 0, 0), ∂e/∂t_y = (0, −1, 0), ∂e/∂φ = (y − t_y, −(x − t_x), −1).
            let mut cols = vec![vec![0.0; e.len()]; 3];
            let turn = Turn::of(align.theta);
            for (k, pk) in pred[a..b].iter().enumerate() {
                let q = align.compose_turned(turn, pk);
                let i = k * dim;
                cols[0][i] = -1.0;
                cols[1][i + 1] = -1.0;
                cols[2][i] = q.y - align.y;
                cols[2][i + 1] = -(q.x - align.x);
                if dim == 3 {
                    cols[2][i + 2] = -1.0;
                }
            }
            let z = self.whiten_window(&e, a, b, weights, scales).0;
            let zc: Vec<Vec<f64>> = cols
                .iter()
                .map(|c| self.whiten_window(c, a, b, weights, scales).0)
                .collect();
            let mut h = nalgebra::Matrix3::<f64>::zeros();
            let mut g = nalgebra::Vector3::<f64>::zeros();
            for i in 0..z.len() {
                for r in 0..3 {
                    g[r] += zc[r][i] * z[i];
                    for c in 0..3 {
                        h[(r, c)] += zc[r][i] * zc[c][i];
                    }
                }
            }
            let Some(step) = h.cholesky().map(|ch| ch.solve(&(-g))) else {
                break;
            };
            align.x += step[0];
            align.y += step[1];
            align.theta += step[2];
        }
        align
    }

    /// Whitens residuals `e` of blocks `[a, b)`: returns the whitened residuals the cost sums
    /// (zero for a block left out, scaled by its weight) and the innovations normalised
    /// without the weights (for judging outliers). Under a random walk each component is
    /// the innovation of a scalar Kalman filter whose state starts at zero with the window
    /// (the alignment plays its initial value); a block left out is not used to update it.
    fn whiten_window(
        &self,
        e: &[f64],
        a: usize,
        b: usize,
        weights: &[f64],
        scales: Scales,
    ) -> (Vec<f64>, Vec<f64>) {
        let dim = self.dim;
        let mut z = vec![0.0; e.len()];
        let mut raw = vec![0.0; e.len()];
        let walk = scales.walks() && self.kind == ReferenceKind::Absolute;
        for c in 0..dim {
            let (sigma, q) = scales.of(c);
            let (mut m, mut var) = (0.0, 0.0);
            let mut t_prev: Option<f64> = None;
            for (blk, &w) in weights.iter().enumerate().take(b).skip(a) {
                let i = (blk - a) * dim + c;
                let meas = (sigma * self.stated(blk, c)).powi(2);
                if !walk {
                    raw[i] = e[i] / meas.sqrt();
                    z[i] = raw[i] * w.sqrt();
                    continue;
                }
                let t = self.block_time(blk);
                if let Some(tp) = t_prev {
                    var += q * (t - tp).max(0.0);
                }
                t_prev = Some(t);
                let nu = e[i] - m;
                raw[i] = nu / (var + meas).sqrt();
                if w > 0.0 {
                    let s = var + meas / w;
                    z[i] = nu / s.sqrt();
                    let k = var / s;
                    m += k * nu;
                    var *= 1.0 - k;
                }
            }
        }
        (z, raw)
    }

    /// Whitens a whole residual vector (all blocks, window by window).
    fn whiten(&self, e: &[f64], weights: &[f64], scales: Scales) -> (Vec<f64>, Vec<f64>) {
        let dim = self.dim;
        let windows: Vec<(usize, usize)> = match self.kind {
            ReferenceKind::Absolute => self.windows.clone(),
            ReferenceKind::Relative => vec![(0, self.blocks())],
        };
        let mut z = Vec::with_capacity(e.len());
        let mut raw = Vec::with_capacity(e.len());
        for (a, b) in windows {
            let (zw, rw) = self.whiten_window(&e[a * dim..b * dim], a, b, weights, scales);
            z.extend(zw);
            raw.extend(rw);
        }
        (z, raw)
    }

    /// The residuals at `x` and their Jacobian with respect to the free parameters.
    fn jacobian(&self, x: &[f64], weights: &[f64], scales: Scales) -> (Vec<f64>, DMatrix<f64>) {
        let p = self.full(x);
        let wheels = &self.recording.wheels;
        let odo = Odometry::integrate(wheels, Self::geometry(&p));
        let r0 = self.residuals(&odo, &p, weights, scales);
        // One column per free parameter; the columns are independent, so they are computed on
        // as many threads as there are cores (two columns at least per thread).
        let column = |j: usize| -> Vec<f64> {
            let param = self.free[j];
            let h = step(param, &p);
            if param.is_geometry() {
                // Forward difference: each side needs a new integration.
                let mut xp = x.to_vec();
                xp[j] += h;
                let pp = self.full(&xp);
                let odo_p = Odometry::integrate(wheels, Self::geometry(&pp));
                let rp = self.residuals(&odo_p, &pp, weights, scales);
                rp.iter()
                    .zip(&r0)
                    .enumerate()
                    .map(|(i, (a, b))| angle_aware_diff(*a, *b, i, self.dim) / h)
                    .collect()
            } else {
                let (mut xp, mut xm) = (x.to_vec(), x.to_vec());
                xp[j] += h;
                xm[j] -= h;
                let (pp, pm) = (self.full(&xp), self.full(&xm));
                let rp = self.residuals(&odo, &pp, weights, scales);
                let rm = self.residuals(&odo, &pm, weights, scales);
                rp.iter()
                    .zip(&rm)
                    .enumerate()
                    .map(|(i, (a, b))| angle_aware_diff(*a, *b, i, self.dim) / (2.0 * h))
                    .collect()
            }
        };
        let n = self.free.len();
        let threads = std::thread::available_parallelism()
            .map_or(1, |t| t.get())
            .min(n.div_ceil(2))
            .max(1);
        let columns: Vec<Vec<f64>> = if threads == 1 || r0.len() < 5_000 {
            (0..n).map(column).collect()
        } else {
            std::thread::scope(|scope| {
                let handles: Vec<_> = (0..threads)
                    .map(|t| {
                        let column = &column;
                        scope.spawn(move || {
                            (t..n)
                                .step_by(threads)
                                .map(|j| (j, column(j)))
                                .collect::<Vec<_>>()
                        })
                    })
                    .collect();
                let mut out = vec![Vec::new(); n];
                for h in handles {
                    // A column's thread fails only by panicking, which is a bug: it goes on
                    // up as the panic it is, never as a silent zero column.
                    let cols = h.join().unwrap_or_else(|e| std::panic::resume_unwind(e));
                    for (j, col) in cols {
                        out[j] = col;
                    }
                }
                out
            })
        };
        let mut jac = DMatrix::zeros(r0.len(), n);
        for (j, col) in columns.iter().enumerate() {
            for (i, v) in col.iter().enumerate() {
                jac[(i, j)] = *v;
            }
        }
        (r0, jac)
    }

    fn cost(&self, x: &[f64], weights: &[f64], scales: Scales) -> f64 {
        let p = self.full(x);
        let odo = Odometry::integrate(&self.recording.wheels, Self::geometry(&p));
        let r = self.residuals(&odo, &p, weights, scales);
        self.whiten(&r, weights, scales)
            .0
            .iter()
            .map(|z| z * z)
            .sum()
    }

    /// The whitened residuals and Jacobian at `x`.
    fn whitened_jacobian(
        &self,
        x: &[f64],
        weights: &[f64],
        scales: Scales,
    ) -> (Vec<f64>, DMatrix<f64>) {
        let (r, jac) = self.jacobian(x, weights, scales);
        let z = self.whiten(&r, weights, scales).0;
        let mut jz = DMatrix::zeros(z.len(), jac.ncols());
        for j in 0..jac.ncols() {
            let col: Vec<f64> = jac.column(j).iter().copied().collect();
            for (i, v) in self.whiten(&col, weights, scales).0.into_iter().enumerate() {
                jz[(i, j)] = v;
            }
        }
        (z, jz)
    }

    fn physical(&self, x: &[f64]) -> bool {
        let p = self.full(x);
        p[..3].iter().all(|v| v.is_finite() && *v > 0.0)
            && p[6].abs() <= self.max_offset
            && p.iter().all(|v| v.is_finite())
    }
}

/// A difference of residual components; yaw components wrap.
fn angle_aware_diff(a: f64, b: f64, i: usize, dim: usize) -> f64 {
    if dim == 3 && i % 3 == 2 {
        wrap_angle(a - b)
    } else {
        a - b
    }
}

/// The finite-difference step of a parameter.
fn step(param: Param, p: &[f64; PARAMS]) -> f64 {
    match param {
        Param::LeftDiameter | Param::RightDiameter | Param::Wheelbase => 1e-7 * p[param.index()],
        Param::SensorX | Param::SensorY => 1e-6,
        Param::SensorYaw => 1e-6,
        Param::TimeOffset => 1e-5,
    }
}

/// Levenberg–Marquardt at fixed weights; returns the solution and the iterations used.
/// Levenberg–Marquardt from `x` on the whitened cost; converged when an iteration gains less
/// than `tolerance` of the cost.
fn levenberg_marquardt(
    problem: &Problem<'_>,
    mut x: Vec<f64>,
    weights: &[f64],
    scales: Scales,
    max_iterations: usize,
    tolerance: f64,
) -> (Vec<f64>, usize) {
    let mut lambda = 1e-4;
    let mut cost = problem.cost(&x, weights, scales);
    let n = x.len();
    for it in 0..max_iterations {
        let (z, jac) = problem.whitened_jacobian(&x, weights, scales);
        let mut h = DMatrix::<f64>::zeros(n, n);
        let mut g = DVector::<f64>::zeros(n);
        for (i, e) in z.iter().enumerate() {
            if *e == 0.0 && jac.row(i).iter().all(|v| *v == 0.0) {
                continue;
            }
            let row = jac.row(i);
            for a in 0..n {
                let ja = row[a];
                g[a] += ja * e;
                for b in a..n {
                    h[(a, b)] += ja * row[b];
                }
            }
        }
        for a in 0..n {
            for b in 0..a {
                h[(a, b)] = h[(b, a)];
            }
        }
        let mut improved = false;
        for _ in 0..12 {
            let mut damped = h.clone();
            for a in 0..n {
                damped[(a, a)] += lambda * h[(a, a)].max(1e-12);
            }
            let Some(chol) = damped.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            // Residuals are reference minus prediction, J their derivative: the step is
            // −(JᵀWJ)⁻¹ JᵀW r.
            let dx = chol.solve(&(-&g));
            let xn: Vec<f64> = x.iter().zip(dx.iter()).map(|(a, d)| a + d).collect();
            if !problem.physical(&xn) {
                lambda *= 10.0;
                continue;
            }
            let cn = problem.cost(&xn, weights, scales);
            if cn <= cost {
                let small = (cost - cn) <= tolerance * cost.max(1e-300);
                x = xn;
                cost = cn;
                lambda = (lambda / 10.0).max(1e-9);
                improved = true;
                if small {
                    return (x, it + 1);
                }
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            return (x, it + 1);
        }
    }
    (x, max_iterations)
}

/// Median of absolute values, scaled to a Gaussian standard deviation.
fn mad_std(values: impl Iterator<Item = f64>) -> f64 {
    let v: Vec<f64> = values.map(f64::abs).filter(|v| v.is_finite()).collect();
    upper_median(v).map_or(0.0, |m| 1.4826 * m)
}

/// Scales from residuals, robustly (median absolute value), over the blocks weighted > 0; no
/// random walk.
fn robust_scales(problem: &Problem<'_>, r: &[f64], weights: &[f64]) -> Scales {
    let dim = problem.dim;
    let pick = |c_lo: usize, c_hi: usize| {
        mad_std(r.chunks(dim).enumerate().flat_map(|(b, e)| {
            let keep = weights[b] > 0.0;
            (c_lo..c_hi)
                .filter(move |_| keep)
                .map(move |c| e[c] / problem.stated(b, c))
        }))
    };
    Scales::white(
        pick(0, 2).max(1e-9),
        if dim == 3 { pick(2, 3).max(1e-9) } else { 1.0 },
    )
}

/// White noise and random walk of an absolute reference's residuals by maximum likelihood:
/// for each class (positions, yaw) the ratio `λ = q/σ²` of the walk's variance per second to
/// the white variance, with `σ²` profiled out (`σ̂² = Σν²/s / n` for innovations `ν` of
/// normalised variance `s`, so `−2 log L = n log σ̂² + Σ log s`), searched on a logarithmic
/// grid and refined; a walk is kept only when it lowers `−2 log L` by more than [`WALK_LR`]
/// (the 95 % quantile of χ² with one degree of freedom, Wilks; conservative, as the walk's
/// variance sits on the boundary at zero), so that noise in the search does not invent one.
fn walk_scales(problem: &Problem<'_>, r: &[f64], weights: &[f64], white: Scales) -> Scales {
    let dim = problem.dim;
    // Σν²/s, Σ log s and the count over components `cs` for ratio `lambda` (σ² = 1).
    let innovations = |cs: &[usize], lambda: f64| -> (f64, f64, usize) {
        let (mut sum, mut logs, mut n) = (0.0, 0.0, 0usize);
        for &(a, b) in &problem.windows {
            for &c in cs {
                let (mut m, mut var) = (0.0f64, 0.0f64);
                let mut t_prev: Option<f64> = None;
                for blk in a..b {
                    let t = problem.block_time(blk);
                    if let Some(tp) = t_prev {
                        var += lambda * (t - tp).max(0.0);
                    }
                    t_prev = Some(t);
                    if weights[blk] <= 0.0 {
                        continue;
                    }
                    let meas = problem.stated(blk, c).powi(2);
                    let nu = r[blk * dim + c] - m;
                    let s = var + meas;
                    sum += nu * nu / s;
                    logs += s.ln();
                    n += 1;
                    let k = var / s;
                    m += k * nu;
                    var *= 1.0 - k;
                }
            }
        }
        (sum, logs, n)
    };
    // −2 log L (up to a constant) with σ² profiled out.
    let profile = |cs: &[usize], lambda: f64| -> f64 {
        let (sum, logs, n) = innovations(cs, lambda);
        if n == 0 || sum <= 0.0 {
            return f64::INFINITY;
        }
        n as f64 * (sum / n as f64).ln() + logs
    };
    let search = |cs: &[usize], sigma: f64| -> (f64, f64) {
        let none = profile(cs, 0.0);
        let mut best = (none, 0.0);
        let mut k = -10.0;
        while k <= 3.0 {
            let lambda = 10f64.powf(k);
            let v = profile(cs, lambda);
            if v < best.0 {
                best = (v, lambda);
            }
            k += 0.25;
        }
        if best.1 > 0.0 {
            // Golden-section refinement on log λ within one grid step each side.
            let (mut lo, mut hi) = (best.1.log10() - 0.25, best.1.log10() + 0.25);
            let g = 0.5 * (5f64.sqrt() - 1.0);
            for _ in 0..20 {
                let (a, b) = (hi - g * (hi - lo), lo + g * (hi - lo));
                if profile(cs, 10f64.powf(a)) < profile(cs, 10f64.powf(b)) {
                    hi = b;
                } else {
                    lo = a;
                }
            }
            let lambda = 10f64.powf(0.5 * (lo + hi));
            let v = profile(cs, lambda);
            if v < best.0 {
                best = (v, lambda);
            }
        }
        if none - best.0 < WALK_LR {
            return (sigma, 0.0);
        }
        // σ̂² at the best λ (in units of the stated σ²), then q = λσ̂².
        let (sum, _, n) = innovations(cs, best.1);
        let sigma2 = (sum / n.max(1) as f64).max(1e-24);
        (sigma2.sqrt(), best.1 * sigma2)
    };
    let (position, walk_position) = search(&[0, 1], white.position);
    let (yaw, walk_yaw) = if dim == 3 {
        search(&[2], white.yaw)
    } else {
        (1.0, 0.0)
    };
    Scales {
        position,
        yaw,
        walk_position,
        walk_yaw,
    }
}

/// Reference samples the kind decision's relative fit uses at most (ten minutes at 10 Hz).
const DECISION_POSES: usize = 6000;

/// Convergence of the final stage: an iteration gaining less than a part in 10⁹ of the cost
/// (for 10⁵ residuals, 10⁻⁴ in χ²: a hundredth of a standard deviation in the parameters), far
/// below what the noise lets them tell apart.
const TIGHT: f64 = 1e-9;
/// Convergence of the stages before it, whose weights and scales change after them.
const LOOSE: f64 = 1e-6;

/// Least drop of `−2 log L` that keeps a random walk: χ²₁'s 95 % quantile.
const WALK_LR: f64 = 3.84;

/// `χ²` 99.9 % quantiles for 2 and 3 degrees of freedom.
fn gate(dim: usize) -> f64 {
    if dim == 3 {
        16.27
    } else {
        13.82
    }
}

/// Normalised squared innovation of each block.
fn block_chi2(problem: &Problem<'_>, r: &[f64], weights: &[f64], scales: Scales) -> Vec<f64> {
    let raw = problem.whiten(r, weights, scales).1;
    raw.chunks(problem.dim)
        .map(|z| z.iter().map(|v| v * v).sum())
        .collect()
}

fn fit_kind(
    recording: &PoseRecording,
    config: &FitConfig,
    kind: ReferenceKind,
    start: Option<[f64; PARAMS]>,
    decision: KindDecision,
) -> Result<PoseFit, CalibrationError> {
    let problem = Problem::new(recording, config, kind)?;
    let blocks = problem.blocks();
    let dim = problem.dim;
    let mut weights = vec![1.0; blocks];
    let mut p0 = problem.fixed;
    if let Some(s) = start {
        for q in &problem.free {
            p0[q.index()] = s[q.index()];
        }
    }
    let unit = Scales::white(1.0, 1.0);
    let mut iterations_before = 0;
    let residual_at = |p: &[f64; PARAMS], w: &[f64], s: Scales| {
        let odo = Odometry::integrate(&recording.wheels, Problem::geometry(p));
        problem.residuals(&odo, p, w, s)
    };
    let mut scales = match config.weighting {
        Weighting::Unit => unit,
        Weighting::Estimated => {
            robust_scales(&problem, &residual_at(&p0, &weights, unit), &weights)
        }
    };
    // The time offset's basin: a lever arm along the direction of travel looks like a delay
    // while the robot drives straight, so the geometry and mounting are fitted first with the
    // offset held at zero, then the offset is searched on a coarse grid from there.
    if problem.free.contains(&Param::TimeOffset) && start.is_none() {
        let mut held = Problem::new(recording, config, kind)?;
        held.free.retain(|q| *q != Param::TimeOffset);
        let (xa, it) =
            levenberg_marquardt(&held, held.free_values(&p0), &weights, scales, 20, LOOSE);
        iterations_before = it;
        p0 = held.full(&xa);
        if config.weighting == Weighting::Estimated {
            scales = robust_scales(&problem, &residual_at(&p0, &weights, unit), &weights);
        }
        let odo = Odometry::integrate(&recording.wheels, Problem::geometry(&p0));
        let steps = (problem.max_offset / 0.02).ceil() as i64;
        let mut best = (f64::INFINITY, 0.0);
        for k in -steps..=steps {
            let mut p = p0;
            p[6] = (k as f64 * 0.02).clamp(-problem.max_offset, problem.max_offset);
            let r = problem.residuals(&odo, &p, &weights, scales);
            let cost: f64 = block_chi2(&problem, &r, &weights, scales)
                .iter()
                .map(|d| d.min(25.0))
                .sum();
            if cost < best.0 {
                best = (cost, p[6]);
            }
        }
        p0[6] = best.1;
        if config.weighting == Weighting::Estimated {
            scales = robust_scales(&problem, &residual_at(&p0, &weights, unit), &weights);
        }
    }
    let mut x = problem.free_values(&p0);
    let mut iterations = iterations_before;
    let stages = if config.robust { 12 } else { 1 };
    for stage in 0..stages {
        // The stages before the weights settle need not converge far: their weights and scales
        // change after them. The last is converged tightly, below.
        let tolerance = if config.robust { LOOSE } else { TIGHT };
        let (xn, it) = levenberg_marquardt(&problem, x, &weights, scales, 50, tolerance);
        x = xn;
        iterations += it;
        if !config.robust {
            break;
        }
        let p = problem.full(&x);
        let r = residual_at(&p, &weights, scales);
        let huber = stage < 2;
        let k2 = gate(dim);
        let ones = vec![1.0; blocks];
        let new_scales = if huber {
            robust_scales(&problem, &r, &ones)
        } else if weights.iter().any(|w| *w > 0.0 && *w < 1.0) {
            // The first gated stage follows Huber's, whose weights leave no block out: its
            // scales come from the blocks that the robust scales' gate keeps, or the outliers
            // would inflate them (by seven times on a localization's jumps) and the gate let
            // them in for a stage.
            let robust = robust_scales(&problem, &r, &ones);
            let kept: Vec<f64> = block_chi2(&problem, &r, &ones, robust)
                .iter()
                .map(|d2| if *d2 <= k2 { 1.0 } else { 0.0 })
                .collect();
            settle_scales(&problem, &r, &kept, config)
        } else {
            settle_scales(&problem, &r, &weights, config)
        };
        let chi2 = block_chi2(&problem, &r, &weights, new_scales);
        let new_weights: Vec<f64> = chi2
            .iter()
            .map(|d2| {
                if huber {
                    // Huber on the block's distance, k at the χ² 95 % quantile.
                    let k = if dim == 3 {
                        7.81f64.sqrt()
                    } else {
                        5.99f64.sqrt()
                    };
                    let d = d2.sqrt();
                    if d <= k {
                        1.0
                    } else {
                        k / d
                    }
                } else if *d2 <= k2 {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-3 * a.abs().max(b.abs()).max(1e-300);
        let settled = !huber
            && new_weights == weights
            && close(new_scales.position, scales.position)
            && close(new_scales.yaw, scales.yaw)
            && close(new_scales.walk_position, scales.walk_position)
            && close(new_scales.walk_yaw, scales.walk_yaw);
        weights = new_weights;
        scales = new_scales;
        if settled || stage + 1 == stages {
            // Converged tightly under the settled (or the last) weights and scales.
            let (xn, it) = levenberg_marquardt(&problem, x, &weights, scales, 50, TIGHT);
            x = xn;
            iterations += it;
            break;
        }
    }
    let p = problem.full(&x);
    // Final scales and covariance at the solution, inliers only.
    let n_free = problem.free.len();
    let outliers = weights.iter().filter(|w| **w == 0.0).count();
    let r = residual_at(&p, &weights, scales);
    if config.robust || config.weighting == Weighting::Estimated {
        scales = inlier_scales(&problem, &r, &weights, scales);
    } else {
        // Unweighted least squares: one variance for every component.
        let n = r
            .len()
            .saturating_sub(n_free + 3 * problem.windows.len())
            .max(1);
        let s = (r.iter().map(|e| e * e).sum::<f64>() / n as f64)
            .sqrt()
            .max(1e-12);
        scales = Scales::white(s, s);
    }
    let (z, jac) = problem.whitened_jacobian(&x, &weights, scales);
    let h = jac.transpose() * &jac;
    let rho = lag_one_correlation(&problem, &z, &weights);
    let inflation = ((1.0 + rho) / (1.0 - rho)).clamp(1.0, 100.0);
    let cov_free = h
        .clone()
        .try_inverse()
        .unwrap_or_else(|| DMatrix::from_element(n_free, n_free, f64::INFINITY));
    let mut covariance = [[0.0; PARAMS]; PARAMS];
    let mut index: Vec<(usize, usize)> = problem
        .free
        .iter()
        .enumerate()
        .map(|(j, q)| (j, q.index()))
        .collect();
    if problem.tie {
        index.push((0, 1));
    }
    for &(a, ia) in &index {
        for &(b, ib) in &index {
            covariance[ia][ib] = cov_free[(a, b)] * inflation;
        }
    }
    let span_s = {
        let first = recording.poses[problem.selected[0]].time_s;
        let last = recording.poses[problem.selected[problem.selected.len() - 1]].time_s;
        last - first
    };
    Ok(PoseFit {
        geometry: Problem::geometry(&p),
        params: p,
        covariance,
        free: problem.free.clone(),
        kind: decision,
        residual_std_position_m: scales.position * problem.stated_rms(0),
        stated_scale: problem.use_stated.then_some(scales.position),
        stated_scale_yaw: (problem.use_stated && dim == 3).then_some(scales.yaw),
        residual_std_yaw_rad: (dim == 3).then_some(scales.yaw * problem.stated_rms(2)),
        walk_position_m2_s: scales.walk_position,
        walk_yaw_rad2_s: (dim == 3).then_some(scales.walk_yaw),
        compared: blocks,
        outliers,
        windows: match kind {
            ReferenceKind::Absolute => problem.windows.len(),
            ReferenceKind::Relative => 0,
        },
        lag_one_correlation: rho,
        variance_inflation: inflation,
        iterations,
        span_s,
        nominal_wheelbase_m: config.nominal.wheelbase_m,
        warnings: if problem.free.contains(&Param::TimeOffset)
            && p[6].abs() >= 0.95 * problem.max_offset
        {
            vec![format!(
                "the time offset {:.3} s is at its limit (±{:.2} s): the streams may be further \
                 apart, and the geometry then absorbs the rest; raise --max-time-offset-s and fit \
                 again",
                p[6], problem.max_offset
            )]
        } else {
            Vec::new()
        },
    })
}

/// The scales of a gated stage: white noise and random walk by maximum likelihood for an
/// absolute reference, white noise for a relative one; then one common factor per class that
/// makes the inliers' whitened residuals unit.
fn settle_scales(problem: &Problem<'_>, r: &[f64], weights: &[f64], config: &FitConfig) -> Scales {
    let shape = match problem.kind {
        ReferenceKind::Absolute if config.weighting == Weighting::Estimated => {
            let white = robust_scales(problem, r, weights);
            walk_scales(problem, r, weights, white)
        }
        _ => robust_scales(problem, r, weights),
    };
    inlier_scales(problem, r, weights, shape)
}

/// `shape` rescaled per class so that the inliers' whitened residuals have unit variance,
/// corrected for the parameters and alignments fitted.
fn inlier_scales(problem: &Problem<'_>, r: &[f64], weights: &[f64], shape: Scales) -> Scales {
    let dim = problem.dim;
    let raw = problem.whiten(r, weights, shape).1;
    let (mut sp, mut np, mut sy, mut ny) = (0.0, 0usize, 0.0, 0usize);
    for (b, z) in raw.chunks(dim).enumerate() {
        if weights[b] <= 0.0 {
            continue;
        }
        for (c, v) in z.iter().enumerate() {
            if c < 2 {
                sp += v * v;
                np += 1;
            } else {
                sy += v * v;
                ny += 1;
            }
        }
    }
    let nuisance = match problem.kind {
        ReferenceKind::Absolute => 3 * problem.windows.len(),
        ReferenceKind::Relative => 0,
    };
    let lost = (problem.free.len() + nuisance) as f64;
    let total = (np + ny).max(1) as f64;
    let dof = |n: usize| (n as f64 - lost * n as f64 / total).max(1.0);
    let fp = (sp / dof(np)).max(1e-24);
    let fy = if ny > 0 {
        (sy / dof(ny)).max(1e-24)
    } else {
        1.0
    };
    Scales {
        position: (shape.position * fp.sqrt()).max(1e-12),
        yaw: if ny > 0 {
            (shape.yaw * fy.sqrt()).max(1e-12)
        } else {
            1.0
        },
        walk_position: shape.walk_position * fp,
        walk_yaw: shape.walk_yaw * fy,
    }
}

/// Lag-one correlation of the whitened residuals `z` of consecutive inlier blocks, pooled over
/// components.
fn lag_one_correlation(problem: &Problem<'_>, z: &[f64], weights: &[f64]) -> f64 {
    let dim = problem.dim;
    let (mut num, mut den) = (0.0, 0.0);
    for b in 0..problem.blocks() {
        if weights[b] <= 0.0 {
            continue;
        }
        for c in 0..dim {
            den += z[b * dim + c].powi(2);
            if b > 0 && weights[b - 1] > 0.0 {
                num += z[b * dim + c] * z[(b - 1) * dim + c];
            }
        }
    }
    if den > 0.0 {
        (num / den).clamp(-1.0, 0.98)
    } else {
        0.0
    }
}

/// The robust variance of the motion residual over `k` reference samples over that over one,
/// at parameters `p` (position components).
pub(crate) fn span_variance_ratio(
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
