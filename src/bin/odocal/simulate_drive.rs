//! `odocal simulate --drive`: normal driving under a pose reference, simulated and fitted; the
//! truth against the fit, and the drive as `odocal fit`'s CSV files or as a bag on request.

use crate::out::print_json;
use odocal::calibration::pose_reference::Geometry;
use odocal::kinematics::WheelParams;
use odocal::offline::drive_study::{compare, DriveSettings};
use odocal::offline::pose_csv::write_new_dir;
use odocal::sim::driving::simulate_drive;

/// Simulates the drive of a robot of `truth` configured with `nominal`, fits it, prints both.
pub fn run(
    args: &DriveSettings,
    nominal: &WheelParams,
    truth: &WheelParams,
    seed: u64,
    json_out: bool,
    bag: Option<&std::path::Path>,
) -> Result<(), Box<dyn std::error::Error>> {
    let config = args.config(Geometry::from(truth), seed)?;
    let drive = simulate_drive(&config)?;
    if let Some(dir) = &args.write_csv {
        write_new_dir(dir, &drive.recording)?;
    }
    #[cfg(feature = "ros")]
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
