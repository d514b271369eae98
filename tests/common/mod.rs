//! Helpers the integration tests share: the demo robot as a mock device or an in-process base,
//! scratch directories, the recorded data set (loud in CI), and running the `odocal` binary.
//! Each test file compiles its own copy, so not every file uses every helper.
#![allow(dead_code)]

use odocal::kinematics::{SplitConvention, WheelParams};
use odocal::mock::{MockConfig, MockDevice, SharedDevice, SimBase};
use odocal::offline::dataset::default_optiodom_root;
use odocal::sim::{NoiseModel, Simulator};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Arc, Mutex};

/// True `E_b` of the test robot (the paper's).
pub const TRUE_E_B: f64 = 0.976;
/// True `E_d` of the test robot (the paper's), left wheel nominal.
pub const TRUE_E_D: f64 = 0.992;

/// A robot profile of the test robot's nominal geometry, wired as the RoboClaw mocks of the
/// tests are (left wheel on M2, right encoder counting down).
pub const ROBOCLAW_PROFILE: &str = "\
# test robot
[geometry]
left_wheel_diameter_m = 0.15
right_wheel_diameter_m = 0.15
wheelbase_m = 0.39
encoder_counts_per_motor_rev = 1024
gear_ratio = 4.0

[wiring]
left_channel = \"M2\"
left_encoder_sign = 1
right_encoder_sign = -1

[limits]
max_speed_m_s = 1.0
max_accel_m_s2 = 1.0
min_battery_v = 10.5
";

/// A ros2_control YAML of the test robot's nominal geometry.
pub const DIFF_DRIVE_YAML: &str = "\
controller_manager:
  ros__parameters:
    update_rate: 100  # Hz

diff_drive_controller:
  ros__parameters:
    left_wheel_names: [\"left_wheel_joint\"]
    right_wheel_names: [\"right_wheel_joint\"]
    wheel_separation: 0.39
    wheel_radius: 0.075
    cmd_vel_timeout: 0.5  # s
";

/// The controller's factory configuration: D 0.15 m, b 0.39 m, 4096 counts per revolution.
pub fn nominal() -> WheelParams {
    WheelParams::nominal(0.15, 0.39, 4096.0)
}

/// The test robot's true parameters.
pub fn truth() -> WheelParams {
    WheelParams::from_ratios(
        &nominal(),
        TRUE_E_B,
        TRUE_E_D,
        &SplitConvention::LeftNominal,
    )
    .expect("the test robot is physical")
}

/// A mock device (protocol firmware) of the test robot with this compass noise and seed.
pub fn mock_device(compass_sigma_deg: f64, seed: u64) -> SharedDevice {
    mock_device_with(compass_sigma_deg, seed, |_| {})
}

/// The same, with `tweak` applied to its configuration first.
pub fn mock_device_with(
    compass_sigma_deg: f64,
    seed: u64,
    tweak: impl FnOnce(&mut MockConfig),
) -> SharedDevice {
    let mut cfg = MockConfig::with_ratios(nominal(), TRUE_E_B, TRUE_E_D).expect("valid robot");
    cfg.noise.compass_sigma_rad = compass_sigma_deg.to_radians();
    cfg.seed = seed;
    tweak(&mut cfg);
    Arc::new(Mutex::new(MockDevice::new(cfg).expect("valid mock")))
}

/// The test robot as an in-process base (no protocol) with this compass noise and seed.
pub fn sim_base(compass_sigma_deg: f64, seed: u64) -> SimBase {
    let noise = NoiseModel {
        compass_sigma_rad: compass_sigma_deg.to_radians(),
        ..NoiseModel::default()
    };
    SimBase::new(Simulator::new(truth(), nominal(), noise, seed).expect("valid simulator"))
}

/// The routine on the in-process base `sim`, with it as the ground truth, unattended.
pub async fn routine_on(
    sim: &SimBase,
    cfg: &odocal::routine::config::RoutineConfig,
) -> Result<odocal::routine::Report, odocal::routine::RoutineError> {
    odocal::routine::run(
        &odocal::base::Base::single(sim.clone()),
        cfg,
        Some(sim),
        &mut odocal::routine::Unattended,
        &tokio_util::sync::CancellationToken::new(),
    )
    .await
}

/// An empty scratch directory unique to this test process.
pub fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("odocal-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// A new [`scratch`] directory holding `file` with `contents`: the directory and the file.
pub fn scratch_with(name: &str, file: &str, contents: &str) -> (PathBuf, PathBuf) {
    let dir = scratch(name);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(file);
    std::fs::write(&path, contents).unwrap();
    (dir, path)
}

/// The OptiOdom data set's root if it holds `sub` (`square`, `free`). Missing data fails the
/// test when `CI` is set, and skips it with a notice otherwise.
pub fn optiodom(sub: &str) -> Option<PathBuf> {
    let root = default_optiodom_root();
    if root.join(sub).is_dir() {
        return Some(root);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "OptiOdom data set missing at {} (set ODOCAL_OPTIODOM); CI must have ../shared",
        root.display()
    );
    eprintln!(
        "NOTICE: skipping, OptiOdom data not found at {}",
        root.display()
    );
    None
}

/// The Python of the virtual environment `.ci/run` makes with the client libraries odocal did
/// not write (`.ci/requirements.txt`: roslibpy, rosbags, basicmicro), or `ODOCAL_PYTHON`. A
/// missing one fails the test when `CI` is set, and skips it with a notice otherwise.
#[allow(dead_code)]
pub fn client_python() -> Option<PathBuf> {
    let python = std::env::var_os("ODOCAL_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("target/ci-venv/bin/python"));
    if python.is_file() {
        return Some(python);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "no Python with the client libraries at {} (.ci/run makes it; or set ODOCAL_PYTHON)",
        python.display()
    );
    eprintln!(
        "NOTICE: skipping, no Python with the client libraries at {} (run .ci/run once, or \
         set ODOCAL_PYTHON)",
        python.display()
    );
    None
}

/// Runs the `odocal` binary: success, stdout, stderr.
pub fn odocal(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(args)
        .output()
        .expect("binary runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Runs the `odocal` binary, which must succeed and print one JSON object.
pub fn odocal_json(args: &[&str]) -> serde_json::Value {
    let (ok, stdout, stderr) = odocal(args);
    assert!(ok, "odocal {args:?} failed: {stderr}");
    serde_json::from_str(&stdout).expect("stdout is one JSON object")
}

/// Starts `odocal mock-device` with `args`; returns the process (stdin kept open: closing it
/// stops the device) and the first line it printed, the terminal's path.
pub fn spawn_mock(args: &[&str]) -> (std::process::Child, String) {
    spawn_server("mock-device", args)
}

/// Starts an `odocal` server subcommand (`mock-device`, `mock-rosbridge`) with `args`; returns
/// the process (closing its stdin stops it) and its first line (its path or URL).
pub fn spawn_server(command: &str, args: &[&str]) -> (std::process::Child, String) {
    let (child, mut lines) = spawn_server_lines(command, args, 1);
    (child, lines.remove(0))
}

/// `odocal mock-rosbridge` serving the robot of the controller YAML `yaml` on a free loopback
/// port, with `extra` flags; the process and its `rosbridge://` URL.
pub fn spawn_ros_mock(yaml: &str, extra: &[&str]) -> (std::process::Child, String) {
    let mut args = vec!["--ros-yaml", yaml, "--port", "0"];
    args.extend(extra);
    spawn_server("mock-rosbridge", &args)
}

/// [`spawn_server`] for a server that prints `n` lines (paths or URLs) first.
pub fn spawn_server_lines(
    command: &str,
    args: &[&str],
    n: usize,
) -> (std::process::Child, Vec<String>) {
    let mut all = vec![command];
    all.extend(args);
    spawn_odocal_server(&all, n, None)
}

/// Starts `odocal args…` (a server: `mock-device`, `mock-rosbridge`, `mock-roboclaw`) in
/// `cwd` when given; returns the process (closing its stdin stops it) and the first `n` lines
/// it printed (its paths or URLs). What it prints later is read and dropped, so it never
/// blocks on a full pipe nor writes into a closed one.
pub fn spawn_odocal_server<S: AsRef<std::ffi::OsStr>>(
    args: &[S],
    n: usize,
    cwd: Option<&std::path::Path>,
) -> (std::process::Child, Vec<String>) {
    use std::io::{BufRead, BufReader};
    use std::process::Stdio;
    let mut command = Command::new(env!("CARGO_BIN_EXE_odocal"));
    command
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null());
    if let Some(dir) = cwd {
        command.current_dir(dir);
    }
    let mut mock = command.spawn().expect("the odocal server starts");
    let mut out = BufReader::new(mock.stdout.take().expect("stdout piped"));
    let lines = (0..n)
        .map(|_| {
            let mut line = String::new();
            out.read_line(&mut line)
                .expect("the server prints its address");
            line.trim().to_string()
        })
        .collect();
    std::thread::spawn(move || std::io::copy(&mut out, &mut std::io::sink()));
    (mock, lines)
}

/// A short routine for tests on real-time mocks: 1 m squares, 3 per direction, 2 verification
/// runs each way, written without asking; backups under `dir`.
pub fn quick_routine(dir: &std::path::Path) -> odocal::routine::config::RoutineConfig {
    odocal::routine::config::RoutineConfig {
        side_m: 1.0,
        runs_per_direction: 3,
        max_speed_m_s: 0.5,
        max_rate_rad_s: 1.5,
        heading_samples: 3,
        settle_s: 0.0,
        verification_runs: 2,
        write_back: odocal::routine::config::WritePolicy::Yes,
        confirm_motion: false,
        backup_dir: Some(dir.join("backups")),
        ..odocal::routine::config::RoutineConfig::default()
    }
}

/// A short routine for virtual-time mocks: 1 m squares, 2 per direction at up to 1 m/s and
/// 3 rad/s, no settling, one verification run each way, written without asking; backups in
/// `backup_dir`.
pub fn virtual_routine(backup_dir: PathBuf) -> odocal::routine::config::RoutineConfig {
    odocal::routine::config::RoutineConfig {
        side_m: 1.0,
        runs_per_direction: 2,
        max_speed_m_s: 1.0,
        max_rate_rad_s: 3.0,
        settle_s: 0.0,
        write_back: odocal::routine::config::WritePolicy::Yes,
        verification_runs: 1,
        backup_dir: Some(backup_dir),
        ..odocal::routine::config::RoutineConfig::default()
    }
}

/// The `calibrate` flags of [`quick_routine`], for CLI tests, without the compass swing (50 s
/// of turning at real speed; `tests/heading_sensors.rs` covers it).
pub const QUICK_FLAGS: [&str; 16] = [
    "--yes",
    "--no-swing",
    "--side-m",
    "1",
    "--runs",
    "3",
    "--max-speed-m-s",
    "0.5",
    "--max-rate-rad-s",
    "1.5",
    "--settle-s",
    "0",
    "--heading-samples",
    "3",
    "--verification-runs",
    "2",
];

/// Relative errors of `written` against `truth` in the two combinations a heading can observe:
/// the diameter ratio `D_R/D_L` and the wheelbase over the mean diameter `b/D̄`.
pub fn combination_errors(written: &WheelParams, truth: &WheelParams) -> (f64, f64) {
    let b_over_d = |p: &WheelParams| {
        2.0 * p.wheelbase_m / (p.left_wheel_diameter_m + p.right_wheel_diameter_m)
    };
    (
        written.e_d() / truth.e_d() - 1.0,
        b_over_d(written) / b_over_d(truth) - 1.0,
    )
}

/// A shell word list: whitespace-separated, single and double quotes group, `\\` + newline
/// continues the line. Enough for the README's commands, which use no variables.
pub fn shell_words(command: &str) -> Vec<String> {
    let command = command.replace("\\\n", " ");
    let (mut words, mut cur, mut quote, mut any) = (Vec::new(), String::new(), None, false);
    for c in command.chars() {
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), c) => cur.push(c),
            (None, '\'' | '"') => (quote, any) = (Some(c), true),
            (None, c) if c.is_whitespace() => {
                if any || !cur.is_empty() {
                    words.push(std::mem::take(&mut cur));
                }
                any = false;
            }
            (None, c) => cur.push(c),
        }
    }
    if any || !cur.is_empty() {
        words.push(cur);
    }
    words
}
