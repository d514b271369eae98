//! `odocal bag` (and the ROS flags other commands share): calibrate from a ROS bag.

use crate::out::print_json;
use odocal::kinematics::SplitConvention;
use odocal::ros::bag::{self, BagOptions, RosTopics};
use odocal::ros::yaml::DiffDriveConfig;
use std::path::PathBuf;

/// Where a ROS robot's geometry and data are.
#[derive(Debug, Clone, clap::Args)]
pub struct RosArgs {
    /// The controller's ros2_control YAML (its `ros__parameters:` at any nesting: `/**:`,
    /// namespaced keys, several documents).
    #[arg(long)]
    pub ros_yaml: Option<PathBuf>,
    /// The diff_drive_controller's name (`ns/name` to pick one namespace's).
    #[arg(long, default_value = "diff_drive_controller")]
    pub controller: String,
    /// Wheel joint states topic (sensor_msgs/JointState).
    #[arg(long, default_value = "/joint_states")]
    pub joint_states_topic: String,
    /// IMU topic (sensor_msgs/Imu with an orientation).
    #[arg(long, default_value = "/imu")]
    pub imu_topic: String,
    /// The controller's odometry topic (nav_msgs/Odometry).
    #[arg(long, default_value = "/odom")]
    pub odom_topic: String,
    /// Left wheel joint name [default: the YAML's first left_wheel_names, else the one name
    /// with "left"].
    #[arg(long)]
    pub left_joint: Option<String>,
    /// Right wheel joint name [default: the YAML's first right_wheel_names, else the one name
    /// with "right"].
    #[arg(long)]
    pub right_joint: Option<String>,
}

impl RosArgs {
    /// The topics.
    pub fn topics(&self) -> RosTopics {
        RosTopics {
            joint_states: self.joint_states_topic.clone(),
            imu: self.imu_topic.clone(),
            odom: self.odom_topic.clone(),
        }
    }

    /// The YAML section, if a file was given.
    pub fn config(&self) -> Result<Option<DiffDriveConfig>, Box<dyn std::error::Error>> {
        Ok(match &self.ros_yaml {
            Some(p) => Some(DiffDriveConfig::load(p, &self.controller)?),
            None => None,
        })
    }
}

/// Arguments of `odocal bag`.
#[derive(Debug, clap::Args)]
pub struct BagArgs {
    /// The bag: a rosbag2 directory (what `ros2 bag record` makes, split files read in order),
    /// or one file: MCAP, sqlite3 (.db3), ROS 1 (.bag v2.0), any of them zstd-compressed. Several
    /// bags of one robot are analysed one by one and their square estimates pooled in physical
    /// terms (they may have been recorded with different multipliers in force).
    #[arg(required = true)]
    files: Vec<PathBuf>,
    #[command(flatten)]
    ros: RosArgs,
    /// Explicit runs instead of finding them: START:END seconds from the bag's first message;
    /// repeatable.
    #[arg(long = "range")]
    ranges: Vec<String>,
    /// Square side (m) [default: the bag's metadata, else the mean leg length by odometry].
    #[arg(long)]
    side_m: Option<f64>,
    /// Shortest rest (s) that separates one run from the next.
    #[arg(long, default_value_t = 0.5)]
    min_rest_s: f64,
    /// Diameter split: left-nominal, mean-preserving or measured-scale:COMMANDED_M,MEASURED_M.
    #[arg(long, default_value = "left-nominal")]
    convention: SplitConvention,
    /// What the IMU's yaw is: magnetic (a compass or a 9-axis fusion: it may deviate), gyro
    /// (integrated), reference (ground truth) or unknown. It decides the default method
    /// [default: what the bag's `odocal` metadata says (bags odocal wrote), else unknown].
    #[arg(long)]
    heading_kind: Option<odocal::calibration::HeadingKind>,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

fn parse_range(s: &str) -> Result<(f64, f64), String> {
    let (a, b) = s
        .split_once(':')
        .ok_or_else(|| format!("--range {s}: expected START:END in seconds"))?;
    let num = |v: &str| {
        v.trim()
            .parse::<f64>()
            .map_err(|_| format!("--range {s}: {v:?} is not a number of seconds"))
    };
    Ok((num(a)?, num(b)?))
}

/// Runs `odocal bag`.
pub fn run(args: BagArgs) -> Result<(), Box<dyn std::error::Error>> {
    let cfg = args.ros.config()?;
    let opts = BagOptions {
        topics: args.ros.topics(),
        left_joint: args.ros.left_joint.clone().or_else(|| {
            cfg.as_ref()
                .and_then(|c| c.left_wheel_names.first().cloned())
        }),
        right_joint: args.ros.right_joint.clone().or_else(|| {
            cfg.as_ref()
                .and_then(|c| c.right_wheel_names.first().cloned())
        }),
        min_rest_s: args.min_rest_s,
        ranges: args
            .ranges
            .iter()
            .map(|r| parse_range(r))
            .collect::<Result<_, _>>()?,
        side_m: args.side_m,
        convention: args.convention,
    };
    if let Some(s) = opts.side_m {
        if !(s.is_finite() && s > 0.0 && s <= 100.0) {
            return Err(format!("--side-m must be in (0, 100] m, got {s}").into());
        }
    }
    let yaml = match (&cfg, &args.ros.ros_yaml) {
        (Some(c), Some(path)) => Some((path.as_path(), c)),
        _ => None,
    };
    let session = bag::session::analyse_files(&args.files, &opts, yaml, args.heading_kind)?;
    if args.json {
        return print_json(&session.json()?);
    }
    print!("{}", session.text(&args.ros.topics()));
    Ok(())
}

/// Arguments of `odocal mock-rosbridge`.
#[derive(Debug, clap::Args)]
pub struct MockArgs {
    /// The controller's YAML: the robot's configured geometry (the mock never writes it).
    #[arg(long)]
    ros_yaml: PathBuf,
    /// The controller's name.
    #[arg(long, default_value = "diff_drive_controller")]
    controller: String,
    /// Loopback TCP port (0: any free one). The URL is printed on the first line.
    #[arg(long = "tcp-port", alias = "port", default_value_t = 9090)]
    port: u16,
    #[command(flatten)]
    robot: odocal::mock::options::RosOptions,
    /// Keep serving when stdin closes (stop with Ctrl-C only).
    #[arg(long)]
    ignore_stdin: bool,
    #[command(flatten)]
    compass: crate::args::MockCompassArgs,
}

/// Runs `odocal mock-rosbridge`.
pub async fn mock(args: MockArgs) -> Result<(), Box<dyn std::error::Error>> {
    use odocal::mock::rosbridge::MockRosbridge;
    let o = &args.robot;
    o.truth.check()?;
    let controller = DiffDriveConfig::load(&args.ros_yaml, &args.controller)?;
    let cfg = o.config(controller)?;
    let server =
        MockRosbridge::spawn(cfg, std::net::SocketAddr::from(([127, 0, 0, 1], args.port))).await?;
    println!("{}", server.url());
    let _compass = args
        .compass
        .spawn(server.separate_compass(), o.time_scale)?;
    eprintln!(
        "mock rosbridge: a ROS 2 robot with diff_drive_controller (true E_b {}, E_d {}) on {}; \
         /joint_states, /odom, /imu{}; obeys {} ({}). Ctrl-C{} stops it.",
        o.truth.true_eb,
        o.truth.true_ed,
        server.url(),
        o.localization
            .as_deref()
            .map(|t| format!(", {t}"))
            .unwrap_or_default(),
        o.cmd_vel,
        if o.cmd_vel_stamped {
            "TwistStamped"
        } else {
            "Twist"
        },
        crate::args::or_stdin(args.ignore_stdin)
    );
    crate::args::serve_until_stopped(args.ignore_stdin).await;
    Ok(())
}
