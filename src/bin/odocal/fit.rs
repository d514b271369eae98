//! `odocal fit`: calibrate from any driving against a pose reference (motion capture, a
//! localization, scan matching, GNSS): parses the inputs, prints the calibration.

use crate::out::print_json;
use odocal::calibration::pose_calibration::FitSettings;
use odocal::calibration::pose_calibration::{calibrate_from_poses, dead_reckon, evaluations_text};
use odocal::calibration::pose_reference::{Geometry, PoseRecording};
use odocal::offline::dataset::{pool_pose_recordings, OptiOdomSet};
use odocal::offline::pose_csv::{read_poses, read_wheels};
#[cfg(feature = "ros")]
use odocal::ros::bag::reference::BagDriveSettings;
use std::path::PathBuf;

/// Arguments of `odocal fit`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Wheels CSV: header `t_s,left_rad,right_rad`, cumulative rotation (rad, forward
    /// positive), any rate.
    #[arg(long, requires = "poses", conflicts_with_all = ["dataset", "bag"])]
    wheels: Option<PathBuf>,
    /// Reference CSV: header `t_s,x_m,y_m,yaw_rad` (yaw optional), the reference frame's pose
    /// in a fixed world frame, any rate.
    #[arg(long, requires = "wheels")]
    poses: Option<PathBuf>,
    /// An OptiOdom set (motion capture); repeat to pool sets of one robot. Each run is one
    /// recording; the nominal geometry comes from the set's metadata.
    #[arg(long, conflicts_with = "bag")]
    dataset: Vec<PathBuf>,
    #[cfg(feature = "ros")]
    #[command(flatten)]
    bag: BagDriveSettings,
    /// (A bag, in a build without `ros`: kept to say so.)
    #[cfg(not(feature = "ros"))]
    #[arg(long, hide = true)]
    bag: Option<PathBuf>,
    /// The controller's ros2_control YAML: the nominal geometry (instead of
    /// --wheel-diameter-m and --wheelbase-m; both wheels and the wheelbase as the controller
    /// uses them, multipliers included).
    #[arg(long, conflicts_with_all = ["wheel_diameter_m", "wheelbase_m"])]
    ros_yaml: Option<PathBuf>,
    /// The diff_drive_controller's name in --ros-yaml.
    #[cfg(feature = "ros")]
    #[arg(long, default_value = odocal::ros::yaml::DEFAULT_CONTROLLER)]
    controller: String,
    /// Nominal wheel diameter (m) the fit starts from (with --wheels).
    #[arg(long)]
    wheel_diameter_m: Option<f64>,
    /// Nominal wheelbase (m) the fit starts from; E_b is relative to it (with --wheels).
    #[arg(long)]
    wheelbase_m: Option<f64>,
    #[command(flatten)]
    fit: FitSettings,
    /// OptiOdom sets to dead-reckon with the result (and with the nominal geometry and the
    /// two-multiplier baseline), final-position errors compared; repeatable.
    #[arg(long)]
    evaluate: Vec<PathBuf>,
    /// Print one JSON object instead of tables.
    #[arg(long)]
    json: bool,
    /// Also write a report into this directory (created if missing): fit.json (what --json
    /// prints; `odocal export --from DIR/fit.json --ros2 YAML` writes it into the controller's
    /// YAML with a backup) and SVG plots of the paths, the dead-reckoning error over time and
    /// the fitted mounting.
    #[arg(long)]
    report: Option<PathBuf>,
}

/// Runs `odocal fit`.
pub fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    let (recordings, nominal) = inputs(&args)?;
    let config = args.fit.config(nominal, !args.dataset.is_empty())?;
    let calibration = calibrate_from_poses(&recordings, &config)?;
    let mut evaluations = Vec::new();
    for dir in &args.evaluate {
        let set = OptiOdomSet::load(dir)?;
        for (name, rec) in set.pose_recordings() {
            evaluations.extend(dead_reckon(&name, &rec, &calibration));
        }
    }
    let out = calibration.json(&evaluations)?;
    if let Some(dir) = &args.report {
        let written = odocal::report::write_fit_dir(dir, &out, &calibration, &recordings)
            .map_err(|e| format!("cannot write the report into {}: {e}", dir.display()))?;
        if !args.json {
            eprintln!(
                "report in {}: {}; write the geometry into a controller's YAML with: odocal \
                 export --from {} --ros2 YAML --force",
                dir.display(),
                written.join(", "),
                dir.join("fit.json").display()
            );
        }
    }
    if args.json {
        return print_json(&out);
    }
    print!("{calibration}{}", evaluations_text(&evaluations));
    Ok(())
}

/// Named recordings and the nominal geometry they start from.
type Inputs = (Vec<(String, PoseRecording)>, Geometry);

/// The nominal geometry from the flags or the controller's YAML.
fn nominal(args: &Args, needed_by: &str) -> Result<Geometry, Box<dyn std::error::Error>> {
    odocal::features::refuse_if_left_out("--ros-yaml", args.ros_yaml.is_some())?;
    #[cfg(feature = "ros")]
    if let Some(yaml) = &args.ros_yaml {
        let p = odocal::ros::yaml::DiffDriveConfig::load(yaml, &args.controller)?.effective();
        return Ok(Geometry::from(&p));
    }
    let (Some(d), Some(b)) = (args.wheel_diameter_m, args.wheelbase_m) else {
        return Err(format!(
            "{needed_by} need the nominal geometry: give --wheel-diameter-m and --wheelbase-m \
             (metres), or the controller's YAML with --ros-yaml"
        )
        .into());
    };
    odocal::ranges::check_geometry(d, b)?;
    Ok(Geometry {
        left_diameter_m: d,
        right_diameter_m: d,
        wheelbase_m: b,
    })
}

/// What `odocal fit` fits: files, a bag, or data sets of one configuration.
fn inputs(args: &Args) -> Result<Inputs, Box<dyn std::error::Error>> {
    if let (Some(w), Some(p)) = (&args.wheels, &args.poses) {
        let nominal = nominal(args, "--wheels and --poses")?;
        let rec = PoseRecording {
            wheels: read_wheels(w)?,
            poses: read_poses(p)?,
        };
        return Ok((vec![(p.display().to_string(), rec)], nominal));
    }
    #[cfg(not(feature = "ros"))]
    odocal::features::refuse_if_left_out("--bag", args.bag.is_some())?;
    #[cfg(feature = "ros")]
    if args.bag.bag.is_some() {
        let nominal = nominal(args, "--bag")?;
        if let Some((name, recording, notes)) = args.bag.read()? {
            notes.iter().for_each(|note| eprintln!("note: {note}"));
            return Ok((vec![(name, recording)], nominal));
        }
    }
    if args.dataset.is_empty() {
        return Err("nothing to fit: give --wheels W.csv --poses P.csv (with \
                    --wheel-diameter-m and --wheelbase-m), --bag BAG --reference TOPIC, or \
                    --dataset DIR"
            .into());
    }
    Ok(pool_pose_recordings(&args.dataset)?)
}
