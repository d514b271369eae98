//! The `odocal` command line: parses arguments, calls the library, prints tables or JSON.

mod device;
mod estimate;
mod ports;
mod replay;
mod ros;
mod routine;
mod serial_bases;
mod simulate;
mod track;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};
use odocal::kinematics::SplitConvention;
use std::process::ExitCode;

/// Odometry calibration for two-wheel differential-drive robots.
#[derive(Debug, Parser)]
#[command(name = "odocal", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

// Parsed once per run: the size of its largest variant costs nothing worth boxing for.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Subcommand)]
enum Command {
    /// Full recalibration of the built-in simulated robot: calibrate, write back, verify, report.
    Demo(routine::DemoArgs),
    /// Recalibrate a real robot: --port (odocal protocol) or --base rosbridge://… (moves it;
    /// asks first unless --yes).
    Calibrate(routine::CalibrateArgs),
    /// Run a routine file (TOML); `port = "mock"` runs it on the simulated robot.
    Run(routine::RunArgs),
    /// Export a calibration report for other software (ros2_control).
    Export(routine::ExportArgs),
    /// Online estimator: calibrate continuously from live telemetry, a log or a recorded set.
    Track(track::TrackArgs),
    /// Record telemetry (encoders, heading) to a JSON-lines log for `track --log`.
    Record(track::RecordArgs),
    /// Estimate E_b, E_d from square-test measurements taken by hand.
    Estimate(estimate::Args),
    /// Simulate the square test on a mis-calibrated robot, calibrate, write back and verify.
    Simulate(simulate::Args),
    /// Calibrate from a recorded OptiOdom square set and evaluate on recorded runs.
    Replay(replay::Args),
    /// Serve a simulated robot base on a new pseudo-terminal (prints its path first).
    MockDevice(device::MockArgs),
    /// Read, write, save or restore the controller's kinematic parameters.
    Params {
        #[command(subcommand)]
        command: device::ParamsCommand,
    },
    /// Show the device's status.
    Status(device::PortArgs),
    /// Read the heading (counter-clockwise positive).
    Heading(device::HeadingArgs),
    /// List this machine's serial ports with their USB ids.
    Ports(ports::Args),
    /// Calibrate offline from a ROS 2 bag (MCAP): finds the square runs, every method.
    Bag(ros::BagArgs),
    /// Serve a simulated ROS 2 robot behind a mock rosbridge server on loopback.
    MockRosbridge(ros::MockArgs),
    /// Serve a mock RoboClaw and a mock NMEA compass of one simulated robot on two PTYs.
    MockRoboclaw(serial_bases::MockArgs),
}

/// Convention flags shared by the subcommands that estimate.
#[derive(Debug, Clone, clap::Args)]
pub struct ConventionArgs {
    /// Diameter split for estimation and write-back: left-nominal, mean-preserving or
    /// measured-scale:COMMANDED_M,MEASURED_M.
    #[arg(long, default_value = "left-nominal")]
    convention: SplitConvention,
    /// Straight-line scale check: distance commanded (m). With --straight-measured-m, fixes
    /// the absolute wheel scale (overrides --convention).
    #[arg(long, requires = "straight_measured_m")]
    straight_commanded_m: Option<f64>,
    /// Straight-line scale check: distance measured start to end with a tape (m).
    #[arg(long, requires = "straight_commanded_m")]
    straight_measured_m: Option<f64>,
}

impl ConventionArgs {
    /// The library convention these flags select.
    pub fn convention(&self) -> SplitConvention {
        match (self.straight_commanded_m, self.straight_measured_m) {
            (Some(commanded_m), Some(measured_m)) => SplitConvention::MeasuredScale {
                commanded_m,
                measured_m,
            },
            _ => self.convention,
        }
    }
}

/// Prints `value` as pretty JSON on stdout.
pub fn print_json(value: &serde_json::Value) -> Result<(), Box<dyn std::error::Error>> {
    println!("{}", serde_json::to_string_pretty(value)?);
    Ok(())
}

/// Checks a numeric flag against its documented physical range (inclusive), naming the flag.
pub fn in_range(flag: &str, value: f64, lo: f64, hi: f64) -> Result<(), String> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(format!("{flag} must be in [{lo}, {hi}], got {value}"))
    }
}

/// Formats an optional standard error as `± x` or blank.
pub fn pm(std_err: Option<f64>) -> String {
    std_err.map_or_else(String::new, |s| format!("± {s:.5}"))
}

/// Waits until Ctrl-C, or until stdin closes unless `ignore_stdin` (how a test or a script
/// that started a mock server stops it).
pub async fn serve_until_stopped(ignore_stdin: bool) {
    let stdin_closed = async {
        if ignore_stdin {
            std::future::pending::<()>().await;
        }
        let mut sink = Vec::new();
        let _ = tokio::io::AsyncReadExt::read_to_end(&mut tokio::io::stdin(), &mut sink).await;
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        () = stdin_closed => {}
    }
}

/// Runs an async command on a fresh runtime.
fn block_on(
    fut: impl std::future::Future<Output = Result<(), Box<dyn std::error::Error>>>,
) -> Result<(), Box<dyn std::error::Error>> {
    tokio::runtime::Runtime::new()?.block_on(fut)
}

/// The command line with negative numbers accepted as values everywhere (`--side-m -4` is a
/// value to validate, not an unknown flag).
fn command() -> clap::Command {
    fn negatives(c: clap::Command) -> clap::Command {
        c.allow_negative_numbers(true).mut_subcommands(negatives)
    }
    negatives(Cli::command())
}

fn main() -> ExitCode {
    // Like every Unix filter: a closed pipe (`odocal … | head`) ends the program quietly
    // instead of failing a print (Rust ignores SIGPIPE by default, so println! would panic).
    #[cfg(unix)]
    // SAFETY: restoring the default disposition of one signal before any thread is started.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = match Cli::from_arg_matches(&command().get_matches()) {
        Ok(cli) => cli,
        Err(e) => e.exit(),
    };
    let result = match cli.command {
        Command::Demo(args) => block_on(routine::demo(args)),
        Command::Calibrate(args) => block_on(routine::calibrate(args)),
        Command::Run(args) => block_on(routine::run_file(args)),
        Command::Export(args) => routine::export(args),
        Command::Track(args) => block_on(track::track(args)),
        Command::Record(args) => block_on(track::record(args)),
        Command::Estimate(args) => estimate::run(args),
        Command::Simulate(args) => simulate::run(args),
        Command::Replay(args) => replay::run(args),
        Command::MockDevice(args) => block_on(device::mock_device(args)),
        Command::Params { command } => block_on(device::params(command)),
        Command::Status(port) => block_on(device::status(port)),
        Command::Heading(args) => block_on(device::heading(args)),
        Command::Ports(args) => ports::run(args),
        Command::Bag(args) => ros::run(args),
        Command::MockRosbridge(args) => block_on(ros::mock(args)),
        Command::MockRoboclaw(args) => block_on(serial_bases::mock(args)),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
