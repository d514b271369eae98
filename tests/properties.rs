//! The fuzz campaigns' findings as property tests with bounded time: random fault
//! specifications, random CRC-valid request frames into the mock device, and random telemetry
//! logs each end in a result or a named error, promptly, without a panic, and without touching
//! what they must not touch.

use odocal::calibration::online::{OnlineConfig, ScaleSource};
use odocal::calibration::tracker::Tracker;
use odocal::kinematics::{SplitConvention, WheelParams};
use odocal::mock::{FaultConfig, MockConfig, MockDevice, MAX_EVENTS_PER_STEP};
use odocal::offline::log::read_log;
use odocal::protocol::message::{id, ParamsBlock};
use odocal::protocol::{Body, Frame, FrameKind, Packet, Response};
use proptest::prelude::*;
use std::time::Duration;

/// Runs `f` on its own thread and fails if it has not finished within `limit`: the bound on
/// time that a property about termination needs (a case that spins forever fails here
/// instead of hanging the suite).
fn within<T: Send + 'static>(
    limit: Duration,
    what: String,
    f: impl FnOnce() -> T + Send + 'static,
) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    match rx.recv_timeout(limit) {
        Ok(v) => v,
        Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
            panic!("still running after {limit:?}: {what}")
        }
        Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => panic!("panicked: {what}"),
    }
}

fn fault_value() -> impl Strategy<Value = String> {
    prop_oneof![
        Just("NaN".to_string()),
        Just("inf".to_string()),
        Just("-inf".to_string()),
        Just("1e300".to_string()),
        Just("-5".to_string()),
        Just("".to_string()),
        any::<f64>().prop_map(|v| v.to_string()),
        any::<u64>().prop_map(|v| v.to_string()),
        "[ -~]{0,8}",
    ]
}

fn fault_spec() -> impl Strategy<Value = String> {
    let key = prop_oneof![
        Just("corrupt"),
        Just("drop"),
        Just("latency-ms"),
        Just("disconnect-after"),
        Just("busy-every"),
        Just("seed"),
        Just("bogus"),
    ];
    prop::collection::vec((key, fault_value()), 0..6).prop_map(|items| {
        items
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect::<Vec<_>>()
            .join(",")
    })
}

/// A request frame of any known id with any payload: CRC-valid, so it reaches the firmware.
fn request_frame() -> impl Strategy<Value = Frame> {
    (
        prop::sample::select(id::REQUESTS.to_vec()),
        any::<u8>(),
        prop::collection::vec(any::<u8>(), 0..24),
    )
        .prop_map(|(msg, seq, payload)| {
            Frame::new(FrameKind::Request, seq, msg, &payload).expect("a payload under 240 bytes")
        })
}

/// Mostly a plausible length (m), sometimes one no robot has.
fn geometry() -> impl Strategy<Value = f64> {
    prop_oneof![
        1 => Just(1e300),
        1 => Just(1e-300),
        1 => Just(0.0),
        1 => Just(-0.15),
        30 => 0.05f64..0.6,
    ]
}

/// One logged step: time step (s), left and right count steps, heading, validity, index step.
/// Mostly a robot driving, sometimes time standing still or going back, a wheel jumping
/// by anything an i64 holds, an index going back.
fn log_step() -> impl Strategy<Value = (f64, i64, i64, f64, bool, u32)> {
    let dt = prop_oneof![
        2000 => 0.005f64..0.1,
        1 => -1.0f64..0.0,
        1 => Just(0.0),
        1 => 0.1f64..1e6,
    ];
    let counts = prop_oneof![2000 => -150i64..150, 1 => any::<i64>()];
    let index = prop_oneof![2000 => Just(1u32), 1 => any::<u32>()];
    (
        dt,
        counts.clone(),
        counts,
        -4.0f64..4.0,
        prop::bool::weighted(0.9),
        index,
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// `--faults "latency-ms=-5"` (and NaN, inf, 1e300) once panicked. Any specification now
    /// parses to settings in range or is refused with a message.
    #[test]
    fn any_fault_specification_is_parsed_in_range_or_refused(spec in fault_spec()) {
        match spec.parse::<FaultConfig>() {
            Ok(f) => {
                prop_assert!((0.0..=1.0).contains(&f.corrupt_byte_rate), "{spec}: {f:?}");
                prop_assert!((0.0..=1.0).contains(&f.drop_frame_rate), "{spec}: {f:?}");
                prop_assert!(f.latency <= Duration::from_secs(10), "{spec}: {f:?}");
            }
            Err(e) => prop_assert!(e.to_string().starts_with("faults: "), "{e}"),
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, ..ProptestConfig::default() })]

    /// 1.16 million CRC-valid random frames left the mock up and its parameters untouched; here
    /// as a property: whatever arrives, every request gets one answer, a step of device time
    /// returns a bounded number of events, and the stored copy changes only through an
    /// accepted SAVE_PARAMS or RESTORE_DEFAULTS.
    #[test]
    fn random_valid_frames_get_answers_and_change_storage_only_when_asked(
        frames in prop::collection::vec((request_frame(), 0.0f64..2.0), 1..40),
    ) {
        let cfg = MockConfig::with_ratios(WheelParams::nominal(0.15, 0.39, 4096.0), 0.976, 0.992)
            .unwrap();
        let what = format!("{} frames", frames.len());
        within(Duration::from_secs(20), what, move || -> Result<(), TestCaseError> {
            let mut device = MockDevice::new(cfg).unwrap();
            for (frame, dt_s) in frames {
                let stored_before = device.stored_params();
                let answers = device.handle(&frame);
                prop_assert_eq!(answers.len(), 1, "one answer to {:?}", frame);
                let packet = Packet::from_frame(&answers[0]).unwrap();
                let stored_by_request = matches!(
                    packet.body,
                    Body::Response {
                        response: Response::SaveParams(_) | Response::RestoreDefaults(_)
                    }
                );
                if !stored_by_request {
                    prop_assert_eq!(device.stored_params(), stored_before, "{:?}", frame);
                }
                if let Some(stored) = device.stored_params() {
                    let block = ParamsBlock::try_from(&stored).unwrap();
                    prop_assert_eq!(block.validate(), Ok(()));
                }
                let events = device.advance(dt_s);
                prop_assert!(events.len() <= MAX_EVENTS_PER_STEP + 64);
            }
            Ok(())
        })?;
    }

    /// A log with an encoder jump of ~1e17 counts, or a header wheel diameter of 1e300, once
    /// made `track` spin at 100 % CPU for ever. Any log now reads and tracks to an estimate or
    /// a named error within a bounded time, and an estimate is finite.
    #[test]
    fn random_telemetry_logs_end_in_an_estimate_or_a_named_error(
        left_d in geometry(),
        right_d in geometry(),
        wheelbase in geometry(),
        steps in prop::collection::vec(log_step(), 0..200),
    ) {
        let dir = std::env::temp_dir().join(format!("odocal-prop-log-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(format!("{:x}.jsonl", rand_name(&steps)));
        let mut text = format!(
            "{{\"type\":\"header\",\"odocal_version\":\"x\",\"device\":null,\"params\":\
             {{\"left_wheel_diameter_m\":{left_d:e},\"right_wheel_diameter_m\":{right_d:e},\
             \"wheelbase_m\":{wheelbase:e},\"counts_per_wheel_rev\":4096.0}},\"period_ms\":20}}\n"
        );
        let (mut t, mut l, mut r, mut index) = (0.0f64, 0i64, 0i64, 0u32);
        for (dt, dl, dr, h, valid, di) in &steps {
            t += dt;
            l = l.wrapping_add(*dl);
            r = r.wrapping_add(*dr);
            index = index.wrapping_add(*di);
            text.push_str(&format!(
                "{{\"type\":\"telemetry\",\"sample_index\":{index},\"device_time_s\":{t:e},\
                 \"left_counts\":{l},\"right_counts\":{r},\"heading_rad\":{h:e},\
                 \"heading_valid\":{valid},\"motion_state\":\"moving\",\"queue_depth\":0,\
                 \"dropped_before\":0}}\n"
            ));
        }
        std::fs::write(&path, text).unwrap();
        let p = path.clone();
        let outcome = within(Duration::from_secs(20), format!("{path:?}"), move || {
            let (header, recording) = read_log(&p).map_err(|e| e.to_string())?;
            let mut tracker = Tracker::new(
                OnlineConfig::new(header.params),
                ScaleSource::Convention(SplitConvention::LeftNominal),
                0.5,
            )
            .map_err(|e| e.to_string())?;
            tracker.feed_recording("log", &recording);
            tracker.estimate().map_err(|e| e.to_string())
        });
        let _ = std::fs::remove_file(&path);
        match outcome {
            Ok(e) => prop_assert!(e.e_b.is_finite() && e.e_d.is_finite(), "{e:?}"),
            Err(why) => prop_assert!(!why.is_empty()),
        }
    }
}

/// A file name from the case's content, so parallel cases never share a file.
fn rand_name<T: std::fmt::Debug>(v: &T) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    format!("{v:?}").hash(&mut h);
    h.finish()
}

/// A number as a file could hold it (TOML: `nan`, `inf`, `-inf` are floats too).
fn file_number() -> impl Strategy<Value = String> {
    prop_oneof![
        Just("nan".to_string()),
        Just("inf".to_string()),
        Just("-inf".to_string()),
        Just("0.0".to_string()),
        Just("-1.0".to_string()),
        Just("1e308".to_string()),
        Just("1e-308".to_string()),
        Just("9.3e18".to_string()),
        (-1e6..1e6f64).prop_map(|v| format!("{v:?}")),
        (0.0..2.0f64).prop_map(|v| format!("{v:?}")),
    ]
}

/// The example profile's numeric fields.
const PROFILE_FIELDS: [&str; 7] = [
    "left_wheel_diameter_m",
    "right_wheel_diameter_m",
    "wheelbase_m",
    "encoder_counts_per_motor_rev",
    "gear_ratio",
    "max_speed_m_s",
    "max_accel_m_s2",
];

/// The example routine's numeric fields.
const ROUTINE_FIELDS: [&str; 5] = [
    "side_m",
    "max_speed_m_s",
    "max_rate_rad_s",
    "settle_s",
    "max_change",
];

/// `text` with the value of `key = …` (the first such line) replaced by `value`.
fn with_value(text: &str, key: &str, value: &str) -> String {
    let mut done = false;
    text.lines()
        .map(|l| {
            if !done && l.trim_start().starts_with(&format!("{key} ")) {
                done = true;
                format!("{key} = {value}")
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, failure_persistence: None, ..ProptestConfig::default() })]

    /// A profile loads only with every parameter physical and every limit finite.
    #[test]
    fn a_profile_loads_only_with_physical_numbers(
        which in 0..PROFILE_FIELDS.len(),
        value in file_number(),
    ) {
        let example = include_str!("../examples/robot.toml");
        let text = with_value(example, PROFILE_FIELDS[which], &value);
        let path = std::path::Path::new("robot.toml");
        if let Ok(p) = odocal::roboclaw::profile::Profile::parse(&text, path) {
            prop_assert!(p.params().check_physical().is_ok(), "{}: {value}", PROFILE_FIELDS[which]);
            prop_assert!(p.limits.max_speed_m_s.is_finite() && p.limits.max_speed_m_s > 0.0);
            prop_assert!(p.limits.max_accel_m_s2.is_finite() && p.limits.max_accel_m_s2 > 0.0);
        }
    }

    /// A routine file loads only with its numbers finite and in their documented ranges (its
    /// `validate`), whatever they are.
    #[test]
    fn a_routine_file_loads_only_with_finite_numbers(
        which in 0..ROUTINE_FIELDS.len(),
        value in file_number(),
    ) {
        let example = include_str!("../examples/routine-mock.toml");
        let text = with_value(example, ROUTINE_FIELDS[which], &value);
        if let Ok(cfg) = odocal::routine::config::RoutineConfig::from_toml(&text) {
            prop_assert!(cfg.validate().is_ok());
            for v in [cfg.side_m, cfg.max_speed_m_s, cfg.max_rate_rad_s, cfg.settle_s, cfg.max_change] {
                prop_assert!(v.is_finite(), "{}: {value}", ROUTINE_FIELDS[which]);
            }
            prop_assert!(cfg.side_m >= 0.05 && cfg.max_speed_m_s >= 0.01);
        }
    }

    /// A backup restores only parameters a robot has: a dry run refuses what the real run
    /// would, before anything is written.
    #[test]
    fn a_backup_restores_only_physical_parameters(
        which in 0..4usize,
        value in file_number(),
    ) {
        let keys = ["left_wheel_diameter_m", "right_wheel_diameter_m", "wheelbase_m", "counts_per_wheel_rev"];
        let mut active = serde_json::json!({
            "left_wheel_diameter_m": 0.15,
            "right_wheel_diameter_m": 0.15,
            "wheelbase_m": 0.39,
            "counts_per_wheel_rev": 4096.0,
        });
        // JSON has no non-finite numbers: those come as the text a hand edit leaves.
        let number: Option<f64> = value.parse().ok().filter(|v: &f64| v.is_finite());
        let dir = std::env::temp_dir().join(format!("odocal-prop-backup-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(format!("b-{which}-{}.json", value.len()));
        let body = match number {
            Some(n) => {
                active[keys[which]] = serde_json::json!(n);
                serde_json::json!({
                    "odocal_version": "0.1.0",
                    "store": {"kind": "odocal-device", "id": "x", "details": {}},
                    "active": active,
                    "committed": null,
                })
                .to_string()
            }
            None => format!(
                "{{\"odocal_version\":\"0.1.0\",\"store\":{{\"kind\":\"odocal-device\",\"id\":\"x\",\"details\":{{}}}},\
                 \"active\":{{\"left_wheel_diameter_m\":0.15,\"right_wheel_diameter_m\":0.15,\"wheelbase_m\":0.39,\
                 \"counts_per_wheel_rev\":4096,\"{}\":{value}}},\"committed\":null}}",
                keys[which]
            ),
        };
        std::fs::write(&path, body).unwrap();
        if let Ok(b) = odocal::base::transaction::read_backup(&path) {
            if odocal::base::transaction::check_restorable(&b, &path).is_ok() {
                prop_assert!(b.active.check_physical().is_ok(), "{}: {value}", keys[which]);
            }
        }
        let _ = std::fs::remove_file(&path);
    }
}
