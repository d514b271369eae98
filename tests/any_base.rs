//! Any drive with any heading source, and the online estimator on every base, from the command
//! line against the mocks on pseudo-terminals and loopback: `track --base` on the ROS mock and
//! on the RoboClaw + NMEA mock agrees with the square test of the same simulated robot, and its
//! log replays to the same numbers; `calibrate` runs end to end on our protocol's controller
//! with a separate NMEA compass, and on a ROS robot with an NMEA compass in place of its IMU.

mod common;

use serde_json::Value;
use std::path::Path;

/// `a` and `b` side by side (each session waits on its robot's clock, not the CPU: a session
/// here keeps a core under a tenth busy), with what each returned.
fn side_by_side<A: Send, B: Send>(
    a: impl FnOnce() -> A + Send,
    b: impl FnOnce() -> B + Send,
) -> (A, B) {
    std::thread::scope(|s| {
        let a = s.spawn(a);
        let b = b();
        (a.join().unwrap(), b)
    })
}

/// The last estimate of `track --json` output: (E_b, σ, E_d, σ).
fn final_estimate(v: &Value) -> (f64, f64, f64, f64) {
    let last = v["estimates"].as_array().unwrap().last().unwrap().clone();
    let f = |k: &str| last[k].as_f64().unwrap();
    (f("e_b"), f("e_b_std"), f("e_d"), f("e_d_std"))
}

/// The first round's chosen estimate of `calibrate --json` output: (E_b, σ, E_d, σ, method).
fn square_estimate(v: &Value) -> (f64, f64, f64, f64, String) {
    let chosen = &v["rounds"][0]["chosen"];
    let f = |k: &str| {
        chosen[k]
            .as_f64()
            .unwrap_or_else(|| panic!("{k}: {chosen}"))
    };
    (
        f("e_b"),
        f("e_b_std_err"),
        f("e_d"),
        f("e_d_std_err"),
        chosen["method"].as_str().unwrap().to_string(),
    )
}

/// The online estimate agrees with the square test's within three combined standard errors.
fn assert_agree(track: &Value, square: &Value) {
    let (eb, sb, ed, sd) = final_estimate(track);
    let (qb, qsb, qd, qsd, method) = square_estimate(square);
    let z_b = (eb - qb) / sb.hypot(qsb);
    let z_d = (ed - qd) / sd.hypot(qsd);
    assert!(
        z_b.abs() < 3.0 && z_d.abs() < 3.0,
        "online E_b {eb:.5} ± {sb:.5}, E_d {ed:.6} ± {sd:.6}; squares ({method}) E_b {qb:.5} ± \
         {qsb:.5}, E_d {qd:.6} ± {qsd:.6}: z {z_b:.2}, {z_d:.2}"
    );
    // A real estimate, not the prior: the path observed both parameters.
    assert!(sb < 0.01 && sd < 0.01, "σ {sb}, {sd}");
}

/// `track --log` of the session's log, with the filter settings of the session (`filter`),
/// gives the session's numbers.
fn assert_replays(track: &Value, log: &Path, filter: &[&str]) {
    let mut args = vec!["track", "--log", log.to_str().unwrap(), "--json"];
    args.extend(filter);
    let replay = common::odocal_json(&args);
    assert_eq!(
        replay["time_offsets"][0]["corrected"], false,
        "the replay corrected an offset: {}",
        replay["time_offsets"]
    );
    let (a, b) = (final_estimate(track), final_estimate(&replay));
    assert_eq!(a, b, "live {a:?}, replayed {b:?}");
    assert_eq!(
        track["heading_updates"], replay["heading_updates"],
        "{track} vs {replay}"
    );
}

/// The flags of a tracking session that drives a wandering path.
fn wander(log: &Path) -> Vec<String> {
    [
        "--drive",
        "wander:2",
        "--motions",
        "24",
        "--max-speed-m-s",
        "0.5",
        "--max-rate-rad-s",
        "1.5",
        "--yes",
        "--json",
        "--record",
        log.to_str().unwrap(),
    ]
    .map(String::from)
    .to_vec()
}

fn run(args: &[String]) -> Value {
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    common::odocal_json(&args)
}

/// A mock RoboClaw and compass of the robot in `profile` (every mock of it is the same robot):
/// the process and the flags that name it.
fn roboclaw_robot(profile: &str) -> (std::process::Child, Vec<String>) {
    let (mock, lines) = common::spawn_server_lines(
        "mock-roboclaw",
        &[
            "--profile",
            profile,
            // Slow enough that the host's stamps (a millisecond of jitter) stay within a real
            // compass's noise: the heading turns at up to 6 rad/s of wall-clock time.
            "--time-scale",
            "4",
            "--compass-hz",
            "20",
            "--compass-sigma-deg",
            "0.2",
        ],
        2,
    );
    let heading = format!("{}?baud=115200", lines[1]);
    let robot = [
        "--base",
        &lines[0],
        "--heading",
        &heading,
        "--profile",
        profile,
    ];
    (mock, robot.map(String::from).to_vec())
}

#[test]
fn track_on_the_roboclaw_and_compass_agrees_with_its_squares_and_replays() {
    let (dir, profile) =
        common::scratch_with("any-roboclaw", "robot.toml", common::ROBOCLAW_PROFILE);
    let profile_s = profile.to_str().unwrap().to_string();
    let log = dir.join("track.jsonl");
    let filter = ["--heading-sigma-deg", "0.5"];
    // The online session and the square test on two mocks of the one robot, side by side.
    let (track, square) = side_by_side(
        || {
            let (mut mock, robot) = roboclaw_robot(&profile_s);
            let mut args: Vec<String> = vec!["track".into()];
            args.extend(robot);
            args.extend(wander(&log));
            args.extend(filter.map(String::from));
            let track = run(&args);
            let _ = mock.kill();
            track
        },
        || {
            let (mut mock, robot) = roboclaw_robot(&profile_s);
            let mut args: Vec<String> = vec!["calibrate".into()];
            args.extend(robot);
            args.extend(common::QUICK_FLAGS.map(String::from));
            let report = dir.join("report");
            args.extend(
                [
                    "--dry-run",
                    "--report-dir",
                    report.to_str().unwrap(),
                    "--json",
                ]
                .map(String::from),
            );
            let square = run(&args);
            let _ = mock.kill();
            square
        },
    );
    assert_agree(&track, &square);
    assert_replays(&track, &log, &filter);
}

/// A mock ROS robot with an NMEA compass, configured by a copy of the controller's YAML in a
/// scratch directory of its own (`name`): the process, the directory, the YAML, its URL and
/// the compass's heading spec. Every one is the same robot.
fn ros_robot(
    name: &str,
) -> (
    std::process::Child,
    std::path::PathBuf,
    String,
    String,
    String,
) {
    let (dir, yaml) = common::scratch_with(name, "diff_drive.yaml", common::DIFF_DRIVE_YAML);
    let yaml_s = yaml.to_str().unwrap().to_string();
    let (server, lines) = common::spawn_server_lines(
        "mock-rosbridge",
        &[
            "--ros-yaml",
            &yaml_s,
            "--port",
            "0",
            "--time-scale",
            "20",
            "--compass-sigma-deg",
            "0.05",
            "--nmea",
            "--nmea-sigma-deg",
            "0.05",
        ],
        2,
    );
    let compass = format!("{}?baud=115200", lines[1]);
    (server, dir, yaml_s, lines[0].clone(), compass)
}

/// `calibrate --base URL --ros-yaml YAML` with the quick flags and `more`.
fn calibrate_ros(url: &str, yaml: &str, more: &[&str]) -> Value {
    let mut args = vec!["calibrate", "--base", url, "--ros-yaml", yaml];
    args.extend(common::QUICK_FLAGS);
    args.extend(more);
    common::odocal_json(&args)
}

#[test]
fn on_a_ros_robot_track_agrees_with_its_squares_and_replays() {
    let filter = ["--heading-sigma-deg", "0.05"];
    // The online session and the square test with the robot's IMU (a dry run: nothing
    // changes) on two mocks of the one robot, side by side (the same robot with an NMEA
    // compass in place of its IMU is the next test's).
    let ((track, log), squares) = side_by_side(
        || {
            let (mut server, dir, yaml, url, _) = ros_robot("any-ros-track");
            let log = dir.join("track.jsonl");
            let mut args: Vec<String> = ["track", "--base", &url, "--ros-yaml", &yaml]
                .map(String::from)
                .to_vec();
            args.extend(wander(&log));
            args.extend(filter.map(String::from));
            let track = run(&args);
            let _ = server.kill();
            (track, log)
        },
        || {
            let (mut server, dir, yaml, url, _) = ros_robot("any-ros-squares");
            let report = dir.join("dry");
            let more = [
                "--dry-run",
                "--json",
                "--report-dir",
                report.to_str().unwrap(),
            ];
            let squares = calibrate_ros(&url, &yaml, &more);
            let _ = server.kill();
            squares
        },
    );
    assert_agree(&track, &squares);
    assert_replays(&track, &log, &filter);
}

#[test]
fn on_a_ros_robot_a_compass_can_replace_its_imu() {
    let (mut server, dir, yaml_s, url, compass) = ros_robot("any-ros-compass");
    let yaml = std::path::PathBuf::from(&yaml_s);
    let report_dir = dir.join("report");
    let more = [
        "--heading",
        &compass,
        "--report-dir",
        report_dir.to_str().unwrap(),
        "--json",
    ];
    let calibrated = calibrate_ros(&url, &yaml_s, &more);
    let _ = server.kill();
    // The run's backup, in its report directory, puts the YAML back as it was.
    let backup = calibrated["backup_path"].as_str().unwrap().to_string();
    assert_eq!(
        std::path::Path::new(&backup).parent(),
        Some(report_dir.as_path())
    );
    let written_text = std::fs::read_to_string(&yaml).unwrap();
    let (ok, _, err) = common::odocal(&["restore", &backup, "--yes"]);
    assert!(ok, "{err}");
    assert_eq!(
        std::fs::read_to_string(&yaml).unwrap(),
        common::DIFF_DRIVE_YAML
    );
    std::fs::write(&yaml, written_text).unwrap();
    assert_eq!(calibrated["base"]["drive"]["kind"], "rosbridge");
    assert_eq!(calibrated["base"]["heading"]["kind"], "nmea0183");
    assert_eq!(calibrated["base"]["store"]["kind"], "ros2-control-yaml");
    // The compass's stamps (this host's clock) and the robot's (a simulation 20 times faster)
    // cannot be compared, so the heading along the legs is not used: the estimate is `exact`'s,
    // from the headings at rest. At 20 times real speed the drive overshoots each turn by
    // 10–20° (by its own odometry); `exact` models the turns the odometry reports.
    assert_eq!(calibrated["rounds"][0]["chosen"]["method"], "exact");
    let before = calibrated["mean_abs_heading_error_before_deg"]
        .as_f64()
        .unwrap();
    let after = calibrated["mean_abs_heading_error_after_deg"]
        .as_f64()
        .unwrap();
    assert!(after * 10.0 < before, "{before}° → {after}°");
    let written = odocal::ros::yaml::DiffDriveConfig::load(&yaml, "diff_drive_controller").unwrap();
    assert!(
        (written.separation_multiplier - common::TRUE_E_B).abs() < 0.003,
        "{written:?}"
    );
}

#[test]
fn our_controller_with_a_separate_nmea_compass_calibrates_end_to_end() {
    let (mut mock, lines) = common::spawn_server_lines(
        "mock-device",
        &[
            "--real-time",
            "20",
            "--seed",
            "3",
            "--nmea",
            "--nmea-sigma-deg",
            "0.1",
        ],
        2,
    );
    let dir = common::scratch("any-odocal-nmea");
    let compass = format!("{}?baud=115200", lines[1]);
    let mut args = vec!["calibrate", "--port", &lines[0], "--heading", &compass];
    args.extend(common::QUICK_FLAGS);
    let report_dir = dir.join("report");
    args.extend(["--report-dir", report_dir.to_str().unwrap(), "--json"]);
    let v = common::odocal_json(&args);
    // The run's backup restores the controller (both copies) while it is still there.
    let backup = v["backup_path"].as_str().unwrap().to_string();
    let restored = common::odocal_json(&["restore", &backup, "--yes", "--json"]);
    assert_eq!(restored["written"], true, "{restored}");
    for source in ["active", "stored"] {
        let p = common::odocal_json(&[
            "params", "get", "--port", &lines[0], "--source", source, "--json",
        ]);
        assert_eq!(p["wheelbase_m"].as_f64(), Some(0.39), "{source}: {p}");
    }
    drop(mock.stdin.take());
    let _ = mock.wait();
    assert_eq!(v["base"]["drive"]["kind"], "odocal-protocol");
    assert_eq!(v["base"]["heading"]["kind"], "nmea0183");
    assert_eq!(v["base"]["store"]["kind"], "odocal-protocol");
    let before = v["mean_abs_heading_error_before_deg"].as_f64().unwrap();
    let after = v["mean_abs_heading_error_after_deg"].as_f64().unwrap();
    assert!(after * 10.0 < before, "{before}° → {after}°");
    let p = &v["final_params"];
    let eb = p["wheelbase_m"].as_f64().unwrap() / 0.39;
    assert!((eb - common::TRUE_E_B).abs() < 0.003, "{p}");
}
