//! `odocal replay`: calibrate on recorded square sets of one robot (pooled), evaluate on
//! recorded runs.

use crate::args::ConventionArgs;
use crate::out::print_json;
use odocal::offline::dataset::{replay, OptiOdomSet};
use odocal::report::stated::{
    default_line, disagreement_lines, pm, pm_b, pm_d, within_session_legend, Basis,
};
use serde_json::json;
use std::path::PathBuf;

/// Arguments of `odocal replay`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// OptiOdom square set to calibrate on (a directory with *_metadata.csv and *_run-NN.csv);
    /// repeat it to pool several recordings of one robot (they may have been recorded with
    /// different configured parameters: they are pooled in physical terms).
    #[arg(long, required = true)]
    dataset: Vec<PathBuf>,
    /// Sets (square or free) to evaluate on; repeatable [default: the calibration sets].
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
    let sets = args
        .dataset
        .iter()
        .map(OptiOdomSet::load)
        .collect::<Result<Vec<_>, _>>()?;
    let calib = &sets[0];
    if let Some(path) = &args.write_bag {
        if sets.len() > 1 {
            return Err("--write-bag converts one set; give one --dataset".into());
        }
        let topics = odocal::ros::bag::RosTopics::default();
        let n = odocal::ros::bag::writer::write_optiodom_bag(path, calib, 2.0, &topics)?;
        println!(
            "wrote {} ({n} messages, {} runs)",
            path.display(),
            calib.runs.len()
        );
        return Ok(());
    }
    let evaluate = if args.evaluate.is_empty() {
        sets.clone()
    } else {
        args.evaluate
            .iter()
            .map(OptiOdomSet::load)
            .collect::<Result<Vec<_>, _>>()?
    };
    let report = replay(&sets, &evaluate, args.convention.convention())?;
    if args.json {
        return print_json(&json!({
            "datasets": report.datasets,
            "configured": calib.configured,
            "estimates": report.estimates,
            "default_method": report.default_method,
            "uncertainty": report.uncertainty,
            "pooled": report.pooled,
            "failures": report.failures.iter().map(|(m, e)| json!({"method": m.name(), "error": e})).collect::<Vec<_>>(),
            "evaluations": report.evaluations,
        }));
    }
    let runs: usize = sets.iter().map(|s| s.runs.len()).sum();
    println!(
        "calibrated on {} ({runs} runs, side {} m); estimates against {}'s configuration: D_L {} D_R {} b {}",
        report.datasets.join(", "),
        calib.side_m.unwrap_or(f64::NAN),
        calib.id,
        calib.configured.left_wheel_diameter_m,
        calib.configured.right_wheel_diameter_m,
        calib.configured.wheelbase_m
    );
    let pooled = report.datasets.len() > 1;
    if pooled {
        println!(
            "± is one standard deviation of what the next session of this robot will read \
             (a prediction: the pooled value's standard error, the session-to-session spread \
             and one session's own scatter; --json has each quantity's std_err and \
             prediction_std)"
        );
    }
    println!(
        "{:<13} {:>9} {:>10} {:>9} {:>10} {:>16}",
        "method", "E_b", "±", "E_d", "±", "E_b spread"
    );
    for (e, p) in report.estimates.iter().zip(&report.pooled) {
        let spread = if pooled {
            format!(
                "{:.5}",
                p.ln_wheelbase_over_diameter.recording_spread * e.e_b
            )
        } else {
            "—".into()
        };
        let mark = if report.default_method == Some(e.method) {
            "  (default)"
        } else {
            ""
        };
        let (b, d) = if pooled {
            let (b, d) = p.prediction_std(e);
            (pm(b), pm(d))
        } else {
            (pm_b(e), pm_d(e))
        };
        println!(
            "{:<13} {:>9.5} {:>10} {:>9.5} {:>10} {:>16}{mark}",
            e.method.name(),
            e.e_b,
            b,
            e.e_d,
            d,
            spread
        );
    }
    if !pooled {
        for line in within_session_legend(&report.estimates) {
            println!("{line}");
        }
    }
    if let Some(m) = report.default_method {
        println!("{}", default_line(m));
    }
    for line in disagreement_lines(
        report.default_method,
        "the default",
        if pooled {
            Basis::Pooled
        } else {
            Basis::Session
        },
        &report.estimates,
    ) {
        println!("{line}");
    }
    for (m, e) in &report.failures {
        println!("{m}: not estimated: {e}");
    }
    println!(
        "\n{:<16} {:<13} {:>18} {:>16} {:>18} {:>16}",
        "evaluated on",
        "parameters",
        "|heading err| deg",
        "position err m",
        "systematic hdg deg",
        "systematic pos m"
    );
    for r in &report.evaluations {
        println!(
            "{:<16} {:<13} {:>18.3} {:>16.4} {:>18.3} {:>16.4}",
            r.dataset,
            r.method,
            r.heading_error_deg,
            r.position_error_m,
            r.systematic_heading_error_deg,
            r.systematic_position_error_m
        );
    }
    Ok(())
}
