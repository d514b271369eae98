//! The `odocal` command line: parses arguments, calls the library, prints tables or JSON.

#[cfg(all(feature = "mock", any(feature = "odocal-protocol", feature = "ros")))]
mod args;
#[cfg(feature = "conformance")]
mod conformance;
#[cfg(feature = "odocal-protocol")]
mod device;
mod estimate;
mod fit;
#[cfg(all(feature = "mock", feature = "odocal-protocol"))]
mod mock_device;
mod out;
mod plan;
#[cfg(feature = "serial")]
mod ports;
mod prompt;
mod replay;
mod restore;
#[cfg(all(feature = "mock", feature = "roboclaw"))]
mod roboclaw;
#[cfg(feature = "ros")]
mod ros;
mod routine;
mod sensor;
mod simulate;
mod simulate_drive;
mod track;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};
use std::process::ExitCode;

/// Odometry calibration for two-wheel differential-drive robots.
#[derive(Debug, Parser)]
#[command(name = "odocal", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Raise (or lower) one budget of what a run may read out of a bag, NAME=SIZE (repeat for
    /// several): bag-file (default 4GiB), bag-chunk (256MiB), bag-message (1MiB), run-bytes
    /// (8GiB decompressed in all), run-messages (50000000). Sizes take KiB, MiB, GiB, TiB.
    #[arg(long = "budget", global = true, value_name = "NAME=SIZE", value_parser = budget)]
    budgets: Vec<String>,
}

/// A `--budget` setting, checked (and set: the value parser runs before anything is read).
fn budget(setting: &str) -> Result<String, String> {
    odocal::io::budget::set(setting).map_err(|e| e.to_string())?;
    Ok(setting.to_string())
}

// Parsed once per run: the size of its largest variant costs nothing worth boxing for.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Subcommand)]
enum Command {
    #[cfg(all(feature = "mock", feature = "odocal-protocol"))]
    /// Full recalibration of the built-in simulated robot: calibrate, write back, verify, report.
    Demo(routine::DemoArgs),
    /// Recalibrate a real robot: --port (odocal protocol) or --base rosbridge://… (moves it;
    /// asks first unless --yes).
    Calibrate(routine::CalibrateArgs),
    /// Plan a calibration (moves nothing): from the floor, the heading noise and a target
    /// precision, the side, squares, robot time and predicted standard errors.
    Plan(plan::Args),
    /// Run a routine file (TOML); `port = "mock"` runs it on the simulated robot.
    Run(routine::RunArgs),
    #[cfg(feature = "ros")]
    /// Export a calibration report for other software (ros2_control).
    Export(odocal::ros::export::ExportSettings),
    /// Online estimator: calibrate continuously from live telemetry, a log or a recorded set.
    Track(track::TrackArgs),
    /// Record telemetry (encoders, heading) to a JSON-lines log for `track --log`.
    Record(track::RecordArgs),
    /// Estimate E_b, E_d from square-test measurements taken by hand.
    Estimate(estimate::Args),
    /// Calibrate from any driving against a pose reference (motion capture, a localization,
    /// scan matching, GNSS): both diameters and the wheelbase in metres, the reference's
    /// mounting and delay, with their standard deviations (moves nothing).
    Fit(fit::Args),
    /// Simulate the square test on a mis-calibrated robot, calibrate, write back and verify.
    Simulate(simulate::Args),
    /// Calibrate from a recorded OptiOdom square set and evaluate on recorded runs.
    Replay(replay::Args),
    #[cfg(all(feature = "mock", feature = "odocal-protocol"))]
    /// Serve a simulated robot base on a new pseudo-terminal (prints its path first).
    MockDevice(mock_device::MockArgs),
    #[cfg(feature = "conformance")]
    /// Check a device against the protocol's rules (SPEC.md §7) in real time: moves the robot
    /// (short motions at low speed; asks first unless --yes).
    Conformance(conformance::Args),
    #[cfg(all(feature = "mock", feature = "odocal-protocol"))]
    /// Serve the protocol crate's device kit (an ideal robot) on a new pseudo-terminal.
    #[command(hide = true)]
    KitDevice(mock_device::KitArgs),
    #[cfg(feature = "odocal-protocol")]
    /// Read, write, save or restore the controller's kinematic parameters.
    Params {
        #[command(subcommand)]
        command: device::ParamsCommand,
    },
    /// Put a backup odocal wrote back into its store (a controller, a robot profile, a
    /// controller's YAML) or another (--to): shows old → new, asks, backs up what is there first.
    Restore(restore::RestoreArgs),
    /// Show the device's status.
    Status(sensor::PortArgs),
    /// Read the heading (counter-clockwise positive).
    Heading(sensor::HeadingArgs),
    /// Compass swing (moves the robot: full turns in place each way): fits the compass's
    /// deviation curve and prints it as --compass-deviation-deg.
    Swing(sensor::SwingArgs),
    /// Gyro spin test (moves the robot: full turns in place): with where it stopped against a
    /// floor mark, the gyro's scale error, printed as --gyro-scale-error.
    Spin(sensor::SpinArgs),
    #[cfg(feature = "serial")]
    /// List this machine's serial ports with their USB ids.
    Ports(ports::Args),
    #[cfg(feature = "ros")]
    /// Calibrate offline from a ROS bag (rosbag2 directory, MCAP, sqlite3 .db3, ROS 1 .bag;
    /// zstd-compressed too): finds the square runs, every method.
    Bag(ros::BagArgs),
    #[cfg(all(feature = "mock", feature = "ros"))]
    /// Serve a simulated ROS 2 robot behind a mock rosbridge server on loopback.
    MockRosbridge(ros::MockArgs),
    #[cfg(all(feature = "mock", feature = "roboclaw"))]
    /// Serve a mock RoboClaw and a mock NMEA compass of one simulated robot on two PTYs.
    MockRoboclaw(roboclaw::MockArgs),
    /// Print a completion script for a shell (bash, zsh, fish, powershell, elvish), e.g.
    /// `odocal completions bash > ~/.local/share/bash-completion/completions/odocal`.
    Completions {
        /// The shell.
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
    /// Print the man page (roff) on stdout, or write one page per subcommand into --out.
    Man {
        /// A directory to write odocal.1 and odocal-SUBCOMMAND.1 into (created if missing;
        /// pages already there are replaced).
        #[arg(long)]
        out: Option<std::path::PathBuf>,
    },
}

/// `odocal man`: the page of `odocal` on stdout, or every page into `out`.
fn man(out: Option<std::path::PathBuf>) -> Result<(), Box<dyn std::error::Error>> {
    match out {
        Some(dir) => {
            std::fs::create_dir_all(&dir)?;
            clap_mangen::generate_to(command(), &dir)?;
            println!("wrote the man pages into {}", dir.display());
        }
        None => clap_mangen::Man::new(command()).render(&mut std::io::stdout().lock())?,
    }
    Ok(())
}

/// Runs an async command on a fresh runtime.
fn block_on(
    fut: impl std::future::Future<Output = Result<(), Box<dyn std::error::Error>>>,
) -> Result<(), Box<dyn std::error::Error>> {
    tokio::runtime::Runtime::new()?.block_on(fut)
}

/// A command that writes a store, with signals held while it writes
/// ([`prompt::guard_writes`]).
async fn guarded(
    fut: impl std::future::Future<Output = Result<(), Box<dyn std::error::Error>>>,
) -> Result<(), Box<dyn std::error::Error>> {
    prompt::guard_writes();
    fut.await
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
    let parsed = command()
        .try_get_matches()
        .and_then(|m| Cli::from_arg_matches(&m));
    let cli = parsed.unwrap_or_else(|e| parse_error(e));
    let code = match dispatch(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    };
    // A signal held while a store was written: the write ended (said above), now leave as
    // the signal asked.
    let code = match prompt::deferred_signal() {
        Some(name) => {
            eprintln!("{name} came during the write, which was finished first: leaving");
            ExitCode::from(130)
        }
        None => code,
    };
    peak_memory();
    code
}

/// Leaves with the parser's error, or for a command or flag this build left out, the feature
/// it needs ([`odocal::features::left_out`]).
fn parse_error(e: clap::Error) -> ! {
    if let Some(not_built) = odocal::features::left_out_in(&e) {
        eprintln!("error: {not_built}");
        std::process::exit(2);
    }
    e.exit()
}

/// Runs the command.
fn dispatch(chosen: Command) -> Result<(), Box<dyn std::error::Error>> {
    match chosen {
        #[cfg(all(feature = "mock", feature = "odocal-protocol"))]
        Command::Demo(args) => block_on(routine::demo(args)),
        Command::Calibrate(args) => block_on(routine::calibrate(args)),
        Command::Plan(args) => plan::run(args),
        Command::Run(args) => block_on(routine::run_file(args)),
        #[cfg(feature = "ros")]
        Command::Export(args) => block_on(guarded(ros::export(args))),
        Command::Track(args) => block_on(track::track(args)),
        Command::Record(args) => block_on(track::record(args)),
        Command::Estimate(args) => estimate::run(args),
        Command::Fit(args) => fit::run(args),
        Command::Simulate(args) => simulate::run(args),
        Command::Replay(args) => replay::run(args),
        #[cfg(all(feature = "mock", feature = "odocal-protocol"))]
        Command::MockDevice(args) => block_on(mock_device::mock_device(args)),
        #[cfg(feature = "conformance")]
        Command::Conformance(args) => block_on(conformance::run(args)),
        #[cfg(all(feature = "mock", feature = "odocal-protocol"))]
        Command::KitDevice(args) => block_on(mock_device::kit_device(args)),
        #[cfg(feature = "odocal-protocol")]
        Command::Params { command } => block_on(guarded(device::params(command))),
        Command::Restore(args) => block_on(guarded(restore::run(args))),
        Command::Status(port) => block_on(sensor::status(port)),
        Command::Heading(args) => block_on(sensor::heading(args)),
        Command::Swing(args) => block_on(sensor::swing(args)),
        Command::Spin(args) => block_on(sensor::spin(args)),
        #[cfg(feature = "serial")]
        Command::Ports(args) => ports::run(args),
        #[cfg(feature = "ros")]
        Command::Bag(args) => ros::run(args),
        #[cfg(all(feature = "mock", feature = "ros"))]
        Command::MockRosbridge(args) => block_on(ros::mock(args)),
        #[cfg(all(feature = "mock", feature = "roboclaw"))]
        Command::MockRoboclaw(args) => block_on(roboclaw::mock(args)),
        Command::Completions { shell } => {
            clap_complete::generate(shell, &mut command(), "odocal", &mut std::io::stdout());
            Ok(())
        }
        Command::Man { out } => man(out),
    }
}

/// With `ODOCAL_PEAK_MEMORY` set, the last line on standard error is this process's peak
/// resident memory ([`odocal::io::peak_resident_memory`]).
fn peak_memory() {
    if std::env::var_os("ODOCAL_PEAK_MEMORY").is_some() {
        let peak = odocal::io::peak_resident_memory();
        let unknown = || "unknown (no /proc/self/status VmHWM here)".to_string();
        eprintln!("peak resident memory: {}", peak.unwrap_or_else(unknown));
    }
}
