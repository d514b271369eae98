//! The baseline the ROS calibration scripts compute (nobleo and ruvu `odometry_calibration`):
//! one `wheel_radius_multiplier` for both wheels and one `wheel_separation_multiplier`, by
//! unweighted least squares of the odometry against the reference's poses taken as
//! `base_link`'s — no left/right split, no mounting, no time offset, no robust loss.
//!
//! It runs the same model as [`super::pose_fit`] with the diameters tied, the mounting and the
//! offset held at zero, metres and radians summed as they are, and the motion between
//! consecutive reference samples compared. Its standard errors are what ordinary least
//! squares would state (one variance for every component), reported so that the difference to
//! the maximum-likelihood fit shows.

use super::pose_fit::{fit_poses, FitConfig, Param, PoseFit, Weighting};
use super::pose_reference::{Geometry, PoseRecording, ReferenceKind};
use super::CalibrationError;
use serde::Serialize;

/// The two multipliers, and the geometry they give.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MultiplierFit {
    /// Multiplies both wheels' radius (`diff_drive_controller`'s `wheel_radius_multiplier`).
    pub wheel_radius_multiplier: f64,
    /// Its standard error as least squares states it.
    pub wheel_radius_multiplier_std: f64,
    /// Multiplies the wheelbase (`wheel_separation_multiplier`).
    pub wheel_separation_multiplier: f64,
    /// Its standard error as least squares states it.
    pub wheel_separation_multiplier_std: f64,
    /// The geometry: both diameters the nominal mean times the radius multiplier (m).
    pub geometry: Geometry,
}

/// Fits the two multipliers to `recording` from `nominal` (whose two diameters are averaged,
/// as the controller's one `wheel_radius` is).
pub fn fit_multipliers(
    recording: &PoseRecording,
    nominal: Geometry,
) -> Result<MultiplierFit, CalibrationError> {
    let mean_d = 0.5 * (nominal.left_diameter_m + nominal.right_diameter_m);
    let start = Geometry {
        left_diameter_m: mean_d,
        right_diameter_m: mean_d,
        wheelbase_m: nominal.wheelbase_m,
    };
    let config = FitConfig {
        nominal: start,
        kind: Some(ReferenceKind::Relative),
        fit_mounting: false,
        fit_time_offset: false,
        max_time_offset_s: 0.0,
        window_s: None,
        robust: false,
        tie_diameters: true,
        weighting: Weighting::Unit,
    };
    let fit: PoseFit = fit_poses(recording, &config)?;
    let d = fit.value(Param::LeftDiameter);
    Ok(MultiplierFit {
        wheel_radius_multiplier: d / mean_d,
        wheel_radius_multiplier_std: fit.std(Param::LeftDiameter).unwrap_or(f64::NAN) / mean_d,
        wheel_separation_multiplier: fit.geometry.wheelbase_m / nominal.wheelbase_m,
        wheel_separation_multiplier_std: fit.std(Param::Wheelbase).unwrap_or(f64::NAN)
            / nominal.wheelbase_m,
        geometry: fit.geometry,
    })
}
