//! The routine on the in-process simulated base: no protocol, no pseudo-terminal, virtual
//! time. The whole procedure and its failure paths, in milliseconds.

mod common;

use odocal::base::transaction::read_backup;
use odocal::base::{Base, GroundTruth};
use odocal::kinematics::WheelParams;
use odocal::mock::{SimBase, SimFaults};
use odocal::report::plots::reintegrated;
use odocal::routine::config::{RoutineConfig, WritePolicy};
use odocal::routine::{run, Report, RoutineError, Unattended};
use tokio_util::sync::CancellationToken;

fn nominal() -> WheelParams {
    common::nominal()
}

fn robot(compass_sigma_deg: f64) -> SimBase {
    common::sim_base(compass_sigma_deg, 3)
}

/// Runs the routine on `sim` after setting `faults`, without ground truth; squares only (no
/// compass swing, no realigning turns between them), so that motions count squares.
async fn run_faulty(sim: &SimBase, faults: SimFaults, name: &str) -> Result<Report, RoutineError> {
    sim.set_faults(faults);
    run(
        &Base::single(sim.clone()),
        &RoutineConfig {
            realign: false,
            swing: false,
            ..routine(name)
        },
        None,
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await
}

fn routine(name: &str) -> RoutineConfig {
    let dir = common::scratch(&format!("simbase-{name}"));
    RoutineConfig {
        write_back: WritePolicy::Yes,
        confirm_motion: false,
        settle_s: 0.0,
        backup_dir: Some(dir),
        ..RoutineConfig::default()
    }
}

#[tokio::test]
async fn the_whole_routine_runs_on_an_in_process_base() {
    let sim = robot(0.37);
    let cfg = routine("whole");
    let report = common::routine_on(&sim, &cfg).await.unwrap();
    assert!(report.written && report.converged, "{report:?}");
    let before = report.e_max_sys_before_m.unwrap();
    let after = report.e_max_sys_after_m.unwrap();
    assert!(before > 1.0 && after * 10.0 < before, "{before} → {after}");
    assert!(
        report.mean_abs_heading_error_after_deg.unwrap() * 10.0
            < report.mean_abs_heading_error_before_deg
    );
    // Every round's squares streamed travel and heading, and the paths were integrated.
    let run1 = &report.rounds[0].runs[0];
    assert!(
        run1.travel_samples > 100 && run1.heading_samples > 100,
        "{run1:?}"
    );
    assert!(run1.true_path.as_ref().is_some_and(|p| p.len() > 10));
    // What the report says is what the store holds, in use and committed.
    assert_eq!(sim.configured(), report.final_params);
    assert_eq!(sim.committed(), Some(report.final_params));
    let truth = sim.true_params();
    assert!((report.final_params.wheelbase_m / truth.wheelbase_m - 1.0).abs() < 1e-3);
    assert!((report.final_params.e_d() / truth.e_d() - 1.0).abs() < 2e-4);
    // The backup holds the original parameters and names its store.
    let backup = read_backup(&report.backup_path).unwrap();
    assert_eq!(backup.active, nominal());
    assert_eq!(backup.store.kind, "simulated");
    let c = sim.counters();
    assert_eq!(c.writes, c.commits, "every write was committed");
    assert!(c.motions >= 8 * 10 * 2 + 8 * 6, "{c:?}");
    // The report names the method written, why, and what its ± is.
    let md = odocal::report::markdown(&report);
    let first = &report.rounds[0];
    assert!(first.written && !report.rounds[1].written);
    let head = format!(
        "Written: the `{}` estimate of round 1: {}.",
        first.chosen.method, first.chosen_because
    );
    assert!(md.contains(&head), "{md}");
    assert!(first.chosen_because.contains("the default"), "{first:?}");
    assert!(
        md.contains("± is the standard error from the scatter of the 5 squares per direction"),
        "{md}"
    );
    the_plots_show_every_run_by_direction_on_equal_axes(&report);
}

/// An SVG element's attribute.
fn attr<'a>(element: &'a str, name: &str) -> Option<&'a str> {
    element
        .split(&format!(" {name}=\""))
        .nth(1)
        .and_then(|rest| rest.split('"').next())
}

/// `(stroke, pixels)` of every `<polyline>` with more than two points (a run's trace; legend
/// samples and the zero line have two), in drawing order.
fn traces(svg: &str) -> Vec<(String, Vec<[f64; 2]>)> {
    svg.split("<polyline")
        .skip(1)
        .filter_map(|e| {
            let pts: Vec<[f64; 2]> = attr(e, "points")?
                .split_whitespace()
                .map(|xy| {
                    let (x, y) = xy.split_once(',').unwrap();
                    [x.parse().unwrap(), y.parse().unwrap()]
                })
                .collect();
            (pts.len() > 2).then(|| (attr(e, "stroke").unwrap().to_string(), pts))
        })
        .collect()
}

/// The centres of every filled `<circle>`, in drawing order.
fn dots(svg: &str) -> Vec<[f64; 2]> {
    svg.split("<circle")
        .skip(1)
        .filter(|e| attr(e, "fill") != Some("none"))
        .map(|e| {
            let c = |n| attr(e, n).unwrap().parse().unwrap();
            [c("cx"), c("cy")]
        })
        .collect()
}

/// The hue (degrees) of an SVG colour `#RRGGBB`.
fn hue(colour: &str) -> f64 {
    let c = |i: usize| f64::from(u8::from_str_radix(&colour[1 + 2 * i..3 + 2 * i], 16).unwrap());
    let (r, g, b) = (c(0), c(1), c(2));
    (3f64.sqrt() * (g - b))
        .atan2(2.0 * r - g - b)
        .to_degrees()
        .rem_euclid(360.0)
}

/// Pixels per metre across and up, from the same points in metres and in pixels.
fn px_per_m(metres: &[[f64; 2]], pixels: &[[f64; 2]]) -> [f64; 2] {
    let span = |pts: &[[f64; 2]], i: usize| {
        let (lo, hi) = pts.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| {
            (lo.min(p[i]), hi.max(p[i]))
        });
        hi - lo
    };
    [0, 1].map(|i| span(pixels, i) / span(metres, i))
}

/// The report's plots as a robotics engineer reads them: every run of round 1 and of the
/// verification drawn (true path and odometry), one colour per direction, a metre as long
/// across as up in paths and end points, and the verification's heading errors on a scale of
/// their own.
fn the_plots_show_every_run_by_direction_on_equal_axes(report: &Report) {
    use odocal::kinematics::Direction;
    let dir = common::scratch("plots");
    std::fs::create_dir_all(&dir).unwrap();
    odocal::report::plots::write_all(report, &dir).unwrap();
    let read = |f: &str| std::fs::read_to_string(dir.join(f)).unwrap();
    let runs: Vec<_> = report.rounds[0]
        .runs
        .iter()
        .chain(&report.verification)
        .collect();
    assert!(runs.len() >= 16, "{} runs", runs.len());

    // Paths, one panel per phase (round 1, then the verification): the true paths, then what
    // the odometry believed, then the same travel with the written parameters where the run
    // was driven with others.
    let drawn = traces(&read("paths.svg"));
    let written = report.final_params;
    let mut expected: Vec<(Direction, Vec<[f64; 2]>)> = Vec::new();
    for runs in [&report.rounds[0].runs, &report.verification] {
        expected.extend(
            runs.iter()
                .map(|r| (r.direction, r.true_path.clone().unwrap())),
        );
        expected.extend(
            runs.iter()
                .map(|r| (r.direction, reintegrated(r, &r.params).unwrap())),
        );
        expected.extend(
            runs.iter()
                .filter(|r| r.params != written)
                .map(|r| (r.direction, reintegrated(r, &written).unwrap())),
        );
    }
    assert!(report.rounds[0].runs.iter().all(|r| r.params != written));
    assert_eq!(drawn.len(), expected.len(), "every run's traces drawn");
    // One colour per direction: one hue, in three tints (truth, belief, correction).
    let mut hues: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    for ((stroke, pixels), (direction, metres)) in drawn.iter().zip(&expected) {
        // A clockwise square lies to the right of its first leg: below its start on screen.
        let below = pixels.iter().map(|p| p[1] - pixels[0][1]).sum::<f64>() > 0.0;
        assert_eq!(
            below,
            *direction == Direction::Cw,
            "{direction} drawn the other way"
        );
        hues[usize::from(*direction == Direction::Ccw)].push(hue(stroke));
        let [x, y] = px_per_m(metres, pixels);
        assert!(
            (x / y - 1.0).abs() < 0.02,
            "{x:.1} px/m across, {y:.1} px/m up: paths drawn out of shape"
        );
    }
    let range = |h: &[f64]| {
        h.iter().fold(f64::MIN, |a, &b| a.max(b)) - h.iter().fold(f64::MAX, |a, &b| a.min(b))
    };
    assert!(range(&hues[0]) < 4.0 && range(&hues[1]) < 4.0, "{hues:?}");
    assert!((hues[0][0] - hues[1][0]).abs() > 60.0, "{hues:?}");
    let strokes: std::collections::BTreeSet<&str> = drawn.iter().map(|t| t.0.as_str()).collect();
    assert_eq!(
        strokes.len(),
        6,
        "each direction's truth, belief and correction: {strokes:?}"
    );

    // End points: round 1's then the verification's, clockwise first; legend dots after.
    let ends = dots(&read("end_points.svg"));
    for (k, runs) in [&report.rounds[0].runs, &report.verification]
        .into_iter()
        .enumerate()
    {
        let metres: Vec<[f64; 2]> = [Direction::Cw, Direction::Ccw]
            .iter()
            .flat_map(|d| {
                runs.iter()
                    .filter(move |r| r.direction == *d)
                    .map(|r| r.true_final_xy_m.unwrap())
            })
            .collect();
        let skip = if k == 0 {
            0
        } else {
            report.rounds[0].runs.len()
        };
        let [x, y] = px_per_m(&metres, &ends[skip..skip + metres.len()]);
        assert!(
            (x / y - 1.0).abs() < 0.03,
            "end points {k}: {x:.1} px/m across, {y:.1} px/m up"
        );
    }

    // Heading errors: every run a dot (and two in the legend); the verification's, a tenth of
    // a degree or so, spread over its own panel instead of flat beside round 1's 20°.
    let heads = dots(&read("heading_errors.svg"));
    let all: usize =
        report.rounds.iter().map(|r| r.runs.len()).sum::<usize>() + report.verification.len();
    assert_eq!(heads.len(), all + 2);
    let after = &heads[all - report.verification.len()..all];
    let spread = after.iter().map(|p| p[1]).fold(f64::MIN, f64::max)
        - after.iter().map(|p| p[1]).fold(f64::MAX, f64::min);
    assert!(spread > 60.0, "the verification's errors span {spread} px");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[tokio::test]
async fn a_drive_that_vanishes_after_a_write_rolls_back_in_use_and_committed() {
    let sim = robot(0.0);
    // Round 1 is 80 motions; the drive vanishes early in round 2, after the first write.
    let faults = SimFaults {
        fail_after_motions: Some(90),
        ..SimFaults::default()
    };
    let err = run_faulty(&sim, faults, "vanish").await.unwrap_err();
    match &err {
        RoutineError::Restored {
            source, committed, ..
        } => {
            assert!(*committed, "the committed copy is put back too");
            assert!(source.to_string().contains("vanished"), "{source}");
        }
        other => panic!("expected a rollback, got {other}"),
    }
    assert_eq!(sim.configured(), nominal());
    assert_eq!(sim.committed(), Some(nominal()));
    assert!(sim.counters().stops >= 1, "the base was told to stop");
}

#[tokio::test]
async fn a_commit_of_unknown_outcome_is_rolled_back_and_reported() {
    let sim = robot(0.0);
    let faults = SimFaults {
        commit_fails: true,
        ..SimFaults::default()
    };
    let err = run_faulty(&sim, faults, "commit").await.unwrap_err();
    // The rollback's own commit fails too: the error says so, names the backup, and says what
    // the store was found to hold when read back instead of one fixed message. Here the lost
    // commits never landed, so both copies hold the original: nothing to restore.
    match &err {
        RoutineError::RestoreFailed {
            backup,
            active,
            committed,
            ..
        } => {
            assert!(backup.is_file());
            assert_eq!(*active, odocal::base::transaction::Holds::Original, "{err}");
            assert_eq!(
                *committed,
                odocal::base::transaction::Holds::Original,
                "{err}"
            );
            let text = err.to_string();
            assert!(text.contains("in use the original parameters"), "{text}");
            assert!(text.contains("nothing to restore"), "{text}");
        }
        other => panic!("expected a failed rollback, got {other}"),
    }
    // What is in use is the original again even though nothing could be committed.
    assert_eq!(sim.configured(), nominal());
}

#[tokio::test]
async fn an_invalid_heading_stops_the_routine_before_anything_moves() {
    let sim = robot(0.0);
    let faults = SimFaults {
        heading_invalid: true,
        ..SimFaults::default()
    };
    let err = run_faulty(&sim, faults, "heading").await.unwrap_err();
    assert!(matches!(err, RoutineError::Preflight(_)), "{err}");
    assert_eq!(sim.counters().motions, 0);
    assert_eq!(sim.counters().writes, 0);
}

#[tokio::test]
async fn a_dry_run_moves_but_writes_nothing() {
    let sim = robot(0.37);
    let mut cfg = routine("dry");
    cfg.write_back = WritePolicy::DryRun;
    let report = run(
        &Base::single(sim.clone()),
        &cfg,
        None,
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await
    .unwrap();
    assert!(!report.written);
    assert!(report.rounds[0].params_after.is_some());
    assert_eq!(sim.counters().writes, 0);
    assert_eq!(sim.committed(), Some(nominal()));
    let md = odocal::report::markdown(&report);
    let head = format!(
        "Nothing written: round 1's `{}` estimate was not written: a dry run.",
        report.rounds[0].chosen.method
    );
    assert!(md.contains(&head), "{md}");
}

#[tokio::test]
async fn a_report_without_ground_truth_has_no_empty_rows_and_reads_as_words() {
    let sim = robot(0.37);
    let report = run_faulty(&sim, SimFaults::default(), "no-truth")
        .await
        .unwrap();
    assert!(report.e_max_sys_before_m.is_none());
    let md = odocal::report::markdown(&report);
    // No row of dashes for what only a simulation can know, no enum names.
    assert!(!md.contains("E_max,sys"), "{md}");
    assert!(md.contains("write-back without asking"), "{md}");
    assert!(!md.contains("`Yes`"), "{md}");
    // The heading along the legs is reported beside the one at rest.
    assert!(md.contains("along the legs"), "{md}");
    let summary = odocal::report::summary_table(&report);
    assert!(!summary.contains("E_max,sys"), "{summary}");
    // The plots: no "true path" without a truth, whole-number ticks without ".0".
    let dir = common::scratch("no-truth-plots");
    std::fs::create_dir_all(&dir).unwrap();
    let written = odocal::report::plots::write_all(&report, &dir).unwrap();
    assert!(!written.is_empty());
    for file in written {
        let svg = std::fs::read_to_string(&file).unwrap();
        assert!(!svg.contains("true path"), "{}", file.display());
        let whole_with_point = svg
            .split('>')
            .filter_map(|t| t.split('<').next())
            .filter(|t| {
                let t = t.trim();
                t.ends_with(".0") && t[..t.len() - 2].parse::<i64>().is_ok()
            })
            .count();
        assert_eq!(whole_with_point, 0, "{}", file.display());
    }
    // Without a truth the odometry alone: every run of round 1 and the verification as the
    // odometry believed it, and round 1's with the written parameters, on equal scales.
    let drawn = traces(&std::fs::read_to_string(dir.join("paths.svg")).unwrap());
    let written = report.final_params;
    let mut expected: Vec<Vec<[f64; 2]>> = Vec::new();
    for runs in [&report.rounds[0].runs, &report.verification] {
        expected.extend(runs.iter().map(|r| reintegrated(r, &r.params).unwrap()));
        expected.extend(
            runs.iter()
                .filter(|r| r.params != written)
                .map(|r| reintegrated(r, &written).unwrap()),
        );
    }
    assert!(report.written);
    assert_eq!(drawn.len(), expected.len());
    for (metres, (_, pixels)) in expected.iter().zip(&drawn) {
        let [x_scale, y_scale] = px_per_m(metres, pixels);
        assert!(
            (x_scale / y_scale - 1.0).abs() < 0.02,
            "{x_scale:.1} px/m across, {y_scale:.1} px/m up: the square is drawn out of shape"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A robot that needs no correction, measured by a noisy compass (σ 3° per reading) with one
/// square each way: whatever the estimate says is noise, the Cramér–Rao bound of the compass's
/// noise measured at rest (one run has no scatter) says so, and nothing is written.
#[tokio::test]
async fn a_correction_within_its_own_noise_is_not_written() {
    use odocal::sim::{NoiseModel, Simulator};
    let noise = NoiseModel {
        compass_sigma_rad: 3f64.to_radians(),
        ..NoiseModel::default()
    };
    let sim = SimBase::new(Simulator::new(nominal(), nominal(), noise, 3).unwrap());
    let report = run(
        &Base::single(sim.clone()),
        &RoutineConfig {
            runs_per_direction: 1,
            max_rounds: 1,
            ..routine("noise")
        },
        None,
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await
    .unwrap();
    let chosen = &report.rounds[0].chosen;
    assert_eq!(chosen.e_b_std_err, None);
    let [sb, sd] = report.rounds[0].cramer_rao_std.unwrap();
    // The noise is real: an estimate away from 1, by no more than its standard errors say.
    assert!(
        chosen.e_b != 1.0 && (chosen.e_b - 1.0).abs() < 2.0 * sb,
        "{chosen:?}"
    );
    assert!(
        chosen.e_d != 1.0 && (chosen.e_d - 1.0).abs() < 2.0 * sd,
        "{chosen:?}"
    );
    assert!(
        !report.written && report.converged,
        "{:?}",
        report.rounds[0]
    );
    let why = report.rounds[0].converged_because.clone().unwrap();
    assert!(why.contains("not significant"), "{why}");
    assert_eq!(sim.configured(), nominal());
    // The report says nothing was written and why, and that one square has no ±.
    let md = odocal::report::markdown(&report);
    let head = format!(
        "Nothing written: round 1's `{}` estimate needs no correction ({why})",
        chosen.method
    );
    assert!(md.contains(&head), "{md}");
    assert!(md.contains("No ± with 1 square(s) per direction"), "{md}");
    assert!(md.contains("Cramér–Rao bound (E_b"), "{md}");
}

/// "Never worse": the leg method forced on a compass with a large deviation (which it cannot
/// see through) writes parameters the verification cannot show clearly better, so they are
/// restored and the routine fails with the numbers; `keep_worse` keeps them, with a warning.
#[tokio::test]
async fn parameters_that_are_not_clearly_better_are_restored_unless_kept() {
    // Without the compass swing, which would measure the deviation and remove it.
    let noisy = |name: &str| RoutineConfig {
        runs_per_direction: 2,
        verification_runs: 2,
        max_rounds: 1,
        max_change: 0.25,
        method: Some(odocal::calibration::Method::Legs),
        swing: false,
        ..routine(name)
    };
    let robot = |_: f64| {
        use odocal::sim::sensor::HeadingModel;
        use odocal::sim::{NoiseModel, Simulator};
        let noise = NoiseModel {
            compass_sigma_rad: 0.1f64.to_radians(),
            ..NoiseModel::default()
        };
        let deviating = HeadingModel {
            deviation: "25,0,0,15".parse().unwrap(),
            ..HeadingModel::default()
        };
        SimBase::new(
            Simulator::new(common::truth(), nominal(), noise, 3)
                .unwrap()
                .with_heading_model(deviating)
                .unwrap(),
        )
    };
    let sim = robot(25.0);
    let err = run(
        &Base::single(sim.clone()),
        &noisy("not-better"),
        None,
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await
    .unwrap_err();
    match &err {
        RoutineError::Restored {
            source, committed, ..
        } => {
            assert!(matches!(**source, RoutineError::NotBetter(_)), "{err}");
            assert!(*committed);
            assert!(err.to_string().contains("before"), "{err}");
        }
        other => panic!("expected the parameters restored, got {other}"),
    }
    assert_eq!(sim.configured(), nominal());
    assert_eq!(sim.committed(), Some(nominal()));
    // The same robot and seed with keep_worse: written, with the verdict as a warning.
    let sim = robot(25.0);
    let report = run(
        &Base::single(sim.clone()),
        &RoutineConfig {
            keep_worse: true,
            ..noisy("keep-worse")
        },
        None,
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await
    .unwrap();
    assert!(report.written);
    assert!(
        report
            .warnings
            .iter()
            .any(|w| w.contains("no clear improvement")),
        "{:?}",
        report.warnings
    );
    assert_ne!(sim.configured(), nominal());
}

/// A report directory that is a file (or any output that cannot be written) stops the routine
/// before the robot moves or a parameter changes.
#[tokio::test]
async fn an_unwritable_report_location_is_refused_before_anything_moves() {
    let dir = common::scratch("unwritable-report");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("not-a-dir");
    std::fs::write(&file, "x").unwrap();
    let sim = robot(0.37);
    let err = run(
        &Base::single(sim.clone()),
        &RoutineConfig {
            report_dir: Some(file.clone()),
            ..routine("report-file")
        },
        None,
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await
    .unwrap_err();
    assert!(
        matches!(&err, RoutineError::Output { path, .. } if *path == file),
        "{err}"
    );
    assert!(err.to_string().contains("not a directory"), "{err}");
    let c = sim.counters();
    assert_eq!((c.motions, c.writes, c.commits), (0, 0, 0), "{c:?}");
    assert_eq!(sim.configured(), nominal());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Reports never replace an earlier report and never follow a planted link: a second report
/// into the same directory goes to `DIR-2`; a directory holding a link named report.json is
/// left alone, and the link's target is untouched.
#[tokio::test]
async fn reports_never_overwrite_or_follow_links() {
    let sim = robot(0.37);
    let report = run_faulty(&sim, SimFaults::default(), "reports-safe")
        .await
        .unwrap();
    let root = common::scratch("reports-safe-files");
    std::fs::create_dir_all(&root).unwrap();
    let dir = root.join("report");
    let first = odocal::report::write_dir(&report, &dir).unwrap();
    assert!(first.iter().all(|f| f.starts_with(&dir)), "{first:?}");
    let second = odocal::report::write_dir(&report, &dir).unwrap();
    let dir2 = root.join("report-2");
    assert!(second.iter().all(|f| f.starts_with(&dir2)), "{second:?}");
    #[cfg(unix)]
    {
        let victim = root.join("victim.txt");
        std::fs::write(&victim, "keep me").unwrap();
        let planted = root.join("planted");
        std::fs::create_dir_all(&planted).unwrap();
        std::os::unix::fs::symlink(&victim, planted.join("report.json")).unwrap();
        let third = odocal::report::write_dir(&report, &planted).unwrap();
        assert!(
            third.iter().all(|f| f.starts_with(root.join("planted-2"))),
            "{third:?}"
        );
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
    }
    std::fs::remove_dir_all(&root).unwrap();
}

/// A run that fails mid-way keeps what it measured: a partial report beside the backup with
/// every square driven so far, the phase it stopped in and the error.
#[tokio::test]
async fn a_failed_run_leaves_a_partial_report_with_every_square_measured() {
    let sim = robot(0.37);
    // Squares only (no swing, no realigning turns), so that motions count squares.
    let cfg = RoutineConfig {
        realign: false,
        swing: false,
        ..routine("partial")
    };
    sim.set_faults(SimFaults {
        // Three whole squares (8 motions each), then the drive vanishes in the fourth.
        fail_after_motions: Some(8 * 3 + 2),
        ..SimFaults::default()
    });
    let err = run(
        &Base::single(sim.clone()),
        &cfg,
        None,
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await
    .unwrap_err();
    let partial: Vec<_> = std::fs::read_dir(cfg.backup_dir.as_ref().unwrap())
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with("partial-report-"))
        })
        .collect();
    assert_eq!(partial.len(), 1, "{partial:?}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&partial[0]).unwrap()).unwrap();
    assert_eq!(v["runs"].as_array().unwrap().len(), 3, "{v}");
    assert_eq!(v["phase"], "round 1");
    assert_eq!(v["error"], err.to_string());
    assert_eq!(v["base"]["drive"]["kind"], "simulated");
    // The measured squares are usable: each has its heading error.
    assert!(v["runs"][0]["heading_error_rad"].as_f64().is_some());
}
