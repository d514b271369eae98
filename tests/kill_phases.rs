//! The mock device killed at each phase of a calibration (pre-flight, round 1, the write-back,
//! round 2, verification), then powered up again from its non-volatile storage: every run that
//! measured a square leaves a partial report (one that drove nothing leaves no file at all),
//! and what the host states about the robot's parameters is what the
//! device's storage really holds afterwards. A run whose report directory cannot be written
//! fails before anything is sent beyond the handshake.

mod common;

use odocal::base::transaction::Holds;
use odocal::base::{Base, ParamStore, Reconnect};
use odocal::calibration::Method;
use odocal::hal::link::LinkConfig;
use odocal::hal::Client;
use odocal::kinematics::WheelParams;
use odocal::mock::{
    lock, spawn_duplex, FaultConfig, MockConfig, MockDevice, SharedDevice, TimeMode,
};
use odocal::protocol::message::{id, ParamsBlock};
use odocal::routine::config::RoutineConfig;
use odocal::routine::report::Phase;
use odocal::routine::{run, ParamsAfterFailure, RoutineError, RoutineEvent, RoutineUi};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use tokio::task::AbortHandle;
use tokio_util::sync::CancellationToken;

/// When the test kills the device.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Kill {
    /// As the pre-flight checks start.
    Preflight,
    /// After this motion (1..=8) of this run of this phase.
    AfterMotion(Phase, usize, usize),
    /// The device dies right after executing its first SAVE_PARAMS, the answer unsent.
    OnSave,
}

/// A UI that kills the device at its moment.
struct Killer {
    kill: Kill,
    server: Arc<Mutex<Option<AbortHandle>>>,
}

impl Killer {
    fn now(&self) {
        if let Some(h) = self.server.lock().unwrap().take() {
            h.abort();
        }
    }
}

impl RoutineUi for Killer {
    fn confirm(&mut self, _question: &str) -> bool {
        true
    }
    fn event(&mut self, event: &RoutineEvent) {
        match (self.kill, event) {
            (Kill::Preflight, RoutineEvent::Stage(s)) if s.starts_with("pre-flight") => self.now(),
            (
                Kill::AfterMotion(phase, run, motion),
                RoutineEvent::Motion {
                    phase: p,
                    run: r,
                    motion: m,
                    ..
                },
            ) if *p == phase && *r == run && *m == motion => self.now(),
            _ => {}
        }
    }
}

fn config(storage: &Path) -> MockConfig {
    let mut cfg = MockConfig::with_ratios(common::nominal(), common::TRUE_E_B, common::TRUE_E_D)
        .expect("valid robot");
    cfg.noise.compass_sigma_rad = 0.0;
    cfg.storage_path = Some(storage.to_path_buf());
    cfg
}

/// The parameters in the device's non-volatile file, as a power-up would load them.
fn stored(storage: &Path) -> WheelParams {
    let block: ParamsBlock =
        serde_json::from_str(&std::fs::read_to_string(storage).expect("stored copy")).unwrap();
    WheelParams::from(&block)
}

/// Powers the device up from its storage and serves it on a new in-memory link.
async fn power_up(
    storage: &Path,
    faults: FaultConfig,
) -> (
    SharedDevice,
    Client,
    tokio::task::JoinHandle<std::io::Result<odocal::mock::ServeEnd>>,
) {
    let device: SharedDevice = Arc::new(Mutex::new(MockDevice::new(config(storage)).unwrap()));
    let (stream, task) = spawn_duplex(device.clone(), TimeMode::Virtual, faults);
    let (client, _) = Client::connect(stream, LinkConfig::default())
        .await
        .unwrap();
    (device, client, task)
}

fn routine(dir: &Path) -> RoutineConfig {
    RoutineConfig {
        method: Some(Method::Exact),
        report_dir: Some(dir.join("report")),
        ..common::virtual_routine(dir.join("backups"))
    }
}

struct Outcome {
    err: RoutineError,
    /// The partial report, when the run left one.
    partial: Option<serde_json::Value>,
    /// The files the run left in its report directory.
    left: Vec<PathBuf>,
    after_power_up: WheelParams,
    reconnected_device: Option<SharedDevice>,
}

/// Calibrates, kills the device at `kill`, and on reconnection powers it up again from its
/// storage, or, unless `comes_back`, finds nothing there.
async fn calibrate_and_kill(name: &str, kill: Kill, comes_back: bool) -> Outcome {
    let dir = common::scratch(&format!("kill-{name}"));
    std::fs::create_dir_all(&dir).unwrap();
    let storage = dir.join("nv.json");
    // The robot holds its factory parameters, saved.
    let original = common::nominal();
    std::fs::write(
        &storage,
        serde_json::to_string(&ParamsBlock::try_from(&original).unwrap()).unwrap(),
    )
    .unwrap();
    let faults = FaultConfig {
        vanish_after_executing: (kill == Kill::OnSave).then_some(id::SAVE_PARAMS),
        ..FaultConfig::default()
    };
    let (_device, client, task) = power_up(&storage, faults).await;
    let server = Arc::new(Mutex::new(Some(task.abort_handle())));
    // Reconnecting powers the device up again from what its storage holds then.
    let reconnected: Arc<Mutex<Option<SharedDevice>>> = Arc::default();
    let reconnect: Reconnect = {
        let (storage, reconnected) = (storage.clone(), reconnected.clone());
        Arc::new(move || {
            let (storage, reconnected) = (storage.clone(), reconnected.clone());
            Box::pin(async move {
                if !comes_back {
                    return Err(odocal::base::BaseError::backend(
                        "store",
                        std::io::Error::other("no device on the port"),
                    ));
                }
                let (device, client, _task) = power_up(&storage, FaultConfig::default()).await;
                *reconnected.lock().unwrap() = Some(device);
                Ok(Arc::new(client) as Arc<dyn ParamStore>)
            })
        })
    };
    let cfg = routine(&dir);
    let err = run(
        &Base::single(client).with_reconnect(reconnect),
        &cfg,
        None,
        &mut Killer { kill, server },
        &CancellationToken::new(),
    )
    .await
    .expect_err(name);
    let left: Vec<PathBuf> = std::fs::read_dir(dir.join("report"))
        .map(|d| d.map(|e| e.unwrap().path()).collect())
        .unwrap_or_default();
    let partials: Vec<&PathBuf> = left
        .iter()
        .filter(|p| {
            p.file_name()
                .unwrap()
                .to_string_lossy()
                .starts_with("partial-report-")
        })
        .collect();
    assert!(
        partials.len() <= 1,
        "{name}: one partial report at most: {err}"
    );
    let partial = partials
        .first()
        .map(|p| serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap());
    let reconnected_device = reconnected.lock().unwrap().take();
    Outcome {
        err,
        partial,
        left,
        after_power_up: stored(&storage),
        reconnected_device,
    }
}

/// Checks the host's statement against the device's storage, and the partial report.
fn check(name: &str, o: &Outcome, phase: &str, runs_measured: usize) {
    let original = common::nominal();
    let statement = ParamsAfterFailure::of(&o.err);
    let Some(partial) = &o.partial else {
        // Nothing driven, nothing written: nothing is left behind, not even the backup.
        assert_eq!(runs_measured, 0, "{name}: no partial report: {}", o.err);
        assert!(o.left.is_empty(), "{name}: files left: {:?}", o.left);
        assert_eq!(statement, ParamsAfterFailure::Untouched, "{name}");
        assert_eq!(o.after_power_up, original, "{name}: untouched, and it is");
        return;
    };
    assert!(runs_measured > 0, "{name}: a partial report of nothing");
    assert_eq!(
        partial["parameters"],
        serde_json::to_value(&statement).unwrap(),
        "{name}: the partial report states what the error states"
    );
    assert_eq!(partial["phase"], phase, "{name}: {}", o.err);
    assert_eq!(
        partial["runs"].as_array().unwrap().len(),
        runs_measured,
        "{name}: every square measured before the kill is kept"
    );
    assert!(
        partial["diagnostics"]["last_request"].is_string(),
        "{name}: the last request is named: {}",
        partial["diagnostics"]
    );
    assert!(
        partial["error"].as_str().unwrap().contains("closed"),
        "{name}: {}",
        partial["error"]
    );
    match statement {
        ParamsAfterFailure::Untouched => {
            assert_eq!(o.after_power_up, original, "{name}: untouched, and it is")
        }
        ParamsAfterFailure::Restored { committed, .. } => {
            assert!(
                committed,
                "{name}: a commit may have landed, so it is undone"
            );
            assert!(
                odocal::base::same_within(
                    &o.after_power_up,
                    &original,
                    &WheelParams {
                        left_wheel_diameter_m: 1e-9,
                        right_wheel_diameter_m: 1e-9,
                        wheelbase_m: 1e-9,
                        counts_per_wheel_rev: 1e-6,
                    }
                ),
                "{name}: said restored, storage holds {:?}",
                o.after_power_up
            );
            let d = o
                .reconnected_device
                .as_ref()
                .expect("restored over a new link");
            assert_eq!(lock(d).active_params(), o.after_power_up, "{name}");
        }
        ParamsAfterFailure::RestoreFailed { committed, .. } => match committed {
            Holds::Original => assert_eq!(o.after_power_up, original, "{name}"),
            // Unknown claims nothing, which is true of a device that is gone.
            Holds::Unknown(_) => {}
            other => panic!("{name}: restore failed with the committed copy {other}"),
        },
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_killed_in_any_phase_leaves_a_partial_report_and_a_true_statement() {
    let restored = ParamsAfterFailure::Restored {
        committed: true,
        reconnected: true,
    };
    for (name, kill, phase, runs_measured, statement) in [
        (
            "preflight",
            Kill::Preflight,
            "pre-flight",
            0,
            ParamsAfterFailure::Untouched,
        ),
        (
            "round1",
            Kill::AfterMotion(Phase::Calibration { round: 1 }, 2, 3),
            "round 1",
            1,
            ParamsAfterFailure::Untouched,
        ),
        // SAVE_PARAMS landed (the storage held the new parameters) but was never acknowledged.
        (
            "write-back",
            Kill::OnSave,
            "write-back after round 1",
            4,
            restored.clone(),
        ),
        (
            "round2",
            Kill::AfterMotion(Phase::Calibration { round: 2 }, 1, 5),
            "round 2",
            4,
            restored.clone(),
        ),
        (
            "verification",
            Kill::AfterMotion(Phase::Verification, 1, 2),
            "verification",
            8,
            restored.clone(),
        ),
    ] {
        let o = calibrate_and_kill(name, kill, true).await;
        check(name, &o, phase, runs_measured);
        assert_eq!(ParamsAfterFailure::of(&o.err), statement, "{name}");
    }
}

/// Killed after a SAVE that landed, and gone for good: the host cannot restore, says that it
/// does not know what either copy holds (rather than guessing), why reconnecting failed, and
/// what to run once the device is back; the storage indeed holds the new parameters.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_that_does_not_come_back_is_reported_as_unknown_with_the_way_back() {
    let o = calibrate_and_kill("gone", Kill::OnSave, false).await;
    check("gone", &o, "write-back after round 1", 4);
    match ParamsAfterFailure::of(&o.err) {
        ParamsAfterFailure::RestoreFailed {
            active: Holds::Unknown(_),
            committed: Holds::Unknown(_),
        } => {}
        other => panic!("expected both copies unknown, got {other:?}: {}", o.err),
    }
    let text = o.err.to_string();
    assert!(
        text.contains("reconnecting failed") && text.contains("no device on the port"),
        "{text}"
    );
    assert!(text.contains("odocal restore "), "{text}");
    assert_ne!(o.after_power_up, common::nominal(), "the SAVE had landed");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nothing_is_sent_before_the_output_locations_are_checked() {
    let dir = common::scratch("kill-output-first");
    std::fs::create_dir_all(&dir).unwrap();
    let storage = dir.join("nv.json");
    let (device, client, _task) = power_up(&storage, FaultConfig::default()).await;
    let not_a_dir = dir.join("report-is-a-file");
    std::fs::write(&not_a_dir, "x").unwrap();
    let cfg = RoutineConfig {
        report_dir: Some(not_a_dir),
        ..routine(&dir)
    };
    let err = run(
        &Base::single(client),
        &cfg,
        None,
        &mut Killer {
            kill: Kill::Preflight,
            server: Arc::default(),
        },
        &CancellationToken::new(),
    )
    .await
    .unwrap_err();
    assert!(matches!(err, RoutineError::Output { .. }), "{err}");
    let counters = lock(&device).counters();
    assert_eq!(
        counters.executed_requests, 1,
        "only the handshake: {counters:?}"
    );
    let backups = std::fs::read_dir(dir.join("backups")).map_or(0, |d| d.count());
    assert_eq!(backups, 0, "no backup was taken either");
    assert!(!storage.exists(), "nothing was saved");
}
