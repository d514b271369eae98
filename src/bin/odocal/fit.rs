//! `odocal fit`: calibrate from any driving against a pose reference (motion capture, a
//! localization, scan matching, GNSS): parses the inputs, prints the calibration.

use crate::out::print_json;
use odocal::calibration::pose_calibration::{calibrate_from_poses, dead_reckon, evaluations_text};
use odocal::calibration::pose_fit::FitConfig;
use odocal::calibration::pose_reference::{Geometry, PoseRecording, ReferenceKind};
use odocal::offline::dataset::OptiOdomSet;
use odocal::offline::pose_csv::{read_poses, read_wheels};
use std::path::PathBuf;

/// Arguments of `odocal fit`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Wheels CSV: header `t_s,left_rad,right_rad`, cumulative rotation (rad, forward
    /// positive), any rate.
    #[arg(long, requires = "poses", conflicts_with = "dataset")]
    wheels: Option<PathBuf>,
    /// Reference CSV: header `t_s,x_m,y_m,yaw_rad` (yaw optional), the reference frame's pose
    /// in a fixed world frame, any rate.
    #[arg(long, requires = "wheels")]
    poses: Option<PathBuf>,
    /// An OptiOdom set (motion capture); repeat to pool sets of one robot. Each run is one
    /// recording; the nominal geometry comes from the set's metadata.
    #[arg(long, conflicts_with = "bag")]
    dataset: Vec<PathBuf>,
    /// A ROS bag (any format `odocal bag` reads) with the wheel joints and --reference.
    #[arg(long, requires = "reference", conflicts_with = "wheels")]
    bag: Option<PathBuf>,
    /// The bag's pose reference: a geometry_msgs/PoseStamped, PoseWithCovarianceStamped
    /// (/amcl_pose) or nav_msgs/Odometry topic (its covariance, when it states one, weights the
    /// samples), or `tf:FRAME` for the TF chain from FRAME (map, world) to --base-frame.
    #[arg(long, requires = "bag")]
    reference: Option<String>,
    /// The robot's frame at the end of a `tf:` chain.
    #[arg(long, default_value = "base_link")]
    base_frame: String,
    /// The bag's sensor_msgs/JointState topic.
    #[arg(long, default_value = "/joint_states")]
    joint_states_topic: String,
    /// Left wheel joint [default: the one joint name containing "left"].
    #[arg(long)]
    left_joint: Option<String>,
    /// Right wheel joint [default: the one joint name containing "right"].
    #[arg(long)]
    right_joint: Option<String>,
    /// The controller's ros2_control YAML: the nominal geometry (instead of
    /// --wheel-diameter-m and --wheelbase-m; both wheels and the wheelbase as the controller
    /// uses them, multipliers included).
    #[arg(long, conflicts_with_all = ["wheel_diameter_m", "wheelbase_m"])]
    ros_yaml: Option<PathBuf>,
    /// The diff_drive_controller's name in --ros-yaml.
    #[arg(long, default_value = "diff_drive_controller")]
    controller: String,
    /// Nominal wheel diameter (m) the fit starts from (with --wheels).
    #[arg(long)]
    wheel_diameter_m: Option<f64>,
    /// Nominal wheelbase (m) the fit starts from; E_b is relative to it (with --wheels).
    #[arg(long)]
    wheelbase_m: Option<f64>,
    /// How the reference errs: absolute (motion capture, a map's localization, GNSS) or
    /// relative (chained scan matching, visual odometry) [default: absolute for a --dataset,
    /// which is motion capture; otherwise decided from the data].
    #[arg(long)]
    reference_kind: Option<ReferenceKind>,
    /// Take the reference frame as base_link itself (do not fit its mounting).
    #[arg(long)]
    no_mounting: bool,
    /// Take the streams' stamps as simultaneous (do not fit a time offset).
    #[arg(long)]
    no_time_offset: bool,
    /// Largest time offset searched (s).
    #[arg(long, default_value_t = 0.5)]
    max_time_offset_s: f64,
    /// Absolute references: align windows of this length separately (s) instead of the whole
    /// trajectory (for long drives on slippery floors).
    #[arg(long)]
    window_s: Option<f64>,
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
    for (flag, v, lo, hi) in [
        ("--max-time-offset-s", args.max_time_offset_s, 0.0, 10.0),
        ("--window-s", args.window_s.unwrap_or(10.0), 1.0, 1e6),
    ] {
        odocal::ranges::check_range(flag, v, lo, hi)?;
    }
    // A data set's reference is motion capture: absolute by its kind.
    let kind = args
        .reference_kind
        .or((!args.dataset.is_empty()).then_some(ReferenceKind::Absolute));
    let config = FitConfig {
        kind,
        fit_mounting: !args.no_mounting,
        fit_time_offset: !args.no_time_offset,
        max_time_offset_s: args.max_time_offset_s,
        window_s: args.window_s,
        ..FitConfig::full(nominal)
    };
    let calibration = calibrate_from_poses(&recordings, &config)?;
    let mut evaluations = Vec::new();
    for dir in &args.evaluate {
        let set = OptiOdomSet::load(dir)?;
        for (name, rec) in set.pose_recordings() {
            if let Some(e) = dead_reckon(&name, &rec, &calibration) {
                evaluations.push(e);
            }
        }
    }
    let out = calibration.json(&evaluations)?;
    if let Some(dir) = &args.report {
        let written = write_report(dir, &out, &calibration, &recordings)?;
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

/// Writes `fit.json` and the plots into `dir`; returns the files' names.
fn write_report(
    dir: &std::path::Path,
    json: &serde_json::Value,
    calibration: &odocal::calibration::pose_calibration::PoseCalibration,
    recordings: &[(String, PoseRecording)],
) -> Result<Vec<String>, Box<dyn std::error::Error>> {
    let failed = |e: std::io::Error| format!("cannot write the report into {}: {e}", dir.display());
    std::fs::create_dir_all(dir).map_err(failed)?;
    std::fs::write(
        dir.join("fit.json"),
        serde_json::to_string_pretty(json)? + "\n",
    )
    .map_err(failed)?;
    let mut names = vec!["fit.json".to_string()];
    for f in odocal::report::pose_plots::write_pose_plots(calibration, recordings, dir)
        .map_err(failed)?
    {
        names.extend(f.file_name().map(|n| n.to_string_lossy().into_owned()));
    }
    Ok(names)
}

/// Named recordings and the nominal geometry they start from.
type Inputs = (Vec<(String, PoseRecording)>, Geometry);

/// The nominal geometry from the flags or the controller's YAML.
fn nominal(args: &Args, needed_by: &str) -> Result<Geometry, Box<dyn std::error::Error>> {
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
    odocal::ranges::check_range("--wheel-diameter-m", d, 1e-3, 5.0)?;
    odocal::ranges::check_range("--wheelbase-m", b, 1e-2, 10.0)?;
    Ok(Geometry {
        left_diameter_m: d,
        right_diameter_m: d,
        wheelbase_m: b,
    })
}

/// `--bag BAG --reference TOPIC` (or `tf:FRAME`): the drive read from the bag.
fn bag_inputs(
    args: &Args,
    bag: &std::path::Path,
    reference: &str,
) -> Result<Inputs, Box<dyn std::error::Error>> {
    let nominal = nominal(args, "--bag")?;
    let opts = odocal::ros::bag::BagOptions {
        topics: odocal::ros::bag::RosTopics {
            joint_states: args.joint_states_topic.clone(),
            ..Default::default()
        },
        left_joint: args.left_joint.clone(),
        right_joint: args.right_joint.clone(),
        ..Default::default()
    };
    let (recording, notes) = match reference.strip_prefix("tf:") {
        Some(fixed) => {
            let d = odocal::ros::bag::tf::read_tf_drive(bag, &opts, fixed, &args.base_frame)?;
            (d.recording, d.notes)
        }
        None => {
            let d = odocal::ros::bag::reference::read_pose_drive(bag, &opts, reference)?;
            (d.recording, d.notes)
        }
    };
    for note in &notes {
        eprintln!("note: {note}");
    }
    let name = format!("{} {reference}", bag.display());
    Ok((vec![(name, recording)], nominal))
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
    if let (Some(bag), Some(reference)) = (&args.bag, &args.reference) {
        return bag_inputs(args, bag, reference);
    }
    if args.dataset.is_empty() {
        return Err("nothing to fit: give --wheels W.csv --poses P.csv (with \
                    --wheel-diameter-m and --wheelbase-m), --bag BAG --reference TOPIC, or \
                    --dataset DIR"
            .into());
    }
    let mut recordings = Vec::new();
    let mut nominal = None;
    for dir in &args.dataset {
        let set = OptiOdomSet::load(dir)?;
        let g = Geometry::from(&set.configured);
        match nominal {
            None => nominal = Some(g),
            Some(n) if n != g => {
                return Err(format!(
                    "{} was recorded with another nominal geometry than the first set; pool \
                     sets recorded with one configuration",
                    set.id
                )
                .into())
            }
            Some(_) => {}
        }
        recordings.extend(set.pose_recordings());
    }
    let nominal = nominal.ok_or("no data set given")?;
    Ok((recordings, nominal))
}
