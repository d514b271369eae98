//! `odocal replay`: calibrate on a recorded square set, evaluate on recorded runs.

use crate::{pm, print_json, ConventionArgs};
use odocal::dataset::{replay, OptiOdomSet};
use serde_json::json;
use std::path::PathBuf;

/// Arguments of `odocal replay`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// OptiOdom square set to calibrate on (a directory with *_metadata.csv and *_run-NN.csv).
    #[arg(long)]
    dataset: PathBuf,
    /// Sets (square or free) to evaluate on; repeatable. Default: the calibration set itself.
    #[arg(long)]
    evaluate: Vec<PathBuf>,
    #[command(flatten)]
    convention: ConventionArgs,
    /// Print one JSON object instead of tables.
    #[arg(long)]
    json: bool,
    /// Instead, convert the set to a ROS 2 bag (MCAP) at this new file: encoder counts as wheel
    /// joint angles, the motion-capture heading as /imu, the configured odometry as /odom.
    #[arg(long)]
    write_bag: Option<PathBuf>,
}

/// Runs `odocal replay`.
pub fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    let calib = OptiOdomSet::load(&args.dataset)?;
    if let Some(path) = &args.write_bag {
        let topics = odocal::ros::bag::RosTopics::default();
        let n = odocal::ros::bag_writer::write_optiodom_bag(path, &calib, 2.0, &topics)?;
        println!(
            "wrote {} ({n} messages, {} runs)",
            path.display(),
            calib.runs.len()
        );
        return Ok(());
    }
    let evaluate = if args.evaluate.is_empty() {
        vec![calib.clone()]
    } else {
        args.evaluate
            .iter()
            .map(OptiOdomSet::load)
            .collect::<Result<Vec<_>, _>>()?
    };
    let report = replay(&calib, &evaluate, args.convention.convention())?;
    if args.json {
        return print_json(&json!({
            "dataset": report.dataset,
            "configured": calib.configured,
            "estimates": report.estimates,
            "failures": report.failures.iter().map(|(m, e)| json!({"method": m.name(), "error": e})).collect::<Vec<_>>(),
            "evaluations": report.evaluations,
        }));
    }
    println!(
        "calibrated on {} ({} runs, side {} m), configured D_L {} D_R {} b {}",
        report.dataset,
        calib.runs.len(),
        calib.side_m.unwrap_or(f64::NAN),
        calib.configured.left_wheel_diameter_m,
        calib.configured.right_wheel_diameter_m,
        calib.configured.wheelbase_m
    );
    println!(
        "{:<13} {:>9} {:>10} {:>9} {:>10}",
        "method", "E_b", "", "E_d", ""
    );
    for e in &report.estimates {
        println!(
            "{:<13} {:>9.5} {:>10} {:>9.5} {:>10}",
            e.method.name(),
            e.e_b,
            pm(e.e_b_std_err),
            e.e_d,
            pm(e.e_d_std_err)
        );
    }
    for (m, e) in &report.failures {
        println!("{m}: not estimated: {e}");
    }
    println!(
        "\n{:<16} {:<13} {:>18} {:>18}",
        "evaluated on", "parameters", "|heading err| deg", "position err m"
    );
    for r in &report.evaluations {
        println!(
            "{:<16} {:<13} {:>18.3} {:>18.4}",
            r.dataset, r.method, r.heading_error_deg, r.position_error_m
        );
    }
    Ok(())
}
