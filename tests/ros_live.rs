//! Calibrating a ROS robot live through rosbridge, against the mock rosbridge server (loopback
//! only): the routine writes multipliers into the controller's YAML that fix the robot, and
//! the robot is stopped (zero twist) on Ctrl-C, on an error, and when rosbridge vanishes.

mod common;

use odocal::base::Base;
use odocal::mock::rosbridge::{EffortStyle, MockRosConfig, MockRosbridge};
use odocal::ros::live::{connect, RosBaseConfig, WheelSource};
use odocal::ros::yaml::DiffDriveConfig;
use odocal::routine::config::RoutineConfig;
use odocal::routine::{run, RoutineError, RoutineEvent, RoutineUi, Unattended};
use std::path::{Path, PathBuf};
use std::time::Duration;
use tokio_util::sync::CancellationToken;

const YAML: &str = common::DIFF_DRIVE_YAML;

fn yaml_file(name: &str) -> (PathBuf, PathBuf) {
    let dir = common::scratch(name);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("diff_drive.yaml");
    std::fs::write(&path, YAML).unwrap();
    (dir, path)
}

async fn mock(yaml: &Path, tweak: impl FnOnce(&mut MockRosConfig)) -> MockRosbridge {
    let controller = DiffDriveConfig::load(yaml, "diff_drive_controller").unwrap();
    let mut cfg =
        MockRosConfig::with_ratios(controller, common::TRUE_E_B, common::TRUE_E_D).unwrap();
    cfg.noise.compass_sigma_rad = 0.05f64.to_radians();
    cfg.time_scale = 40.0;
    tweak(&mut cfg);
    MockRosbridge::spawn(cfg, "127.0.0.1:0".parse().unwrap())
        .await
        .unwrap()
}

fn ros_config(url: String, yaml: &Path) -> RosBaseConfig {
    RosBaseConfig {
        url,
        yaml: yaml.to_path_buf(),
        ..RosBaseConfig::default()
    }
}

fn routine(dir: &Path) -> RoutineConfig {
    common::quick_routine(dir)
}

/// The routine on `base`, saying yes to everything.
async fn unattended(
    base: &Base,
    routine: &RoutineConfig,
) -> Result<odocal::routine::report::Report, RoutineError> {
    run(
        base,
        routine,
        None,
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await
}

/// The error of a straight motion (at 0.3 m/s) on a robot that does not move, which must come
/// within two seconds of the command.
async fn stopped_within_two_seconds(base: &Base, distance_m: f64) -> String {
    let started = std::time::Instant::now();
    let err = base.drive.move_straight(distance_m, 0.3).await.unwrap_err();
    let took = started.elapsed();
    let text = err.to_string();
    assert!(took < Duration::from_secs(2), "{took:?}: {text}");
    text
}

/// The routine end to end through rosbridge, for each form joint_state_broadcaster's `effort`
/// takes on the wire; odocal never reads `effort`, so none must cost a message. The NaN
/// efforts of wheels without an effort interface through a rosbridge that writes NaN as the
/// bare token (rosbridge_suite #916, not JSON) drive the whole routine; `effort: []` (drivers
/// that leave it empty) a short one: one square each way, one round, no compass swing (the
/// command-line test below drives `null` through the whole routine).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn calibrating_through_rosbridge_writes_multipliers_that_fix_the_robot() {
    for (effort, short) in [(EffortStyle::BareNan, false), (EffortStyle::Empty, true)] {
        let (dir, yaml) = yaml_file(&format!("ros-live-{effort:?}"));
        let server = mock(&yaml, |c| c.effort = effort).await;
        let base = connect(&ros_config(server.url(), &yaml)).await.unwrap();
        let mut routine = routine(&dir);
        if short {
            routine.runs_per_direction = 1;
            routine.verification_runs = 1;
            routine.max_rounds = 1;
            routine.swing = false;
            routine.realign = false;
        }
        let report = unattended(&base, &routine)
            .await
            .unwrap_or_else(|e| panic!("{effort:?}: {e}"));
        let before = report.mean_abs_heading_error_before_deg;
        let after = report.mean_abs_heading_error_after_deg.unwrap();
        assert!(
            before > 3.0,
            "{effort:?}: the robot is mis-calibrated: {before}°"
        );
        assert!(
            after * 10.0 < before,
            "{effort:?}: mean |heading error| {before}° → {after}°"
        );
        // The YAML holds the multipliers (the rest of the file as it was), with its backup
        // beside it.
        let written = DiffDriveConfig::load(&yaml, "diff_drive_controller").unwrap();
        assert!(
            (written.separation_multiplier - common::TRUE_E_B).abs() < 0.003,
            "{effort:?}: {written:?}"
        );
        assert!(
            (written.right_radius_multiplier / written.left_radius_multiplier - common::TRUE_E_D)
                .abs()
                < 0.002,
            "{effort:?}: {written:?}"
        );
        assert_eq!(written.wheel_separation_m, 0.39);
        let text = std::fs::read_to_string(&yaml).unwrap();
        assert!(
            text.contains("update_rate: 100  # Hz") && text.contains("cmd_vel_timeout: 0.5  # s"),
            "{text}"
        );
        // One backup for the write, where the run keeps its files, holding the YAML whole.
        let record = odocal::base::transaction::read_backup(&report.backup_path).unwrap();
        assert_eq!(record.text.as_deref(), Some(YAML));
        assert!(report
            .backup_path
            .file_name()
            .unwrap()
            .to_string_lossy()
            .starts_with("diff_drive.yaml.odocal-backup-"));
        let beside = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().contains("odocal-backup"))
            .count();
        assert_eq!(beside, 0, "nothing beside the YAML");
        assert_eq!(
            last_command(&server).await,
            (0.0, 0.0),
            "the last word is a zero twist"
        );
        drop(base);
    }
}

/// A driver that glitches (every 25th joint-state message 3 rad off on one wheel, the one after
/// it stamped 0.1 s back): every glitch is dropped and counted, none moves the result.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn glitches_in_live_joint_states_are_dropped_counted_and_do_not_move_the_result() {
    let (dir, yaml) = yaml_file("ros-live-glitches");
    let server = mock(&yaml, |c| c.joint_glitch_every = Some(25)).await;
    let base = connect(&ros_config(server.url(), &yaml)).await.unwrap();
    let mut routine = routine(&dir);
    routine.runs_per_direction = 1;
    routine.verification_runs = 1;
    routine.max_rounds = 1;
    routine.swing = false;
    routine.realign = false;
    let report = unattended(&base, &routine).await.unwrap();
    let written = DiffDriveConfig::load(&yaml, "diff_drive_controller").unwrap();
    assert!(
        (written.separation_multiplier - common::TRUE_E_B).abs() < 0.003,
        "{written:?}"
    );
    assert!(
        (written.right_radius_multiplier / written.left_radius_multiplier - common::TRUE_E_D).abs()
            < 0.002,
        "{written:?}"
    );
    let after = report.mean_abs_heading_error_after_deg.unwrap();
    assert!(after < 0.5, "{after}°");
    // The report counts what was dropped, by reason.
    let dropped = report.diagnostics["dropped"]["/joint_states"].clone();
    let count = |reason: &str| {
        dropped
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["reason"].as_str().unwrap().starts_with(reason))
            .map_or(0, |r| r["count"].as_u64().unwrap())
    };
    let (spikes, back) = (count("a spike"), count("stamped before"));
    assert!(spikes > 10, "{dropped}");
    assert!(back > 10, "{dropped}");
    assert!(
        spikes.abs_diff(back) <= 2,
        "one of each per glitch: {dropped}"
    );
    drop(base);
}

/// Cancels the routine on the first motion of round 1's second square.
struct CancelMidLeg(CancellationToken);

impl RoutineUi for CancelMidLeg {
    fn confirm(&mut self, _: &str) -> bool {
        true
    }
    fn event(&mut self, e: &RoutineEvent) {
        if let RoutineEvent::Motion {
            run: 2, motion: 1, ..
        } = e
        {
            self.0.cancel();
        }
    }
}

/// The last velocity command the mock has processed, once it is zero (or after 2 s).
async fn last_command(server: &MockRosbridge) -> (f64, f64) {
    for _ in 0..200 {
        let c = server.state().counters.last_command;
        if c == (0.0, 0.0) {
            return c;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    server.state().counters.last_command
}

async fn wait_still(server: &MockRosbridge) -> (f64, f64) {
    // Give the controller up to 2 s of wall time (40 s of robot time) to come to rest.
    for _ in 0..200 {
        let w = server.state().wheel_speeds();
        if w.0.abs() < 1e-9 && w.1.abs() < 1e-9 {
            return w;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    server.state().wheel_speeds()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ctrl_c_mid_leg_publishes_zero_and_writes_nothing() {
    let (dir, yaml) = yaml_file("ros-cancel");
    let server = mock(&yaml, |_| {}).await;
    let base: Base = connect(&ros_config(server.url(), &yaml)).await.unwrap();
    let token = CancellationToken::new();
    let err = run(
        &base,
        &routine(&dir),
        None,
        &mut CancelMidLeg(token.clone()),
        &token,
    )
    .await
    .unwrap_err();
    assert!(matches!(err, RoutineError::Cancelled), "{err}");
    let zeros = server.state().counters.zero_commands;
    assert_eq!(last_command(&server).await, (0.0, 0.0));
    assert!(
        server.state().counters.zero_commands > zeros.saturating_sub(1),
        "no zero twist"
    );
    assert_eq!(
        wait_still(&server).await,
        (0.0, 0.0),
        "the robot must stand"
    );
    assert_eq!(
        std::fs::read_to_string(&yaml).unwrap(),
        YAML,
        "nothing written"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_error_mid_leg_publishes_zero() {
    let (dir, yaml) = yaml_file("ros-error");
    // The wheel driver stops publishing 3 s of robot time in: mid-leg.
    let server = mock(&yaml, |c| c.joint_states_stop_after_s = Some(3.0)).await;
    let base = connect(&ros_config(server.url(), &yaml)).await.unwrap();
    let err = unattended(&base, &routine(&dir)).await.unwrap_err();
    assert!(err.to_string().contains("no wheel data"), "{err}");
    assert_eq!(last_command(&server).await, (0.0, 0.0));
    assert_eq!(wait_still(&server).await, (0.0, 0.0));
    assert_eq!(std::fs::read_to_string(&yaml).unwrap(), YAML);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rosbridge_vanishing_mid_leg_fails_fast_and_the_controller_stops_the_robot() {
    let (dir, yaml) = yaml_file("ros-vanish");
    let server = mock(&yaml, |_| {}).await;
    let base = connect(&ros_config(server.url(), &yaml)).await.unwrap();
    let server = std::sync::Arc::new(server);
    let s2 = server.clone();
    let killer = tokio::spawn(async move {
        // Wait until the robot is moving, then take rosbridge away.
        loop {
            let w = s2.state().wheel_speeds();
            if w.0.abs() > 1.0 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
        s2.vanish();
    });
    let started = std::time::Instant::now();
    let err = unattended(&base, &routine(&dir)).await.unwrap_err();
    killer.await.unwrap();
    assert!(
        started.elapsed() < Duration::from_secs(10),
        "took {:?}",
        started.elapsed()
    );
    assert!(err.to_string().contains("closed"), "{err}");
    // Nothing can reach the robot now: its controller's cmd_vel_timeout stops it.
    assert_eq!(wait_still(&server).await, (0.0, 0.0));
    assert_eq!(std::fs::read_to_string(&yaml).unwrap(), YAML);
}

/// A controller YAML odocal reads but cannot write back keeping the rest of it (here, a
/// multiplier that is an anchor another line repeats) is refused by `calibrate` — and by
/// `calibrate --dry-run` — before the robot is commanded to move, with the reason and the
/// line; nothing is written and no rollback is owed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_yaml_that_cannot_be_written_is_refused_before_the_robot_moves() {
    let (dir, good) = yaml_file("ros-unwritable");
    let server = mock(&good, |_| {}).await;
    let bad = dir.join("bad.yaml");
    let text = format!(
        "{YAML}    wheel_separation_multiplier: &m 1.0\n    left_wheel_radius_multiplier: *m\n"
    );
    std::fs::write(&bad, &text).unwrap();
    for dry_run in [false, true] {
        let mut args: Vec<String> = ["calibrate", "--base", &server.url(), "--ros-yaml"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        args.push(bad.display().to_string());
        args.extend(common::QUICK_FLAGS.iter().map(|s| s.to_string()));
        args.extend([
            "--report-dir".into(),
            dir.join("report").display().to_string(),
        ]);
        if dry_run {
            args.push("--dry-run".into());
        }
        let started = std::time::Instant::now();
        let (ok, _, err) = tokio::task::spawn_blocking(move || {
            common::odocal(&args.iter().map(String::as_str).collect::<Vec<_>>())
        })
        .await
        .unwrap();
        assert!(!ok, "dry run {dry_run}: must fail");
        assert!(
            err.contains("line 12")
                && err.contains("`wheel_separation_multiplier`")
                && err.contains("the alias at line 13 repeats the anchor at line 12")
                && err.contains("nothing was changed"),
            "dry run {dry_run}: {err}"
        );
        assert!(!err.contains("restor"), "no rollback is owed: {err}");
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "fails fast, took {:?}",
            started.elapsed()
        );
    }
    let c = server.state().counters.clone();
    assert!(c.connections >= 2, "calibrate connected: {c:?}");
    assert_eq!(
        c.commands, c.zero_commands,
        "never commanded to move: {c:?}"
    );
    assert_eq!(server.state().wheel_speeds(), (0.0, 0.0));
    assert_eq!(
        std::fs::read_to_string(&bad).unwrap(),
        text,
        "nothing written"
    );
    let beside: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains("odocal-backup"))
        .collect();
    assert!(beside.is_empty(), "no copy of the YAML was needed");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_that_is_not_rosbridge_is_diagnosed() {
    let (_dir, yaml) = yaml_file("ros-wrong");
    // A plain HTTP server: no WebSocket upgrade.
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move {
        while let Ok((mut s, _)) = listener.accept().await {
            use tokio::io::{AsyncReadExt, AsyncWriteExt};
            let mut buf = [0u8; 1024];
            let _ = s.read(&mut buf).await;
            let _ = s
                .write_all(b"HTTP/1.1 200 OK\r\ncontent-length: 2\r\n\r\nhi")
                .await;
        }
    });
    let err = match connect(&ros_config(format!("rosbridge://{addr}"), &yaml)).await {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a plain HTTP server must be refused"),
    };
    assert!(err.contains("not a rosbridge server"), "{err}");
    // An HTTP/1.0 server (Python's http.server) and something that is not HTTP at all.
    for answer in [
        &b"HTTP/1.0 200 OK\r\n\r\nhi"[..],
        &b"SSH-2.0-OpenSSH_9.2\r\n"[..],
    ] {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        tokio::spawn(async move {
            use tokio::io::{AsyncReadExt, AsyncWriteExt};
            if let Ok((mut s, _)) = listener.accept().await {
                let mut buf = [0u8; 1024];
                let _ = s.read(&mut buf).await;
                let _ = s.write_all(answer).await;
            }
        });
        let err = match connect(&ros_config(format!("rosbridge://{addr}"), &yaml)).await {
            Err(e) => e.to_string(),
            Ok(_) => panic!("{answer:?} must be refused"),
        };
        assert!(err.contains("not a rosbridge server"), "{err}");
    }
    let _ = Unattended;
}

#[test]
fn calibrate_base_rosbridge_end_to_end_from_the_command_line() {
    let (dir, yaml) = yaml_file("ros-cli");
    let yaml_s = yaml.to_str().unwrap();
    let (mut server, url) = common::spawn_ros_mock(
        yaml_s,
        &[
            "--time-scale",
            "20",
            "--compass-sigma-deg",
            "0.05",
            // NaN efforts as rosbridge writes a NaN in a variable-length array.
            "--effort",
            "null",
        ],
    );
    assert!(url.starts_with("rosbridge://127.0.0.1:"), "{url}");
    let report_dir = dir.join("report");
    let v = {
        let mut args = vec!["calibrate", "--base", &url, "--ros-yaml", yaml_s];
        args.extend(common::QUICK_FLAGS);
        args.extend(["--report-dir", report_dir.to_str().unwrap(), "--json"]);
        common::odocal_json(&args)
    };
    let _ = server.kill();
    let before = v["mean_abs_heading_error_before_deg"].as_f64().unwrap();
    let after = v["mean_abs_heading_error_after_deg"].as_f64().unwrap();
    assert!(after * 10.0 < before, "{before}° → {after}°");
    assert_eq!(v["base"]["drive"]["kind"], "rosbridge");
    assert_eq!(v["base"]["store"]["kind"], "ros2-control-yaml");
    let written = DiffDriveConfig::load(&yaml, "diff_drive_controller").unwrap();
    assert!(
        (written.separation_multiplier - common::TRUE_E_B).abs() < 0.003,
        "{written:?}"
    );
    assert!(report_dir.join("report.json").is_file());
}

/// Joint states whose `effort` rosbridge writes as `null` (a NaN in a variable-length array),
/// or leaves empty: the base connects on the first messages and drives by them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn joint_states_with_effort_null_or_empty_drive_the_robot() {
    for effort in [EffortStyle::Null, EffortStyle::Empty, EffortStyle::Zero] {
        let (_dir, yaml) = yaml_file(&format!("ros-effort-{effort:?}"));
        let server = mock(&yaml, |c| {
            c.effort = effort;
            // Real time: at forty times the robot overshoots what the test wants to see.
            c.time_scale = 1.0;
        })
        .await;
        let base = connect(&ros_config(server.url(), &yaml))
            .await
            .unwrap_or_else(|e| panic!("{effort:?}: {e}"));
        let done = base
            .drive
            .move_straight(0.3, 0.3)
            .await
            .unwrap_or_else(|e| panic!("{effort:?}: {e}"))
            .expect("the odometry's distance");
        assert!((done.distance_m - 0.3).abs() < 0.02, "{effort:?}: {done:?}");
    }
}

/// A velocity topic nothing listens to (Jazzy's controller takes TwistStamped on
/// /diff_drive_controller/cmd_vel): the first motion stops within two seconds and says why,
/// naming the topic, that nothing subscribes to it, and the controller's topic with its type.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_velocity_topic_nothing_listens_to_is_diagnosed_at_once() {
    let (_dir, yaml) = yaml_file("ros-wrong-cmd-vel");
    let server = mock(&yaml, |c| {
        c.cmd_vel = "/diff_drive_controller/cmd_vel".into();
        c.cmd_vel_stamped = true;
        c.time_scale = 1.0;
    })
    .await;
    let base = connect(&ros_config(server.url(), &yaml)).await.unwrap();
    let text = stopped_within_two_seconds(&base, 1.0).await;
    for needle in [
        "did not move",
        "/cmd_vel",
        "nothing subscribes to /cmd_vel",
        "/diff_drive_controller/cmd_vel (geometry_msgs/msg/TwistStamped)",
    ] {
        assert!(text.contains(needle), "{needle:?} not in: {text}");
    }
    assert_eq!(
        server.state().counters.commands,
        0,
        "the robot was never commanded"
    );
    // With the right topic and type, the same robot moves.
    let mut cfg = ros_config(server.url(), &yaml);
    cfg.cmd_vel = "/diff_drive_controller/cmd_vel".into();
    cfg.twist_stamped = true;
    let base = connect(&cfg).await.unwrap();
    let done = base.drive.move_straight(0.2, 0.3).await.unwrap().unwrap();
    assert!((done.distance_m - 0.2).abs() < 0.02, "{done:?}");
}

/// `--ros-set-live` on a controller that cannot take the multipliers live is refused before
/// the robot moves, naming the service that says so: one that does not answer for them (the
/// running controller has another name: `get_parameters`), one that declares one read-only
/// (`describe_parameters`), and one whose parameter callback refuses sets (`set_parameters`
/// of the values it has now, which changes nothing).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn set_live_is_proved_before_the_robot_moves() {
    type Tweak = fn(&mut MockRosConfig);
    let cases: [(&str, Tweak, &[&str]); 3] = [
        (
            "renamed",
            |c| c.controller.controller = "base_controller".into(),
            &["/diff_drive_controller/get_parameters"],
        ),
        (
            "read-only",
            |c| c.read_only_parameters = vec!["left_wheel_radius_multiplier".into()],
            &[
                "/diff_drive_controller/describe_parameters",
                "left_wheel_radius_multiplier is read-only",
            ],
        ),
        (
            "callback",
            |c| c.refuse_parameter_sets = Some("parameters are read at configure only".into()),
            &[
                "/diff_drive_controller/set_parameters refused",
                "wheel_separation_multiplier: parameters are read at configure only",
            ],
        ),
    ];
    for (name, tweak, says) in cases {
        let (dir, yaml) = yaml_file(&format!("ros-set-live-{name}"));
        let server = mock(&yaml, |c| {
            tweak(c);
            c.time_scale = 1.0;
        })
        .await;
        let mut cfg = ros_config(server.url(), &yaml);
        cfg.set_live = true;
        let base = connect(&cfg).await.unwrap();
        let err = unattended(&base, &routine(&dir)).await.unwrap_err();
        let text = err.to_string();
        assert!(text.contains("--ros-set-live"), "{name}: {text}");
        for needle in says {
            assert!(text.contains(needle), "{name}: {needle:?} not in {text}");
        }
        assert_eq!(
            server.state().counters.commands,
            0,
            "{name}: the robot never moved"
        );
        assert_eq!(std::fs::read_to_string(&yaml).unwrap(), YAML, "{name}");
    }
}

/// `--ros-set-live` on a controller that has its multipliers, writable: the pre-flight's
/// `describe_parameters` and `set_parameters` of the present values pass, and a committed write
/// lands in the file and on the running controller, as its `get_parameters` reads them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn set_live_sets_the_running_controllers_multipliers() {
    let (_dir, yaml) = yaml_file("ros-set-live-ok");
    let server = mock(&yaml, |c| c.time_scale = 1.0).await;
    let mut cfg = ros_config(server.url(), &yaml);
    cfg.set_live = true;
    let base = connect(&cfg).await.unwrap();
    let mut p = base.store.read().await.unwrap();
    p.wheelbase_m *= 0.98;
    p.right_wheel_diameter_m *= 1.01;
    base.store.check_write(&p).await.unwrap();
    // The pre-flight set the multipliers to the values they had: one set, nothing changed.
    assert_eq!(server.state().counters.parameter_sets, 1);
    assert_eq!(server.state().configured().wheelbase_m, 0.39);
    base.store.write(&p).await.unwrap();
    base.store.commit().await.unwrap();
    let get = |name: &str| match server.state().parameter(name) {
        Some(odocal::mock::rosbridge::ParamValue::Double(d)) => *d,
        other => panic!("{name}: {other:?}"),
    };
    assert!((get("wheel_separation_multiplier") - 0.98).abs() < 1e-9);
    assert!((get("right_wheel_radius_multiplier") - 1.01).abs() < 1e-9);
    assert!((get("left_wheel_radius_multiplier") - 1.0).abs() < 1e-9);
    let written = DiffDriveConfig::load(&yaml, "diff_drive_controller").unwrap();
    assert!((written.separation_multiplier - 0.98).abs() < 1e-9);
    assert!((server.state().configured().wheelbase_m - 0.39 * 0.98).abs() < 1e-9);
}

/// A velocity topic of another type than the one published (a Jazzy controller taking
/// `TwistStamped` on `/cmd_vel`, commanded with `Twist`): the first motion stops within two
/// seconds, saying the topic carries the other type and that the other wheel source did not
/// change either, whichever source motions close on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_velocity_topic_of_another_type_is_diagnosed_at_once() {
    let (_dir, yaml) = yaml_file("ros-wrong-type");
    let server = mock(&yaml, |c| {
        c.cmd_vel_stamped = true;
        c.time_scale = 1.0;
    })
    .await;
    for (source, other) in [
        (
            WheelSource::JointStates,
            "/odom (the controller's odometry) did not change either",
        ),
        (
            WheelSource::Odom,
            "/joint_states (the joint states) did not change either",
        ),
    ] {
        let mut cfg = ros_config(server.url(), &yaml);
        cfg.wheel_source = source;
        let base = connect(&cfg).await.unwrap();
        let text = stopped_within_two_seconds(&base, 1.0).await;
        for needle in [
            "did not move",
            "/cmd_vel carries geometry_msgs/msg/TwistStamped, not the \
             geometry_msgs/msg/Twist published (--twist-stamped)",
            "/cmd_vel is subscribed by /diff_drive_controller",
            other,
        ] {
            assert!(
                text.contains(needle),
                "{source:?}: {needle:?} not in: {text}"
            );
        }
    }
    assert_eq!(server.state().counters.commands, 0, "nothing was obeyed");
}

/// Joint states whose wheel positions never change (mock hardware without position feedback)
/// while the controller drives the robot: the motion stops within two seconds, and the
/// diagnosis says the controller's odometry moved, so that the joint states are what to look at.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn wheels_that_do_not_show_a_moving_robot_are_told_by_the_other_source() {
    let (_dir, yaml) = yaml_file("ros-frozen-joints");
    let server = mock(&yaml, |c| {
        c.frozen_joint_states = true;
        c.time_scale = 1.0;
    })
    .await;
    let base = connect(&ros_config(server.url(), &yaml)).await.unwrap();
    let text = stopped_within_two_seconds(&base, 1.0).await;
    assert!(
        text.contains(
            "/odom (the controller's odometry) did change: the robot moves, but /joint_states \
             does not show it"
        ),
        "{text}"
    );
    assert!(server.state().counters.commands > 0);
    assert_eq!(last_command(&server).await, (0.0, 0.0), "stopped");
}

/// A rosbridge that sends `texts` (raw, as a server writes them: NaN tokens and all) to every
/// client every 20 ms, and answers nothing (no rosapi, no services).
async fn raw_rosbridge(texts: Vec<String>) -> String {
    use futures_util::{SinkExt, StreamExt};
    use tokio_tungstenite::tungstenite::Message;
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move {
        while let Ok((tcp, _)) = listener.accept().await {
            let texts = texts.clone();
            tokio::spawn(async move {
                let Ok(ws) = tokio_tungstenite::accept_async(tcp).await else {
                    return;
                };
                let (mut sink, mut source) = ws.split();
                tokio::spawn(async move { while let Some(Ok(_)) = source.next().await {} });
                loop {
                    for t in &texts {
                        if sink.send(Message::text(t.clone())).await.is_err() {
                            return;
                        }
                    }
                    tokio::time::sleep(Duration::from_millis(20)).await;
                }
            });
        }
    });
    format!("rosbridge://{addr}")
}

const STAMP: &str = r#""stamp":{"sec":1700000000,"nanosec":0}"#;

fn publish(topic: &str, msg: &str) -> String {
    format!(r#"{{"op":"publish","topic":"{topic}","msg":{msg}}}"#)
}

fn joint_states(position: &str) -> String {
    publish(
        "/joint_states",
        &format!(
            r#"{{"header":{{{STAMP},"frame_id":""}},"name":["left_wheel_joint","right_wheel_joint"],"position":{position},"velocity":[0,0],"effort":[NaN,NaN]}}"#
        ),
    )
}

/// An IMU message whose every field odocal does not use is malformed, as drivers and rosbridge
/// have them: rates as text, a covariance of eight, an acceleration missing, NaN tokens.
fn imu_with_odd_unused_fields() -> String {
    publish(
        "/imu",
        &format!(
            r#"{{"header":{{{STAMP},"frame_id":"imu"}},"orientation":{{"x":0,"y":0,"z":0.25881904510252074,"w":0.9659258262890683}},"orientation_covariance":[0,0,0,0,0,0,0,0,0],"angular_velocity":"n/a","angular_velocity_covariance":[NaN,NaN,NaN,NaN,NaN,NaN,NaN,NaN],"linear_acceleration_covariance":[-1]}}"#
        ),
    )
}

/// Odometry with its unused fields malformed: covariances cut short or null, a twist as text.
fn odom_with_odd_unused_fields() -> String {
    publish(
        "/odom",
        &format!(
            r#"{{"header":{{{STAMP},"frame_id":"odom"}},"child_frame_id":null,"pose":{{"pose":{{"position":{{"x":0,"y":0,"z":0}},"orientation":{{"x":0,"y":0,"z":0,"w":1}}}},"covariance":[0,0,0]}},"twist":"unknown"}}"#
        ),
    )
}

/// Wheel positions that are not numbers, in the raw text rosbridge sends: the base refuses to
/// connect, and the error names the topic, the field and shows a message, so that a topic
/// that talks and one that is silent are told apart.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn messages_that_arrive_but_cannot_be_used_are_named_with_the_field_and_an_example() {
    let (_dir, yaml) = yaml_file("ros-unusable");
    let url = raw_rosbridge(vec![
        joint_states(r#"[0.5,"jammed"]"#),
        imu_with_odd_unused_fields(),
    ])
    .await;
    let mut cfg = ros_config(url, &yaml);
    cfg.first_message_timeout_s = 0.5;
    let err = match connect(&cfg).await {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a wheel position that is not a number must not be driven by"),
    };
    for needle in [
        "no usable message on /joint_states",
        "message(s) arrived and none could be used",
        "field `position[1]`",
        r#"e.g. {"effort":"#,
        r#""position":[0.5,"jammed"]"#,
    ] {
        assert!(err.contains(needle), "{needle:?} not in: {err}");
    }
}

/// Every field odocal does not use, malformed in the raw text (the IMU's rates, accelerations
/// and their covariances; the odometry's covariance, twist and child frame), costs nothing: the
/// base connects on either wheel source and reads the IMU's heading. With no rosapi to ask
/// (this server answers nothing), a robot that does not move is still diagnosed within two
/// seconds of the first command: each question waits a bounded time.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unused_fields_never_cost_a_message_and_a_silent_rosapi_costs_no_time() {
    let (_dir, yaml) = yaml_file("ros-odd-unused");
    let url = raw_rosbridge(vec![
        joint_states("[0.5,-0.5]"),
        imu_with_odd_unused_fields(),
        odom_with_odd_unused_fields(),
    ])
    .await;
    for source in [WheelSource::JointStates, WheelSource::Odom] {
        let mut cfg = ros_config(url.clone(), &yaml);
        cfg.first_message_timeout_s = 2.0;
        cfg.wheel_source = source;
        let base = connect(&cfg)
            .await
            .unwrap_or_else(|e| panic!("{source:?}: {e}"));
        let h = base.heading.read().await.unwrap();
        assert!(
            matches!(h.validity, odocal::base::Validity::Valid),
            "{source:?}: {h:?}"
        );
        assert!((h.heading_rad - 30f64.to_radians()).abs() < 1e-9, "{h:?}");
        let text = stopped_within_two_seconds(&base, 0.5).await;
        assert!(
            text.contains("did not move") && text.contains("rosapi did not say who subscribes"),
            "{text}"
        );
    }
}

/// `odocal heading` reads a ROS robot's IMU through the whole base (`--base rosbridge://…`):
/// a hundred distinct messages at rest, whose spread is the mock IMU's σ 0.3° within 30 % (four
/// of the estimate's standard errors; what `odocal plan --heading-sigma-deg` wants from a ROS
/// user).
#[test]
fn odocal_heading_reads_a_ros_robots_imu_and_its_noise() {
    let (_dir, yaml) = yaml_file("ros-heading");
    let yaml_s = yaml.to_str().unwrap();
    let (mut server, url) = common::spawn_ros_mock(yaml_s, &["--compass-sigma-deg", "0.3"]);
    let v = common::odocal_json(&[
        "heading",
        "--base",
        &url,
        "--ros-yaml",
        yaml_s,
        "--samples",
        "100",
        "--json",
    ]);
    let _ = server.kill();
    assert_eq!(v["samples"], 100, "{v}");
    let sigma = v["sigma_deg"].as_f64().unwrap_or(f64::NAN);
    assert!((0.21..=0.39).contains(&sigma), "{v}");
}

/// `track` on a ROS robot with a localization topic (the mock's `/amcl_pose`: 10 Hz, 3 mm and
/// 0.3°, 1 % jumps, the pose of a frame 12 cm ahead, 5 cm right and turned 6° on the robot):
/// the online filter's both diameters and wheelbase agree with the batch fit of the same
/// drive (the samples the session saw) within 3σ of their combined errors, and the true robot
/// lies within 3σ of each.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tracking_against_a_localization_topic_agrees_with_the_fit_of_the_same_drive() {
    use odocal::calibration::online::{OnlineConfig, ScaleSource};
    use odocal::calibration::pose_fit::{fit_poses, FitConfig, Param};
    use odocal::calibration::pose_reference::{Geometry, Pose2};
    use odocal::calibration::tracker::Tracker;
    use odocal::mock::rosbridge::MockLocalization;
    use odocal::ros::pose_source::RosPoseSource;
    use odocal::routine::track::{track_live, DrivePath, TrackOptions};
    let (_dir, yaml) = yaml_file("ros-live-pose");
    let server = mock(&yaml, |c| {
        c.localization = Some(MockLocalization {
            mount: Pose2 {
                x: 0.12,
                y: -0.05,
                theta: 6f64.to_radians(),
            },
            ..MockLocalization::amcl()
        })
    })
    .await;
    let base = connect(&ros_config(server.url(), &yaml)).await.unwrap();
    let poses = RosPoseSource::connect(&server.url(), "/amcl_pose", Duration::from_secs(5))
        .await
        .unwrap();
    let configured = base.store.read().await.unwrap();
    let mut cfg = OnlineConfig::new(configured);
    cfg.slip_fraction = 0.002;
    let mut tracker = Tracker::new(cfg, ScaleSource::Filter, 1.0).unwrap();
    let opts = TrackOptions {
        path: Some(DrivePath::Wander { area_m: 3.0 }),
        motions: 40,
        max_speed_m_s: 0.3,
        max_rate_rad_s: 1.0,
        ..TrackOptions::default()
    };
    let outcome = track_live(
        &base,
        Some(&poses),
        &mut tracker,
        &opts,
        &mut |_| {},
        &mut |_| {},
        &CancellationToken::new(),
    )
    .await
    .unwrap();
    let online = tracker.estimate().unwrap();
    let nominal = Geometry::from(&configured);
    let drive = outcome.recording.pose_recording(nominal);
    let fit = fit_poses(&drive, &FitConfig::full(nominal)).unwrap();
    let truth = server.state().true_params();
    let scale_std = online.correction_std.expect("the scale is observed");
    let c = online.correction;
    for (p, configured_m, factor, factor_std, true_m) in [
        (
            Param::LeftDiameter,
            nominal.left_diameter_m,
            c.left_diameter_scale,
            scale_std[0],
            truth.left_wheel_diameter_m,
        ),
        (
            Param::RightDiameter,
            nominal.right_diameter_m,
            c.right_diameter_scale,
            scale_std[1],
            truth.right_wheel_diameter_m,
        ),
        (
            Param::Wheelbase,
            nominal.wheelbase_m,
            c.wheelbase_scale,
            scale_std[2],
            truth.wheelbase_m,
        ),
    ] {
        let (value, std) = (configured_m * factor, configured_m * factor_std);
        let (batch, batch_std) = (fit.value(p), fit.std(p).unwrap());
        let name = p.name();
        assert!(
            (value - batch).abs() < 3.0 * std.hypot(batch_std),
            "{name}: track {value} ± {std}, fit {batch} ± {batch_std}"
        );
        assert!(
            (value - true_m).abs() < 3.0 * std,
            "{name}: track {value} ± {std}, truth {true_m}"
        );
        assert!(
            (batch - true_m).abs() < 3.0 * batch_std,
            "{name}: fit {batch} ± {batch_std}, truth {true_m}"
        );
    }
    assert!(tracker.started_from.is_some(), "the filter started");
    assert_eq!(poses.dropped(), 0);
    assert!(
        outcome.recording.poses.len() > 500,
        "{} poses",
        outcome.recording.poses.len()
    );
}

/// A pose reference that is not one: a topic the robot does not have, and one of another type,
/// are refused by name before anything is read.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_missing_or_mistyped_pose_topic_is_refused_by_name() {
    use odocal::ros::pose_source::RosPoseSource;
    let (_dir, yaml) = yaml_file("ros-live-pose-refused");
    let server = mock(&yaml, |_| {}).await;
    let timeout = Duration::from_secs(5);
    let err = match RosPoseSource::connect(&server.url(), "/amcl_pose", timeout).await {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a topic the robot does not publish was accepted"),
    };
    assert!(err.contains("/amcl_pose is not a topic"), "{err}");
    let err = match RosPoseSource::connect(&server.url(), "/imu", timeout).await {
        Err(e) => e.to_string(),
        Ok(_) => panic!("an IMU topic was taken as a pose reference"),
    };
    assert!(
        err.contains("/imu carries") && err.contains("PoseStamped"),
        "{err}"
    );
}

/// The rosbridge client against the mock over an in-memory duplex (no socket, no
/// pseudo-terminal): the WebSocket handshake, the first messages of every stream, a straight
/// motion measured by the wheels, a reading of the IMU and the controller's parameters from
/// the store, all as over TCP; the server counts the one connection it served.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_rosbridge_client_runs_against_an_in_memory_peer() {
    use odocal::ros::rosbridge::RosbridgeClient;
    let (_dir, yaml) = yaml_file("ros-in-memory");
    // Real time: at forty times the robot overshoots what the test wants to see.
    let server = mock(&yaml, |c| c.time_scale = 1.0).await;
    // Not a URL: only the stream can carry the connection.
    let cfg = ros_config("in-memory".into(), &yaml);
    let stream = server.connect_in_memory();
    let open = RosbridgeClient::connect_stream(stream, "in-memory", Duration::from_secs(5));
    let base = odocal::ros::live::connect_over(&cfg, open).await.unwrap();
    assert_eq!(server.state().counters.connections, 1);
    let done = base.drive.move_straight(0.2, 0.3).await.unwrap().unwrap();
    assert!((done.distance_m - 0.2).abs() < 0.02, "{done:?}");
    assert!(
        server.state().counters.commands > 0,
        "the robot was commanded"
    );
    let heading = base.heading.read().await.unwrap();
    assert!(heading.heading_rad.is_finite(), "{heading:?}");
    let configured = base.store.read().await.unwrap();
    let file = DiffDriveConfig::load(&yaml, "diff_drive_controller").unwrap();
    assert_eq!(configured, file.effective());
    // A peer that never answers the handshake is told within the timeout.
    let (silent, _peer) = tokio::io::duplex(1024);
    let e = RosbridgeClient::connect_stream(silent, "silent", Duration::from_millis(200))
        .await
        .err()
        .unwrap();
    assert!(e.to_string().contains("no answer within"), "{e}");
}
