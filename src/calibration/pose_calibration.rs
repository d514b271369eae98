//! A calibration against a pose reference from one or several recordings of one robot: the
//! checks before ([`super::observability`]), the maximum-likelihood fit of each recording
//! ([`super::pose_fit`]), the two-multiplier baseline beside it ([`super::multiplier_fit`]),
//! and the recordings pooled into one robot.
//!
//! **Pooling.** Each recording is fitted on its own (its own alignment, mounting and time
//! offset), then every parameter is pooled by the random-effects model `pool` uses for squares
//! (DerSimonian & Laird 1986): when the recordings disagree by more than their stated errors
//! allow, a between-recording spread `τ` is estimated and the pooled standard deviation
//! widened by it, and the report says so. A recording whose own fit did not observe the
//! geometry is left out of the pool, with its reason.

use super::heading_reference::heading_scales;
use super::holes::hole_warnings;
use super::independence::{compare, more_wheel_like, Independence, ReferenceSource};
use super::multiplier_fit::{fit_multipliers, MultiplierFit};
use super::observability::{judge, survey, DriveSurvey, Observability};
use super::plausibility::{
    check_fit, check_units_and_signs, check_wheel_jumps, direction_warning, survey_scale,
};
use super::pool::pool_log;
use super::pose_fit::{fit_poses, FitConfig, Param, PoseFit};
use super::pose_reference::{final_position_error_m, Geometry, Pose2, PoseRecording};
use super::CalibrationError;
use serde::Serialize;

/// One recording's result.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RecordingResult {
    /// Its name (file, set and run).
    pub name: String,
    /// What the drive did.
    pub survey: DriveSurvey,
    /// Whether the reference measures the robot by itself or follows its wheels.
    pub independence: Independence,
    /// The fit, when the drive allowed one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fit: Option<PoseFit>,
    /// Which parameters its fit observed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub observability: Option<Observability>,
    /// The two-multiplier baseline on the same recording.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub baseline: Option<MultiplierFit>,
    /// Why it is not in the pool, when it is not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub left_out: Option<String>,
}

/// One parameter pooled over the recordings.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PooledParameter {
    /// Its name (with unit).
    pub parameter: &'static str,
    /// The pooled value.
    pub value: f64,
    /// Its standard deviation: the recordings' stated errors and, when they disagree, the
    /// between-recording spread.
    pub std: f64,
    /// The between-recording spread `τ` (0: the recordings agree within their errors).
    pub between_recordings: f64,
}

/// The calibration of one robot from pose-reference recordings.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PoseCalibration {
    /// The geometry the fits started from.
    pub nominal: Geometry,
    /// Per recording.
    pub recordings: Vec<RecordingResult>,
    /// Per fitted parameter, pooled over the recordings in the pool.
    pub pooled: Vec<PooledParameter>,
    /// The pooled geometry (m).
    pub geometry: Geometry,
    /// `E_d = D_R / D_L`, pooled.
    pub e_d: PooledParameter,
    /// `E_b = b / b_nominal`, pooled.
    pub e_b: PooledParameter,
    /// The baseline pooled as a plain mean of the recordings' multipliers (radius, separation).
    pub baseline_geometry: Option<Geometry>,
}

impl PoseCalibration {
    /// A pooled parameter's value and standard deviation; `None` when no recording fitted it.
    pub fn get(&self, p: Param) -> Option<&PooledParameter> {
        self.pooled.iter().find(|q| q.parameter == p.name())
    }

    /// The pooled mounting `(x, y, yaw)` in `base_link` (zeros where not fitted).
    pub fn mount(&self) -> Pose2 {
        let v = |p| self.get(p).map_or(0.0, |q| q.value);
        Pose2 {
            x: v(Param::SensorX),
            y: v(Param::SensorY),
            theta: v(Param::SensorYaw),
        }
    }

    /// The pooled time offset (s; 0 when not fitted).
    pub fn time_offset_s(&self) -> f64 {
        self.get(Param::TimeOffset).map_or(0.0, |q| q.value)
    }
}

/// The fit as a user sets it (with the `cli` feature, `odocal fit`'s flags, their doc
/// comments the help).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct FitSettings {
    /// How the reference errs: absolute (motion capture, a map's localization, GNSS) or
    /// relative (chained scan matching, visual odometry) [default: absolute for a --dataset,
    /// which is motion capture; otherwise decided from the data].
    #[cfg_attr(feature = "cli", arg(long))]
    pub reference_kind: Option<super::pose_reference::ReferenceKind>,
    /// Take the reference frame as base_link itself (do not fit its mounting).
    #[cfg_attr(feature = "cli", arg(long))]
    pub no_mounting: bool,
    /// Take the streams' stamps as simultaneous (do not fit a time offset).
    #[cfg_attr(feature = "cli", arg(long))]
    pub no_time_offset: bool,
    /// Largest time offset searched (s).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.5))]
    pub max_time_offset_s: f64,
    /// Absolute references: align windows of this length separately (s) instead of the whole
    /// trajectory (for long drives on slippery floors).
    #[cfg_attr(feature = "cli", arg(long))]
    pub window_s: Option<f64>,
}

impl Default for FitSettings {
    fn default() -> Self {
        FitSettings {
            reference_kind: None,
            no_mounting: false,
            no_time_offset: false,
            max_time_offset_s: 0.5,
            window_s: None,
        }
    }
}

impl FitSettings {
    /// The full fit from `nominal` with these settings, checked; `motion_capture` says the
    /// recordings are a data set's, whose reference is absolute by its kind.
    pub fn config(
        &self,
        nominal: Geometry,
        motion_capture: bool,
    ) -> Result<FitConfig, CalibrationError> {
        for (flag, v, lo, hi) in [
            ("--max-time-offset-s", self.max_time_offset_s, 0.0, 10.0),
            ("--window-s", self.window_s.unwrap_or(10.0), 1.0, 1e6),
        ] {
            crate::ranges::check_range(flag, v, lo, hi).map_err(CalibrationError::OutOfRange)?;
        }
        let absolute = super::pose_reference::ReferenceKind::Absolute;
        Ok(FitConfig {
            kind: self.reference_kind.or(motion_capture.then_some(absolute)),
            fit_mounting: !self.no_mounting,
            fit_time_offset: !self.no_time_offset,
            max_time_offset_s: self.max_time_offset_s,
            window_s: self.window_s,
            ..FitConfig::full(nominal)
        })
    }
}

/// Calibrates from `recordings` (name, recording), all of one robot, by `config`.
pub fn calibrate_from_poses(
    recordings: &[(String, PoseRecording)],
    config: &FitConfig,
) -> Result<PoseCalibration, CalibrationError> {
    if recordings.is_empty() {
        return Err(CalibrationError::PoseInput(
            "no recording to fit: give wheels and poses, a bag or a data set".into(),
        ));
    }
    let mut results: Vec<RecordingResult> = Vec::new();
    let mut first_refusal: Option<CalibrationError> = None;
    let mut seen: Vec<(u64, usize)> = Vec::new();
    for (name, rec) in recordings {
        // One recording is one piece of evidence however often it is given (twice, or through
        // a link under another name): counted again it would shrink every ± by √2.
        let print = fingerprint(rec);
        if let Some(&(_, i)) = seen
            .iter()
            .find(|(f, i)| *f == print && recordings[*i].1 == *rec)
        {
            results.push(RecordingResult {
                name: name.clone(),
                left_out: Some(format!(
                    "the same data as {}: counted once",
                    recordings[i].0
                )),
                fit: None,
                observability: None,
                baseline: None,
                ..results[i].clone()
            });
            continue;
        }
        seen.push((print, results.len()));
        results.push(fit_recording(name, rec, config, &mut first_refusal)?);
    }
    let in_pool: Vec<&PoseFit> = results
        .iter()
        .filter(|r| r.left_out.is_none())
        .filter_map(|r| r.fit.as_ref())
        .collect();
    if in_pool.is_empty() {
        return Err(first_refusal.unwrap_or_else(|| {
            CalibrationError::PoseInput("no recording could be fitted".into())
        }));
    }
    let pooled = pool_parameters(&in_pool);
    let geometry = pooled_geometry(&pooled, config.nominal);
    let e_d = pool_one(
        "e_d",
        &in_pool.iter().map(|f| f.e_d()).collect::<Vec<_>>(),
        &in_pool
            .iter()
            .map(|f| Some(f.e_d_std()))
            .collect::<Vec<_>>(),
    );
    let e_b = pool_one(
        "e_b",
        &in_pool.iter().map(|f| f.e_b()).collect::<Vec<_>>(),
        &in_pool
            .iter()
            .map(|f| Some(f.e_b_std()))
            .collect::<Vec<_>>(),
    );
    let baseline_geometry = mean_baseline_geometry(&results);
    Ok(PoseCalibration {
        nominal: config.nominal,
        recordings: results,
        pooled,
        geometry,
        e_d,
        e_b,
        baseline_geometry,
    })
}

/// Surveys, fits and judges one recording: a refusal leaves it out, an input error stops all.
fn fit_recording(
    name: &str,
    rec: &PoseRecording,
    config: &FitConfig,
    first_refusal: &mut Option<CalibrationError>,
) -> Result<RecordingResult, CalibrationError> {
    check_wheel_jumps(rec).map_err(|e| prefix(name, e))?;
    let drive = survey(rec, config.nominal);
    // Units and signs first: wheels in revolutions or poses in millimetres also break the
    // conventions' slopes, whose messages would then mislead.
    let scale = survey_scale(rec, config.nominal);
    check_units_and_signs(&scale, &drive).map_err(|e| prefix(name, e))?;
    // A reference in another convention is an error of the input, whatever the others do.
    drive.diagnose().map_err(|e| prefix(name, e))?;
    let independence = compare(rec, config.nominal, Pose2::default(), 0.0);
    refuse_wheel_made(&independence, rec, config.nominal).map_err(|e| prefix(name, e))?;
    let mut result = RecordingResult {
        name: name.to_owned(),
        survey: drive.clone(),
        independence,
        fit: None,
        observability: None,
        baseline: None,
        left_out: None,
    };
    if let Err(e) = drive.require() {
        result.left_out = Some(e.to_string());
        first_refusal.get_or_insert(e);
        return Ok(result);
    }
    // A heading made from the wheels says nothing of them: the positions alone are fitted.
    let own_heading = result.independence.source == ReferenceSource::WheelHeadingOwnPositions;
    let positions_only;
    let (fitted, fit_config) = if own_heading {
        positions_only = without_yaw(rec);
        (&positions_only, positions_only_config(config))
    } else {
        (rec, config.clone())
    };
    let mut fit = fit_poses(fitted, &fit_config).map_err(|e| prefix(name, e))?;
    // The same test with the fitted mounting and time offset: a wheel-made reference stamped
    // late, or reported in a frame of its own, follows the wheels there.
    let at_fit = compare(
        rec,
        config.nominal,
        fit_mount(&fit),
        fit.value(Param::TimeOffset),
    );
    result.independence = more_wheel_like(result.independence, at_fit);
    refuse_wheel_made(&result.independence, rec, config.nominal).map_err(|e| prefix(name, e))?;
    check_fit(&fit, config.nominal).map_err(|e| prefix(name, e))?;
    if own_heading {
        fit.warnings.push(result.independence.explanation());
    }
    fit.warnings.extend(direction_warning(&scale));
    fit.warnings.extend(hole_warnings(rec));
    let obs = judge(&fit);
    if let Err(e) = obs.require_geometry() {
        result.left_out = Some(e.to_string());
        first_refusal.get_or_insert(e);
    }
    result.baseline = fit_multipliers(fitted, config.nominal).ok();
    result.fit = Some(fit);
    result.observability = Some(obs);
    Ok(result)
}

/// A hash of a recording's numbers (their bits), to find the same data given twice.
fn fingerprint(rec: &PoseRecording) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for w in &rec.wheels {
        [w.time_s, w.left_rad, w.right_rad]
            .map(f64::to_bits)
            .hash(&mut h);
    }
    for p in &rec.poses {
        [p.time_s, p.x_m, p.y_m, p.yaw_rad.unwrap_or(f64::NAN)]
            .map(f64::to_bits)
            .hash(&mut h);
    }
    h.finish()
}

/// Refuses a reference whose positions follow the wheels; one whose heading is its own is
/// refused with what that heading alone measures.
fn refuse_wheel_made(
    independence: &Independence,
    rec: &PoseRecording,
    nominal: Geometry,
) -> Result<(), CalibrationError> {
    match independence.source {
        ReferenceSource::WheelOdometry => Err(CalibrationError::ReferenceFromWheels(
            independence.explanation(),
        )),
        ReferenceSource::WheelPositionsOwnHeading => {
            let heading = heading_scales(rec, nominal).map_or(String::new(), |h| {
                format!(
                    ". Its heading alone gives E_d = {:.5} ± {:.1e} and E_b = {:.5} ± {:.1e} (1σ \
                     over {} increments; the diameters' mean held at the nominal, the gyro's \
                     scale error in E_b)",
                    h.e_d, h.e_d_std, h.e_b, h.e_b_std, h.increments
                )
            });
            Err(CalibrationError::ReferenceFromWheels(format!(
                "{}{heading}",
                independence.explanation()
            )))
        }
        ReferenceSource::Independent | ReferenceSource::WheelHeadingOwnPositions => Ok(()),
    }
}

/// `rec` without the reference's yaw.
fn without_yaw(rec: &PoseRecording) -> PoseRecording {
    let mut out = rec.clone();
    for p in &mut out.poses {
        p.yaw_rad = None;
    }
    out
}

/// `config` for a position-only reference: absolute, whatever was given (a reference without
/// yaw cannot be chained).
fn positions_only_config(config: &FitConfig) -> FitConfig {
    FitConfig {
        kind: Some(super::pose_reference::ReferenceKind::Absolute),
        ..config.clone()
    }
}

/// The fitted mounting (zeros where not fitted).
fn fit_mount(fit: &PoseFit) -> Pose2 {
    Pose2 {
        x: fit.value(Param::SensorX),
        y: fit.value(Param::SensorY),
        theta: fit.value(Param::SensorYaw),
    }
}

/// Pools each parameter over the fits in the pool that left it free, in `Param::ALL` order.
fn pool_parameters(in_pool: &[&PoseFit]) -> Vec<PooledParameter> {
    let mut pooled = Vec::new();
    for p in Param::ALL {
        let fitted: Vec<&&PoseFit> = in_pool.iter().filter(|f| f.free.contains(&p)).collect();
        if fitted.is_empty() {
            continue;
        }
        let y: Vec<f64> = fitted.iter().map(|f| f.value(p)).collect();
        let se: Vec<Option<f64>> = fitted.iter().map(|f| f.std(p)).collect();
        pooled.push(pool_one(p.name(), &y, &se));
    }
    pooled
}

/// The geometry from the pooled parameters, falling back where one was not fitted: the right
/// diameter to the pooled left one (diameters tied), else to the nominal.
fn pooled_geometry(pooled: &[PooledParameter], nominal: Geometry) -> Geometry {
    let value = |p: Param| {
        pooled
            .iter()
            .find(|q| q.parameter == p.name())
            .map(|q| q.value)
    };
    Geometry {
        left_diameter_m: value(Param::LeftDiameter).unwrap_or(nominal.left_diameter_m),
        right_diameter_m: value(Param::RightDiameter)
            .or(value(Param::LeftDiameter))
            .unwrap_or(nominal.right_diameter_m),
        wheelbase_m: value(Param::Wheelbase).unwrap_or(nominal.wheelbase_m),
    }
}

/// The plain mean of the pooled recordings' multiplier baselines; `None` when there is none.
fn mean_baseline_geometry(results: &[RecordingResult]) -> Option<Geometry> {
    let baselines: Vec<&MultiplierFit> = results
        .iter()
        .filter(|r| r.left_out.is_none())
        .filter_map(|r| r.baseline.as_ref())
        .collect();
    (!baselines.is_empty()).then(|| {
        let n = baselines.len() as f64;
        let d = baselines
            .iter()
            .map(|b| b.geometry.left_diameter_m)
            .sum::<f64>()
            / n;
        Geometry {
            left_diameter_m: d,
            right_diameter_m: d,
            wheelbase_m: baselines
                .iter()
                .map(|b| b.geometry.wheelbase_m)
                .sum::<f64>()
                / n,
        }
    })
}

fn prefix(name: &str, e: CalibrationError) -> CalibrationError {
    match e {
        CalibrationError::PoseInput(s) => CalibrationError::PoseInput(format!("{name}: {s}")),
        other => other,
    }
}

fn pool_one(name: &'static str, y: &[f64], se: &[Option<f64>]) -> PooledParameter {
    let runs = vec![1; y.len()];
    let p = pool_log(y, se, &runs);
    PooledParameter {
        parameter: name,
        value: p.mean,
        std: p.std_err,
        between_recordings: p.recording_spread,
    }
}

/// Dead reckoning of one recording by three parameter sets: the calibration (with its mounting
/// and offset), the nominal geometry and the baseline (both taking the reference as
/// `base_link`'s, as their tools do).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DeadReckoning {
    /// The recording's name.
    pub name: String,
    /// Final-position error with the calibration (m).
    pub calibrated_m: f64,
    /// With the nominal geometry (m).
    pub nominal_m: f64,
    /// With the two-multiplier baseline (m), when there is one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub baseline_m: Option<f64>,
    /// With the calibration's geometry but no mounting or offset: the geometry's share (m).
    pub calibrated_geometry_only_m: f64,
}

/// Dead-reckons `recording` with `calibration` and the alternatives; `None` when the reference
/// has no yaw to start from or the streams do not overlap.
pub fn dead_reckon(
    name: &str,
    recording: &PoseRecording,
    calibration: &PoseCalibration,
) -> Option<DeadReckoning> {
    let none = Pose2::default();
    let calibrated_m = final_position_error_m(
        recording,
        calibration.geometry,
        calibration.mount(),
        calibration.time_offset_s(),
    )?;
    let nominal_m = final_position_error_m(recording, calibration.nominal, none, 0.0)?;
    let baseline_m = calibration
        .baseline_geometry
        .and_then(|g| final_position_error_m(recording, g, none, 0.0));
    let calibrated_geometry_only_m =
        final_position_error_m(recording, calibration.geometry, none, 0.0)?;
    Some(DeadReckoning {
        name: name.to_string(),
        calibrated_m,
        nominal_m,
        baseline_m,
        calibrated_geometry_only_m,
    })
}

/// The calibration flattened for machines: the contract's top-level fields (`odocal fit
/// --json`); standard deviations are one σ, `null` where a parameter was not fitted.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FitSummary {
    /// Left wheel diameter (m).
    pub left_wheel_diameter_m: f64,
    /// Its standard deviation (m).
    pub left_wheel_diameter_m_std: Option<f64>,
    /// Right wheel diameter (m).
    pub right_wheel_diameter_m: f64,
    /// Its standard deviation (m).
    pub right_wheel_diameter_m_std: Option<f64>,
    /// Wheelbase (m).
    pub wheelbase_m: f64,
    /// Its standard deviation (m).
    pub wheelbase_m_std: Option<f64>,
    /// The reference frame's x in `base_link` (m).
    pub sensor_x_m: f64,
    /// Its standard deviation (m).
    pub sensor_x_m_std: Option<f64>,
    /// The reference frame's y in `base_link` (m).
    pub sensor_y_m: f64,
    /// Its standard deviation (m).
    pub sensor_y_m_std: Option<f64>,
    /// The reference frame's yaw in `base_link` (rad, counter-clockwise positive).
    pub sensor_yaw_rad: f64,
    /// Its standard deviation (rad).
    pub sensor_yaw_rad_std: Option<f64>,
    /// Lateness of the reference's stamps (s; positive: late).
    pub time_offset_s: f64,
    /// Its standard deviation (s).
    pub time_offset_s_std: Option<f64>,
    /// `E_d = D_R / D_L`.
    pub e_d: f64,
    /// Its standard deviation.
    pub e_d_std: f64,
    /// `E_b = b / b_nominal`.
    pub e_b: f64,
    /// Its standard deviation.
    pub e_b_std: f64,
    /// The nominal (configured) left wheel diameter the fit started from (m).
    pub nominal_left_wheel_diameter_m: f64,
    /// The nominal right wheel diameter (m).
    pub nominal_right_wheel_diameter_m: f64,
    /// The nominal wheelbase `E_b` refers to (m).
    pub nominal_wheelbase_m: f64,
    /// How the reference was fitted: `absolute` or `relative`.
    pub reference_kind: &'static str,
    /// Why.
    pub reference_kind_reason: String,
    /// Recordings pooled.
    pub recordings_pooled: usize,
    /// What a ± means.
    pub uncertainty: &'static str,
}

impl PoseCalibration {
    /// The flat summary.
    pub fn summary(&self) -> FitSummary {
        let v = |p: Param| self.get(p).map(|q| (q.value, Some(q.std)));
        let g = |p: Param, default: f64| v(p).unwrap_or((default, None));
        let (dl, dl_s) = g(Param::LeftDiameter, self.geometry.left_diameter_m);
        let (dr, dr_s) = v(Param::RightDiameter)
            .or(v(Param::LeftDiameter))
            .unwrap_or((self.geometry.right_diameter_m, None));
        let (b, b_s) = g(Param::Wheelbase, self.geometry.wheelbase_m);
        let (sx, sx_s) = g(Param::SensorX, 0.0);
        let (sy, sy_s) = g(Param::SensorY, 0.0);
        let (syaw, syaw_s) = g(Param::SensorYaw, 0.0);
        let (dt, dt_s) = g(Param::TimeOffset, 0.0);
        let kind = self
            .recordings
            .iter()
            .filter(|r| r.left_out.is_none())
            .find_map(|r| r.fit.as_ref())
            .map(|f| f.kind.clone());
        FitSummary {
            left_wheel_diameter_m: dl,
            left_wheel_diameter_m_std: dl_s,
            right_wheel_diameter_m: dr,
            right_wheel_diameter_m_std: dr_s,
            wheelbase_m: b,
            wheelbase_m_std: b_s,
            sensor_x_m: sx,
            sensor_x_m_std: sx_s,
            sensor_y_m: sy,
            sensor_y_m_std: sy_s,
            sensor_yaw_rad: syaw,
            sensor_yaw_rad_std: syaw_s,
            time_offset_s: dt,
            time_offset_s_std: dt_s,
            e_d: self.e_d.value,
            e_d_std: self.e_d.std,
            e_b: self.e_b.value,
            e_b_std: self.e_b.std,
            nominal_left_wheel_diameter_m: self.nominal.left_diameter_m,
            nominal_right_wheel_diameter_m: self.nominal.right_diameter_m,
            nominal_wheelbase_m: self.nominal.wheelbase_m,
            reference_kind: kind.as_ref().map_or("absolute", |k| k.kind.name()),
            reference_kind_reason: kind.map(|k| k.reason).unwrap_or_default(),
            recordings_pooled: self
                .recordings
                .iter()
                .filter(|r| r.left_out.is_none() && r.fit.is_some())
                .count(),
            uncertainty: "one standard deviation: each recording's maximum-likelihood \
                          covariance (inflated for correlated residuals), pooled with the \
                          between-recording spread when recordings disagree",
        }
    }
}

impl PoseCalibration {
    /// The fit as `fit.json` and stdout's JSON hold it: the summary, each recording's fit, the
    /// pooled parameters, the baseline geometry, and the dead reckoning on other recordings.
    pub fn json(&self, evaluations: &[DeadReckoning]) -> serde_json::Result<serde_json::Value> {
        let mut out = serde_json::to_value(self.summary())?;
        if let Some(map) = out.as_object_mut() {
            map.insert("recordings".into(), serde_json::to_value(&self.recordings)?);
            map.insert("pooled".into(), serde_json::to_value(&self.pooled)?);
            map.insert(
                "baseline_geometry".into(),
                serde_json::to_value(self.baseline_geometry)?,
            );
            map.insert("evaluations".into(), serde_json::to_value(evaluations)?);
        }
        Ok(out)
    }
}

/// Dead reckoning on other recordings as a table: the distance from the reference's last pose
/// with the fitted, the nominal and the baseline geometry (m); empty when there is none.
pub fn evaluations_text(evaluations: &[DeadReckoning]) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    if evaluations.is_empty() {
        return out;
    }
    let _ = writeln!(
        out,
        "\ndead reckoning from the reference's first pose, distance from its last (m):\n\
         {:<34} {:>10} {:>10} {:>10}",
        "recording", "fitted", "nominal", "baseline"
    );
    for e in evaluations {
        let _ = writeln!(
            out,
            "{:<34} {:>10.4} {:>10.4} {:>10}",
            e.name,
            e.calibrated_m,
            e.nominal_m,
            e.baseline_m.map_or("—".into(), |b| format!("{b:.4}"))
        );
    }
    out
}

/// The fit as the terminal shows it: what kind of reference and why, each parameter with its
/// ± (one standard deviation) beside the nominal, E_d and E_b, and each recording's fit.
impl std::fmt::Display for PoseCalibration {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let c = self;
        let s = c.summary();
        writeln!(
            f,
            "fitted {} recording(s) as {} reference: {}",
            s.recordings_pooled,
            if s.reference_kind == "absolute" {
                "an absolute"
            } else {
                "a relative"
            },
            s.reference_kind_reason
        )?;
        writeln!(f, "± is one standard deviation ({})", s.uncertainty)?;
        writeln!(
            f,
            "{:<24} {:>14} {:>12} {:>14}",
            "parameter", "value", "±", "nominal"
        )?;
        let nominal = |p: Param| match p {
            Param::LeftDiameter => format!("{:.6}", c.nominal.left_diameter_m),
            Param::RightDiameter => format!("{:.6}", c.nominal.right_diameter_m),
            Param::Wheelbase => format!("{:.6}", c.nominal.wheelbase_m),
            _ => "—".into(),
        };
        for q in &c.pooled {
            let p = Param::ALL.iter().copied().find(|p| p.name() == q.parameter);
            writeln!(
                f,
                "{:<24} {:>14.6} {:>12.2e} {:>14}",
                q.parameter,
                q.value,
                q.std,
                p.map_or("—".into(), nominal)
            )?;
        }
        writeln!(
            f,
            "{:<24} {:>14.6} {:>12.2e}\n{:<24} {:>14.6} {:>12.2e}",
            "E_d = D_R/D_L", s.e_d, s.e_d_std, "E_b = b/b_nominal", s.e_b, s.e_b_std
        )?;
        for r in &c.recordings {
            if let Some(why) = &r.left_out {
                writeln!(f, "{}: left out: {why}", r.name)?;
            }
            if let Some(fit) = &r.fit {
                for w in &fit.warnings {
                    writeln!(f, "{}: warning: {w}", r.name)?;
                }
                writeln!(
            f,
                "{}: {} compared, {} outlier(s) left out; residual σ {:.4} m{}; covariance × {:.2} \
                 for correlated residuals (lag-one ρ {:.2})",
                r.name,
                fit.compared,
                fit.outliers,
                fit.residual_std_position_m,
                fit.residual_std_yaw_rad
                    .map_or(String::new(), |y| format!(", {:.3}°", y.to_degrees())),
                fit.variance_inflation,
                fit.lag_one_correlation
            )?;
            }
            if let Some(b) = &r.baseline {
                writeln!(
                    f,
                    "{}: baseline (two multipliers, as the ROS scripts): wheel_radius_multiplier \
                 {:.5}, wheel_separation_multiplier {:.5}",
                    r.name, b.wheel_radius_multiplier, b.wheel_separation_multiplier
                )?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::pose_reference::ReferenceKind;

    #[test]
    fn fit_settings_make_the_full_fit_and_refuse_what_is_out_of_range() {
        let nominal = Geometry {
            left_diameter_m: 0.1,
            right_diameter_m: 0.1,
            wheelbase_m: 0.4,
        };
        let s = FitSettings::default();
        let full = s.config(nominal, false).unwrap();
        assert_eq!(full, FitConfig::full(nominal));
        assert_eq!(
            s.config(nominal, true).unwrap().kind,
            Some(ReferenceKind::Absolute),
            "a data set's motion capture is absolute"
        );
        let relative = FitSettings {
            reference_kind: Some(ReferenceKind::Relative),
            no_mounting: true,
            ..FitSettings::default()
        };
        let c = relative.config(nominal, true).unwrap();
        assert_eq!(c.kind, Some(ReferenceKind::Relative), "what is given wins");
        assert!(!c.fit_mounting && c.fit_time_offset);
        for bad in [
            FitSettings {
                max_time_offset_s: 11.0,
                ..FitSettings::default()
            },
            FitSettings {
                window_s: Some(0.5),
                ..FitSettings::default()
            },
        ] {
            let e = bad.config(nominal, false).unwrap_err();
            assert!(matches!(e, CalibrationError::OutOfRange(_)), "{e}");
        }
    }
}
