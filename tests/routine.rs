//! The recalibration routine end to end against the mock device: the demo calibrates and
//! verifies, and every failure path stops the base and leaves the parameters as they were.

mod common;

use odocal::base::Base;
use odocal::demo::{run_demo, DemoError, DemoOptions, MockTruth};
use odocal::hal::link::LinkConfig;
use odocal::hal::Client;
use odocal::kinematics::WheelParams;
use odocal::mock::{lock, spawn_duplex, FaultConfig, MockConfig, MockDevice, TimeMode};
use odocal::routine::config::{RoutineConfig, WritePolicy};
use odocal::routine::report::Report;
use odocal::routine::{run, RoutineError, RoutineEvent, RoutineUi, Unattended};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio_util::sync::CancellationToken;

fn temp_dir(name: &str) -> std::path::PathBuf {
    common::scratch(name)
}

fn demo_options(name: &str) -> DemoOptions {
    let mut opts = DemoOptions::default();
    opts.routine.backup_dir = Some(temp_dir(name));
    opts
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_demo_calibrates_verifies_and_writes_its_report() {
    let mut opts = demo_options("demo");
    let report_dir = opts.routine.backup_dir.clone().unwrap().join("report");
    opts.routine.report_dir = Some(report_dir.clone());
    let (report, device) = run_demo(&opts, &mut Unattended, &CancellationToken::new())
        .await
        .unwrap();
    let before = report.e_max_sys_before_m.unwrap();
    let after = report.e_max_sys_after_m.unwrap();
    assert!(
        before > 1.0,
        "the mis-calibrated robot misses by {before} m"
    );
    assert!(
        after * 10.0 < before,
        "E_max,sys {before} → {after}: not a tenfold reduction"
    );
    assert!(
        report.converged && report.rounds.len() <= 3,
        "{} rounds",
        report.rounds.len()
    );
    assert!(report.written);
    assert!(
        report.mean_abs_heading_error_after_deg.unwrap() * 10.0
            < report.mean_abs_heading_error_before_deg
    );
    // What was reported is what the controller has, in RAM and in storage.
    let d = lock(&device);
    assert_eq!(d.active_params(), report.final_params);
    let stored = d.stored_params().unwrap();
    assert!((stored.wheelbase_m - report.final_params.wheelbase_m).abs() < 1e-9);
    // And it is close to the truth (left wheel nominal, as the demo robot is built).
    let truth = *d.sim().truth();
    assert!((report.final_params.wheelbase_m / truth.wheelbase_m - 1.0).abs() < 1e-3);
    assert!((report.final_params.e_d() / truth.e_d() - 1.0).abs() < 2e-4);
    drop(d);
    // The backup holds the original parameters.
    let backup: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report.backup_path).unwrap()).unwrap();
    assert_eq!(backup["active"]["wheelbase_m"], 0.39);
    // The report directory.
    let files = odocal::report::write_dir(&report, &report_dir).unwrap();
    for name in [
        "report.json",
        "report.md",
        "paths.svg",
        "heading_errors.svg",
        "end_points.svg",
    ] {
        let f = report_dir.join(name);
        assert!(files.contains(&f), "{name} missing");
        assert!(
            std::fs::metadata(&f).unwrap().len() > 200,
            "{name} is empty"
        );
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report_dir.join("report.json")).unwrap())
            .unwrap();
    assert!(json["e_max_sys_before_m"].as_f64().unwrap() > 1.0);
    assert!(json["estimates"]
        .as_array()
        .unwrap()
        .iter()
        .any(|e| e["method"] == "exact"));
    let svg = std::fs::read_to_string(report_dir.join("paths.svg")).unwrap();
    assert!(
        svg.contains("<polyline") || svg.contains("<path"),
        "no lines drawn"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_dry_run_writes_nothing() {
    let mut opts = demo_options("dry");
    opts.routine.write_back = WritePolicy::DryRun;
    let (report, device) = run_demo(&opts, &mut Unattended, &CancellationToken::new())
        .await
        .unwrap();
    assert!(!report.written);
    assert_eq!(report.rounds.len(), 1);
    assert!(
        report.rounds[0].params_after.is_some(),
        "a proposal is still reported"
    );
    assert!(report.verification.is_empty());
    let d = lock(&device);
    assert_eq!(d.active_params(), opts.nominal);
    assert!(d.stored_params().is_none());
}

/// A UI that answers with a script and records what it saw.
struct Scripted {
    answers: Vec<bool>,
    questions: Vec<String>,
    cancel_on: Option<(String, CancellationToken)>,
}

impl RoutineUi for Scripted {
    fn confirm(&mut self, question: &str) -> bool {
        self.questions.push(question.to_string());
        if self.answers.is_empty() {
            false
        } else {
            self.answers.remove(0)
        }
    }
    fn event(&mut self, event: &RoutineEvent) {
        if let Some((trigger, token)) = &self.cancel_on {
            if format!("{event:?}").contains(trigger.as_str()) {
                token.cancel();
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn declining_to_move_or_to_write_changes_nothing() {
    let mut opts = demo_options("decline");
    opts.routine.write_back = WritePolicy::Ask;
    opts.routine.confirm_motion = true;
    let dir = opts.routine.backup_dir.clone().unwrap();
    opts.routine.report_dir = Some(dir.join("report"));
    let mut ui = Scripted {
        answers: vec![false],
        questions: Vec::new(),
        cancel_on: None,
    };
    let err = run_demo(&opts, &mut ui, &CancellationToken::new())
        .await
        .unwrap_err();
    assert!(
        matches!(err, DemoError::Routine(RoutineError::Declined(_))),
        "{err}"
    );
    assert!(ui.questions[0].contains("may it move"));
    // Declined before the robot moved: no backup, no partial report, no directory.
    assert!(!dir.exists(), "declining leaves nothing behind");
    // Allowed to move, not to write.
    let mut ui = Scripted {
        answers: vec![true, false],
        questions: Vec::new(),
        cancel_on: None,
    };
    let (report, device) = run_demo(&opts, &mut ui, &CancellationToken::new())
        .await
        .unwrap();
    assert!(
        ui.questions[1].contains("wheelbase (m)"),
        "old → new is shown: {}",
        ui.questions[1]
    );
    assert!(!report.written);
    assert_eq!(lock(&device).active_params(), opts.nominal);
    // Once it moved, the backup was taken (into the backup directory, none elsewhere).
    assert_eq!(
        std::fs::read_dir(&dir).unwrap().count(),
        2,
        "the backup and report/"
    );
    assert!(
        report.backup_path.starts_with(&dir),
        "{:?}",
        report.backup_path
    );
    let _ = std::fs::remove_dir_all(&dir);
}

fn real_time_device(storage_fails: bool) -> Arc<Mutex<MockDevice>> {
    common::mock_device_with(0.2, 1, |c| c.storage_fails = storage_fails)
}

fn quick_routine(name: &str) -> RoutineConfig {
    common::virtual_routine(temp_dir(name))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_nack_on_save_restores_the_backup() {
    let device = real_time_device(true);
    let (stream, _task) = spawn_duplex(device.clone(), TimeMode::Virtual, FaultConfig::default());
    let (client, _) = Client::connect(stream, LinkConfig::default())
        .await
        .unwrap();
    let truth = MockTruth(device.clone());
    let err = run(
        &Base::single(client),
        &quick_routine("save-nack"),
        Some(&truth),
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await
    .unwrap_err();
    match &err {
        RoutineError::Restored {
            source,
            committed: saved,
            ..
        } => {
            assert!(!saved, "a refused save leaves the stored copy alone");
            assert!(source.to_string().contains("STORAGE_FAILURE"), "{source}");
        }
        other => panic!("expected a restored write, got {other}"),
    }
    let d = lock(&device);
    assert_eq!(d.active_params(), WheelParams::nominal(0.15, 0.39, 4096.0));
    assert!(d.stored_params().is_none());
    assert!(!d.is_moving());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cancelling_mid_square_stops_the_base_and_leaves_parameters_alone() {
    let device = real_time_device(false);
    let (stream, _task) = spawn_duplex(
        device.clone(),
        TimeMode::RealTime { scale: 20.0 },
        FaultConfig::default(),
    );
    let (client, _) = Client::connect(stream, LinkConfig::default())
        .await
        .unwrap();
    let token = CancellationToken::new();
    let mut ui = Scripted {
        answers: vec![true; 8],
        questions: Vec::new(),
        // Cancel after the third motion of the second square of round 1: mid-square.
        cancel_on: Some((
            "run: 2, of: 4, direction: Cw, motion: 3".into(),
            token.clone(),
        )),
    };
    let err = run(
        &Base::single(client),
        &quick_routine("cancel"),
        None,
        &mut ui,
        &token,
    )
    .await
    .unwrap_err();
    assert!(matches!(err, RoutineError::Cancelled), "{err}");
    tokio::time::sleep(Duration::from_millis(30)).await;
    let d = lock(&device);
    assert!(!d.is_moving(), "the base must be stopped");
    assert!(d.counters().stops >= 1);
    assert_eq!(d.active_params(), WheelParams::nominal(0.15, 0.39, 4096.0));
    assert!(d.stored_params().is_none());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cancelling_after_a_write_restores_ram_and_storage() {
    let device = real_time_device(false);
    let (stream, _task) = spawn_duplex(
        device.clone(),
        TimeMode::RealTime { scale: 20.0 },
        FaultConfig::default(),
    );
    let (client, _) = Client::connect(stream, LinkConfig::default())
        .await
        .unwrap();
    let token = CancellationToken::new();
    let mut ui = Scripted {
        answers: vec![true; 8],
        questions: Vec::new(),
        cancel_on: Some(("round 2".into(), token.clone())),
    };
    let err = run(
        &Base::single(client),
        &quick_routine("cancel-after"),
        None,
        &mut ui,
        &token,
    )
    .await
    .unwrap_err();
    match err {
        RoutineError::Restored {
            source,
            committed: saved,
            ..
        } => {
            assert!(matches!(*source, RoutineError::Cancelled));
            assert!(saved);
        }
        other => panic!("expected a restored cancellation, got {other}"),
    }
    let d = lock(&device);
    let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
    assert_eq!(d.active_params(), nominal);
    assert_eq!(
        d.stored_params(),
        Some(nominal),
        "the stored copy is the backup again"
    );
    assert!(!d.is_moving());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_clockwise_compass_is_caught_before_anything_is_written() {
    let mut cfg =
        MockConfig::with_ratios(WheelParams::nominal(0.15, 0.39, 4096.0), 0.976, 0.992).unwrap();
    cfg.compass = odocal::mock::CompassConvention::Clockwise;
    let device = Arc::new(Mutex::new(MockDevice::new(cfg).unwrap()));
    let (stream, _task) = spawn_duplex(device.clone(), TimeMode::Virtual, FaultConfig::default());
    let (client, _) = Client::connect(stream, LinkConfig::default())
        .await
        .unwrap();
    let err = run(
        &Base::single(client),
        &quick_routine("cw-compass"),
        None,
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await
    .unwrap_err();
    assert!(err.to_string().contains("clockwise-positive"), "{err}");
    assert!(lock(&device).stored_params().is_none());
    assert_eq!(
        lock(&device).active_params(),
        WheelParams::nominal(0.15, 0.39, 4096.0)
    );
}

/// The whole routine on a link that corrupts 1 % of bytes and loses 5 % of frames in both
/// directions, with the default link settings and the default method: 20 seeds, every one
/// completes, no motion runs twice, and the written combinations are within 0.05 % of the truth
/// and within 3 of the standard errors the last round stated.
///
/// The methods that read only the headings at rest (request and answer, retried until answered)
/// give the clean link's estimates in the first round (to the compass swing's fit, which reads
/// the stream). The leg methods read the telemetry
/// stream, of which the lossy link drops samples (the encoder counts are cumulative, so a gap only
/// thins the heading average): they differ from the clean run, but within what they state.
///
/// Virtual time: the mock completes motions as they are accepted and tokio's clock is paused,
/// so retries and deadlines cost no wall-clock time.
#[tokio::test(start_paused = true)]
async fn calibrate_completes_on_a_lossy_link_twenty_seeds_out_of_twenty() {
    async fn calibrate(
        faults: FaultConfig,
        name: &str,
    ) -> (
        Report,
        odocal::mock::DeviceCounters,
        odocal::hal::LinkStatsSnapshot,
        WheelParams,
        u64,
    ) {
        let device = real_time_device(false);
        let (stream, _task) = spawn_duplex(device.clone(), TimeMode::Virtual, faults);
        let (client, _) = Client::connect(stream, LinkConfig::default())
            .await
            .unwrap_or_else(|e| panic!("{name}: connect: {e}"));
        let truth = MockTruth(device.clone());
        let link = client.clone();
        let mut ui = CountTurns(0);
        let report = run(
            &Base::single(client),
            &quick_routine(name),
            Some(&truth),
            &mut ui,
            &CancellationToken::new(),
        )
        .await
        .unwrap_or_else(|e| panic!("{name}: {e}"));
        let d = lock(&device);
        (report, d.counters(), link.stats(), *d.sim().truth(), ui.0)
    }
    struct CountTurns(u64);
    impl RoutineUi for CountTurns {
        fn confirm(&mut self, _: &str) -> bool {
            true
        }
        fn event(&mut self, event: &RoutineEvent) {
            if let RoutineEvent::Realigned { turns, .. } = event {
                self.0 += u64::from(*turns);
            }
        }
    }
    let at_rest_only = |r: &Report| -> Vec<Vec<odocal::calibration::Estimate>> {
        r.rounds
            .iter()
            .map(|round| {
                round
                    .estimates
                    .iter()
                    .filter(|e| !e.method.needs_leg_headings() && !e.method.needs_positions())
                    .cloned()
                    .collect()
            })
            .collect()
    };
    let (clean, clean_counters, _, _, _) = calibrate(FaultConfig::default(), "lossy-clean").await;
    assert_eq!(
        clean_counters.motions_accepted,
        clean_counters.motions_completed
    );
    let mut completed = 0;
    for seed in 0..20 {
        let faults = FaultConfig {
            corrupt_byte_rate: 0.01,
            drop_frame_rate: 0.05,
            seed,
            ..FaultConfig::default()
        };
        let (report, counters, stats, truth, turns) =
            calibrate(faults, &format!("lossy-{seed}")).await;
        // The faults bite: hundreds of frames lost or corrupted and retried.
        assert!(
            stats.retries > 50 && stats.decoder_dropped_bytes > 0 && stats.telemetry_dropped > 0,
            "seed {seed}: {stats:?}"
        );
        assert!(report.converged, "seed {seed}");
        assert!(report.written, "seed {seed}");
        // The at-rest methods are untouched by the loss (in the first round: later rounds
        // start from what the leg method wrote) but for the compass swing's deviation, fitted
        // from the streamed (lossy) telemetry: far inside their standard errors.
        for (a, b) in at_rest_only(&report)[0]
            .iter()
            .zip(&at_rest_only(&clean)[0])
        {
            assert_eq!(a.method, b.method);
            if let (Some(sb), Some(sd)) = (b.e_b_std_err, b.e_d_std_err) {
                assert!(
                    (a.e_b - b.e_b).abs() < 0.25 * sb && (a.e_d - b.e_d).abs() < 0.25 * sd,
                    "seed {seed}: {a:?} vs {b:?}"
                );
            }
        }
        for round in &report.rounds {
            assert!(
                round
                    .estimates
                    .iter()
                    .any(|e| e.method == round.chosen.method),
                "seed {seed}"
            );
        }
        // What the last round states: the written parameters' error is its estimate (zero when
        // it wrote its correction), within its standard errors.
        let last = report.rounds.last().expect("a round ran");
        let (sd, sb) = (
            last.chosen.e_d_std_err.expect("a standard error"),
            last.chosen.e_b_std_err.expect("a standard error"),
        );
        let c = &last.chosen.correction;
        let (stated_d, stated_b) = if last.written {
            (0.0, 0.0)
        } else {
            (
                c.right_diameter_scale / c.left_diameter_scale - 1.0,
                2.0 * c.wheelbase_scale / (c.left_diameter_scale + c.right_diameter_scale) - 1.0,
            )
        };
        let (err_d, err_b) = common::combination_errors(&report.final_params, &truth);
        let what = format!(
            "seed {seed}: D_R/D_L {err_d:+.2e} (stated {:+.2e} ± {sd:.1e}), b/D {err_b:+.2e} \
             (stated {:+.2e} ± {sb:.1e}) by {:?}",
            -stated_d, -stated_b, last.chosen.method
        );
        assert!(err_d.abs() < 5e-4 && err_b.abs() < 5e-4, "{what}");
        assert!(
            (err_d + stated_d).abs() < 3.0 * sd && (err_b + stated_b).abs() < 3.0 * sb,
            "{what}"
        );
        // Every motion the routine commanded ran exactly once: the swing's four full turns,
        // 8 per square and the realigning turns.
        assert!(report.swing.is_some(), "seed {seed}");
        let squares: usize =
            report.rounds.iter().map(|r| r.runs.len()).sum::<usize>() + report.verification.len();
        assert_eq!(
            counters.motions_accepted,
            4 + 8 * squares as u64 + turns,
            "seed {seed}: {counters:?}"
        );
        assert_eq!(counters.motions_completed, counters.motions_accepted);
        completed += 1;
    }
    assert_eq!(completed, 20);
}

/// `demo --true-eb 0.5` once oscillated through three rounds, left the robot worse and said
/// "parameters written and saved" with exit 0. Now it fails, and the simulated robot's
/// parameters, in use and stored, are what they were before the run.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_robot_the_routine_cannot_fix_fails_and_keeps_its_parameters() {
    for allow_large_change in [false, true] {
        let mut opts = demo_options(&format!("half-eb-{allow_large_change}"));
        opts.true_e_b = 0.5;
        if allow_large_change {
            opts.routine.max_change = 1.0;
            opts.routine.allow_large_change = true;
        }
        let device = odocal::demo::demo_device(&opts).unwrap();
        let before = {
            let d = lock(&device);
            (d.active_params(), d.stored_params())
        };
        let result =
            odocal::demo::run_demo_on(&device, &opts, &mut Unattended, &CancellationToken::new())
                .await;
        let d = lock(&device);
        match result {
            Err(err) => assert_eq!(
                (d.active_params(), d.stored_params()),
                before,
                "large change allowed: {allow_large_change}: {err}"
            ),
            // Succeeding is allowed only as a real fix: converged and clearly better.
            Ok(report) => {
                assert!(allow_large_change && report.converged);
                assert!(
                    report.mean_abs_heading_error_after_deg.unwrap() * 10.0
                        < report.mean_abs_heading_error_before_deg
                );
            }
        }
    }
}
