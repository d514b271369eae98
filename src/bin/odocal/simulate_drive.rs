//! `odocal simulate --drive`: normal driving under a pose reference, simulated and fitted; the
//! truth against the fit, and the drive as `odocal fit`'s CSV files or as a bag on request.

use crate::out::print_json;
use odocal::calibration::pose_reference::{Geometry, ReferenceKind};
use odocal::kinematics::WheelParams;
use odocal::offline::drive_study::compare;
use odocal::offline::pose_csv::{write_poses, write_wheels};
use odocal::sim::driving::{simulate_drive, DrivingConfig};
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

/// `--write-csv`: the drive as `odocal fit`'s two files in a new directory.
fn write_csv(
    dir: &std::path::Path,
    recording: &odocal::calibration::pose_reference::PoseRecording,
) -> Result<(), Box<dyn std::error::Error>> {
    if dir.exists() {
        return Err(format!(
            "{} exists; --write-csv writes a new directory (give another path)",
            dir.display()
        )
        .into());
    }
    std::fs::create_dir_all(dir)?;
    write_wheels(&dir.join("wheels.csv"), &recording.wheels)?;
    write_poses(&dir.join("poses.csv"), &recording.poses)?;
    Ok(())
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
        write_csv(dir, &drive.recording)?;
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
    let comparison = compare(&config, &drive, Geometry::from(nominal))?;
    if json_out {
        return print_json(&comparison.json());
    }
    print!("{}", comparison.text());
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
