//! A simulated drive under a pose reference, fitted, against the truth it was simulated from
//! (`odocal simulate --drive`): every parameter's truth, fit and ± (1σ), and how many
//! standard errors apart they are.

use crate::calibration::pose_calibration::{calibrate_from_poses, PoseCalibration};
use crate::calibration::pose_fit::{FitConfig, Param};
use crate::calibration::pose_reference::{Geometry, ReferenceKind};
use crate::calibration::CalibrationError;
use crate::sim::driving::{DrivingConfig, SimulatedDrive};
use serde_json::json;
use std::fmt::Write as _;

/// A simulated drive as a user sets it (with the `cli` feature, `odocal simulate --drive`'s
/// flags).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct DriveSettings {
    /// Simulate normal driving under a pose reference instead of squares.
    #[cfg_attr(feature = "cli", arg(long))]
    pub drive: bool,
    /// The simulated reference: absolute (motion capture, 3 mm / 0.3°, 1 % outliers of
    /// 15–45 cm) or relative (chained scan matching, 1 mm / 0.1° per increment, 2 % failures).
    #[cfg_attr(
        feature = "cli",
        arg(long, default_value = "absolute", requires = "drive")
    )]
    pub reference_kind: ReferenceKind,
    /// Length of the drive (s).
    #[cfg_attr(
        feature = "cli",
        arg(long, default_value_t = 300.0, requires = "drive")
    )]
    pub drive_s: f64,
    /// Also write the drive to this new directory as wheels.csv and poses.csv (for `odocal fit`).
    #[cfg_attr(feature = "cli", arg(long, requires = "drive"))]
    pub write_csv: Option<std::path::PathBuf>,
}

impl DriveSettings {
    /// The drive of a robot of `truth`, from `seed`; its length checked (10 s to an hour).
    pub fn config(&self, truth: Geometry, seed: u64) -> Result<DrivingConfig, CalibrationError> {
        crate::ranges::check_range("--drive-s", self.drive_s, 10.0, 3600.0)
            .map_err(CalibrationError::OutOfRange)?;
        Ok(DrivingConfig {
            truth,
            duration_s: self.drive_s,
            seed,
            ..DrivingConfig::with_reference(self.reference_kind)
        })
    }
}

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
