//! The HAL client against the mock device: over a real pseudo-terminal opened by path (as a user
//! opens a USB adapter) and over an in-memory duplex, clean and with injected faults.

use odocal::base::{Base, MotionGuard};
mod common;

use odocal::calibration::{estimate, Method, RunMeasurement, SquareTest};
use odocal::hal::link::LinkConfig;
use odocal::hal::{open_port, Client, HalError, LinkError};
use odocal::kinematics::{wrap_angle, Direction, SplitConvention, WheelParams};
use odocal::mock::{
    lock, spawn_duplex, spawn_pty, FaultConfig, MockConfig, MockDevice, ServeEnd, SharedDevice,
    TimeMode,
};
use odocal::protocol::message::{
    HelloRequest, MotionMode, NackCode, ParamSource, ParamsBlock, WatchdogState,
};
use odocal::protocol::Request;
use odocal::routine::square::{self, SquareCommand, SquareRecord};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn nominal() -> WheelParams {
    common::nominal()
}

fn device(compass_sigma_deg: f64, seed: u64) -> SharedDevice {
    common::mock_device(compass_sigma_deg, seed)
}

fn fast_link() -> LinkConfig {
    LinkConfig {
        response_time: Duration::from_millis(10),
        margin: Duration::from_millis(5),
        retries: 12,
        ..LinkConfig::default()
    }
}

fn square(side_m: f64, direction: Direction) -> SquareCommand {
    SquareCommand {
        side_m,
        direction,
        max_speed_m_s: 0.5,
        max_rate_rad_s: 2.0,
        heading_samples: 3,
        settle: Duration::ZERO,
        stream_period: Duration::from_millis(20),
    }
}

/// Drives one square on the client through the seam, as the routine does.
async fn run_square(
    client: &Client,
    cmd: &SquareCommand,
) -> Result<SquareRecord, odocal::routine::RoutineError> {
    square::run_square(&Base::single(client.clone()), cmd, |_| {}).await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pty_handshake_parameters_and_power_cycle() {
    let dev = device(0.0, 1);
    let server = spawn_pty(dev.clone(), TimeMode::Virtual, FaultConfig::default()).unwrap();
    let (client, info) = open_port(&server.path, 115_200).await.unwrap();
    assert_eq!((info.major, info.firmware_id.as_str()), (1, "odocal-mock"));
    assert_eq!(
        client.get_params(ParamSource::Active).await.unwrap(),
        nominal()
    );
    // Nothing saved yet: the stored copy is missing.
    assert_eq!(
        client
            .get_params(ParamSource::Stored)
            .await
            .unwrap_err()
            .nack_code(),
        Some(NackCode::StorageFailure)
    );

    let saved = WheelParams {
        right_wheel_diameter_m: 0.1488,
        wheelbase_m: 0.3806,
        ..nominal()
    };
    let applied = client.set_params(&saved).await.unwrap();
    assert!((applied.wheelbase_m - 0.3806).abs() < 1e-9);
    client.save_params().await.unwrap();
    let unsaved = WheelParams {
        wheelbase_m: 0.4,
        ..nominal()
    };
    client.set_params(&unsaved).await.unwrap();
    assert!(
        (client
            .get_params(ParamSource::Active)
            .await
            .unwrap()
            .wheelbase_m
            - 0.4)
            .abs()
            < 1e-9
    );

    lock(&dev).power_cycle().unwrap();
    let after = client.get_params(ParamSource::Active).await.unwrap();
    assert!(
        (after.wheelbase_m - 0.3806).abs() < 1e-9,
        "unsaved change survived: {after:?}"
    );
    assert!((after.right_wheel_diameter_m - 0.1488).abs() < 1e-9);
    assert_eq!(after, client.get_params(ParamSource::Stored).await.unwrap());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pty_square_heading_errors_match_the_simulated_truth() {
    let sigma_deg = 0.37;
    let dev = device(sigma_deg, 7);
    let server = spawn_pty(dev.clone(), TimeMode::Virtual, FaultConfig::default()).unwrap();
    let (client, _) = open_port(&server.path, 115_200).await.unwrap();
    for direction in [Direction::Cw, Direction::Ccw] {
        let start = lock(&dev).sim().pose().heading_rad;
        let cmd = SquareCommand {
            heading_samples: 5,
            ..square(4.0, direction)
        };
        let rec = run_square(&client, &cmd).await.unwrap();
        let truth = wrap_angle(lock(&dev).sim().pose().heading_rad - start);
        // Each end averages 5 readings: the error's σ is σ·√(2/5); allow 4 of those.
        let tol = 4.0 * sigma_deg.to_radians() * (2.0f64 / 5.0).sqrt();
        assert!(
            (rec.heading_error_rad - truth).abs() < tol,
            "{direction:?}: measured {} vs true {truth}",
            rec.heading_error_rad
        );
        // The robot really is mis-calibrated: the error is far above the noise.
        assert!(truth.abs() > 10.0 * tol);
    }
}

/// Drives `n` squares each way over a link with `faults` and returns the test and the device.
async fn ten_squares(faults: FaultConfig) -> (SquareTest, SharedDevice, Client) {
    let dev = device(0.37, 99);
    let (stream, _task) = spawn_duplex(dev.clone(), TimeMode::Virtual, faults);
    let (client, _) = Client::connect(stream, fast_link()).await.unwrap();
    let mut test = SquareTest {
        side_m: 4.0,
        wheelbase_m: 0.39,
        cw: Vec::new(),
        ccw: Vec::new(),
    };
    for direction in [Direction::Cw, Direction::Ccw] {
        for _ in 0..5 {
            let rec = run_square(&client, &square(4.0, direction)).await.unwrap();
            let m = RunMeasurement {
                heading_error_rad: rec.heading_error_rad,
                final_xy_m: None,
                ..RunMeasurement::default()
            };
            match direction {
                Direction::Cw => test.cw.push(m),
                Direction::Ccw => test.ccw.push(m),
            }
        }
    }
    (test, dev, client)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_noisy_link_gives_the_same_estimates_and_executes_nothing_twice() {
    let (clean, clean_dev, _) = ten_squares(FaultConfig::default()).await;
    let faults = FaultConfig {
        corrupt_byte_rate: 0.01,
        drop_frame_rate: 0.05,
        seed: 5,
        ..FaultConfig::default()
    };
    let (noisy, noisy_dev, client) = ten_squares(faults).await;
    let stats = client.stats();
    assert!(
        stats.retries > 10,
        "the faults must actually bite: {stats:?}"
    );
    assert!(stats.decoder_dropped_bytes > 0);
    assert_eq!(noisy, clean, "same seed, same measurements");
    let a = estimate(Method::Exact, &clean, SplitConvention::LeftNominal).unwrap();
    let b = estimate(Method::Exact, &noisy, SplitConvention::LeftNominal).unwrap();
    assert_eq!(a, b);
    assert!(
        (a.e_b - 0.976).abs() < 0.002 && (a.e_d - 0.992).abs() < 0.0005,
        "{a:?}"
    );
    for dev in [&clean_dev, &noisy_dev] {
        let c = lock(dev).counters();
        assert_eq!(c.motions_accepted, 80, "{c:?}");
        assert_eq!(c.motions_completed, 80);
    }
    assert!(lock(&noisy_dev).counters().replayed_answers > 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn busy_answers_are_retried_without_double_execution() {
    let faults = FaultConfig {
        busy_every: Some(3),
        ..FaultConfig::default()
    };
    let dev = device(0.0, 3);
    let (stream, _task) = spawn_duplex(dev.clone(), TimeMode::Virtual, faults);
    let (client, _) = Client::connect(stream, fast_link()).await.unwrap();
    run_square(&client, &square(1.0, Direction::Ccw))
        .await
        .unwrap();
    assert!(client.stats().busy > 0);
    assert_eq!(lock(&dev).counters().motions_accepted, 8);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_that_vanishes_mid_move_gives_a_typed_error_and_stops() {
    let dev = device(0.0, 4);
    let faults = FaultConfig {
        // HELLO, watchdog, move, then two status polls: the device vanishes mid-move.
        disconnect_after_frames: Some(5),
        ..FaultConfig::default()
    };
    let (stream, task) = spawn_duplex(dev.clone(), TimeMode::RealTime { scale: 1.0 }, faults);
    // Three attempts and no time budget: the vanished device is noticed at once.
    let config = LinkConfig {
        retries: 2,
        retry_budget: Duration::ZERO,
        ..fast_link()
    };
    let (client, _) = Client::connect(stream, config).await.unwrap();
    client
        .configure_watchdog(Some(Duration::from_millis(150)))
        .await
        .unwrap();
    let mut done = client.subscribe_motion_done();
    let accepted = client
        .move_straight(2.0, 0.2, MotionMode::Replace)
        .await
        .unwrap();
    let started = Instant::now();
    let err = client
        .wait_motion(accepted.motion_id, 1, Duration::from_secs(20), &mut done)
        .await
        .unwrap_err();
    let took = started.elapsed();
    assert!(
        matches!(
            err,
            HalError::Link(LinkError::Timeout { .. } | LinkError::Closed)
        ),
        "{err:?}"
    );
    // A heartbeat or poll answered, then one request's three attempts at ~15 ms each.
    assert!(took < Duration::from_millis(500), "error took {took:?}");
    assert_eq!(task.await.unwrap().unwrap(), ServeEnd::Disconnected);
    let d = lock(&dev);
    assert!(!d.is_moving(), "the base must be stopped");
    assert_eq!(d.status().watchdog_state, WatchdogState::Tripped);
    assert_eq!(d.counters().watchdog_trips, 1);
    assert!(
        d.sim().pose().x_m < 0.2,
        "stopped early, at {} m",
        d.sim().pose().x_m
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_host_trips_the_watchdog() {
    let dev = device(0.0, 5);
    let (stream, _task) = spawn_duplex(
        dev.clone(),
        TimeMode::RealTime { scale: 1.0 },
        FaultConfig::default(),
    );
    let (client, _) = Client::connect(stream, fast_link()).await.unwrap();
    client
        .configure_watchdog(Some(Duration::from_millis(100)))
        .await
        .unwrap();
    client
        .move_straight(1.0, 0.2, MotionMode::Replace)
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(400)).await;
    {
        let d = lock(&dev);
        assert!(!d.is_moving());
        assert_eq!(d.counters().watchdog_trips, 1);
        let x = d.sim().pose().x_m;
        assert!(x > 0.005 && x < 0.06, "moved {x} m in ~0.1 s at 0.2 m/s");
    }
    // While tripped, motions are refused until the host acknowledges with a heartbeat.
    let refused = client
        .move_straight(0.1, 0.2, MotionMode::Replace)
        .await
        .unwrap_err();
    assert_eq!(refused.nack_code(), Some(NackCode::InvalidState));
    client.heartbeat().await.unwrap();
    client
        .move_straight(0.01, 0.2, MotionMode::Replace)
        .await
        .unwrap();
    client.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_parameter_writes_are_refused_and_change_nothing() {
    let dev = device(0.0, 6);
    let (stream, _task) = spawn_duplex(
        dev.clone(),
        TimeMode::RealTime { scale: 1.0 },
        FaultConfig::default(),
    );
    let (client, _) = Client::connect(stream, fast_link()).await.unwrap();
    let before = client.get_params(ParamSource::Active).await.unwrap();
    let good = ParamsBlock::try_from(&before).unwrap();
    for (block, field) in [
        (
            ParamsBlock {
                left_wheel_diameter_nm: 0,
                ..good
            },
            0,
        ),
        (
            ParamsBlock {
                right_wheel_diameter_nm: 100_000_000,
                ..good
            },
            1,
        ),
        (
            ParamsBlock {
                wheelbase_nm: 5,
                ..good
            },
            2,
        ),
        (
            ParamsBlock {
                counts_per_wheel_rev_micro: 0,
                ..good
            },
            3,
        ),
    ] {
        let err = client.request(Request::SetParams(block)).await.unwrap_err();
        match err {
            HalError::Nack { nack, .. } => {
                assert_eq!((nack.code, nack.detail), (NackCode::OutOfRange, field))
            }
            other => panic!("expected OUT_OF_RANGE, got {other:?}"),
        }
    }
    // NaN never leaves the host.
    let nan = WheelParams {
        wheelbase_m: f64::NAN,
        ..before
    };
    assert!(matches!(
        client.set_params(&nan).await,
        Err(HalError::InvalidArgument(_))
    ));
    // Saving or writing while moving is refused too.
    client
        .move_straight(1.0, 0.2, MotionMode::Replace)
        .await
        .unwrap();
    assert_eq!(
        client.save_params().await.unwrap_err().nack_code(),
        Some(NackCode::InvalidState)
    );
    assert_eq!(
        client.set_params(&before).await.unwrap_err().nack_code(),
        Some(NackCode::InvalidState)
    );
    client.stop().await.unwrap();
    assert_eq!(
        client.get_params(ParamSource::Active).await.unwrap(),
        before
    );
    assert!(lock(&dev).stored_params().is_none());
    // Over-limit wheel speeds are refused naming the wheel; unsendable ones never leave the
    // host.
    let err = client.wheel_speed(0.1, 2.0, None).await.unwrap_err();
    assert!(
        matches!(err, HalError::Nack { nack, .. } if nack.code == NackCode::OutOfRange && nack.detail == 1),
        "{err:?}"
    );
    assert!(matches!(
        client.wheel_speed(f64::NAN, 0.1, None).await,
        Err(HalError::InvalidArgument(_))
    ));
    // Over-limit speeds are refused with the field named.
    let fast = client
        .move_straight(1.0, 5.0, MotionMode::Replace)
        .await
        .unwrap_err();
    assert!(matches!(fast, HalError::Nack { nack, .. } if nack.detail == 1));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_incompatible_host_version_is_refused() {
    let dev = device(0.0, 8);
    let (stream, _task) = spawn_duplex(dev, TimeMode::Virtual, FaultConfig::default());
    let (client, _) = Client::connect(stream, fast_link()).await.unwrap();
    let err = client
        .request(Request::Hello(HelloRequest {
            host_major: 2,
            host_min_minor: 0,
        }))
        .await
        .unwrap_err();
    assert_eq!(err.nack_code(), Some(NackCode::VersionMismatch));
    // SPEC 1.1: the NACK says which version the device speaks.
    match &err {
        HalError::Nack { nack, .. } => assert_eq!(nack.detail, 0x11),
        other => panic!("{other:?}"),
    }
    // And the host turns that into words naming both versions (or saying a 1.0 device did
    // not tell).
    let told = LinkError::VersionMismatch {
        device: Some((2, 3)),
        host: 1,
    };
    assert!(
        told.to_string()
            .contains("speaks protocol 2.3, this host speaks 1.x"),
        "{told}"
    );
    let untold = LinkError::VersionMismatch {
        device: None,
        host: 1,
    };
    assert!(
        untold.to_string().contains("does not say which"),
        "{untold}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dropping_a_motion_guard_stops_the_base() {
    let dev = device(0.0, 9);
    let (stream, _task) = spawn_duplex(
        dev.clone(),
        TimeMode::RealTime { scale: 1.0 },
        FaultConfig::default(),
    );
    let (client, _) = Client::connect(stream, fast_link()).await.unwrap();
    {
        let drive: Arc<dyn odocal::base::Drive> = Arc::new(client.clone());
        let _guard = MotionGuard::new(&drive);
        client
            .move_straight(1.0, 0.2, MotionMode::Replace)
            .await
            .unwrap();
        // An error or a cancelled future here drops the guard.
    }
    tokio::time::sleep(Duration::from_millis(50)).await;
    let d = lock(&dev);
    assert!(!d.is_moving());
    assert_eq!(d.counters().stops, 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn telemetry_at_200_hz_for_10_s_arrives_complete_and_unwrapped() {
    let dev = device(0.0, 10);
    let server = spawn_pty(dev.clone(), TimeMode::Virtual, FaultConfig::default()).unwrap();
    let (client, _) = open_port(&server.path, 115_200).await.unwrap();
    let mut rx = client.subscribe();
    client
        .configure_telemetry(Some(Duration::from_millis(5)))
        .await
        .unwrap();
    // 2 m at 0.2 m/s: 10 s of device time, 2000 samples at 200 Hz.
    client
        .move_straight(2.0, 0.2, MotionMode::Replace)
        .await
        .unwrap();
    let mut samples = Vec::new();
    while samples.len() < 2000 {
        match tokio::time::timeout(Duration::from_secs(5), rx.recv()).await {
            Ok(Ok(s)) => samples.push(s),
            other => panic!(
                "telemetry stopped after {} samples: {other:?}",
                samples.len()
            ),
        }
    }
    let stats = client.stats();
    assert_eq!(stats.telemetry_dropped, 0);
    assert!(samples
        .windows(2)
        .all(|w| w[1].sample_index == w[0].sample_index + 1));
    let span = samples[1999].device_time_s - samples[0].device_time_s;
    assert!((span - 1999.0 * 0.005).abs() < 1e-6, "span {span}");
    // Counts only grow while driving forward, and end at the 2 m target.
    assert!(samples
        .windows(2)
        .all(|w| w[1].left_counts >= w[0].left_counts));
    let (l, r) = lock(&dev).sim().encoder_counts();
    let target = 2.0 / (std::f64::consts::PI * 0.15) * 4096.0;
    assert!((l - target).abs() < 1.0 && (r - target).abs() < 1.0);
    assert!((samples[1999].left_counts as f64 - target).abs() < target * 0.001);
}

#[test]
fn a_mock_whose_factory_parameters_cannot_travel_on_the_wire_is_refused() {
    let mut cfg = MockConfig::with_ratios(nominal(), 0.976, 0.992).unwrap();
    cfg.factory.wheelbase_m = 5.0; // the wire's limit is 2 m
    assert!(matches!(
        MockDevice::new(cfg),
        Err(odocal::mock::MockError::FactoryOutOfRange(_))
    ));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn wheel_speed_commands_drive_until_their_duration_or_stop() {
    // Virtual time: a timed command runs to completion; an open-ended one cannot.
    let dev = device(0.0, 11);
    let (stream, _task) = spawn_duplex(dev.clone(), TimeMode::Virtual, FaultConfig::default());
    let (client, _) = Client::connect(stream, fast_link()).await.unwrap();
    client
        .wheel_speed(0.2, 0.2, Some(Duration::from_millis(2000)))
        .await
        .unwrap();
    // 2 s at 0.2 m/s by the configured wheels: 0.4 m of configured travel per wheel, in whole
    // encoder counts (SPEC.md §7.6), which the true robot (right wheel 0.992, base 0.976 ×
    // 0.39 m) turns into a slight right arc.
    let per_count = std::f64::consts::PI * 0.15 / 4096.0;
    let travel = (0.4 / per_count).round() * per_count;
    let expected =
        odocal::kinematics::Pose::default().advance(travel, travel * 0.992, 0.39 * 0.976);
    let p = lock(&dev).sim().pose();
    assert!(
        (p.x_m - expected.x_m).abs() < 1e-9 && (p.y_m - expected.y_m).abs() < 1e-9,
        "{p:?} vs {expected:?}"
    );
    let open = client.wheel_speed(0.2, 0.2, None).await.unwrap_err();
    assert!(
        matches!(open, HalError::Nack { nack, .. } if nack.detail == 2),
        "{open:?}"
    );
    // Real time: an open-ended command runs until STOP.
    let dev = device(0.0, 12);
    let (stream, _task) = spawn_duplex(
        dev.clone(),
        TimeMode::RealTime { scale: 1.0 },
        FaultConfig::default(),
    );
    let (client, _) = Client::connect(stream, fast_link()).await.unwrap();
    client.wheel_speed(0.2, 0.2, None).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert!(lock(&dev).is_moving());
    client.stop().await.unwrap();
    let d = lock(&dev);
    assert!(!d.is_moving());
    let x = d.sim().pose().x_m;
    assert!(x > 0.01 && x < 0.1, "{x}");
}

#[test]
fn a_corrupt_stored_copy_is_discarded_and_said_a_missing_one_is_not() {
    let dir = common::scratch("mock-nv");
    std::fs::create_dir_all(&dir).unwrap();
    let with_storage = |path: &std::path::Path| {
        let mut cfg = MockConfig::with_ratios(nominal(), 0.976, 0.992).unwrap();
        cfg.storage_path = Some(path.to_path_buf());
        MockDevice::new(cfg).unwrap()
    };
    // Never saved: no file, nothing to say.
    let missing = with_storage(&dir.join("none.json"));
    assert_eq!(missing.storage_discarded(), None);
    // Garbage: discarded, factory defaults, and the reason names the file.
    let bad = dir.join("bad.json");
    std::fs::write(&bad, "{ not json").unwrap();
    let d = with_storage(&bad);
    let why = d.storage_discarded().expect("a discarded copy is reported");
    assert!(
        why.contains("bad.json") && why.contains("not a parameter block"),
        "{why}"
    );
    assert!(d.stored_params().is_none());
    assert_eq!(d.active_params(), nominal());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn telemetry_from_one_long_virtual_motion_stays_bounded() {
    use odocal::mock::MAX_EVENTS_PER_STEP;
    use odocal::protocol::message::{MoveStraightRequest, TelemetryPeriod};
    use odocal::protocol::Packet;
    let dev = device(0.0, 11);
    let mut d = lock(&dev);
    let send = |d: &mut MockDevice, seq: u8, r: Request| {
        let mut out = d.handle(&Packet::request(seq, r).to_frame());
        out.extend(d.run_until_idle());
        out
    };
    send(
        &mut d,
        1,
        Request::ConfigureTelemetry(TelemetryPeriod { period_ms: 5 }),
    );
    // 100 m at 1 mm/s: 10^5 s of device time, 2·10^7 samples at 5 ms.
    let out = send(
        &mut d,
        2,
        Request::MoveStraight(MoveStraightRequest {
            distance_um: 100_000_000,
            max_speed_mm_s: 1,
            mode: MotionMode::Replace,
        }),
    );
    assert!(out.len() <= MAX_EVENTS_PER_STEP + 2, "{} frames", out.len());
    let c = d.counters();
    assert!(c.telemetry_over_bound > 19_000_000, "{c:?}");
    assert_eq!(c.motions_completed, 1);
}

/// A motion that the device ends without completing it (a STOP from elsewhere, a fault, a
/// watchdog trip already acknowledged) is reported at once as stopped, not waited out until
/// the motion's deadline.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_motion_stopped_by_the_device_is_reported_at_once() {
    let dev = device(0.0, 12);
    let (stream, _task) = spawn_duplex(
        dev.clone(),
        TimeMode::RealTime { scale: 1.0 },
        FaultConfig::default(),
    );
    let (client, _) = Client::connect(stream, fast_link()).await.unwrap();
    let mut done = client.subscribe_motion_done();
    // 2 m at 0.2 m/s: ten seconds of driving.
    let accepted = client
        .move_straight(2.0, 0.2, MotionMode::Replace)
        .await
        .unwrap();
    let stopper = dev.clone();
    tokio::spawn(async move {
        tokio::time::sleep(Duration::from_millis(100)).await;
        lock(&stopper).stop();
    });
    let started = Instant::now();
    let err = client
        .wait_motion(accepted.motion_id, 1, Duration::from_secs(20), &mut done)
        .await
        .unwrap_err();
    assert!(
        matches!(err, HalError::MotionStopped { motion_id } if motion_id == accepted.motion_id),
        "{err:?}"
    );
    assert!(
        started.elapsed() < Duration::from_secs(2),
        "took {:?}",
        started.elapsed()
    );
}

/// A serial port is opened exclusively: while a link whose device stopped answering still
/// holds it, it cannot be opened again. The reconnection closes that link, waits until the port
/// is free, and opens it again with the handshake; the old handle then fails as closed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reconnecting_a_port_frees_it_from_the_old_link_and_reopens_the_device() {
    let dev = device(0.0, 21);
    let server = spawn_pty(dev.clone(), TimeMode::Virtual, FaultConfig::default()).unwrap();
    let (old, _) = open_port(&server.path, 115_200).await.unwrap();
    let busy = open_port(&server.path, 115_200).await.err();
    assert!(
        matches!(busy, Some(HalError::Open { .. })),
        "the port is held: {busy:?}"
    );
    let reconnect = odocal::hal::base::reconnect_port(old.clone(), server.path.clone(), 115_200);
    let store = reconnect().await.expect("reopened");
    assert_eq!(store.read().await.unwrap(), nominal());
    // Closing a link that has already let go returns at once.
    let t = Instant::now();
    old.close().await;
    assert!(
        t.elapsed() < Duration::from_millis(500),
        "{:?}",
        t.elapsed()
    );
    assert!(
        matches!(old.status().await, Err(HalError::Link(LinkError::Closed))),
        "the old link is closed"
    );
}

/// A slow adapter (30 ms before every answer) on a link that expects answers within 10 ms:
/// the first exchange measures it, and from then on no request is sent twice; the watchdog
/// the device acknowledged is what the link's budget follows (virtual time).
#[tokio::test(start_paused = true)]
async fn a_slow_adapter_is_measured_and_costs_no_retries() {
    let faults = FaultConfig {
        latency: Duration::from_millis(30),
        ..FaultConfig::default()
    };
    let (stream, _task) = spawn_duplex(device(0.1, 4), TimeMode::Virtual, faults);
    let config = LinkConfig {
        response_time: Duration::from_millis(5),
        margin: Duration::from_millis(5),
        ..LinkConfig::default()
    };
    let (client, _) = Client::connect(stream, config).await.unwrap();
    // HELLO was retried (30 ms > its 12 ms deadline), and so are the first reads (this mock
    // answers one request at a time, so each retry queues 30 ms more): their answers bound
    // the latency, and the next exchanges measure it.
    for _ in 0..6 {
        client.read_heading().await.unwrap();
    }
    let measured = client.stats();
    let latency = measured.adapter_latency_us.expect("measured");
    assert!((27_000..31_000).contains(&latency), "{latency} µs");
    for _ in 0..20 {
        client.read_heading().await.unwrap();
    }
    let applied = client
        .configure_watchdog(Some(Duration::from_millis(4000)))
        .await
        .unwrap();
    assert_eq!(applied, Duration::from_millis(4000));
    let stats = client.stats();
    assert_eq!(stats.retries, measured.retries, "{stats:?}");
    assert_eq!(stats.watchdog_ms, 4000);
    // The budget of a request covers the watchdog: the host outlasts the device's own stop.
    let budget = config.budget(&Request::GetStatus, Duration::from_millis(4000));
    assert!(budget > Duration::from_millis(4000), "{budget:?}");
    assert_eq!(
        config.budget(&Request::GetStatus, Duration::ZERO),
        config.retry_budget
    );
}

/// A port that takes no bytes (a USB adapter whose device has gone, flow control held) fails
/// the link by the write's deadline, with an error that says so, instead of hanging the link
/// task on a write that never ends.
#[tokio::test(start_paused = true)]
async fn a_port_that_takes_no_bytes_fails_the_link_by_the_writes_deadline() {
    // Room for four bytes, and a peer that never reads: HELLO's frame never fits.
    let (host, _deaf) = odocal::io::transport::pair(4);
    let connect = Client::connect(host, LinkConfig::default());
    let result = tokio::time::timeout(Duration::from_secs(30), connect)
        .await
        .expect("the link hung on a write");
    match result {
        Err(HalError::Link(LinkError::Io(e))) => {
            assert_eq!(e.kind(), std::io::ErrorKind::TimedOut, "{e}");
            assert!(e.to_string().contains("did not take"), "{e}");
        }
        Err(other) => panic!("another error: {other}"),
        Ok(_) => panic!("connected to a port that takes nothing"),
    }
}
