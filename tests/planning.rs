//! `odocal plan`'s predictions against what calibrations with its plan show: 200 seeded
//! calibrations of the in-process simulated robot (virtual time) driving the plan's squares,
//! their spread beside the predicted standard errors; and a round that stops once its target
//! is reached.

mod common;

use odocal::base::HeadingSource;
use odocal::calibration::plan::{Plan, Space};
use odocal::calibration::Method;
use odocal::routine::config::{RoutineConfig, WritePolicy};
use odocal::routine::planning::{plan_of, Setting, DEFAULT_FOOTPRINT_M};

const COMPASS_SIGMA_DEG: f64 = 0.37;

/// Squares only, one round, nothing written: what the plan's first round predicts.
fn settings(method: Option<Method>) -> RoutineConfig {
    RoutineConfig {
        method,
        telemetry_ms: 50,
        swing: false,
        max_rounds: 1,
        verification_runs: 0,
        settle_s: 0.0,
        write_back: WritePolicy::DryRun,
        confirm_motion: false,
        backup_dir: Some(common::scratch("planning")),
        ..RoutineConfig::default()
    }
}

/// The plan for this robot's compass on 2 m of floor with a target that needs a few runs.
fn plan(cfg: &RoutineConfig) -> Plan {
    let kind = common::sim_base(COMPASS_SIGMA_DEG, 1).kind();
    let setting = Setting {
        space: Some(Space::MaxSide(2.0)),
        footprint_m: DEFAULT_FOOTPRINT_M,
        wheelbase_m: common::nominal().wheelbase_m,
        heading_sigma_rad: COMPASS_SIGMA_DEG.to_radians(),
        heading_kind: kind,
        readings_per_s: None,
        run_scatter_rad: 0.0,
        m_per_count: 0.0,
    };
    plan_of(cfg, &setting).expect("a plan")
}

fn std_dev(v: &[f64]) -> f64 {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
}

#[tokio::test]
async fn the_plan_predicts_the_spread_of_200_calibrations_within_20_percent() {
    // The plan for an E_d target of the default method (matched-legs, the heading along the
    // legs) and for the method at rest (exact), on the same squares.
    let target = RoutineConfig {
        target_e_d_std: Some(2e-5),
        ..settings(None)
    };
    let legs = plan(&target);
    assert_eq!(legs.method, Method::MatchedLegs);
    assert!(legs.target_reached && legs.side_m == 2.0, "{legs:?}");
    assert!(
        (2..=6).contains(&legs.runs_per_direction),
        "a few runs: {legs:?}"
    );
    // The calibrations drive the plan's squares (a fixed number: the spread at that number).
    let cfg = RoutineConfig {
        side_m: legs.side_m,
        runs_per_direction: legs.runs_per_direction,
        ..settings(None)
    };
    let at_rest = plan(&RoutineConfig {
        method: Some(Method::Exact),
        ..cfg.clone()
    });
    assert_eq!(
        (at_rest.side_m, at_rest.runs_per_direction),
        (legs.side_m, legs.runs_per_direction)
    );
    let mut estimates: Vec<[f64; 4]> = Vec::new();
    for seed in 1..=200 {
        let sim = common::sim_base(COMPASS_SIGMA_DEG, seed);
        let report = common::routine_on(&sim, &cfg)
            .await
            .expect("the routine runs");
        let round = &report.rounds[0];
        assert_eq!(round.runs.len(), 2 * legs.runs_per_direction);
        let of = |m: Method| {
            let e = round
                .estimates
                .iter()
                .find(|e| e.method == m)
                .expect("an estimate");
            (e.e_b, e.e_d)
        };
        let (b, d) = of(Method::MatchedLegs);
        let (xb, xd) = of(Method::Exact);
        estimates.push([b, d, xb, xd]);
    }
    let spread = |k: usize| std_dev(&estimates.iter().map(|e| e[k]).collect::<Vec<_>>());
    for (what, predicted, seen) in [
        ("matched-legs E_b", legs.predicted_std_e_b, spread(0)),
        ("matched-legs E_d", legs.predicted_std_e_d, spread(1)),
        ("exact E_b", at_rest.predicted_std_e_b, spread(2)),
        ("exact E_d", at_rest.predicted_std_e_d, spread(3)),
    ] {
        eprintln!("{what}: predicted {predicted:.3e}, spread of 200 {seen:.3e}");
        assert!(
            (seen / predicted - 1.0).abs() <= 0.2,
            "{what}: predicted {predicted:.3e}, 200 calibrations spread {seen:.3e}"
        );
    }
}

#[tokio::test]
async fn a_target_stops_the_squares_and_the_confirming_round_verifies() {
    let sim = common::sim_base(COMPASS_SIGMA_DEG, 7);
    let cfg = RoutineConfig {
        side_m: 2.0,
        telemetry_ms: 50,
        swing: false,
        settle_s: 0.0,
        target_e_b_std: Some(1e-4),
        write_back: WritePolicy::Yes,
        confirm_motion: false,
        backup_dir: Some(common::scratch("planning-target")),
        ..RoutineConfig::default()
    };
    let report = common::routine_on(&sim, &cfg)
        .await
        .expect("the routine runs");
    let plan = report.plan.expect("the plan is in the report");
    assert!(plan.sequential && plan.target_reached, "{plan:?}");
    let first = &report.rounds[0];
    // Pairs until the stated error is within the target, and no further.
    let n = first.runs.len() / 2;
    assert!(first.runs.len() % 2 == 0 && n >= 2, "{n}");
    let stated = first.chosen.e_b_std_err.expect("a stated error");
    assert!(stated <= 1e-4, "{stated}");
    assert!(
        first
            .stopped_because
            .as_deref()
            .is_some_and(|s| s.contains("target was reached")),
        "{first:?}"
    );
    // The first round wrote; the second confirmed with two pairs, and its squares, driven
    // with the written parameters, are the verification: no further squares.
    assert!(first.written && report.written && report.converged);
    assert_eq!(report.rounds.len(), 2);
    let second = &report.rounds[1];
    assert_eq!(second.runs.len(), 4);
    assert_eq!(report.verification, second.runs);
    let squares = report.rounds.iter().map(|r| r.runs.len()).sum::<usize>();
    let motion_s = squares as f64 * (4.0 * 2.0 / 0.2 + 2.0 * std::f64::consts::PI / 0.5);
    // Robot time: the squares' motions and the small turns back to the first heading.
    assert!(
        sim.time_s() >= motion_s && sim.time_s() < motion_s * 1.05,
        "{} s for {squares} squares",
        sim.time_s()
    );
    // The written wheelbase is within three stated errors of the truth.
    let truth = common::truth().wheelbase_m / common::nominal().wheelbase_m;
    assert!((first.chosen.e_b - truth).abs() <= 3.0 * stated);
}

/// `odocal plan`'s text, from the binary as a user runs it.
fn plan_text(args: &[&str]) -> String {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_odocal"))
        .arg("plan")
        .args(args)
        .output()
        .expect("odocal runs");
    assert!(
        out.status.success(),
        "odocal plan {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn plan_drives_the_largest_square_that_fits_and_speaks_of_a_target_only_when_given() {
    // Issue 28: with a 5 × 9.5 m floor and an E_b target, plan chose 2.5 m squares though
    // 4 m fit (4.9 × 9.3 m with a 0.5 m footprint and 10 % for drift), its "without a target"
    // line switched to 4 m silently, and its first line spoke of a target when none was given.
    let robot = [
        "--floor-m",
        "5,9.5",
        "--heading-sigma-deg",
        "0.37",
        "--wheelbase-m",
        "0.39",
        "--heading-kind",
        "magnetic",
    ];
    let with = plan_text(&[&robot[..], &["--target-eb-std", "3e-5"]].concat());
    let lines: Vec<&str> = with.lines().collect();
    assert!(lines[1].starts_with("squares of 4.00 m:"), "{with}");
    assert!(
        with.contains("the largest square that fits 5 × 9.5 m of floor"),
        "{with}"
    );
    assert!(lines[0].contains("target is reached"), "{with}");
    assert!(
        with.contains("without a target, on the same 4.00 m squares"),
        "{with}"
    );
    assert!(with.contains("--side-m 4 "), "{with}");
    let without = plan_text(&robot);
    let first = without.lines().next().unwrap_or_default();
    assert!(!first.contains("target is reached"), "{first}");
    assert!(!without.contains("without a target"), "{without}");
    assert!(without
        .lines()
        .nth(1)
        .is_some_and(|l| l.starts_with("squares of 4.00 m:")));
    // The rounding to whole encoder counts is counted when the wheels are known.
    let counted = plan_text(
        &[
            &robot[..],
            &["--wheel-diameter-m", "0.15", "--counts-per-rev", "4096"],
        ]
        .concat(),
    );
    assert!(
        counted.contains("from rounding every motion to whole encoder counts"),
        "{counted}"
    );
}
