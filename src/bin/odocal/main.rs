//! The `odocal` command line: parses arguments, calls the library, prints tables or JSON.

mod conformance;
mod device;
mod estimate;
mod fit;
mod plan;
mod ports;
mod prompt;
mod replay;
mod restore;
mod roboclaw;
mod robot;
mod ros;
mod routine;
mod sensor;
mod simulate;
mod simulate_drive;
mod stated;
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
    /// Export a calibration report for other software (ros2_control).
    Export(routine::ExportArgs),
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
    /// Serve a simulated robot base on a new pseudo-terminal (prints its path first).
    MockDevice(device::MockArgs),
    /// Check a device against the protocol's rules (SPEC.md §7) in real time: moves the robot
    /// (short motions at low speed; asks first unless --yes).
    Conformance(conformance::Args),
    /// Serve the protocol crate's device kit (an ideal robot) on a new pseudo-terminal.
    #[command(hide = true)]
    KitDevice(conformance::KitArgs),
    /// Read, write, save or restore the controller's kinematic parameters.
    Params {
        #[command(subcommand)]
        command: device::ParamsCommand,
    },
    /// Put a backup odocal wrote back into its store (a controller, a robot profile, a
    /// controller's YAML) or another (--to): shows old → new, asks, backs up what is there first.
    Restore(restore::RestoreArgs),
    /// Show the device's status.
    Status(device::PortArgs),
    /// Read the heading (counter-clockwise positive).
    Heading(device::HeadingArgs),
    /// Compass swing (moves the robot: full turns in place each way): fits the compass's
    /// deviation curve and prints it as --compass-deviation-deg.
    Swing(sensor::SwingArgs),
    /// Gyro spin test (moves the robot: full turns in place): with where it stopped against a
    /// floor mark, the gyro's scale error, printed as --gyro-scale-error.
    Spin(sensor::SpinArgs),
    /// List this machine's serial ports with their USB ids.
    Ports(ports::Args),
    /// Calibrate offline from a ROS bag (rosbag2 directory, MCAP, sqlite3 .db3, ROS 1 .bag;
    /// zstd-compressed too): finds the square runs, every method.
    Bag(ros::BagArgs),
    /// Serve a simulated ROS 2 robot behind a mock rosbridge server on loopback.
    MockRosbridge(ros::MockArgs),
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

/// A mock NMEA compass on the simulated robot of a mock server (`--nmea`): its terminal is
/// printed as `nmea:PATH` on the line after the server's own.
#[derive(Debug, Clone, clap::Args)]
pub struct MockCompassArgs {
    /// Also serve an NMEA 0183 compass on the robot, on a pseudo-terminal of its own (printed
    /// as nmea:PATH on the next line): a second sensor, the true heading with its own noise,
    /// sharing none of the robot's own heading sensor's errors.
    #[arg(long)]
    nmea: bool,
    /// Sentences per second of robot time of the --nmea compass.
    #[arg(long, default_value_t = 10.0)]
    nmea_hz: f64,
    /// Noise per sentence of the --nmea compass (deg).
    #[arg(long, default_value_t = 0.2)]
    nmea_sigma_deg: f64,
    /// How the --nmea compass ends its sentences: crlf (NMEA), lf or cr.
    #[arg(long, default_value = "crlf")]
    nmea_line_end: odocal::mock::nmea::LineEnd,
}

impl MockCompassArgs {
    /// Starts the compass if asked for and prints its spec; keep the handle while serving.
    pub fn spawn(
        &self,
        heading: odocal::mock::nmea::HeadingFn,
        time_scale: f64,
    ) -> Result<Option<odocal::mock::PtyServer<()>>, Box<dyn std::error::Error>> {
        if !self.nmea {
            return Ok(None);
        }
        in_range("--nmea-hz", self.nmea_hz, 0.1, 100.0)?;
        in_range("--nmea-sigma-deg", self.nmea_sigma_deg, 0.0, 10.0)?;
        let cfg = odocal::mock::nmea::MockCompassConfig {
            hz: self.nmea_hz,
            sigma_rad: self.nmea_sigma_deg.to_radians(),
            time_scale,
            line_end: self.nmea_line_end,
            ..Default::default()
        };
        let pty = odocal::mock::nmea::spawn_pty(cfg, heading)?;
        println!("nmea:{}", pty.path);
        Ok(Some(pty))
    }
}

/// Prints `value` as pretty JSON on stdout.
pub fn print_json(value: &serde_json::Value) -> Result<(), Box<dyn std::error::Error>> {
    println!("{}", serde_json::to_string_pretty(value)?);
    Ok(())
}

/// The simulated heading sensor's noise per reading (deg, σ) every mock and simulation starts
/// with unless told otherwise: a real compass's at rest (`--heading-sigma-deg`).
pub const SIM_HEADING_SIGMA_DEG: f64 = 0.37;

/// Checks a numeric flag against its documented physical range (inclusive), naming the flag.
pub fn in_range(flag: &str, value: f64, lo: f64, hi: f64) -> Result<(), String> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(format!(
            "{flag} must be in [{lo}, {hi}], got {}",
            compact(value)
        ))
    }
}

/// A number as a person reads it: plain when moderate, in exponent form when huge or tiny
/// (1e300 is not 301 digits).
pub fn compact(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-4..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// [`in_range`] for several flags: (flag, value, lowest, highest).
pub fn in_ranges(checks: &[(&str, f64, f64, f64)]) -> Result<(), String> {
    checks
        .iter()
        .try_for_each(|&(flag, v, lo, hi)| in_range(flag, v, lo, hi))
}

/// The true errors of a mock's simulated robot.
#[derive(Debug, Clone, clap::Args)]
pub struct TrueRobotArgs {
    /// True E_b of the simulated robot (relative to its configured parameters).
    #[arg(long, default_value_t = 0.976)]
    pub true_eb: f64,
    /// True E_d of the simulated robot (left wheel nominal).
    #[arg(long, default_value_t = 0.992)]
    pub true_ed: f64,
}

impl TrueRobotArgs {
    /// Checks both against what a mock can simulate.
    pub fn check(&self) -> Result<(), String> {
        in_ranges(&[
            ("--true-eb", self.true_eb, 0.5, 2.0),
            ("--true-ed", self.true_ed, 0.8, 1.25),
        ])
    }
}

/// How a mock's heading sensor errs (all off by default: an ideal sensor with the mock's noise).
#[derive(Debug, Clone, clap::Args)]
pub struct HeadingModelArgs {
    /// The simulated heading sensor: compass (absolute, magnetic) or gyro (integrated).
    #[arg(long, default_value = "compass", value_parser = ["compass", "gyro"])]
    heading_sensor: String,
    /// A compass's deviation curve A1,B1,A2,B2 (deg): d(ψ) = A1 sin ψ + B1 cos ψ + A2 sin 2ψ +
    /// B2 cos 2ψ.
    #[arg(long, allow_hyphen_values = true)]
    deviation_deg: Option<odocal::sim::sensor::Deviation>,
    /// A compass's offset while the wheels drive (the motor currents' field, deg).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    motor_offset_deg: f64,
    /// A gyro's scale error (0.01: it reads 1 % more turn).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    gyro_scale_error: f64,
    /// A gyro's bias (deg/s).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    gyro_bias_deg_s: f64,
    /// A gyro bias's random walk (deg/s per √s).
    #[arg(long, default_value_t = 0.0)]
    gyro_bias_walk_deg_s: f64,
    /// Readings rounded to this step (deg; 0: none).
    #[arg(long, default_value_t = 0.0)]
    heading_quantum_deg: f64,
    /// Readings show the heading this long ago (s).
    #[arg(long, default_value_t = 0.0)]
    heading_latency_s: f64,
    /// Probability that a reading is lost.
    #[arg(long, default_value_t = 0.0)]
    heading_loss: f64,
}

impl HeadingModelArgs {
    /// The model these flags describe, checked.
    pub fn model(&self) -> Result<odocal::sim::sensor::HeadingModel, String> {
        use odocal::sim::sensor::{HeadingModel, SensorKind};
        let m = HeadingModel {
            kind: if self.heading_sensor == "gyro" {
                SensorKind::Gyro
            } else {
                SensorKind::Compass
            },
            deviation: self.deviation_deg.unwrap_or_default(),
            motor_offset_rad: self.motor_offset_deg.to_radians(),
            gyro_scale_error: self.gyro_scale_error,
            gyro_bias_rad_s: self.gyro_bias_deg_s.to_radians(),
            gyro_bias_walk: self.gyro_bias_walk_deg_s.to_radians(),
            quantum_rad: self.heading_quantum_deg.to_radians(),
            latency_s: self.heading_latency_s,
            loss: self.heading_loss,
        };
        m.validate()
            .map_err(|(name, value)| format!("heading sensor: {name} = {value} is out of range"))?;
        Ok(m)
    }
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
    let cli = match Cli::from_arg_matches(&command().get_matches()) {
        Ok(cli) => cli,
        Err(e) => e.exit(),
    };
    let result = match cli.command {
        Command::Demo(args) => block_on(routine::demo(args)),
        Command::Calibrate(args) => block_on(routine::calibrate(args)),
        Command::Plan(args) => plan::run(args),
        Command::Run(args) => block_on(routine::run_file(args)),
        Command::Export(args) => block_on(guarded(routine::export(args))),
        Command::Track(args) => block_on(track::track(args)),
        Command::Record(args) => block_on(track::record(args)),
        Command::Estimate(args) => estimate::run(args),
        Command::Fit(args) => fit::run(args),
        Command::Simulate(args) => simulate::run(args),
        Command::Replay(args) => replay::run(args),
        Command::MockDevice(args) => block_on(device::mock_device(args)),
        Command::Conformance(args) => block_on(conformance::run(args)),
        Command::KitDevice(args) => block_on(conformance::kit_device(args)),
        Command::Params { command } => block_on(guarded(device::params(command))),
        Command::Restore(args) => block_on(guarded(restore::restore(args))),
        Command::Status(port) => block_on(device::status(port)),
        Command::Heading(args) => block_on(device::heading(args)),
        Command::Swing(args) => block_on(sensor::swing(args)),
        Command::Spin(args) => block_on(sensor::spin(args)),
        Command::Ports(args) => ports::run(args),
        Command::Bag(args) => ros::run(args),
        Command::MockRosbridge(args) => block_on(ros::mock(args)),
        Command::MockRoboclaw(args) => block_on(roboclaw::mock(args)),
        Command::Completions { shell } => {
            clap_complete::generate(shell, &mut command(), "odocal", &mut std::io::stdout());
            Ok(())
        }
        Command::Man { out } => man(out),
    };
    let code = match result {
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

/// With `ODOCAL_PEAK_MEMORY` set, the last line on standard error is this process's peak
/// resident memory, as Linux counts it for this program alone (`VmHWM`: unlike a parent's
/// `wait4`, which also counts what the parent held when it started the child). For the
/// memory figures of the benchmarks and the hostile-input tests.
fn peak_memory() {
    if std::env::var_os("ODOCAL_PEAK_MEMORY").is_none() {
        return;
    }
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    match status.lines().find_map(|l| l.strip_prefix("VmHWM:")) {
        Some(kib) => eprintln!("peak resident memory: {}", kib.trim()),
        None => eprintln!("peak resident memory: unknown (no /proc/self/status VmHWM here)"),
    }
}
