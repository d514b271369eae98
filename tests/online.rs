//! The online estimator (augmented EKF) in simulation along random non-square paths, and on
//! the recorded OptiOdom runs.

mod common;

use common::odocal_json;
use odocal::calibration::online::{OnlineConfig, OnlineEstimator, ScaleSource};
use odocal::calibration::{estimate, Method};
use odocal::kinematics::{Correction, SplitConvention, WheelParams};
use odocal::offline::dataset::OptiOdomSet;
use odocal::sim::{NoiseModel, Simulator};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SLIP: f64 = 0.005;
const COMPASS_DEG: f64 = 0.37;

/// A random drive: every 2 s a new speed (0.1–0.5 m/s) and turn rate (±1.5 rad/s), as the
/// encoder counts of each `dt` step for a robot configured with `nominal`.
struct RandomPath {
    rng: ChaCha8Rng,
    v: f64,
    w: f64,
    t: f64,
}

impl RandomPath {
    fn new(seed: u64) -> Self {
        RandomPath {
            rng: ChaCha8Rng::seed_from_u64(seed),
            v: 0.3,
            w: 0.0,
            t: 0.0,
        }
    }

    /// Encoder counts (left, right) of the next `dt` seconds.
    fn counts(&mut self, dt: f64, nominal: &WheelParams) -> (f64, f64) {
        if self.t <= 0.0 {
            self.v = self.rng.random_range(0.1..0.5);
            self.w = self.rng.random_range(-1.5..1.5);
            self.t = 2.0;
        }
        self.t -= dt;
        let half = 0.5 * self.w * nominal.wheelbase_m;
        (
            (self.v - half) * dt / nominal.left_m_per_count(),
            (self.v + half) * dt / nominal.right_m_per_count(),
        )
    }
}

/// A simulated robot with `truth` applied to `nominal`, with the compass noise and per-step
/// slip the filters here assume.
fn noisy_robot(nominal: &WheelParams, truth: &Correction, seed: u64) -> Simulator {
    let noise = NoiseModel {
        compass_sigma_rad: COMPASS_DEG.to_radians(),
        wheel_slip_sigma: SLIP,
        ..NoiseModel::default()
    };
    Simulator::new(truth.apply(nominal).unwrap(), *nominal, noise, seed).unwrap()
}

/// A filter whose noise model matches [`noisy_robot`].
fn matched_config(nominal: &WheelParams) -> OnlineConfig {
    let mut cfg = OnlineConfig::new(*nominal);
    cfg.slip_fraction = SLIP;
    cfg.count_noise = 0.0;
    cfg.heading_sigma_rad = COMPASS_DEG.to_radians();
    cfg
}

struct Drive {
    filter: OnlineEstimator,
    true_u: (f64, f64),
    truth: Correction,
}

/// Drives a random path of `steps` × 10 ms (random curvature and speed changes every ~2 s),
/// with a compass reading every 100 ms, and runs the filter alongside.
fn random_drive(seed: u64, steps: usize) -> Drive {
    let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
    let truth = Correction {
        left_diameter_scale: 1.0,
        right_diameter_scale: 0.992,
        wheelbase_scale: 0.976,
    };
    let mut sim = noisy_robot(&nominal, &truth, seed);
    let mut filter = OnlineEstimator::new(matched_config(&nominal)).unwrap();
    let mut path = RandomPath::new(seed ^ 0xABCD);
    filter.update_heading(sim.read_heading());
    for step in 0..steps {
        let (cl, cr) = path.counts(0.01, &nominal);
        sim.step_counts(cl, cr);
        filter.predict_counts(cl, cr);
        if step % 10 == 9 {
            filter.update_heading(sim.read_heading());
        }
    }
    Drive {
        filter,
        true_u: (
            truth.left_diameter_scale / truth.wheelbase_scale,
            truth.right_diameter_scale / truth.wheelbase_scale,
        ),
        truth,
    }
}

#[test]
fn converges_to_the_truth_within_three_sigma() {
    for seed in 0..10 {
        let d = random_drive(seed, 12_000); // 2 minutes, ~36 m
        let e = d
            .filter
            .estimate(ScaleSource::Convention(SplitConvention::LeftNominal))
            .unwrap();
        let (true_b, true_d) = (d.truth.e_b(), d.truth.e_d());
        assert!(
            (e.e_b - true_b).abs() < 3.0 * e.e_b_std,
            "seed {seed}: E_b {} ± {} vs {true_b}",
            e.e_b,
            e.e_b_std
        );
        assert!(
            (e.e_d - true_d).abs() < 3.0 * e.e_d_std,
            "seed {seed}: E_d {} ± {} vs {true_d}",
            e.e_d,
            e.e_d_std
        );
        // And it has learned something: far tighter than the 5 % prior.
        assert!(e.e_b_std < 0.005 && e.e_d_std < 0.002, "{e:?}");
        assert!(e.distance_m > 20.0);
    }
}

#[test]
fn the_filter_is_consistent_over_many_seeds() {
    // NEES of (u_L, u_R) averaged over M runs: for a consistent filter M·mean ~ χ²(2M).
    // 95 % band for M = 60: χ²(120) ∈ [91.57, 152.21].
    let m = 60;
    let mut nees = 0.0;
    let mut nis = 0.0;
    for seed in 100..100 + m {
        let d = random_drive(seed, 6_000);
        nees += d.filter.nees_ratios(d.true_u.0, d.true_u.1);
        nis += d.filter.nis_mean().0;
    }
    let total = nees;
    eprintln!(
        "NEES sum {total:.1} over {m} runs, mean heading NIS {:.3}",
        nis / m as f64
    );
    assert!(
        (91.57..=152.21).contains(&total),
        "sum of NEES {total} over {m} runs outside the 95 % band [91.6, 152.2]"
    );
    let nis = nis / m as f64;
    assert!((0.9..1.1).contains(&nis), "mean heading NIS {nis}");
}

fn optiodom() -> Option<std::path::PathBuf> {
    common::optiodom("free")
}

/// Runs the filter over every run of `set`: ticks predict, ground-truth heading updates.
fn learn(filter: &mut OnlineEstimator, set: &OptiOdomSet) {
    for run in &set.runs {
        filter.restart_pose();
        for s in &run.samples {
            filter.predict_counts(s.left_counts, s.right_counts);
            filter.update_heading(s.truth.heading_rad);
        }
    }
}

#[test]
fn learned_on_a_free_run_it_improves_the_other_recorded_runs() {
    let Some(root) = optiodom() else { return };
    let free = OptiOdomSet::load(root.join("free/020120212354")).unwrap();
    let mut cfg = OnlineConfig::new(free.configured);
    cfg.slip_fraction = 0.02;
    cfg.heading_sigma_rad = 0.5f64.to_radians();
    let mut filter = OnlineEstimator::new(cfg).unwrap();
    learn(&mut filter, &free);
    let online = filter
        .estimate(ScaleSource::Convention(SplitConvention::LeftNominal))
        .unwrap();
    let calibrated = online.correction.apply(&free.configured).unwrap();
    // Other runs of the same robot with the same configured parameters: the other free set
    // and the square sets.
    let others = [
        "free/030120210001",
        "square/231220200029",
        "square/231220200040",
        "square/231220200045",
        "square/230620202042",
    ];
    for id in others {
        let set = OptiOdomSet::load(root.join(id)).unwrap();
        assert_eq!(
            set.configured, free.configured,
            "{id} is the same configuration"
        );
        let (before, _) = set.evaluate(&set.configured);
        let (after, _) = set.evaluate(&calibrated);
        assert!(
            after < before,
            "{id}: final heading error {:.2}° with nominal, {:.2}° with the online estimate",
            before.to_degrees(),
            after.to_degrees()
        );
    }
    // Compared with the square test on the same robot: report the difference (the free run is
    // short and mostly straight, so its E_b is less certain than a square test's).
    let square = OptiOdomSet::load(root.join("square/231220200040")).unwrap();
    let sq = estimate(
        Method::Exact,
        &square.square_test().unwrap(),
        SplitConvention::LeftNominal,
    )
    .unwrap();
    eprintln!(
        "online (free run, {:.1} m): E_b {:.4} ± {:.4}, E_d {:.5} ± {:.5}; square test: E_b {:.4} ± {:.4}, E_d {:.5} ± {:.5}",
        online.distance_m, online.e_b, online.e_b_std, online.e_d, online.e_d_std,
        sq.e_b, sq.e_b_std_err.unwrap_or(f64::NAN), sq.e_d, sq.e_d_std_err.unwrap_or(f64::NAN)
    );
    // Agreement within the stated uncertainties (3 σ of the difference).
    let sb = online.e_b_std.hypot(sq.e_b_std_err.unwrap());
    let sd = online.e_d_std.hypot(sq.e_d_std_err.unwrap());
    assert!(
        (online.e_b - sq.e_b).abs() < 3.0 * sb,
        "E_b differs by more than 3σ"
    );
    assert!(
        (online.e_d - sq.e_d).abs() < 3.0 * sd,
        "E_d differs by more than 3σ"
    );
}

/// Writes a 3-minute random drive as a telemetry log at 50 Hz (counts unwrapped) for a robot
/// configured with `nominal` whose truth is `truth`; the heading is read `delay_samples` samples
/// late (a sensor delay or a clock offset of `delay_samples × 20 ms`).
fn write_random_log(
    path: &std::path::Path,
    nominal: &WheelParams,
    truth: &Correction,
    delay_samples: usize,
) {
    use odocal::offline::log::{LogHeader, LogWriter, TelemetryLine};
    let mut sim = noisy_robot(nominal, truth, 42);
    let header = LogHeader {
        odocal_version: "test".into(),
        device: None,
        params: *nominal,
        period_ms: 20,
        base: None,
        clocks: odocal::calibration::recording::Clocks::Shared,
    };
    let mut log = LogWriter::create(path, header).unwrap();
    let mut path_gen = RandomPath::new(42);
    let (mut cl, mut cr) = (0.0f64, 0.0f64);
    let dt = 0.02;
    let mut headings = std::collections::VecDeque::new();
    for step in 0..9000u32 {
        let (dl, dr) = path_gen.counts(dt, nominal);
        sim.step_counts(dl, dr);
        cl += dl;
        cr += dr;
        headings.push_back(sim.read_heading());
        let heading_rad = if headings.len() > delay_samples {
            headings.pop_front().unwrap()
        } else {
            headings[0]
        };
        log.sample(&TelemetryLine {
            sample_index: step,
            device_time_s: f64::from(step) * dt,
            left_counts: cl.round() as i64,
            right_counts: cr.round() as i64,
            heading_rad,
            heading_valid: true,
        })
        .unwrap();
    }
    log.flush().unwrap();
}

#[test]
fn track_reads_a_recorded_log_and_converges() {
    let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
    let truth = Correction {
        left_diameter_scale: 1.0,
        right_diameter_scale: 0.992,
        wheelbase_scale: 0.976,
    };
    let dir = std::env::temp_dir().join(format!("odocal-track-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let log_path = dir.join("drive.jsonl");
    write_random_log(&log_path, &nominal, &truth, 0);
    let v = odocal_json(&[
        "track",
        "--log",
        log_path.to_str().unwrap(),
        "--slip-fraction",
        "0.005",
        "--json",
    ]);
    let est = v["estimates"].as_array().unwrap();
    assert!(est.len() > 10, "running estimates are printed");
    let last = est.last().unwrap();
    assert_eq!(last["method"], "online");
    let f = |k: &str| last[k].as_f64().unwrap();
    assert!((f("e_b") - 0.976).abs() < 3.0 * f("e_b_std"), "{last}");
    assert!((f("e_d") - 0.992).abs() < 3.0 * f("e_d_std"), "{last}");
    assert!(f("distance_m") > 40.0);
    // Standard deviations shrink as the robot drives.
    assert!(est[0]["e_b_std"].as_f64().unwrap() > 3.0 * f("e_b_std"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_heading_stream_three_tenths_of_a_second_late_is_detected_reported_and_corrected() {
    use odocal::calibration::tracker::Tracker;
    use odocal::offline::log::read_log;
    let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
    let truth = Correction {
        left_diameter_scale: 1.0,
        right_diameter_scale: 0.992,
        wheelbase_scale: 0.976,
    };
    let dir = common::scratch("track-offset");
    std::fs::create_dir_all(&dir).unwrap();
    let log_path = dir.join("late.jsonl");
    write_random_log(&log_path, &nominal, &truth, 15);
    let v = odocal_json(&[
        "track",
        "--log",
        log_path.to_str().unwrap(),
        "--slip-fraction",
        "0.005",
        "--json",
    ]);
    let offsets = v["time_offsets"].as_array().unwrap();
    assert_eq!(offsets.len(), 1, "{v}");
    let found = offsets[0]["offset"]["offset_s"].as_f64().unwrap();
    assert!((found - 0.3).abs() < 0.02, "found {found} s");
    assert_eq!(offsets[0]["corrected"], true);
    // Corrected, the estimate is the truth's within 3σ and the NIS is about 1.
    let last = v["estimates"].as_array().unwrap().last().unwrap().clone();
    let f = |k: &str| last[k].as_f64().unwrap();
    assert!((f("e_b") - 0.976).abs() < 3.0 * f("e_b_std"), "{last}");
    assert!((f("e_d") - 0.992).abs() < 3.0 * f("e_d_std"), "{last}");
    let nis = v["heading_nis_mean"].as_f64().unwrap();
    assert!((0.5..2.0).contains(&nis), "NIS {nis}");
    // Fed as it is, the same log puts the filter far off: what the correction saved.
    let (header, rec) = read_log(&log_path).unwrap();
    let mut raw = Tracker::new(
        {
            let mut c = OnlineConfig::new(header.params);
            c.slip_fraction = 0.005;
            c
        },
        ScaleSource::Convention(SplitConvention::LeftNominal),
        1.0,
    )
    .unwrap();
    for (t, h) in rec.travel.iter().zip(&rec.headings) {
        raw.push_travel(*t);
        raw.push_heading(h.clone());
    }
    raw.finish_stream();
    let (raw_nis, _) = raw.filter().nis_mean();
    let g = raw.filter().gate_stats();
    assert!(
        raw_nis > 2.0 * nis || g.rejected > 100,
        "uncorrected NIS {raw_nis}, gate {g:?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn track_on_the_recorded_free_run_prints_converging_estimates() {
    let Some(root) = optiodom() else { return };
    let v = odocal_json(&[
        "track",
        "--dataset",
        root.join("free/030120210001").to_str().unwrap(),
        "--json",
    ]);
    let est = v["estimates"].as_array().unwrap();
    let std_b: Vec<f64> = est.iter().map(|e| e["e_b_std"].as_f64().unwrap()).collect();
    assert!(std_b.len() > 10);
    assert!(
        std_b.windows(2).all(|w| w[1] <= w[0] * 1.05),
        "std must shrink: {std_b:?}"
    );
    assert!(std_b[std_b.len() - 1] < 0.25 * std_b[0]);
    let (bad, _, err) = {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_odocal"))
            .args(["track", "--log", "/nonexistent.jsonl"])
            .output()
            .unwrap();
        (
            out.status.success(),
            (),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    assert!(!bad && err.contains("/nonexistent.jsonl"), "{err}");
}

#[test]
fn position_fixes_make_the_wheel_scale_observable() {
    // Both wheels 1.2 % larger and the base 2.4 % shorter than configured: the scale is not the
    // left-nominal one, so only absolute positions can reveal it.
    let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
    let truth = Correction {
        left_diameter_scale: 1.012,
        right_diameter_scale: 1.004,
        wheelbase_scale: 0.976,
    };
    let mut sim = noisy_robot(&nominal, &truth, 9);
    let mut cfg = matched_config(&nominal);
    cfg.position_sigma_m = 0.01;
    let mut f = OnlineEstimator::new(cfg).unwrap();
    let mut path = RandomPath::new(9);
    let mut rng = ChaCha8Rng::seed_from_u64(10);
    f.update_heading(sim.read_heading());
    for step in 0..12_000 {
        let (cl, cr) = path.counts(0.01, &nominal);
        sim.step_counts(cl, cr);
        f.predict_counts(cl, cr);
        if step % 10 == 9 {
            f.update_heading(sim.read_heading());
        }
        if step % 100 == 99 {
            // An external tracker with 1 cm noise, once a second.
            let p = sim.pose();
            f.update_position(
                p.x_m + rng.random_range(-0.017..0.017),
                p.y_m + rng.random_range(-0.017..0.017),
            );
        }
    }
    let e = f.estimate(ScaleSource::Filter).unwrap();
    assert!((e.e_b - 0.976).abs() < 3.0 * e.e_b_std, "{e:?}");
    let c = e.correction;
    assert!((c.left_diameter_scale - 1.012).abs() < 0.002, "{c:?}");
    assert!((c.right_diameter_scale - 1.004).abs() < 0.002, "{c:?}");
    let (nis, n) = f.nis_position_mean();
    assert!(n == 120 && nis < 4.0, "position NIS {nis}");
    // Heading-only, the left-nominal answer would have been off by the unseen scale.
    let ln = f
        .estimate(ScaleSource::Convention(SplitConvention::LeftNominal))
        .unwrap();
    assert!((ln.e_b - 0.976 / 1.012).abs() < 0.003, "{ln:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn live_telemetry_from_the_mock_calibrates_and_writes_back() {
    use odocal::base::write::WritePolicy;
    use odocal::base::Base;
    use odocal::calibration::tracker::Tracker;
    use odocal::hal::link::LinkConfig;
    use odocal::hal::Client;
    use odocal::kinematics::Direction;
    use odocal::mock::{lock, spawn_duplex, FaultConfig, TimeMode};
    use odocal::protocol::message::ParamSource;
    use odocal::routine::square::{run_square, SquareCommand};
    use odocal::routine::track::{write_back, WriteBack};
    use std::time::Duration;

    let device = common::mock_device(COMPASS_DEG, 1);
    let (stream, _task) = spawn_duplex(device.clone(), TimeMode::Virtual, FaultConfig::default());
    let (client, _) = Client::connect(stream, LinkConfig::default())
        .await
        .unwrap();
    let configured = client.get_params(ParamSource::Active).await.unwrap();
    let mut cfg = OnlineConfig::new(configured);
    cfg.slip_fraction = 0.001;
    let mut tracker = Tracker::new(
        cfg,
        ScaleSource::Convention(SplitConvention::LeftNominal),
        1.0,
    )
    .unwrap();
    let base = Base::single(client.clone());
    tracker.start_stream(base.clocks());
    let period = Duration::from_millis(20);
    let mut travel = base.drive.travel(period).await.unwrap().unwrap();
    let mut headings = base.heading.stream(period).await.unwrap().unwrap();
    // Any driving will do; squares of 2 m in both directions here.
    for direction in [Direction::Cw, Direction::Ccw, Direction::Cw, Direction::Ccw] {
        let cmd = SquareCommand {
            side_m: 2.0,
            direction,
            max_speed_m_s: 0.3,
            max_rate_rad_s: 1.0,
            heading_samples: 1,
            settle: Duration::ZERO,
            stream_period: Duration::from_millis(20),
        };
        run_square(&base, &cmd, |_| {}).await.unwrap();
        while let Ok(s) = travel.try_recv() {
            tracker.push_travel(s);
        }
        while let Ok(s) = headings.try_recv() {
            tracker.push_heading(s);
        }
    }
    tracker.finish_stream();
    let e = tracker.estimate().unwrap();
    assert!(
        (e.e_b - 0.976).abs() < 3.0 * e.e_b_std && e.e_b_std < 0.002,
        "{e:?}"
    );
    assert!(
        (e.e_d - 0.992).abs() < 3.0 * e.e_d_std && e.e_d_std < 0.002,
        "{e:?}"
    );
    let backup_dir = std::env::temp_dir().join(format!("odocal-online-wb-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&backup_dir);
    // What `track --write-back` does: refused while the estimate is not precise enough...
    let ui = &mut odocal::base::write::Unattended;
    let policy = WritePolicy::Yes;
    let early = write_back(&base, &e, &configured, 1e-9, policy, &backup_dir, ui)
        .await
        .unwrap();
    assert!(
        matches!(&early, WriteBack::TooUncertain(why) if why.contains("--max-std")),
        "{early:?}"
    );
    assert!(
        !backup_dir.exists(),
        "nothing backed up for a write not made"
    );
    // ... and written through the write service once it is.
    let done = write_back(&base, &e, &configured, 0.002, policy, &backup_dir, ui)
        .await
        .unwrap();
    let WriteBack::Written(applied) = done else {
        panic!("not written: {done:?}");
    };
    let backup = std::fs::read_dir(&backup_dir)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    assert!(backup.is_file());
    let d = lock(&device);
    assert_eq!(d.active_params(), applied);
    assert_eq!(d.stored_params(), Some(applied));
    assert!((applied.wheelbase_m / d.sim().truth().wheelbase_m - 1.0).abs() < 0.003);
    let _ = std::fs::remove_dir_all(&backup_dir);
}

#[test]
fn a_log_without_driving_is_an_error_not_a_nan() {
    use odocal::offline::log::{LogHeader, LogWriter, TelemetryLine};
    let dir = common::scratch("track-empty");
    std::fs::create_dir_all(&dir).unwrap();
    let header = LogHeader {
        odocal_version: "test".into(),
        device: None,
        params: WheelParams::nominal(0.15, 0.39, 4096.0),
        period_ms: 20,
        base: None,
        clocks: odocal::calibration::recording::Clocks::Shared,
    };
    // A header and nothing else; then a robot that stood still.
    let empty = dir.join("empty.jsonl");
    LogWriter::create(&empty, header.clone())
        .unwrap()
        .flush()
        .unwrap();
    let still = dir.join("still.jsonl");
    let mut log = LogWriter::create(&still, header).unwrap();
    for i in 0..50u32 {
        log.sample(&TelemetryLine {
            sample_index: i,
            device_time_s: f64::from(i) * 0.02,
            left_counts: 0,
            right_counts: 0,
            heading_rad: 0.1,
            heading_valid: true,
        })
        .unwrap();
    }
    log.flush().unwrap();
    drop(log);
    for path in [&empty, &still] {
        let (ok, stdout, err) = common::odocal(&["track", "--log", path.to_str().unwrap()]);
        assert!(!ok, "{path:?} must fail: {stdout}");
        assert!(
            err.contains("too little data") && !stdout.contains("NaN"),
            "{err}"
        );
    }
}
