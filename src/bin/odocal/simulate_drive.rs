//! `odocal simulate --drive`: normal driving under a pose reference, simulated and fitted; the
//! truth against the fit, and the drive as `odocal fit`'s CSV files or as a bag on request.

use crate::out::print_json;
use odocal::calibration::pose_calibration::calibrate_from_poses;
use odocal::calibration::pose_fit::{FitConfig, Param};
use odocal::calibration::pose_reference::{Geometry, ReferenceKind};
use odocal::kinematics::WheelParams;
use odocal::offline::pose_csv::{write_poses, write_wheels};
use odocal::sim::driving::{simulate_drive, DrivingConfig};
use serde_json::json;
use std::path::PathBuf;

/// The flags of `odocal simulate --drive`.
#[derive(Debug, clap::Args)]
pub struct DriveArgs {
    /// Simulate normal driving under a pose reference instead of squares.
    #[arg(long)]
    pub drive: bool,
    /// The simulated reference: absolute (motion capture, 3 mm / 0.3°, 1 % outliers of
    /// 15–45 cm) or relative (chained scan matching, 1 mm / 0.1° per increment, 2 % failures).
    #[arg(long, default_value = "absolute", requires = "drive")]
    reference_kind: ReferenceKind,
    /// Length of the drive (s).
    #[arg(long, default_value_t = 300.0, requires = "drive")]
    drive_s: f64,
    /// Also write the drive to this new directory as wheels.csv and poses.csv (for `odocal fit`).
    #[arg(long, requires = "drive")]
    write_csv: Option<PathBuf>,
}

/// Simulates the drive of a robot of `truth` configured with `nominal`, fits it, prints both.
pub fn run(
    args: &DriveArgs,
    nominal: &WheelParams,
    truth: &WheelParams,
    seed: u64,
    json_out: bool,
    bag: Option<&std::path::Path>,
) -> Result<(), Box<dyn std::error::Error>> {
    odocal::ranges::check_range("--drive-s", args.drive_s, 10.0, 3600.0)?;
    let config = DrivingConfig {
        truth: Geometry::from(truth),
        duration_s: args.drive_s,
        seed,
        ..DrivingConfig::with_reference(args.reference_kind)
    };
    let drive = simulate_drive(&config)?;
    if let Some(dir) = &args.write_csv {
        if dir.exists() {
            return Err(format!(
                "{} exists; --write-csv writes a new directory (give another path)",
                dir.display()
            )
            .into());
        }
        std::fs::create_dir_all(dir)?;
        write_wheels(&dir.join("wheels.csv"), &drive.recording.wheels)?;
        write_poses(&dir.join("poses.csv"), &drive.recording.poses)?;
    }
    if let Some(path) = bag {
        // A ROS clock does not start at zero: the bag's stamps from the session's start.
        odocal::ros::bag::writer::write_localization_bag(
            path,
            &drive.recording,
            Geometry::from(nominal),
            1.7e9,
        )?;
    }
    let calibration = calibrate_from_poses(
        &[("simulated drive".into(), drive.recording)],
        &FitConfig::full(Geometry::from(nominal)),
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
    let rows: Vec<(Param, f64, f64, f64)> = Param::ALL
        .iter()
        .filter_map(|p| {
            let q = calibration.get(*p)?;
            Some((*p, truth_of(*p), q.value, q.std))
        })
        .collect();
    if json_out {
        let summary = calibration.summary();
        return print_json(&json!({
            "truth": rows.iter().map(|(p, t, _, _)| (p.name().to_string(), json!(t))).collect::<serde_json::Map<_, _>>(),
            "fit": summary,
            "outliers_simulated": drive.outliers,
        }));
    }
    let summary = calibration.summary();
    println!(
        "{:.0} s of driving, {} reference poses ({} of them outliers), fitted as {}: {}",
        args.drive_s,
        calibration
            .recordings
            .first()
            .and_then(|r| r.fit.as_ref())
            .map_or(0, |f| f.compared),
        drive.outliers,
        summary.reference_kind,
        summary.reference_kind_reason
    );
    println!(
        "{:<24} {:>12} {:>12} {:>11} {:>8}",
        "parameter", "truth", "fitted", "± (1σ)", "err/σ"
    );
    for (p, t, v, s) in &rows {
        let z = if *s > 0.0 && s.is_finite() {
            format!("{:.2}", (v - t) / s)
        } else {
            "—".into()
        };
        println!(
            "{:<24} {:>12.6} {:>12.6} {:>11.2e} {:>8}",
            p.name(),
            t,
            v,
            s,
            z
        );
    }
    if let Some(path) = bag {
        println!(
            "wrote {0} (/joint_states, /amcl_pose, /tf, /tf_static); fit it with: odocal fit \
             --bag {0} --reference /amcl_pose --wheel-diameter-m {1} --wheelbase-m {2}",
            path.display(),
            nominal.left_wheel_diameter_m,
            nominal.wheelbase_m
        );
    }
    if let Some(dir) = &args.write_csv {
        println!(
            "wrote {0}/wheels.csv and {0}/poses.csv; fit them with: odocal fit --wheels \
             {0}/wheels.csv --poses {0}/poses.csv --wheel-diameter-m {1} --wheelbase-m {2}",
            dir.display(),
            nominal.left_wheel_diameter_m,
            nominal.wheelbase_m
        );
    }
    Ok(())
}
