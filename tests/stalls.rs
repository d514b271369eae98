//! A busy laptop and a slow adapter: `calibrate` on our protocol's mock device and on the
//! RoboClaw + NMEA mock, in real time, while the host process — or the device's, as a USB
//! adapter or a starved controller would — is stopped (SIGSTOP) for 300 ms at five random
//! moments, and while every answer comes 40 ms late. Each must
//! complete with the default method, and estimates that agree with the simulated robot as an
//! undisturbed run's do (within three of their stated standard errors).

mod common;

use serde_json::Value;
use std::process::{Command, Stdio};
use std::sync::RwLock;
use std::time::{Duration, Instant};

/// The loaded-machine test saturates both cores on purpose; the real-time stall tests beside
/// it would then measure its load, not theirs (a 2-core CI starved a mock for seconds). They
/// share the machine with each other (read) and never with it (write).
static MACHINE: RwLock<()> = RwLock::new(());

/// Runs `odocal args…` (which prints one JSON object), stopping it — or the process `other`
/// when given — for `stall` `stalls` times, at random moments 1–3 s apart; the JSON and how
/// many stalls landed while it ran.
fn stalled(
    args: &[&str],
    other: Option<u32>,
    stalls: usize,
    stall: Duration,
    seed: u64,
) -> (Value, usize) {
    let child = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("odocal runs");
    let pid = other.unwrap_or(child.id()).to_string();
    let stopper = std::thread::spawn(move || {
        let mut x = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
        let mut landed = 0;
        for _ in 0..stalls {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let wait_ms = 1000 + (x >> 33) % 2000;
            std::thread::sleep(Duration::from_millis(wait_ms));
            let stopped = Command::new("kill")
                .args(["-STOP", &pid])
                .status()
                .is_ok_and(|s| s.success());
            std::thread::sleep(stall);
            let _ = Command::new("kill").args(["-CONT", &pid]).status();
            landed += usize::from(stopped);
        }
        landed
    });
    let started = Instant::now();
    let out = child.wait_with_output().expect("odocal finishes");
    let landed = stopper.join().expect("the stopper runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "odocal {args:?} failed after {:?}: {stderr}",
        started.elapsed()
    );
    let v = serde_json::from_slice(&out.stdout).expect("one JSON object");
    (v, landed)
}

/// The last round's chosen estimate agrees with the simulated robot within three of its own
/// standard errors, by the default method.
fn assert_right(v: &Value, what: &str) {
    let chosen = &v["rounds"][0]["chosen"];
    assert_eq!(chosen["method"], "matched-legs", "{what}: {chosen}");
    for (key, truth) in [("e_b", common::TRUE_E_B), ("e_d", common::TRUE_E_D)] {
        let got = chosen[key].as_f64().unwrap();
        let se = chosen[format!("{key}_std_err")].as_f64().unwrap();
        assert!(
            (got - truth).abs() < 3.0 * se.max(2e-4),
            "{what}: {key} {got} ± {se} against {truth}"
        );
    }
}

/// A short routine at real speed: 0.5 m squares, two each way, one verification each way.
const SHORT: [&str; 20] = [
    "--yes",
    "--no-swing",
    "--dry-run",
    "--json",
    "--side-m",
    "0.5",
    "--runs",
    "2",
    "--max-speed-m-s",
    "0.5",
    "--max-rate-rad-s",
    "3",
    "--settle-s",
    "0",
    "--heading-samples",
    "3",
    "--verification-runs",
    "1",
    "--max-rounds",
    "1",
];

#[test]
fn our_protocol_survives_host_and_device_stalls_and_late_answers() {
    let _shared = MACHINE.read().unwrap_or_else(|e| e.into_inner());
    // The three cases wait on the robot's real time, not on the CPU: run side by side.
    std::thread::scope(|s| {
        for (faults, stalls, stop_device) in
            [("", 5, false), ("", 5, true), ("latency-ms=40", 0, false)]
        {
            s.spawn(move || our_protocol_case(faults, stalls, stop_device));
        }
    });
}

/// One case of the test above: `faults` on the mock device, `stalls` stops of the host (or of
/// the device when `stop_device`).
fn our_protocol_case(faults: &str, stalls: usize, stop_device: bool) {
    let mut mock_args = vec![
        "--real-time",
        "1",
        "--seed",
        "5",
        "--compass-sigma-deg",
        "0.1",
    ];
    if !faults.is_empty() {
        mock_args.extend(["--faults", faults]);
    }
    let (mut mock, port) = common::spawn_mock(&mock_args);
    let dir = common::scratch(&format!("stall-odocal-{stalls}-{stop_device}"));
    let report = dir.join("report");
    let mut args = vec!["calibrate", "--port", &port, "--report-dir"];
    args.push(report.to_str().unwrap());
    args.extend(SHORT);
    let device = stop_device.then(|| mock.id());
    let (v, landed) = stalled(&args, device, stalls, Duration::from_millis(300), 7);
    drop(mock.stdin.take());
    let _ = mock.wait();
    assert_eq!(landed, stalls, "every stall landed while it ran");
    let whose = if stop_device { "device" } else { "host" };
    assert_right(
        &v,
        &format!("our protocol, faults {faults:?}, {stalls} {whose} stalls"),
    );
}

/// Starts `mock-roboclaw` for `profile` (a 20 Hz compass of σ 0.1°, plus `extra`); the
/// process and the `calibrate` arguments that reach it, with the report in `dir`.
fn roboclaw(
    dir: &std::path::Path,
    profile: &std::path::Path,
    extra: &[&str],
) -> (std::process::Child, Vec<String>) {
    let profile = profile.to_str().unwrap();
    let mut mock_args = vec![
        "--profile",
        profile,
        "--compass-hz",
        "20",
        "--compass-sigma-deg",
        "0.1",
    ];
    mock_args.extend(extra);
    let (mock, lines) = common::spawn_server_lines("mock-roboclaw", &mock_args, 2);
    let args = [
        "calibrate",
        "--base",
        &lines[0],
        "--heading",
        &format!("{}?baud=115200", lines[1]),
        "--profile",
        profile,
        "--report-dir",
        dir.join("report").to_str().unwrap(),
    ]
    .map(String::from)
    .to_vec();
    (mock, args)
}

#[test]
fn a_roboclaw_survives_host_and_device_stalls_and_late_answers() {
    let _shared = MACHINE.read().unwrap_or_else(|e| e.into_inner());
    // As above: three real-time cases side by side.
    std::thread::scope(|s| {
        for (stop_device, delay_ms) in [(false, "0"), (true, "0"), (false, "40")] {
            s.spawn(move || roboclaw_case(stop_device, delay_ms));
        }
    });
}

/// One case of the test above: the host (or the device when `stop_device`) stopped five times
/// when answers are prompt, none when they come `delay_ms` late.
fn roboclaw_case(stop_device: bool, delay_ms: &str) {
    let (dir, profile) = common::scratch_with(
        &format!("stall-roboclaw-{stop_device}-{delay_ms}"),
        "robot.toml",
        common::ROBOCLAW_PROFILE,
    );
    let (mut mock, args) = roboclaw(&dir, &profile, &["--answer-delay-ms", delay_ms]);
    let mut args: Vec<&str> = args.iter().map(String::as_str).collect();
    args.extend(SHORT);
    let device = stop_device.then(|| mock.id());
    let stalls = if delay_ms == "0" { 5 } else { 0 };
    let (v, landed) = stalled(&args, device, stalls, Duration::from_millis(300), 11);
    drop(mock.stdin.take());
    let _ = mock.kill();
    assert_eq!(landed, stalls, "every stall landed while it ran");
    let whose = if stop_device { "device" } else { "host" };
    assert_right(
        &v,
        &format!("RoboClaw, {stalls} {whose} stalls, answers {delay_ms} ms late"),
    );
}

/// Both cores busy (two spinning processes beside the calibration and the mock): the default
/// method is the one an idle machine gets, the estimates as right, and every run says how
/// completely its heading stream covered it.
#[test]
fn the_default_method_does_not_depend_on_the_machines_load() {
    let _alone = MACHINE.write().unwrap_or_else(|e| e.into_inner());
    let (dir, profile) =
        common::scratch_with("stall-loaded", "robot.toml", common::ROBOCLAW_PROFILE);
    let spinners: Vec<std::process::Child> = (0..2)
        .map(|_| {
            Command::new("sh")
                .args(["-c", "while :; do :; done"])
                .spawn()
                .expect("sh runs")
        })
        .collect();
    let (mut mock, args) = roboclaw(&dir, &profile, &[]);
    let mut args: Vec<&str> = args.iter().map(String::as_str).collect();
    args.extend(SHORT);
    let (v, _) = stalled(&args, None, 0, Duration::ZERO, 0);
    for mut s in spinners {
        let _ = s.kill();
        let _ = s.wait();
    }
    drop(mock.stdin.take());
    let _ = mock.kill();
    assert_right(&v, "RoboClaw on a loaded machine");
    for run in v["rounds"][0]["runs"].as_array().unwrap() {
        let c = &run["heading_coverage"];
        assert!(c["fraction"].as_f64().is_some_and(|f| f > 0.0), "{run}");
    }
}
