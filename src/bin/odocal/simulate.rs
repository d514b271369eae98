//! `odocal simulate`: the paper's simulation study on a configurable robot.

use crate::out::print_json;
use odocal::offline::study::{run_trials, StudySettings};
use odocal::report::text::Study;

/// Arguments of `odocal simulate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    study: StudySettings,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// Instead of the study, write the simulated square test as a ROS 2 bag (MCAP) to this new
    /// file: /joint_states, /imu and /odom as a ROS robot would publish them, for `odocal bag`.
    /// With --drive: the drive under a localization (/joint_states, /amcl_pose, /tf,
    /// /tf_static), for `odocal fit --bag`.
    #[arg(long = "write-bag", alias = "bag")]
    bag: Option<std::path::PathBuf>,
    /// How the --write-bag's IMU errs (a deviation, a gyro's scale, a late or lossy stream).
    #[command(flatten)]
    sensor: odocal::sim::options::SensorErrors,
    /// `--drive`: normal driving under a pose reference instead of squares.
    #[command(flatten)]
    pub drive: odocal::offline::drive_study::DriveSettings,
}

/// Writes the simulated square test as a ROS 2 bag.
#[cfg(feature = "ros")]
fn write_bag(args: &Args, path: &std::path::Path) -> Result<(), Box<dyn std::error::Error>> {
    use odocal::ros::bag::writer::{write_simulated_bag, SimulatedBag};
    use odocal::ros::bag::RosTopics;
    use odocal::sim::NoiseModel;
    use serde_json::json;
    let st = &args.study;
    let (configured, truth) = st.robot(odocal::ros::yaml::RAD_PER_REV)?;
    let noise = NoiseModel {
        quantise_encoders: false,
        position_sigma_m: 0.0,
        ..st.noise()
    };
    let mut sim = odocal::sim::Simulator::new(truth, configured, noise, st.seed)?
        .with_heading_model(args.sensor.model()?)?;
    let cfg = SimulatedBag {
        side_m: st.side_m,
        runs: st.runs.max(1),
        ..SimulatedBag::default()
    };
    let n = write_simulated_bag(path, &mut sim, &cfg, &RosTopics::default())?;
    if args.json {
        return print_json(&json!({
            "bag": path,
            "messages": n,
            "truth": truth,
            "configured": configured,
            "side_m": cfg.side_m,
            "runs_per_direction": cfg.runs,
        }));
    }
    println!(
        "wrote {} ({n} messages: {} squares of {} m each way; /joint_states, /imu, /odom)",
        path.display(),
        cfg.runs,
        cfg.side_m
    );
    println!("calibrate from it: odocal bag {}", path.display());
    Ok(())
}

/// Runs `odocal simulate`.
pub fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    args.study.check()?;
    odocal::features::refuse_if_left_out("--write-bag", args.bag.is_some())?;
    // Checked even when unused: a value the command would ignore is still a mistake to name.
    let model = args.sensor.model()?;
    if args.bag.is_none() && model != odocal::sim::sensor::HeadingModel::default() {
        return Err(
            "the heading sensor's flags (--heading-sensor, --deviation-deg, \
                    --motor-offset-deg, --gyro-…, --heading-quantum-deg, --heading-latency-s, \
                    --heading-loss) describe the IMU of a --write-bag; the study's compass errs \
                    by --heading-sigma-deg and --compass-bias-deg: give --write-bag, or drop them"
                .into(),
        );
    }
    if args.drive.drive {
        let (nominal, truth) = args.study.robot(1.0)?;
        let (seed, bag) = (args.study.seed, args.bag.as_deref());
        return crate::simulate_drive::run(&args.drive, &nominal, &truth, seed, args.json, bag);
    }
    #[cfg(feature = "ros")]
    if let Some(path) = &args.bag {
        return write_bag(&args, path);
    }
    let cfg = args.study.config();
    let (studies, summaries) = run_trials(&cfg, args.study.seed, args.study.trials)?;
    let study = Study {
        config: &cfg,
        trials: args.study.trials,
        studies: &studies,
        summaries: &summaries,
    };
    if args.json {
        return print_json(&study.json());
    }
    print!("{}", study.text());
    Ok(())
}
