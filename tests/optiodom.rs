//! Calibration on real recorded squares (OptiOdom, `../shared/datasets/optiodom/`): calibrating
//! on one set must reduce the odometry's final-heading error on the *other* sets of the same
//! robot and side length. Fails when `CI` is set and the data is missing; otherwise skips with
//! a notice.

mod common;

use odocal::calibration::{estimate, Method};
use odocal::kinematics::SplitConvention;
use odocal::offline::dataset::{replay, DatasetError, OptiOdomSet};
use std::path::PathBuf;

fn data_root() -> Option<PathBuf> {
    common::optiodom("square")
}

fn square_sets(root: &std::path::Path) -> Vec<OptiOdomSet> {
    let mut dirs: Vec<_> = std::fs::read_dir(root.join("square"))
        .expect("square dir readable")
        .map(|e| e.expect("dir entry").path())
        .collect();
    dirs.sort();
    dirs.iter()
        .map(|d| OptiOdomSet::load(d).expect("set loads"))
        .collect()
}

#[test]
fn calibrating_on_one_set_improves_the_others() {
    let Some(root) = data_root() else { return };
    let sets = square_sets(&root);
    assert_eq!(sets.len(), 6, "expected the six recorded square sets");
    let mut pairs = 0;
    for calib in &sets {
        let others: Vec<OptiOdomSet> = sets
            .iter()
            .filter(|s| s.id != calib.id && s.side_m == calib.side_m)
            .cloned()
            .collect();
        assert!(!others.is_empty());
        let report = replay(
            std::slice::from_ref(calib),
            &others,
            SplitConvention::LeftNominal,
        )
        .unwrap();
        for other in &others {
            let row = |method: &str| {
                report
                    .evaluations
                    .iter()
                    .find(|r| r.dataset == other.id && r.method == method)
                    .unwrap_or_else(|| panic!("no {method} row for {}", other.id))
                    .heading_error_deg
            };
            let before = row("uncalibrated");
            for method in ["exact", "jung-chung"] {
                let after = row(method);
                assert!(
                    after < before,
                    "{method} from {} on {}: {after:.3}° vs uncalibrated {before:.3}°",
                    calib.id,
                    other.id
                );
            }
            // On these runs the improvement is large, not marginal: at least a factor 2.
            assert!(row("exact") < 0.5 * before, "{} on {}", calib.id, other.id);
            pairs += 1;
        }
    }
    assert_eq!(pairs, 12);
}

#[test]
fn directions_and_heading_errors_come_from_the_data() {
    let Some(root) = data_root() else { return };
    let set = OptiOdomSet::load(root.join("square/231220200040")).unwrap();
    let test = set.square_test().unwrap();
    // First half clockwise, second half counter-clockwise (told from the ground truth).
    assert_eq!((test.cw.len(), test.ccw.len()), (3, 3));
    assert_eq!(test.side_m, 1.7);
    assert_eq!(test.wheelbase_m, 0.2);
    // This robot's turns fall short: CW runs end counter-clockwise of their start.
    assert!(test.cw.iter().all(|r| r.heading_error_rad > 0.0));
    assert!(test.ccw.iter().all(|r| r.heading_error_rad < 0.0));
    let e = estimate(Method::Exact, &test, SplitConvention::LeftNominal).unwrap();
    assert!(e.e_b > 1.0 && e.e_b < 1.03, "E_b {}", e.e_b);
    assert!(e.e_b_std_err.is_some());
}

#[test]
fn malformed_and_missing_files_are_typed_errors() {
    let dir = std::env::temp_dir().join(format!("odocal-bad-set-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    assert!(matches!(
        OptiOdomSet::load(&dir),
        Err(DatasetError::NotASet(_))
    ));
    std::fs::write(
        dir.join("x_metadata.csv"),
        "ngear,43.7,\nencRes,64,\nLi,0.2,\nDi,0.084,0.084\nL,1.7,\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("x_run-01.csv"),
        "0,0,0,0,0,0\n0.05,0.1,0,zero,3,4\n",
    )
    .unwrap();
    match OptiOdomSet::load(&dir) {
        Err(DatasetError::Malformed { line, reason, .. }) => {
            assert_eq!(line, 2);
            assert!(reason.contains("column 4"), "{reason}");
        }
        other => panic!("expected a malformed-row error, got {other:?}"),
    }
    std::fs::write(dir.join("x_run-01.csv"), "0,0,0,0,0,0\n0.05,0.1,0,0,3,4\n").unwrap();
    std::fs::write(
        dir.join("x_metadata.csv"),
        "ngear,43.7,\nLi,0.2,\nDi,0.084,0.084\n",
    )
    .unwrap();
    assert!(matches!(
        OptiOdomSet::load(&dir),
        Err(DatasetError::Metadata { key: "encRes", .. })
    ));
    std::fs::remove_dir_all(&dir).unwrap();
    assert!(matches!(
        OptiOdomSet::load(&dir),
        Err(DatasetError::Io { .. })
    ));
}

#[test]
fn legs_are_found_in_every_recorded_run_and_the_leg_method_escapes_the_start_transient() {
    let Some(root) = data_root() else { return };
    for set in square_sets(&root) {
        let test = set.square_test().unwrap();
        for r in test.cw.iter().chain(test.ccw.iter()) {
            assert!(
                r.legs.is_some(),
                "{}: a run without four legs found",
                set.id
            );
        }
    }
    // On this set the runs pick up a heading offset before the first corner: the at-rest
    // methods turn it into E_b, the leg method does not, and lands where the position-based
    // UMBmark (immune to such an offset) does.
    let set = OptiOdomSet::load(root.join("square/231220200040")).unwrap();
    let test = set.square_test().unwrap();
    let e = |m| {
        estimate(m, &test, SplitConvention::LeftNominal)
            .unwrap()
            .e_b
    };
    let (legs, exact, umbmark) = (e(Method::Legs), e(Method::Exact), e(Method::Umbmark));
    assert!(
        (legs - umbmark).abs() < 0.25 * (exact - umbmark).abs(),
        "legs {legs}, exact {exact}, umbmark {umbmark}"
    );
}

#[test]
fn pooled_leave_one_recording_out_the_default_method_is_honest_and_no_worse_than_umbmark_on_position(
) {
    use odocal::offline::dataset::leave_one_recording_out;
    let Some(root) = data_root() else { return };
    let sets = square_sets(&root);
    let held = leave_one_recording_out(&sets, SplitConvention::LeftNominal).unwrap();
    // Every set has two others of its robot: six held-out recordings, each pooled from two
    // recordings (so the stated ± counts the recording-to-recording spread).
    assert_eq!(held.len(), 6);
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        0.5 * (v[2] + v[3])
    };
    let column = |method: &str| -> Vec<f64> {
        held.iter()
            .map(|h| {
                h.replay
                    .evaluations
                    .iter()
                    .find(|r| r.method == method)
                    .unwrap_or_else(|| panic!("no {method} row for {}", h.dataset))
                    .systematic_position_error_m
            })
            .collect()
    };
    for h in &held {
        assert_eq!(h.replay.default_method, Some(Method::Legs), "{}", h.dataset);
        assert_eq!(h.replay.datasets.len(), 2);
    }
    let (legs, umbmark) = (median(column("legs")), median(column("umbmark")));
    assert!(legs <= 0.0088, "legs held-out position median {legs} m");
    assert!(legs <= umbmark, "legs {legs} m vs UMBmark {umbmark} m");
    // The stated uncertainty covers another recording: each held-out recording's own E_b lies
    // within two combined standard errors of the pooled estimate from the others.
    for h in &held {
        let set = sets.iter().find(|s| s.id == h.dataset).unwrap();
        let pooled = h
            .replay
            .pooled
            .iter()
            .find(|p| p.method == Method::Legs)
            .unwrap()
            .estimate_for(&set.configured, SplitConvention::LeftNominal)
            .unwrap();
        let own = h.own.iter().find(|e| e.method == Method::Legs).unwrap();
        let se = pooled
            .e_b_std_err
            .unwrap()
            .hypot(own.e_b_std_err.unwrap_or(0.0));
        let z = (own.e_b - pooled.e_b) / se;
        assert!(z.abs() <= 2.0, "{}: z = {z:.2}", h.dataset);
    }
}

/// One robot's three sessions (231220200029, …0040, …0045: same configured geometry): pooled
/// on two, the default method's prediction for the next session (`prediction_std`, the
/// session-to-session spread included) covers the third session's own estimate at 2σ, for
/// `E_b` and `E_d`; and the prediction is wider than the pooled mean's standard error.
#[test]
fn pooled_on_two_sessions_the_prediction_interval_covers_the_third() {
    let Some(root) = data_root() else { return };
    let ids = ["231220200029", "231220200040", "231220200045"];
    let sets: Vec<OptiOdomSet> = ids
        .iter()
        .map(|id| OptiOdomSet::load(root.join("square").join(id)).expect("set loads"))
        .collect();
    let conv = SplitConvention::LeftNominal;
    for (k, held) in sets.iter().enumerate() {
        let others: Vec<OptiOdomSet> = sets
            .iter()
            .enumerate()
            .filter(|(i, _)| *i != k)
            .map(|(_, s)| s.clone())
            .collect();
        let pooled = replay(&others, &others, conv).unwrap();
        let own = replay(std::slice::from_ref(held), std::slice::from_ref(held), conv).unwrap();
        let method = pooled.default_method.expect("a default method");
        assert_eq!(own.default_method, Some(method), "{}", held.id);
        let p = pooled.pooled.iter().find(|p| p.method == method).unwrap();
        let predicted = p.estimate_for(&held.configured, conv).unwrap();
        let (sb, sd) = p.prediction_std(&predicted);
        let (sb, sd) = (sb.expect("E_b prediction"), sd.expect("E_d prediction"));
        // The prediction counts the session-to-session spread and a session's own scatter: it
        // is wider than the pooled mean's standard error by more than rounding.
        assert!(
            sb > 1.2 * predicted.e_b_std_err.unwrap() && sd > 1.2 * predicted.e_d_std_err.unwrap(),
            "held out {}: prediction E_b {sb:.5}, E_d {sd:.5} vs pooled standard errors {:?}",
            held.id,
            (predicted.e_b_std_err, predicted.e_d_std_err)
        );
        let mine = own.estimates.iter().find(|e| e.method == method).unwrap();
        for (q, got, want, s) in [
            ("E_b", mine.e_b, predicted.e_b, sb),
            ("E_d", mine.e_d, predicted.e_d, sd),
        ] {
            assert!(
                (got - want).abs() <= 2.0 * s,
                "held out {}: {method} {q} {got:.5} outside {want:.5} ± 2·{s:.5}",
                held.id
            );
        }
    }
}

#[test]
fn impossible_ticks_backward_time_and_absurd_geometry_are_named() {
    let dir = common::scratch("bad-set-bounds");
    std::fs::create_dir_all(&dir).unwrap();
    let meta = |d: &str| format!("ngear,43.7,\nencRes,64,\nLi,0.2,\nDi,{d},{d}\nL,1.7,\n");
    let run = dir.join("x_run-01.csv");
    std::fs::write(dir.join("x_metadata.csv"), meta("0.084")).unwrap();
    // 10^18 ticks in one 0.05 s cycle.
    std::fs::write(&run, "0,0,0,0,0,0\n0.05,0.1,0,0,1e18,4\n").unwrap();
    match OptiOdomSet::load(&dir) {
        Err(DatasetError::Malformed { line, reason, .. }) => {
            assert_eq!(line, 2);
            assert!(
                reason.contains("column 5") && reason.contains("m/s"),
                "{reason}"
            );
        }
        other => panic!("expected impossible ticks to be refused, got {other:?}"),
    }
    // Time going backwards.
    std::fs::write(&run, "0,0,0,0,0,0\n0.05,0,0,0,3,4\n0.04,0,0,0,3,4\n").unwrap();
    match OptiOdomSet::load(&dir) {
        Err(DatasetError::Malformed { line, reason, .. }) => {
            assert_eq!(line, 3);
            assert!(reason.contains("time must go forward"), "{reason}");
        }
        other => panic!("expected backward time to be refused, got {other:?}"),
    }
    // A wheel diameter of 10^300 m.
    std::fs::write(&run, "0,0,0,0,0,0\n0.05,0,0,0,3,4\n").unwrap();
    std::fs::write(dir.join("x_metadata.csv"), meta("1e300")).unwrap();
    assert!(matches!(
        OptiOdomSet::load(&dir),
        Err(DatasetError::Metadata { key: "Di", .. })
    ));
    std::fs::remove_dir_all(&dir).unwrap();
}
