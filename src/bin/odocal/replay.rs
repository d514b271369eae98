//! `odocal replay`: calibrate on recorded square sets of one robot (pooled), evaluate on
//! recorded runs.

use crate::out::print_json;
use odocal::calibration::convention::ConventionChoice;
use odocal::offline::dataset::{replay, OptiOdomSet};
use std::path::{Path, PathBuf};

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
    convention: ConventionChoice,
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
    odocal::features::refuse_if_left_out("--write-bag", args.write_bag.is_some())?;
    let sets = OptiOdomSet::load_all(&args.dataset)?;
    let calib = &sets[0];
    if let Some(path) = &args.write_bag {
        if sets.len() > 1 {
            return Err("--write-bag converts one set; give one --dataset".into());
        }
        let n = write_bag(calib, path)?;
        println!(
            "wrote {} ({n} messages, {} runs)",
            path.display(),
            calib.runs.len()
        );
        return Ok(());
    }
    let evaluate = match args.evaluate.is_empty() {
        true => sets.clone(),
        false => OptiOdomSet::load_all(&args.evaluate)?,
    };
    let report = replay(&sets, &evaluate, args.convention.convention())?;
    if args.json {
        return print_json(&odocal::report::text::replay_json(&report, calib));
    }
    print!("{}", odocal::report::text::replay(&report, &sets));
    Ok(())
}

/// The set `calib` as a ROS 2 bag at `path` (motion capture: its heading is the reference);
/// how many messages it holds.
#[cfg(feature = "ros")]
fn write_bag(calib: &OptiOdomSet, path: &Path) -> Result<u64, Box<dyn std::error::Error>> {
    use odocal::ros::bag::writer::write_recording_bag;
    let topics = odocal::ros::bag::RosTopics::default();
    let kind = odocal::calibration::HeadingKind::Reference;
    let (rec, about) = (calib.to_recording(2.0), (calib.side_m, kind));
    Ok(write_recording_bag(
        path,
        (&rec, &calib.configured),
        about,
        &topics,
    )?)
}

/// (A bag, in a build without `ros`: refused by name before anything is read.)
#[cfg(not(feature = "ros"))]
fn write_bag(_: &OptiOdomSet, _: &Path) -> Result<u64, Box<dyn std::error::Error>> {
    Ok(odocal::features::refuse_if_left_out("--write-bag", true).map(|()| 0)?)
}
