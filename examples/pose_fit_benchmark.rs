//! Time to read an hour of driving against a pose reference from a bag and fit it.
//!
//! `cargo run --release --example pose_fit_benchmark [-- MINUTES]`: a simulated drive (wheels
//! at 50 Hz, poses at 10 Hz, the `sim::driving` defaults otherwise) written as a ROS 2 bag
//! (MCAP, zstd) under a localization (`/joint_states`, `/amcl_pose`, `/tf`, `/tf_static`), then
//! what `odocal fit --bag BAG --reference /amcl_pose` does, timed: reading the bag, and the
//! calibration (drive survey, the fit with the kind decided from the data, the two-multiplier
//! baseline). The same from `--reference tf:map`, and the fit alone given each kind.

use odocal::calibration::pose_calibration::calibrate_from_poses;
use odocal::calibration::pose_fit::{fit_poses, FitConfig};
use odocal::calibration::pose_reference::{Geometry, ReferenceKind};
use odocal::ros::bag::{reference::read_pose_drive, tf::read_tf_drive, BagOptions};
use odocal::sim::driving::{simulate_drive, DrivingConfig};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let minutes: f64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(60.0);
    let drive = simulate_drive(&DrivingConfig {
        duration_s: 60.0 * minutes,
        ..DrivingConfig::default()
    })?;
    let nominal = Geometry {
        left_diameter_m: 0.1,
        right_diameter_m: 0.1,
        wheelbase_m: 0.3,
    };
    let dir = std::env::temp_dir().join(format!("odocal-pose-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let bag = dir.join("drive.mcap");
    odocal::ros::bag::writer::write_localization_bag(&bag, &drive.recording, nominal, 1000.0)?;
    let size_mib = std::fs::metadata(&bag)?.len() as f64 / (1024.0 * 1024.0);
    println!(
        "{minutes} min of driving: {} wheel samples, {} poses; bag {size_mib:.1} MiB",
        drive.recording.wheels.len(),
        drive.recording.poses.len(),
    );
    let opts = BagOptions::default();
    for reference in ["/amcl_pose", "tf:map"] {
        let started = Instant::now();
        let recording = match reference.strip_prefix("tf:") {
            Some(fixed) => read_tf_drive(&bag, &opts, fixed, "base_link")?.recording,
            None => read_pose_drive(&bag, &opts, reference)?.recording,
        };
        let read = started.elapsed().as_secs_f64();
        let started = Instant::now();
        let calibration = calibrate_from_poses(
            &[(reference.to_string(), recording)],
            &FitConfig::full(nominal),
        )?;
        let fitted = started.elapsed().as_secs_f64();
        let Some(fit) = calibration.recordings[0].fit.as_ref() else {
            return Err(format!("{reference}: the drive was not fitted").into());
        };
        println!(
            "  --reference {reference}: read in {read:.2} s, calibrated in {fitted:.2} s, \
             {:.2} s in all ({} iterations, fitted as {})",
            read + fitted,
            fit.iterations,
            fit.kind.kind.name()
        );
    }
    std::fs::remove_dir_all(&dir)?;
    for kind in [ReferenceKind::Absolute, ReferenceKind::Relative] {
        let started = Instant::now();
        let fit = fit_poses(
            &drive.recording,
            &FitConfig {
                kind: Some(kind),
                ..FitConfig::full(nominal)
            },
        )?;
        println!(
            "  the fit alone, given as {}: {:.2} s ({} iterations)",
            kind.name(),
            started.elapsed().as_secs_f64(),
            fit.iterations
        );
    }
    Ok(())
}
