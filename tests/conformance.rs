//! `odocal conformance` against devices on pseudo-terminals, in real time sped up five times:
//! the mock device and the protocol crate's device kit pass every rule that real time can
//! check (the 65535-motion id wrap is skipped, said as needing the clock hook); a kit device
//! whose watchdog never trips fails the watchdog's rules and no other. With its clock held,
//! the kit follows every rule of the vectors, the id wrap included.

mod common;

use odocal::hal::conformance::{run_clocked, Outcome};
use odocal::mock::kit::{kit, kit_config, spawn_kit_pty};
use odocal::protocol::device::{
    Board, Device, DeviceConfig, DriveCommand, HeadingReading, IdealBoard, RamStorage,
    SimulatedBoard,
};
use odocal::protocol::message::{FirmwareId, ParamsBlock};
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

/// Runs `odocal conformance --port port --json …`; its exit status and JSON report.
fn conformance(port: &str, extra: &[&str]) -> (bool, Value) {
    let _one = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let out = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(["conformance", "--port", port, "--yes", "--json"])
        .args(["--time-scale", SCALE])
        .args(extra)
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

#[test]
fn the_mock_device_passes_conformance_on_a_pty() {
    let (mut mock, port) = common::spawn_mock(&["--real-time", SCALE]);
    let (ok, report) = conformance(&port, &[]);
    let _ = mock.kill();
    let _ = mock.wait();
    assert_eq!(report["device"]["firmware_id"], "odocal-mock");
    assert_conforms(ok, &report, "mock-device");
}

#[test]
fn the_device_kit_passes_conformance_on_a_pty() {
    let (mut kit, port) = common::spawn_server("kit-device", &["--real-time", SCALE]);
    let (ok, report) = conformance(&port, &[]);
    let _ = kit.kill();
    let _ = kit.wait();
    assert_eq!(report["device"]["firmware_id"], "odocal-kit");
    assert_conforms(ok, &report, "kit-device");
}

/// The ideal board with a watchdog that waits a hundred times too long.
struct LateWatchdog(IdealBoard);

impl Board for LateWatchdog {
    fn now_us(&mut self) -> u64 {
        self.0.now_us()
    }
    fn drive(&mut self, command: &DriveCommand) {
        self.0.drive(command);
    }
    fn stop(&mut self) {
        self.0.stop();
    }
    fn encoders(&mut self) -> (i32, i32) {
        self.0.encoders()
    }
    fn reset_encoders(&mut self) {
        self.0.reset_encoders();
    }
    fn heading(&mut self) -> HeadingReading {
        self.0.heading()
    }
    fn watchdog_timeout_us(&self, timeout_ms: u16) -> u64 {
        100 * self.0.watchdog_timeout_us(timeout_ms)
    }
}

impl SimulatedBoard for LateWatchdog {
    fn advance_to(&mut self, now_us: u64) {
        self.0.advance_to(now_us);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_whose_watchdog_never_trips_fails_the_watchdog_rules_only() {
    let scale: f64 = SCALE.parse().unwrap();
    let config = DeviceConfig {
        firmware_id: FirmwareId::new("late-watchdog").unwrap(),
        ..kit_config(robot())
    };
    let board = LateWatchdog(IdealBoard::new(&robot()).with_host_time_scale(scale));
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
