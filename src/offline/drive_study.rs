//! A simulated drive under a pose reference, fitted, against the truth it was simulated from
//! (`odocal simulate --drive`): every parameter's truth, fit and ± (1σ), and how many
//! standard errors apart they are.

use crate::calibration::pose_calibration::{calibrate_from_poses, PoseCalibration};
use crate::calibration::pose_fit::{FitConfig, Param};
use crate::calibration::pose_reference::Geometry;
use crate::calibration::CalibrationError;
use crate::sim::driving::{DrivingConfig, SimulatedDrive};
use serde_json::json;
use std::fmt::Write as _;

/// The fit of a simulated drive beside its truth.
#[derive(Debug, Clone)]
pub struct DriveComparison {
    /// The fit.
    pub calibration: PoseCalibration,
    /// Each fitted parameter: truth, fitted value, its standard error (SI units of the
    /// parameter: m, rad, s).
    pub rows: Vec<(Param, f64, f64, f64)>,
    /// Reference outliers the simulation put in.
    pub outliers: usize,
    /// Length of the drive (s).
    pub duration_s: f64,
}

/// Fits `drive` (simulated with `config`) starting from `nominal`, and sets each parameter
/// beside its truth.
pub fn compare(
    config: &DrivingConfig,
    drive: &SimulatedDrive,
    nominal: Geometry,
) -> Result<DriveComparison, CalibrationError> {
    let calibration = calibrate_from_poses(
        &[("simulated drive".into(), drive.recording.clone())],
        &FitConfig::full(nominal),
    )?;
    let truth_of = |p: Param| match p {
        Param::LeftDiameter => config.truth.left_diameter_m,
        Param::RightDiameter => config.truth.right_diameter_m,
        Param::Wheelbase => config.truth.wheelbase_m,
        Param::SensorX => config.sensor_x_m,
        Param::SensorY => config.sensor_y_m,
        Param::SensorYaw => config.sensor_yaw_rad,
        Param::TimeOffset => config.delay_s,
    };
    let rows = Param::ALL
        .iter()
        .filter_map(|p| {
            let q = calibration.get(*p)?;
            Some((*p, truth_of(*p), q.value, q.std))
        })
        .collect();
    Ok(DriveComparison {
        calibration,
        rows,
        outliers: drive.outliers,
        duration_s: config.duration_s,
    })
}

impl DriveComparison {
    /// As stdout's JSON: the truth by parameter, the fit's summary, the outliers simulated.
    pub fn json(&self) -> serde_json::Value {
        let truth: serde_json::Map<_, _> = self
            .rows
            .iter()
            .map(|(p, t, _, _)| (p.name().to_string(), json!(t)))
            .collect();
        json!({
            "truth": truth,
            "fit": self.calibration.summary(),
            "outliers_simulated": self.outliers,
        })
    }

    /// As the terminal shows it: the drive, then truth, fit, ± and error in σ per parameter.
    pub fn text(&self) -> String {
        let summary = self.calibration.summary();
        let mut out = String::new();
        let _ = writeln!(
            out,
            "{:.0} s of driving, {} reference poses ({} of them outliers), fitted as {}: {}",
            self.duration_s,
            self.calibration
                .recordings
                .first()
                .and_then(|r| r.fit.as_ref())
                .map_or(0, |f| f.compared),
            self.outliers,
            summary.reference_kind,
            summary.reference_kind_reason
        );
        let _ = writeln!(
            out,
            "{:<24} {:>12} {:>12} {:>11} {:>8}",
            "parameter", "truth", "fitted", "± (1σ)", "err/σ"
        );
        for (p, t, v, s) in &self.rows {
            let z = if *s > 0.0 && s.is_finite() {
                format!("{:.2}", (v - t) / s)
            } else {
                "—".into()
            };
            let _ = writeln!(
                out,
                "{:<24} {:>12.6} {:>12.6} {:>11.2e} {:>8}",
                p.name(),
                t,
                v,
                s,
                z
            );
        }
        out
    }
}
