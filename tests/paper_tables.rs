//! Reproduces the numbers of Jung & Chung (2011), Sec. 3 and Table 2, to the printed digits.
//!
//! Setup (see `StudyConfig::paper`): truth split left-nominal, D = 0.150 m, b = 0.390 m, 4 m
//! square, Lee on a 2 m square, noise-free, write-back left-nominal. "Error (%)" is
//! `|est − true|·100` (percentage points). Where our figure differs from the paper's we say so.

use odocal::calibration::Method;
use odocal::offline::study::{run_study, MethodOutcome, StudyConfig, StudyOutcome};

fn study(e_b: f64, e_d: f64) -> StudyOutcome {
    run_study(&StudyConfig::paper(e_b, e_d), 0).expect("paper study runs")
}

fn outcome(s: &StudyOutcome, m: Method) -> &MethodOutcome {
    s.outcomes
        .iter()
        .find(|o| o.estimate.method == m)
        .expect("method produced an estimate")
}

/// Rounds to four decimals, the precision the reproduced figures are quoted at.
fn r4(x: f64) -> f64 {
    (x * 1e4).round() / 1e4
}

#[test]
fn base_case_umbmark_heading_only_and_proposed() {
    let s = study(0.976, 0.992);
    assert!(s.failures.is_empty(), "{:?}", s.failures);
    let umb = outcome(&s, Method::Umbmark);
    assert_eq!(r4(umb.e_b_error_pp), 0.7253); // paper 0.725
    assert_eq!(r4(umb.e_d_error_pp), 0.0298); // paper 0.030
    assert_eq!(r4(umb.e_max_sys_m), 0.1639); // paper 0.164 m
    let ho = outcome(&s, Method::HeadingOnly);
    assert_eq!(r4(ho.e_b_error_pp), 0.3920); // paper 0.392
    assert_eq!(r4(ho.e_d_error_pp), 0.0161); // paper 0.016
    let jc = outcome(&s, Method::JungChung);
    assert_eq!(r4(jc.e_b_error_pp), 0.0000); // paper 0.001
    assert_eq!(r4(jc.e_d_error_pp), 0.0034); // paper 0.003
    assert!(
        jc.e_max_sys_m < 0.01,
        "paper: within 0.01 m, got {}",
        jc.e_max_sys_m
    );
}

#[test]
fn table2_case_one() {
    let s = study(1.025, 0.987);
    let umb = outcome(&s, Method::Umbmark);
    assert_eq!(r4(umb.e_b_error_pp), 0.9296); // paper 0.930
    assert_eq!(r4(umb.e_d_error_pp), 0.0560); // paper 0.056
    let jc = outcome(&s, Method::JungChung);
    assert_eq!(r4(jc.e_b_error_pp), 0.0000); // paper 0.001
    assert_eq!(r4(jc.e_d_error_pp), 0.0093); // paper 0.009
}

#[test]
fn table2_case_two() {
    let s = study(0.970, 0.985);
    let umb = outcome(&s, Method::Umbmark);
    assert_eq!(r4(umb.e_b_error_pp), 1.8286); // paper 1.829
    assert_eq!(r4(umb.e_d_error_pp), 0.1248); // paper 0.125
    let jc = outcome(&s, Method::JungChung);
    assert_eq!(r4(jc.e_b_error_pp), 0.0000); // paper 0.001
                                             // The paper prints 0.003 here, which breaks its own trend (0.0034 at E_d 0.992, 0.0093 at
                                             // 0.987); the equations as printed give 0.0127.
    assert_eq!(r4(jc.e_d_error_pp), 0.0127);
}

#[test]
fn exact_method_is_exact_and_closes_the_square() {
    for (e_b, e_d) in [(0.976, 0.992), (1.025, 0.987), (0.970, 0.985)] {
        let s = study(e_b, e_d);
        let ex = outcome(&s, Method::Exact);
        assert!(ex.e_b_error_pp < 1e-10 && ex.e_d_error_pp < 1e-10);
        assert!(ex.e_max_sys_m < 1e-9, "E_max,sys {}", ex.e_max_sys_m);
        // Lee's reconstruction and UMBmark both leave visible error on these cases.
        assert!(outcome(&s, Method::Lee).e_max_sys_m > 1e-3);
        assert!(outcome(&s, Method::Umbmark).e_max_sys_m > 0.05);
    }
}

#[test]
fn estimation_and_write_back_must_share_a_convention() {
    use odocal::calibration::estimate;
    use odocal::kinematics::SplitConvention;
    use odocal::offline::study::{e_max_sys, simulate_tests};
    use odocal::sim::{NoiseModel, Simulator};
    let cfg = StudyConfig::paper(0.976, 0.992);
    let tests = simulate_tests(&cfg, 0).unwrap();
    let verify = |e_b: f64, e_d: f64, split: SplitConvention| {
        let written = split
            .split(e_b, e_d, cfg.nominal.wheelbase_m)
            .unwrap()
            .apply(&cfg.nominal)
            .unwrap();
        let mut sim =
            Simulator::new(*tests.sim.truth(), written, NoiseModel::default(), 0).unwrap();
        let (cw, ccw) = sim.run_square_test(cfg.side_m, 1).unwrap();
        e_max_sys(&cw, &ccw)
    };
    for conv in [
        SplitConvention::LeftNominal,
        SplitConvention::MeanPreserving,
    ] {
        let ex = estimate(Method::Exact, &tests.main, conv).unwrap();
        // Matched: closes to rounding. (A uniform wheel-scale error cannot open a square.)
        assert!(verify(ex.e_b, ex.e_d, conv) < 1e-9);
    }
    // Mixed: E_b estimated left-nominal, written back mean-preserving: ~7 cm remain.
    let left = estimate(Method::Exact, &tests.main, SplitConvention::LeftNominal).unwrap();
    let mixed = verify(left.e_b, left.e_d, SplitConvention::MeanPreserving);
    assert_eq!((mixed * 1e3).round() / 1e3, 0.071, "{mixed}");
    // Under the mean-preserving split the matched exact E_b differs from the left-nominal
    // truth: the absolute scale is not observable from headings.
    let mean = estimate(Method::Exact, &tests.main, SplitConvention::MeanPreserving).unwrap();
    assert!((mean.e_b - 0.976).abs() > 1e-3);
}
