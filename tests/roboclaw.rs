//! A RoboClaw, an NMEA compass and a robot profile as one base, against the mocks (one
//! simulated robot behind both): calibration fixes the robot and writes the profile; the
//! controller's serial timeout stops the robot when the host vanishes; a lost acknowledgement
//! never drives a leg twice.

mod common;

use odocal::base::Drive;
use odocal::kinematics::WheelParams;
use odocal::mock::roboclaw::{
    compass_of, robot, serve_roboclaw, spawn_robot, MockRoboClawConfig, SharedRobot,
};
use odocal::nmea::NmeaCompass;
use odocal::roboclaw::client::{RoboClaw, RoboClawConfig};
use odocal::roboclaw::drive::RoboClawDrive;
use odocal::roboclaw::profile::{Profile, ProfileStore};
use odocal::routine::config::RoutineConfig;
use odocal::routine::{run, Unattended};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

const PROFILE: &str = common::ROBOCLAW_PROFILE;

fn profile_file(name: &str) -> (PathBuf, PathBuf) {
    let dir = common::scratch(name);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("robot.toml");
    std::fs::write(&path, PROFILE).unwrap();
    (dir, path)
}

fn mock_config(time_scale: f64) -> MockRoboClawConfig {
    let mut truth = common::truth();
    truth.counts_per_wheel_rev = 4096.0;
    let mut cfg = MockRoboClawConfig::new(truth);
    // Wired as the profile says: left wheel on M2, right encoder counting down.
    cfg.left_on_m1 = false;
    cfg.right_encoder_sign = -1;
    cfg.noise.compass_sigma_rad = 0.05f64.to_radians();
    cfg.time_scale = time_scale;
    cfg.compass_hz = 20.0;
    cfg
}

/// A RoboClaw client on an in-memory link to the mock.
fn claw_on(robot_state: &SharedRobot) -> RoboClaw {
    let (host, dev) = tokio::io::duplex(4096);
    tokio::spawn(serve_roboclaw(dev, robot_state.clone()));
    RoboClaw::new(host, RoboClawConfig::default(), "duplex").unwrap()
}

fn compass_on(robot_state: &SharedRobot) -> NmeaCompass {
    let (host, dev) = tokio::io::duplex(4096);
    let (cfg, heading) = compass_of(robot_state);
    tokio::spawn(odocal::mock::nmea::serve_compass(dev, cfg, heading));
    NmeaCompass::new(host, "duplex", Duration::from_millis(500))
}

fn routine(dir: &Path) -> RoutineConfig {
    common::quick_routine(dir)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_roboclaw_and_a_compass_calibrate_the_robot_and_write_its_profile() {
    let (dir, path) = profile_file("roboclaw-e2e");
    let robot_state = spawn_robot(mock_config(20.0)).unwrap();
    let store = ProfileStore::open(&path).unwrap();
    let base = odocal::roboclaw::base(
        claw_on(&robot_state),
        Arc::new(compass_on(&robot_state)),
        store,
    )
    .await
    .unwrap();
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
    assert!(
        before > 3.0 && after * 10.0 < before,
        "{before}° → {after}°"
    );
    // The profile holds the heading-observable combinations of the truth: the diameter ratio
    // and the wheelbase over the left diameter (left wheel nominal).
    let written = Profile::load(&path).unwrap().params();
    let truth = common::truth();
    assert!(
        (written.e_d() / truth.e_d() - 1.0).abs() < 5e-4,
        "{written:?}"
    );
    let ratio = |p: &WheelParams| p.wheelbase_m / p.left_wheel_diameter_m;
    assert!(
        (ratio(&written) / ratio(&truth) - 1.0).abs() < 2e-3,
        "{written:?}"
    );
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(
        text.contains("# test robot") && text.contains("left_channel = \"M2\""),
        "{text}"
    );
    // One backup for the write, where the run was told to keep it (not in the profile's
    // folder), named after the profile and holding it whole.
    let beside: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains("odocal-backup"))
        .collect();
    assert!(beside.is_empty(), "nothing beside the profile");
    assert_eq!(
        report.backup_path.parent(),
        Some(dir.join("backups").as_path())
    );
    assert!(report
        .backup_path
        .file_name()
        .unwrap()
        .to_string_lossy()
        .starts_with("robot.toml.odocal-backup-"));
    let record = odocal::base::transaction::read_backup(&report.backup_path).unwrap();
    assert_eq!(record.text.as_deref(), Some(PROFILE));
    assert!(!robot(&robot_state).moving());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_serial_timeout_stops_the_robot_when_the_host_vanishes_mid_leg() {
    let (_dir, path) = profile_file("roboclaw-vanish");
    let robot_state = spawn_robot(mock_config(1.0)).unwrap();
    let profile = Arc::new(std::sync::RwLock::new(Profile::load(&path).unwrap()));
    let drive = RoboClawDrive::connect(claw_on(&robot_state), profile)
        .await
        .unwrap();
    let armed = drive
        .arm_watchdog(Duration::from_millis(200))
        .await
        .unwrap();
    assert_eq!(armed, Some(Duration::from_millis(200)));
    // A 5 m leg, abandoned after 300 ms: the host stops talking (no stop is sent).
    let leg = tokio::time::timeout(Duration::from_millis(300), drive.move_straight(5.0, 0.5)).await;
    assert!(leg.is_err(), "the leg cannot be done yet");
    std::mem::forget(drive);
    assert!(
        robot(&robot_state).moving(),
        "it was moving when the host went silent"
    );
    tokio::time::sleep(Duration::from_millis(500)).await;
    let r = robot(&robot_state);
    assert!(!r.moving(), "the serial timeout must stop it");
    assert_eq!(r.counters.serial_timeouts, 1);
    assert_eq!(
        r.counters.stops, 0,
        "stopped by the controller itself, not by a host command"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lost_acknowledgement_never_drives_a_leg_twice() {
    let (_dir, path) = profile_file("roboclaw-ack");
    let mut cfg = mock_config(10.0);
    cfg.lose_ack_rate = 1.0;
    let robot_state = spawn_robot(cfg).unwrap();
    let profile = Arc::new(std::sync::RwLock::new(Profile::load(&path).unwrap()));
    let drive = RoboClawDrive::connect(claw_on(&robot_state), profile)
        .await
        .unwrap();
    let start = robot(&robot_state).pose();
    let achieved = drive.move_straight(1.0, 0.5).await.unwrap().unwrap();
    let r = robot(&robot_state);
    assert_eq!(r.counters.drive_commands, 1, "the leg was sent once");
    assert!(r.counters.lost_acks >= 1);
    // One leg: a metre by the drive's odometry, a metre (±scale error) in truth.
    assert!((achieved.distance_m - 1.0).abs() < 1e-3, "{achieved:?}");
    let moved = r.pose().relative_to(&start).distance_m();
    assert!((moved - 1.0).abs() < 0.02, "moved {moved} m");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn something_else_on_the_port_is_not_a_roboclaw() {
    let (host, mut dev) = tokio::io::duplex(1024);
    tokio::spawn(async move {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let mut b = [0u8; 64];
        while let Ok(n) = dev.read(&mut b).await {
            if n == 0 {
                break;
            }
            let _ = dev.write_all(b"garbage!").await;
        }
    });
    let claw = RoboClaw::new(host, RoboClawConfig::default(), "/dev/ttyACM0").unwrap();
    let (_dir, path) = profile_file("roboclaw-wrong");
    let profile = Arc::new(std::sync::RwLock::new(Profile::load(&path).unwrap()));
    let err = match RoboClawDrive::connect(claw, profile).await {
        Err(e) => e.to_string(),
        Ok(_) => panic!("garbage is not a RoboClaw"),
    };
    assert!(
        err.contains("not a RoboClaw") && err.contains("/dev/ttyACM0"),
        "{err}"
    );
}

/// A port that never stops sending (a GPS, a console at the wrong baud) is named as not a
/// RoboClaw in bounded time: draining it before each attempt does not wait for a quiet that
/// never comes.
#[tokio::test(start_paused = true)]
async fn a_port_that_never_stops_sending_is_not_a_roboclaw_in_bounded_time() {
    let (host, mut dev) = tokio::io::duplex(1024);
    tokio::spawn(async move {
        use tokio::io::AsyncWriteExt;
        while dev.write_all(b"$GPGGA,chatter\r\n").await.is_ok() {
            tokio::time::sleep(std::time::Duration::from_millis(1)).await;
        }
    });
    let claw = RoboClaw::new(host, RoboClawConfig::default(), "/dev/ttyUSB9").unwrap();
    let (_dir, path) = profile_file("roboclaw-chatter");
    let profile = Arc::new(std::sync::RwLock::new(Profile::load(&path).unwrap()));
    let connect = RoboClawDrive::connect(claw, profile);
    let err = match tokio::time::timeout(std::time::Duration::from_secs(60), connect).await {
        Err(_) => panic!("still draining a chattering port after 60 s"),
        Ok(Err(e)) => e.to_string(),
        Ok(Ok(_)) => panic!("chatter is not a RoboClaw"),
    };
    assert!(err.contains("not a RoboClaw"), "{err}");
}

#[test]
fn calibrate_a_roboclaw_base_from_the_command_line_on_pseudo_terminals() {
    let (dir, path) = profile_file("roboclaw-cli");
    let profile = path.to_str().unwrap();
    let (mut mock, lines) = common::spawn_server_lines(
        "mock-roboclaw",
        &[
            "--profile",
            profile,
            "--time-scale",
            "20",
            "--compass-hz",
            "20",
            "--compass-sigma-deg",
            "0.05",
        ],
        2,
    );
    let (first, compass) = (lines[0].clone(), lines[1].clone());
    assert!(first.starts_with("roboclaw:/"), "{first}");
    assert!(compass.starts_with("nmea:/"), "{compass}");
    let heading = format!("{compass}?baud=115200");
    let v = common::odocal_json(&["heading", "--port", &heading, "--samples", "2", "--json"]);
    assert!(v["heading_rad"].as_f64().is_some_and(f64::is_finite), "{v}");
    let v = common::odocal_json(&["status", "--port", &first, "--json"]);
    assert!(v["firmware"].as_str().unwrap().contains("Roboclaw"), "{v}");
    let report_dir = dir.join("report");
    let v = {
        let mut args = vec![
            "calibrate",
            "--base",
            &first,
            "--heading",
            &heading,
            "--profile",
            profile,
        ];
        args.extend(common::QUICK_FLAGS);
        args.extend(["--report-dir", report_dir.to_str().unwrap(), "--json"]);
        common::odocal_json(&args)
    };
    let _ = mock.kill();
    // The run's backup is in its report directory, not beside the profile, and restores the
    // profile as it was.
    let backup = v["backup_path"].as_str().unwrap().to_string();
    assert_eq!(
        std::path::Path::new(&backup).parent(),
        Some(report_dir.as_path())
    );
    let calibrated = std::fs::read_to_string(&path).unwrap();
    assert_ne!(calibrated, common::ROBOCLAW_PROFILE);
    let (ok, _, err) = common::odocal(&["restore", &backup, "--yes"]);
    assert!(ok, "{err}");
    assert_eq!(
        std::fs::read_to_string(&path).unwrap(),
        common::ROBOCLAW_PROFILE
    );
    std::fs::write(&path, &calibrated).unwrap();
    let before = v["mean_abs_heading_error_before_deg"].as_f64().unwrap();
    let after = v["mean_abs_heading_error_after_deg"].as_f64().unwrap();
    assert!(after * 10.0 < before, "{before}° → {after}°");
    assert_eq!(v["base"]["drive"]["kind"], "roboclaw");
    assert_eq!(v["base"]["heading"]["kind"], "nmea0183");
    assert_eq!(v["base"]["store"]["kind"], "robot-profile");
    // And the result exports to ros2_control like any other.
    let yaml = dir.join("diff_drive.yaml");
    let (ok, _, err) = common::odocal(&[
        "export",
        "--from",
        report_dir.join("report.json").to_str().unwrap(),
        "--ros2",
        yaml.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(std::fs::read_to_string(&yaml)
        .unwrap()
        .contains("wheel_separation_multiplier: 0.97"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lost_answers_are_recovered_by_retried_reads_and_a_brown_out_is_seen() {
    let mut cfg = mock_config(10.0);
    cfg.lose_answer_rate = 0.3;
    let robot_state = spawn_robot(cfg).unwrap();
    let claw = claw_on(&robot_state);
    // Reads are safe to repeat: 30 % of answers lost, every read still completes.
    let mut ok = 0;
    for _ in 0..50 {
        if claw.encoders().await.is_ok() {
            ok += 1;
        }
    }
    assert!(ok >= 48, "{ok} of 50 reads completed");
    assert!(robot(&robot_state).counters.lost_answers > 5);
    // A brown-out resets the controller: its encoders read zero again.
    robot(&robot_state).brown_out();
    let (_dir, path) = profile_file("roboclaw-brownout");
    let profile = Arc::new(std::sync::RwLock::new(Profile::load(&path).unwrap()));
    let drive = RoboClawDrive::connect(claw, profile).await.unwrap();
    drive.move_straight(0.2, 0.5).await.unwrap();
    robot(&robot_state).brown_out();
    let (m1, m2) = odocal::roboclaw::client::RoboClaw::encoders(&claw_on(&robot_state))
        .await
        .unwrap();
    assert_eq!((m1, m2), (0, 0));
}

/// Virtual time: the budget is a second of silence.
#[tokio::test(start_paused = true)]
async fn answers_with_bad_crcs_are_refused_as_such_and_a_silent_port_times_out() {
    use odocal::roboclaw::client::RoboClawError;
    // A device that answers every read with the right length but a corrupted CRC.
    let (host, mut dev) = tokio::io::duplex(1024);
    tokio::spawn(async move {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let mut b = [0u8; 2];
        while dev.read_exact(&mut b).await.is_ok() {
            // READ_ENCODERS: 8 data bytes, then a CRC that is off by one.
            let mut crc = odocal::roboclaw::packet::CRC16.digest();
            crc.update(&b);
            crc.update(&[0u8; 8]);
            let bad = crc.finalize().wrapping_add(1).to_be_bytes();
            let _ = dev
                .write_all(&[0, 0, 0, 0, 0, 0, 0, 0, bad[0], bad[1]])
                .await;
        }
    });
    let claw = RoboClaw::new(host, RoboClawConfig::default(), "duplex").unwrap();
    match claw.encoders().await {
        Err(RoboClawError::Crc { command, attempts }) => assert_eq!((command, attempts), (78, 3)),
        other => panic!("expected a CRC error, got {other:?}"),
    }
    // A port where nothing answers: retried until the budget (a second before the serial
    // timeout is set) is spent, then a timeout naming the command.
    let (host, _dev) = tokio::io::duplex(1024);
    let claw = RoboClaw::new(host, RoboClawConfig::default(), "duplex").unwrap();
    let started = tokio::time::Instant::now();
    match claw.battery_v().await {
        Err(RoboClawError::Timeout {
            command, attempts, ..
        }) => assert!(command == 24 && attempts > 3, "{command} {attempts}"),
        other => panic!("expected a timeout, got {other:?}"),
    }
    let took = started.elapsed();
    assert!(
        took >= Duration::from_millis(900) && took <= Duration::from_millis(1300),
        "{took:?}"
    );
    // A write answered with something other than the acknowledgement is a NAK, not success.
    let (host, mut dev) = tokio::io::duplex(1024);
    tokio::spawn(async move {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let mut b = [0u8; 5];
        while dev.read_exact(&mut b).await.is_ok() {
            let _ = dev.write_all(&[0x00]).await;
        }
    });
    let claw = RoboClaw::new(host, RoboClawConfig::default(), "duplex").unwrap();
    let err = claw
        .write(odocal::roboclaw::packet::cmd::SET_SERIAL_TIMEOUT, &[5])
        .await
        .unwrap_err();
    assert!(
        matches!(
            err,
            RoboClawError::Nak {
                command: 14,
                got: 0
            }
        ),
        "{err:?}"
    );
}

/// A controller that answers every read of the battery (12.3 V), each answer `late`, and
/// stays silent for `stall` before its `stall_at`-th answer (a host or an adapter that stops
/// for a while).
fn slow_controller(late: Duration, stall_at: usize, stall: Duration) -> tokio::io::DuplexStream {
    let (host, mut dev) = tokio::io::duplex(4096);
    tokio::spawn(async move {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let mut b = [0u8; 2];
        let mut n = 0;
        while dev.read_exact(&mut b).await.is_ok() {
            n += 1;
            if n == stall_at {
                tokio::time::sleep(stall).await;
            }
            tokio::time::sleep(late).await;
            let data = 123u16.to_be_bytes();
            let mut crc = odocal::roboclaw::packet::CRC16.digest();
            crc.update(&b);
            crc.update(&data);
            let c = crc.finalize().to_be_bytes();
            if dev
                .write_all(&[data[0], data[1], c[0], c[1]])
                .await
                .is_err()
            {
                return;
            }
        }
    });
    host
}

/// Link budgets, not attempt counts (virtual time): answers 40 ms late are read once the
/// adapter's latency is measured, and a 400 ms stall in the middle of the reads costs
/// nothing; only silence past the budget fails.
#[tokio::test(start_paused = true)]
async fn late_answers_and_stalls_shorter_than_the_budget_cost_nothing() {
    let claw = RoboClaw::new(
        slow_controller(Duration::from_millis(40), 8, Duration::from_millis(400)),
        RoboClawConfig::default(),
        "duplex",
    )
    .unwrap();
    let latency = claw.measure_latency().await.unwrap();
    assert!(latency >= Duration::from_millis(15), "{latency:?}");
    for _ in 0..10 {
        assert!((claw.battery_v().await.unwrap() - 12.3).abs() < 1e-9);
    }
    // A stall of 1.5 s: past the default budget a read fails; within a budget of 2 s (what a
    // serial timeout of 2 s sets) it does not.
    let claw = RoboClaw::new(
        slow_controller(Duration::ZERO, 1, Duration::from_millis(1500)),
        RoboClawConfig::default(),
        "duplex",
    )
    .unwrap();
    assert!(claw.battery_v().await.is_err());
    let claw = RoboClaw::new(
        slow_controller(Duration::ZERO, 1, Duration::from_millis(1500)),
        RoboClawConfig {
            budget: Duration::from_secs(2),
            ..RoboClawConfig::default()
        },
        "duplex",
    )
    .unwrap();
    assert!((claw.battery_v().await.unwrap() - 12.3).abs() < 1e-9);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_encoder_counting_down_through_zero_is_no_preflight_warning() {
    let (_dir, path) = profile_file("roboclaw-wrap");
    let robot_state = spawn_robot(mock_config(10.0)).unwrap();
    let profile = Arc::new(std::sync::RwLock::new(Profile::load(&path).unwrap()));
    let drive = RoboClawDrive::connect(claw_on(&robot_state), profile)
        .await
        .unwrap();
    // The right encoder (M1) counts down driving forward: from zero it wraps below it, and the
    // controller sets M1's underflow bit until it is read.
    drive.move_straight(0.2, 0.5).await.unwrap();
    let claw = claw_on(&robot_state);
    let (m1, _) = claw.encoders().await.unwrap();
    assert!(m1 > u32::MAX / 2, "M1 wrapped below zero: {m1}");
    let check = drive.preflight().await.unwrap();
    assert!(
        check.warnings.is_empty() && check.faults.is_empty(),
        "{check:?}"
    );
    let (_, status) = claw.encoder(1).await.unwrap();
    assert_eq!(
        status & odocal::roboclaw::packet::encoder_status::UNDERFLOW,
        0,
        "the preflight read cleared it"
    );
}

/// The port belongs to the client's task, not to its callers: a caller that gives up while a
/// write waits for its acknowledgement (a timeout around it, Ctrl-C) leaves the task to read
/// it, so the next read starts on a clean line and is sent once. (Were the port shared under
/// a lock, the late 0xFF would have been read as the start of the battery's answer, failed its
/// CRC and had the request sent again.)
#[tokio::test(start_paused = true)]
async fn a_caller_that_gives_up_never_cuts_a_transaction_in_half() {
    use odocal::io::transport::{self, Deadline, Read};
    use odocal::roboclaw::packet::{cmd, ACK, CRC16};
    let (host, mut dev) = transport::pair(256);
    let claw = RoboClaw::new(host, RoboClawConfig::default(), "pair").unwrap();
    let peer = tokio::spawn(async move {
        let mut seen = Vec::new();
        // The write: address, command, 8 data bytes, CRC; acknowledged 25 ms later.
        let mut write = [0u8; 12];
        let got = transport::read_exact_by(&mut dev, &mut write, Deadline::never()).await;
        assert_eq!(got.unwrap(), Read::Got(12));
        seen.push(write[1]);
        tokio::time::sleep(Duration::from_millis(25)).await;
        transport::write_all_by(&mut dev, &[ACK], Deadline::never())
            .await
            .unwrap();
        // Read requests (address, command), each answered at once with 12.3 V.
        let mut request = [0u8; 2];
        let quiet = || Deadline::after(Duration::from_millis(300));
        while let Ok(Read::Got(_)) = transport::read_exact_by(&mut dev, &mut request, quiet()).await
        {
            seen.push(request[1]);
            let data = 123u16.to_be_bytes();
            let mut crc = CRC16.digest();
            crc.update(&request);
            crc.update(&data);
            let mut answer = data.to_vec();
            answer.extend_from_slice(&crc.finalize().to_be_bytes());
            transport::write_all_by(&mut dev, &answer, Deadline::never())
                .await
                .unwrap();
        }
        seen
    });
    let speeds = claw.write(cmd::DRIVE_SPEEDS, &[0; 8]);
    let gave_up = tokio::time::timeout(Duration::from_millis(5), speeds).await;
    assert!(
        gave_up.is_err(),
        "the acknowledgement came before the caller gave up"
    );
    let volts = claw.battery_v().await.unwrap();
    assert!((volts - 12.3).abs() < 1e-9, "{volts} V");
    drop(claw);
    let seen = peer.await.unwrap();
    assert_eq!(seen, vec![cmd::DRIVE_SPEEDS, cmd::READ_MAIN_BATTERY]);
}

/// `odocal status` on a port where another device talks (an NMEA compass: the wrong device on
/// the port) says that no RoboClaw answered the version request and what may be wrong, instead
/// of a bare timeout or a misread answer.
#[tokio::test]
async fn status_on_a_port_where_another_device_talks_says_it_is_not_a_roboclaw() {
    use odocal::spec::DriveSpec;
    let compass = odocal::mock::pty::spawn_on_pty::<()>(Box::new(|master| {
        Box::pin(async move {
            use tokio::io::AsyncWriteExt;
            loop {
                master.write_all(b"$HEHDT,123.4,T*2D\r\n").await?;
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        })
    }))
    .unwrap();
    let drive: DriveSpec = format!("roboclaw:{}", compass.path).parse().unwrap();
    let err = drive
        .status()
        .await
        .expect_err("a compass taken for a RoboClaw");
    let text = err.to_string();
    assert!(text.contains("no answer to the version request"), "{text}");
    assert!(
        text.contains("not a RoboClaw, or the wrong baud or address"),
        "{text}"
    );
    assert!(text.contains(&compass.path), "{text}");
}

/// A caller that gives up on a read the controller never answers (its transmit line broken,
/// say) does not hold the port for the read's whole budget: the read ends after the attempt
/// under way, and the stop that follows goes out at once.
#[tokio::test(start_paused = true)]
async fn a_stop_after_an_abandoned_read_does_not_wait_out_the_read() {
    use odocal::io::transport::{self, Deadline, Read};
    use odocal::roboclaw::packet::{cmd, ACK};
    let (host, mut dev) = transport::pair(256);
    let claw = RoboClaw::new(host, RoboClawConfig::default(), "pair").unwrap();
    let peer = tokio::spawn(async move {
        let mut seen = Vec::new();
        let mut head = [0u8; 2];
        let quiet = || Deadline::after(Duration::from_secs(2));
        while let Ok(Read::Got(_)) = transport::read_exact_by(&mut dev, &mut head, quiet()).await {
            seen.push(head[1]);
            // Reads go unanswered; the stop (8 data bytes and the CRC) is acknowledged.
            if head[1] == cmd::DRIVE_SPEEDS {
                let mut rest = [0u8; 10];
                let got = transport::read_exact_by(&mut dev, &mut rest, quiet()).await;
                assert_eq!(got.unwrap(), Read::Got(10));
                transport::write_all_by(&mut dev, &[ACK], Deadline::never())
                    .await
                    .unwrap();
            }
        }
        seen
    });
    let started = tokio::time::Instant::now();
    let read = tokio::time::timeout(Duration::from_millis(100), claw.battery_v()).await;
    assert!(read.is_err(), "a read nobody answers came back");
    assert!(
        claw.budget() >= Duration::from_secs(1),
        "{:?}",
        claw.budget()
    );
    let stopped = tokio::time::timeout(Duration::from_millis(300), claw.stop()).await;
    assert!(
        matches!(stopped, Ok(Ok(()))),
        "the stop waited behind the read"
    );
    let took = started.elapsed();
    assert!(took < Duration::from_millis(400), "{took:?}");
    drop(claw);
    let seen = peer.await.unwrap();
    let (stop, reads) = seen.split_last().unwrap();
    assert_eq!(*stop, cmd::DRIVE_SPEEDS, "{seen:?}");
    assert!(
        (2..=3).contains(&reads.len()) && reads.iter().all(|c| *c == cmd::READ_MAIN_BATTERY),
        "the read is asked again until its caller goes, then no more: {seen:?}"
    );
}
