//! `odocal bag`, `export` and `mock-rosbridge`: calibrate from a ROS bag; write a calibration
//! into a controller's YAML; serve a simulated ROS robot.

use crate::out::print_json;
use odocal::ros::bag::session::BagSettings;
#[cfg(feature = "mock")]
use odocal::ros::yaml::DiffDriveConfig;
use std::path::PathBuf;

type CliResult = Result<(), Box<dyn std::error::Error>>;

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
    bag: BagSettings,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

/// Runs `odocal bag`.
pub fn run(args: BagArgs) -> Result<(), Box<dyn std::error::Error>> {
    let session = args.bag.analyse(&args.files)?;
    if args.json {
        return print_json(&session.json()?);
    }
    print!("{}", session.text(&args.bag.ros.topics()));
    Ok(())
}

/// Arguments of `odocal mock-rosbridge`.
#[cfg(feature = "mock")]
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
#[cfg(feature = "mock")]
pub async fn mock(args: MockArgs) -> Result<(), Box<dyn std::error::Error>> {
    use odocal::mock::rosbridge::MockRosbridge;
    let o = &args.robot;
    o.check()?;
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
        odocal::mock::stop::or_closing_stdin(args.ignore_stdin)
    );
    odocal::mock::stop::until_stopped(args.ignore_stdin).await;
    Ok(())
}

/// Runs `odocal export`.
pub async fn export(how: odocal::ros::export::ExportSettings) -> CliResult {
    let cal = how.calibration()?;
    let mut ui = crate::prompt::TerminalWriteUi;
    let exported =
        odocal::ros::export::export((&how.ros2, how.force), &how.controller, &cal, &mut ui);
    let exported = crate::prompt::writing(exported).await?;
    println!("{}", how.said(&cal, &exported));
    Ok(())
}
