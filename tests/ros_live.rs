//! Calibrating a ROS robot live through rosbridge, against the mock rosbridge server (loopback
//! only): the routine writes multipliers into the controller's YAML that fix the robot, and
//! the robot is stopped (zero twist) on Ctrl-C, on an error, and when rosbridge vanishes.

mod common;

use odocal::base::Base;
use odocal::mock::rosbridge::{EffortStyle, MockRosConfig, MockRosbridge};
use odocal::ros::live::{connect, RosBaseConfig};
use odocal::ros::yaml::DiffDriveConfig;
use odocal::routine::config::RoutineConfig;
use odocal::routine::{run, RoutineError, RoutineEvent, RoutineUi, Unattended};
use std::path::{Path, PathBuf};
use std::time::Duration;
use tokio_util::sync::CancellationToken;

const YAML: &str = common::DIFF_DRIVE_YAML;

/// The two end-to-end calibrations run one at a time: each drives a robot at many times real
/// speed, and two at once on a 2-core machine starve each other's control loops.
static END_TO_END: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn calibrating_through_rosbridge_writes_multipliers_that_fix_the_robot() {
    let _one_at_a_time = END_TO_END.lock().await;
    let (dir, yaml) = yaml_file("ros-live");
    // Joint states as joint_state_broadcaster sends them for wheels without an effort
    // interface, through a rosbridge that writes NaN as the bare token (rosbridge_suite #916):
    // not JSON, and odocal never reads `effort`, so they must not cost a message.
    let server = mock(&yaml, |c| c.effort = EffortStyle::BareNan).await;
    let base = connect(&ros_config(server.url(), &yaml)).await.unwrap();
    let report = run(
        &base,
        &routine(&dir),
        None,
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await
    .unwrap();
    let before = report.mean_abs_heading_error_before_deg;
    let after = report.mean_abs_heading_error_after_deg.unwrap();
    assert!(before > 3.0, "the robot is mis-calibrated: {before}°");
    assert!(
        after * 10.0 < before,
        "mean |heading error| {before}° → {after}°"
    );
    // The YAML holds the multipliers (the rest of the file as it was), with its backup beside it.
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
    assert_eq!(written.wheel_separation_m, 0.39);
    let text = std::fs::read_to_string(&yaml).unwrap();
    assert!(
        text.contains("update_rate: 100  # Hz") && text.contains("cmd_vel_timeout: 0.5  # s"),
        "{text}"
    );
    let backups: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| {
            e.file_name()
                .to_string_lossy()
                .starts_with("diff_drive.yaml.odocal-backup-")
        })
        .collect();
    assert_eq!(backups.len(), 1);
    assert_eq!(std::fs::read_to_string(backups[0].path()).unwrap(), YAML);
    assert_eq!(
        last_command(&server).await,
        (0.0, 0.0),
        "the last word is a zero twist"
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
    let err = run(
        &base,
        &routine(&dir),
        None,
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await
    .unwrap_err();
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
    let err = run(
        &base,
        &routine(&dir),
        None,
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await
    .unwrap_err();
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
    let _one_at_a_time = END_TO_END.blocking_lock();
    let (dir, yaml) = yaml_file("ros-cli");
    let yaml_s = yaml.to_str().unwrap();
    let (mut server, url) = common::spawn_server(
        "mock-rosbridge",
        &[
            "--ros-yaml",
            yaml_s,
            "--port",
            "0",
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
    let started = std::time::Instant::now();
    let err = base.drive.move_straight(1.0, 0.3).await.unwrap_err();
    let took = started.elapsed();
    let text = err.to_string();
    assert!(took < Duration::from_secs(2), "{took:?}: {text}");
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

/// `--ros-set-live` on a controller that does not answer for its multipliers (here: the running
/// controller has another name): refused before the robot moves, naming the service.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn set_live_is_proved_before_the_robot_moves() {
    let (dir, yaml) = yaml_file("ros-set-live");
    let server = mock(&yaml, |c| {
        c.controller.controller = "base_controller".into();
        c.time_scale = 1.0;
    })
    .await;
    let mut cfg = ros_config(server.url(), &yaml);
    cfg.set_live = true;
    let base = connect(&cfg).await.unwrap();
    let err = run(
        &base,
        &routine(&dir),
        None,
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await
    .unwrap_err();
    let text = err.to_string();
    assert!(
        text.contains("--ros-set-live") && text.contains("/diff_drive_controller/get_parameters"),
        "{text}"
    );
    assert_eq!(server.state().counters.commands, 0, "the robot never moved");
    assert_eq!(std::fs::read_to_string(&yaml).unwrap(), YAML);
}

/// `--ros-set-live` on a controller that has its multipliers: a committed write lands in the
/// file and on the running controller, as its `get_parameters` reads them.
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
