//! `odocal conformance` against devices on pseudo-terminals, in real time sped up five times:
//! the mock device and the protocol crate's device kit pass every rule that real time can
//! check (the 65535-motion id wrap is skipped, said as needing the clock hook); a kit device
//! whose watchdog never trips fails the watchdog's rules and no other. With its clock held,
//! the kit follows every rule of the vectors, the id wrap included.

mod common;

use odocal::hal::conformance::{run_clocked, Outcome};
use odocal::mock::kit::{kit, kit_config, serve_kit, spawn_kit_pty};
use odocal::protocol::device::{
    Board, Device, DeviceConfig, DriveCommand, HeadingReading, IdealBoard, RamStorage,
    SimulatedBoard,
};
use odocal::protocol::message::{heading_status, FirmwareId, ParamsBlock};
use serde_json::Value;
use std::process::Command;
use std::sync::{Arc, Mutex};

const SCALE: &str = "5";

fn robot() -> ParamsBlock {
    ParamsBlock {
        left_wheel_diameter_nm: 150_000_000,
        right_wheel_diameter_nm: 150_000_000,
        wheelbase_nm: 390_000_000,
        counts_per_wheel_rev_micro: 4_096_000_000,
    }
}

/// One real-time run at a time: they measure time on a machine of two shared cores.
static REAL_TIME: Mutex<()> = Mutex::new(());

/// Runs `odocal conformance --port port --json --time-scale 5 …`; its exit status and JSON
/// report.
fn conformance(port: &str, extra: &[&str]) -> (bool, Value) {
    let mut args = vec!["--time-scale", SCALE];
    args.extend(extra);
    conformance_as(port, &args)
}

/// Runs `odocal conformance --port port --yes --json` with `args`; its exit status and JSON
/// report.
fn conformance_as(port: &str, args: &[&str]) -> (bool, Value) {
    let _one = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let out = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(["conformance", "--port", port, "--yes", "--json"])
        .args(args)
        .output()
        .expect("odocal runs");
    let report = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "no JSON report ({e}): {}",
            String::from_utf8_lossy(&out.stderr)
        )
    });
    (out.status.success(), report)
}

/// The rules with this outcome, as "section rule".
fn with(report: &Value, outcome: &str) -> Vec<String> {
    report["rules"]
        .as_array()
        .expect("rules")
        .iter()
        .filter(|r| r["outcome"] == outcome)
        .map(|r| format!("{} {} ({})", r["section"], r["rule"], r["reason"]))
        .collect()
}

/// Every rule passes but the id wrap, which is skipped for want of the clock hook; the
/// extra checks of §3, §7.2 and §5 ran too.
fn assert_conforms(ok: bool, report: &Value, who: &str) {
    assert!(ok, "{who}: {:?}", with(report, "fail"));
    assert_eq!(with(report, "fail"), Vec::<String>::new(), "{who}");
    let skipped = with(report, "skip");
    assert_eq!(skipped.len(), 1, "{who}: {skipped:?}");
    assert!(
        skipped[0].contains("wraps") && skipped[0].contains("clock hook"),
        "{who}: {skipped:?}"
    );
    let passed = with(report, "pass");
    for section in ["\"3\"", "\"5\"", "\"7.1\"", "\"7.7\"", "\"7.11\""] {
        assert!(
            passed.iter().any(|p| p.starts_with(section)),
            "{who}: {section} not passed: {passed:?}"
        );
    }
    assert!(passed.len() >= 17, "{who}: {passed:?}");
}

/// The words of the README's command line that starts with `start` (its comment dropped).
fn readme_command(start: &str) -> Vec<String> {
    let readme = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md"))
        .expect("README.md");
    let line = readme
        .lines()
        .find(|l| l.starts_with(start))
        .unwrap_or_else(|| panic!("the README has no line starting `{start}`"));
    let command = line.split(" #").next().unwrap_or(line);
    command.split_whitespace().map(String::from).collect()
}

/// `odocal mock-device` started as the README shows it before `odocal conformance`, and
/// conformance run as the README shows it (the time scale measured, not given): it passes.
#[test]
fn the_mock_device_as_the_readme_shows_it_passes_conformance() {
    let mock_words = readme_command("odocal mock-device --time-scale");
    let mock_args: Vec<&str> = mock_words[2..].iter().map(String::as_str).collect();
    let (mut mock, port) = common::spawn_mock(&mock_args);
    let check = readme_command("odocal conformance --port /dev/pts/N");
    // Beyond `conformance --port PATH`, less what `conformance_as` gives itself.
    let extra: Vec<&str> = check[4..]
        .iter()
        .map(String::as_str)
        .filter(|w| !matches!(*w, "--yes" | "--json"))
        .collect();
    assert_eq!(
        check[4..].first().map(String::as_str),
        Some("--yes"),
        "{check:?}"
    );
    let (ok, report) = conformance_as(&port, &extra);
    let _ = mock.kill();
    let _ = mock.wait();
    assert_eq!(report["device"]["firmware_id"], "odocal-mock");
    assert_conforms(ok, &report, "mock-device as the README shows it");
}

/// A mock device in virtual time (its motions end the moment they are accepted) cannot be
/// checked against rules about time: refused at once, naming how to start one that can.
#[test]
fn a_device_whose_clock_stands_still_is_refused_with_the_way_to_start_one() {
    let (mut mock, port) = common::spawn_mock(&[]);
    let _one = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (ok, _, err) = common::odocal(&["conformance", "--port", &port, "--yes"]);
    let _ = mock.kill();
    let _ = mock.wait();
    assert!(
        !ok && err.contains("virtual time") && err.contains("--time-scale 5"),
        "{err}"
    );
}

/// A given time scale that the device's clock contradicts is refused with the measured one.
#[test]
fn a_time_scale_the_clock_contradicts_is_refused_with_the_measured_one() {
    let (mut mock, port) = common::spawn_mock(&["--time-scale", SCALE]);
    let _one = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (ok, _, err) =
        common::odocal(&["conformance", "--port", &port, "--yes", "--time-scale", "1"]);
    let _ = mock.kill();
    let _ = mock.wait();
    assert!(!ok && err.contains("--time-scale 5"), "{err}");
}

#[test]
fn the_device_kit_passes_conformance_on_a_pty() {
    let (mut kit, port) = common::spawn_server("kit-device", &["--time-scale", SCALE]);
    let (ok, report) = conformance(&port, &[]);
    let _ = kit.kill();
    let _ = kit.wait();
    assert_eq!(report["device"]["firmware_id"], "odocal-kit");
    assert_conforms(ok, &report, "kit-device");
}

/// The ideal board with one defect: a watchdog that waits `watchdog_factor` times too long, or
/// a compass that takes a reading only every `compass_period_us` (each reading one µrad on
/// from the last, so that two are told apart; numbered by [`Board::heading_sample`]).
struct Tweaked {
    ideal: IdealBoard,
    watchdog_factor: u64,
    compass_period_us: Option<u64>,
    /// The last reading: when it was taken, its number, its value.
    sample: Option<(u64, u32, i32)>,
}

impl Tweaked {
    fn new(ideal: IdealBoard) -> Self {
        Tweaked {
            ideal,
            watchdog_factor: 1,
            compass_period_us: None,
            sample: None,
        }
    }

    /// The compass's newest reading: a new one once its period has passed.
    fn sample(&mut self, period: u64) -> (u32, i32) {
        let now = self.ideal.now_us();
        let (taken, number, value) = match self.sample {
            Some((at, n, v)) if now < at + period => (at, n, v),
            Some((at, n, v)) => (at + period * ((now - at) / period), n + 1, v + 1),
            None => (now, 0, self.ideal.heading().heading_urad),
        };
        self.sample = Some((taken, number, value));
        (number, value)
    }
}

impl Board for Tweaked {
    fn now_us(&mut self) -> u64 {
        self.ideal.now_us()
    }
    fn drive(&mut self, command: &DriveCommand) {
        self.ideal.drive(command);
    }
    fn stop(&mut self) {
        self.ideal.stop();
    }
    fn encoders(&mut self) -> (i32, i32) {
        self.ideal.encoders()
    }
    fn reset_encoders(&mut self) {
        self.ideal.reset_encoders();
    }
    fn heading(&mut self) -> HeadingReading {
        match self.compass_period_us {
            None => self.ideal.heading(),
            Some(period) => HeadingReading {
                heading_urad: self.sample(period).1,
                valid: true,
                sensor_status: heading_status::CALIBRATED,
            },
        }
    }
    fn heading_sample(&mut self) -> Option<u32> {
        let period = self.compass_period_us?;
        Some(self.sample(period).0)
    }
    fn watchdog_timeout_us(&self, timeout_ms: u16) -> u64 {
        self.watchdog_factor * self.ideal.watchdog_timeout_us(timeout_ms)
    }
}

impl SimulatedBoard for Tweaked {
    fn advance_to(&mut self, now_us: u64) {
        self.ideal.advance_to(now_us);
    }
}

/// A device whose compass reads at 10 Hz, asked far faster and streaming telemetry: the host
/// reads again while the device answers "not new" (SPEC §5, READ_HEADING bit 3), so five
/// readings are five samples at least 0.4 s apart, never one sample five times; a compass that
/// never takes another reading gives an invalid one, named, after the host has waited for it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn readings_of_a_slow_compass_are_distinct_samples() {
    use odocal::base::HeadingSource;
    for period_us in [100_000, u64::MAX / 4] {
        let mut board = Tweaked::new(IdealBoard::new(&robot()));
        board.compass_period_us = Some(period_us);
        let device = Device::new(board, RamStorage::default(), kit_config(robot())).unwrap();
        let (host, dev) = tokio::io::duplex(4096);
        tokio::spawn(serve_kit(Arc::new(Mutex::new(device)), dev, 1.0));
        let (client, _) = odocal::hal::Client::connect(host, Default::default())
            .await
            .unwrap();
        // Telemetry reads the compass too, 50 times a second: it takes no sample from the
        // host's reads.
        client
            .configure_telemetry(Some(std::time::Duration::from_millis(20)))
            .await
            .unwrap();
        let start = std::time::Instant::now();
        let mut values = Vec::new();
        for _ in 0..5 {
            let h = client.read().await.unwrap();
            if period_us > 1_000_000 && !values.is_empty() {
                match &h.validity {
                    odocal::base::Validity::Invalid(why) => {
                        assert!(why.contains("no new reading"), "{why}");
                        break;
                    }
                    other => panic!("a compass that took no new reading read {other:?}"),
                }
            }
            assert!(h.validity.is_valid(), "{:?}", h.validity);
            values.push(h.heading_rad);
        }
        if period_us > 1_000_000 {
            assert_eq!(values.len(), 1);
            assert!(start.elapsed() >= std::time::Duration::from_millis(1400));
            continue;
        }
        values.dedup();
        assert_eq!(values.len(), 5, "{values:?}");
        assert!(start.elapsed() >= std::time::Duration::from_millis(400));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_whose_watchdog_never_trips_fails_the_watchdog_rules_only() {
    let scale: f64 = SCALE.parse().unwrap();
    let config = DeviceConfig {
        firmware_id: FirmwareId::new("late-watchdog").unwrap(),
        ..kit_config(robot())
    };
    let mut board = Tweaked::new(IdealBoard::new(&robot()).with_host_time_scale(scale));
    board.watchdog_factor = 100;
    let device = Device::new(board, RamStorage::default(), config).unwrap();
    let server = spawn_kit_pty(Arc::new(Mutex::new(device)), scale).unwrap();
    let path = server.path.clone();
    let (ok, report) = tokio::task::spawn_blocking(move || {
        conformance(&path, &["--rule", "7.7", "--rule", "7.10", "--rule", "7.2"])
    })
    .await
    .unwrap();
    assert!(!ok, "a failing rule makes the command fail");
    let failed = with(&report, "fail");
    assert_eq!(failed.len(), 2, "{failed:?}");
    for f in &failed {
        assert!(f.starts_with("\"7.7\""), "{failed:?}");
        assert!(f.contains("tripped") || f.contains("fault_flags"), "{f}");
    }
    // 7.10, 7.2 (vector and retry check) and §5 still pass.
    assert_eq!(
        with(&report, "pass").len(),
        4,
        "{:?}",
        with(&report, "pass")
    );
}

#[tokio::test]
async fn with_its_clock_held_the_kit_follows_every_device_rule() {
    let results = run_clocked(|| kit(robot(), 1.0).unwrap()).await.unwrap();
    let failed: Vec<_> = results
        .iter()
        .filter(|r| r.outcome != Outcome::Pass)
        .collect();
    assert!(failed.is_empty(), "{failed:#?}");
    let sections: std::collections::BTreeSet<_> =
        results.iter().map(|r| r.section.as_str()).collect();
    for s in [
        "7.1", "7.2", "7.3", "7.4", "7.5", "7.6", "7.7", "7.8", "7.9", "7.10", "7.11",
    ] {
        assert!(sections.contains(s), "no rule of §{s} ran");
    }
    assert!(
        results.iter().any(|r| r.rule.contains("wraps")),
        "the id wrap ran"
    );
}
