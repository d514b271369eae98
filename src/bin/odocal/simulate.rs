//! `odocal simulate`: the paper's simulation study on a configurable robot.

use crate::args::ConventionArgs;
use crate::args::SIM_HEADING_SIGMA_DEG;
use crate::out::print_json;
use odocal::kinematics::{SplitConvention, WheelParams};
use odocal::offline::study::{run_trials, StudyConfig};
use odocal::report::text::Study;
use odocal::sim::NoiseModel;
use serde_json::json;

/// Arguments of `odocal simulate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// True E_b of the simulated robot.
    #[arg(long, default_value_t = 0.976)]
    true_eb: f64,
    /// True E_d of the simulated robot.
    #[arg(long, default_value_t = 0.992)]
    true_ed: f64,
    /// Square side (m).
    #[arg(long, default_value_t = 4.0)]
    side_m: f64,
    /// Square side of Lee's own track (m).
    #[arg(long, default_value_t = 2.0)]
    lee_side_m: f64,
    /// Nominal (configured) wheelbase (m).
    #[arg(long, default_value_t = 0.39)]
    wheelbase_m: f64,
    /// Nominal (configured) wheel diameter (m).
    #[arg(long, default_value_t = 0.15)]
    wheel_diameter_m: f64,
    /// Encoder counts per wheel revolution.
    #[arg(long, default_value_t = 10_000.0)]
    counts_per_rev: f64,
    /// How the true E_d splits into two true diameters.
    #[arg(long, default_value = "left-nominal")]
    truth_split: SplitConvention,
    #[command(flatten)]
    convention: ConventionArgs,
    /// Runs per direction (calibration and verification).
    #[arg(long, default_value_t = 1)]
    runs: usize,
    /// The simulated compass's noise per reading (deg; σ; 0 reproduces the paper's noise-free
    /// tables).
    #[arg(long = "heading-sigma-deg", alias = "compass-sigma-deg", default_value_t = SIM_HEADING_SIGMA_DEG)]
    compass_sigma_deg: f64,
    /// Constant compass bias (deg).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    compass_bias_deg: f64,
    /// Relative wheel slip per motion (standard deviation, e.g. 0.001).
    #[arg(long, default_value_t = 0.0)]
    slip_sigma: f64,
    /// Noise of each measured final-position axis (m), seen by UMBmark and Lee.
    #[arg(long, default_value_t = 0.0)]
    position_sigma_m: f64,
    /// Round wheel targets to whole encoder counts.
    #[arg(long)]
    quantise: bool,
    /// Seed of the first trial (trial k uses seed + k).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Independent trials to average.
    #[arg(long, default_value_t = 1)]
    trials: usize,
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
    sensor: odocal::mock::options::SensorErrors,
    /// Instead of squares, normal driving under a pose reference (5 minutes; the reference at
    /// 10 Hz, mounted off the axle, 60 ms late, noisy, 1 % outliers), fitted as `odocal fit`
    /// does: the truth against the fit.
    #[command(flatten)]
    pub drive: crate::simulate_drive::DriveArgs,
}

/// Writes the simulated square test as a ROS 2 bag.
fn write_bag(args: &Args, path: &std::path::Path) -> Result<(), Box<dyn std::error::Error>> {
    use odocal::ros::bag::writer::{write_simulated_bag, SimulatedBag};
    use odocal::ros::bag::RosTopics;
    use odocal::ros::yaml::RAD_PER_REV;
    let configured = WheelParams::nominal(args.wheel_diameter_m, args.wheelbase_m, RAD_PER_REV);
    let truth =
        WheelParams::from_ratios(&configured, args.true_eb, args.true_ed, &args.truth_split)?;
    let noise = NoiseModel {
        compass_sigma_rad: args.compass_sigma_deg.to_radians(),
        compass_bias_rad: args.compass_bias_deg.to_radians(),
        wheel_slip_sigma: args.slip_sigma,
        ..NoiseModel::default()
    };
    let mut sim = odocal::sim::Simulator::new(truth, configured, noise, args.seed)?
        .with_heading_model(args.sensor.model()?)?;
    let cfg = SimulatedBag {
        side_m: args.side_m,
        runs: args.runs.max(1),
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

/// Every flag in its range, before anything is simulated.
fn check(args: &Args) -> Result<(), Box<dyn std::error::Error>> {
    use odocal::ranges::check_range as in_range;
    // Bounds before anything is simulated: memory and time grow with runs × trials.
    in_range("--runs", args.runs as f64, 1.0, 1000.0)?;
    in_range("--trials", args.trials as f64, 1.0, 100_000.0)?;
    in_range("--side-m", args.side_m, 0.01, 100.0)?;
    in_range("--lee-side-m", args.lee_side_m, 0.01, 100.0)?;
    in_range("--wheelbase-m", args.wheelbase_m, 0.01, 10.0)?;
    in_range("--wheel-diameter-m", args.wheel_diameter_m, 0.001, 5.0)?;
    in_range("--counts-per-rev", args.counts_per_rev, 1.0, 1e9)?;
    in_range("--true-eb", args.true_eb, 0.2, 5.0)?;
    in_range("--true-ed", args.true_ed, 0.5, 2.0)?;
    in_range("--heading-sigma-deg", args.compass_sigma_deg, 0.0, 45.0)?;
    in_range("--compass-bias-deg", args.compass_bias_deg, -180.0, 180.0)?;
    in_range("--slip-sigma", args.slip_sigma, 0.0, 0.5)?;
    in_range("--position-sigma-m", args.position_sigma_m, 0.0, 10.0)?;
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
    Ok(())
}

/// The study the flags describe.
fn study_config(args: &Args) -> StudyConfig {
    StudyConfig {
        nominal: WheelParams::nominal(args.wheel_diameter_m, args.wheelbase_m, args.counts_per_rev),
        true_e_b: args.true_eb,
        true_e_d: args.true_ed,
        truth_split: args.truth_split,
        side_m: args.side_m,
        lee_side_m: args.lee_side_m,
        runs: args.runs,
        convention: args.convention.convention(),
        noise: NoiseModel {
            compass_sigma_rad: args.compass_sigma_deg.to_radians(),
            compass_bias_rad: args.compass_bias_deg.to_radians(),
            quantise_encoders: args.quantise,
            wheel_slip_sigma: args.slip_sigma,
            position_sigma_m: args.position_sigma_m,
        },
    }
}

/// Runs `odocal simulate`.
pub fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    check(&args)?;
    if args.drive.drive {
        let nominal = WheelParams::nominal(args.wheel_diameter_m, args.wheelbase_m, 1.0);
        let truth =
            WheelParams::from_ratios(&nominal, args.true_eb, args.true_ed, &args.truth_split)?;
        return crate::simulate_drive::run(
            &args.drive,
            &nominal,
            &truth,
            args.seed,
            args.json,
            args.bag.as_deref(),
        );
    }
    if let Some(path) = &args.bag {
        return write_bag(&args, path);
    }
    let cfg = study_config(&args);
    let (studies, summaries) = run_trials(&cfg, args.seed, args.trials)?;
    let study = Study {
        config: &cfg,
        trials: args.trials,
        studies: &studies,
        summaries: &summaries,
    };
    if args.json {
        return print_json(&study.json());
    }
    print!("{}", study.text());
    Ok(())
}
