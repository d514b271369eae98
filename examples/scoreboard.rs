//! The real-data scoreboard: every method, leave-one-recording-out over the shared OptiOdom
//! square sets. Recordings are grouped by robot (same square side: one recording campaign); for
//! each recording, every method is calibrated on all the *other* recordings of its robot, pooled
//! in physical terms (`calibration::pool`), expressed against the held-out recording's own
//! configured parameters, and evaluated by replaying the held-out runs against motion capture.
//!
//! Prints, per method, the held-out final heading error (deg) and final position error (m),
//! median and worst over the held-out recordings, twice: **systematic** (per direction the mean
//! error of the runs, the larger of the two directions, as Borenstein's `E_max,sys`: what a
//! calibration can remove) and **per run** (mean |error| of single runs, which adds the
//! run-to-run scatter no parameter can remove). The `best possible` row is the floor: parameters
//! fitted to the held-out runs themselves. Last, per method, how often the held-out recording's
//! own `E_b` lies within 2 stated standard errors of the pooled one (both ± combined) — a check
//! that the stated ± is honest.
//!
//! `cargo run --release --example scoreboard [-- DATA_ROOT]` (default ../shared/datasets/optiodom)

use odocal::calibration::Method;
use odocal::dataset::{default_optiodom_root, leave_one_recording_out, OptiOdomSet};
use odocal::kinematics::{SplitConvention, WheelParams};
use std::collections::BTreeMap;

fn median_max(v: &mut [f64]) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    let median = if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    };
    (median, v[n - 1])
}

/// Parameters fitted to `set` itself by a coarse-to-fine search over `E_b`, `E_d` minimising
/// `score`: the floor no calibration from other recordings can beat.
fn best_possible(set: &OptiOdomSet, score: impl Fn(&WheelParams) -> f64) -> WheelParams {
    let (mut eb, mut ed, mut step_b, mut step_d) = (1.0, 1.0, 0.01, 0.002);
    let params = |eb: f64, ed: f64| {
        WheelParams::from_ratios(&set.configured, eb, ed, &SplitConvention::LeftNominal)
            .unwrap_or(set.configured)
    };
    for _ in 0..6 {
        let mut best = (f64::MAX, eb, ed);
        for i in -10..=10 {
            for j in -10..=10 {
                let (b, d) = (eb + f64::from(i) * step_b, ed + f64::from(j) * step_d);
                let s = score(&params(b, d));
                if s < best.0 {
                    best = (s, b, d);
                }
            }
        }
        (eb, ed) = (best.1, best.2);
        step_b /= 5.0;
        step_d /= 5.0;
    }
    params(eb, ed)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = std::env::args()
        .nth(1)
        .map(std::path::PathBuf::from)
        .unwrap_or_else(default_optiodom_root);
    let mut dirs: Vec<_> = std::fs::read_dir(root.join("square"))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    let sets: Vec<OptiOdomSet> = dirs
        .iter()
        .map(OptiOdomSet::load)
        .collect::<Result<_, _>>()?;
    let convention = SplitConvention::LeftNominal;
    // Per method: [systematic heading, systematic position, per-run heading, per-run position].
    let mut table: BTreeMap<&str, [Vec<f64>; 4]> = BTreeMap::new();
    // Per method: (held-out recordings within 2σ, recordings compared), and |z| values.
    let mut coverage: BTreeMap<&str, (usize, usize, Vec<f64>)> = BTreeMap::new();
    let mut held_out = 0;
    let mut default = None;
    for h in leave_one_recording_out(&sets, convention)? {
        let Some(test_set) = sets.iter().find(|s| s.id == h.dataset) else {
            continue;
        };
        held_out += 1;
        let pooled = &h.replay;
        default = default.or(pooled.default_method);
        for row in &pooled.evaluations {
            let name = Method::ALL
                .iter()
                .map(|m| m.name())
                .find(|n| *n == row.method)
                .unwrap_or("uncalibrated");
            let t = table.entry(name).or_default();
            t[0].push(row.systematic_heading_error_deg);
            t[1].push(row.systematic_position_error_m);
            t[2].push(row.heading_error_deg);
            t[3].push(row.position_error_m);
        }
        // The floor, for each metric fitted separately.
        let t = table.entry("best possible").or_default();
        let sys = |p: &WheelParams| test_set.evaluate_systematic(p);
        let run = |p: &WheelParams| test_set.evaluate(p);
        t[0].push(sys(&best_possible(test_set, |p| sys(p).0)).0.to_degrees());
        t[1].push(sys(&best_possible(test_set, |p| sys(p).1)).1);
        t[2].push(run(&best_possible(test_set, |p| run(p).0)).0.to_degrees());
        t[3].push(run(&best_possible(test_set, |p| run(p).1)).1);
        // The held-out recording's own E_b against the pooled one (the parameter recordings
        // disagree on), both against the held-out set's configuration.
        for p in &pooled.pooled {
            let Some(mine) = h.own.iter().find(|e| e.method == p.method) else {
                continue;
            };
            let theirs = p.estimate_for(&test_set.configured, convention)?;
            let own_se = mine.e_b_std_err.unwrap_or(0.0);
            let Some(se) = theirs.e_b_std_err else {
                continue;
            };
            let z = (mine.e_b - theirs.e_b) / se.hypot(own_se);
            let c = coverage.entry(p.method.name()).or_default();
            c.1 += 1;
            c.0 += usize::from(z.abs() <= 2.0);
            c.2.push(z.abs());
        }
    }
    println!(
        "{held_out} held-out recordings (each evaluated with every method calibrated on the other \
         recordings of its robot, pooled)"
    );
    println!(
        "{:<14} {:>23} {:>23} {:>23} {:>23} {:>9} {:>6}",
        "",
        "systematic heading °",
        "systematic position m",
        "per-run heading °",
        "per-run position m",
        "E_b",
        ""
    );
    println!(
        "{:<14} {:>11} {:>11} {:>11} {:>11} {:>11} {:>11} {:>11} {:>11} {:>9} {:>6}",
        "method",
        "median",
        "worst",
        "median",
        "worst",
        "median",
        "worst",
        "median",
        "worst",
        "in 2σ",
        "max|z|"
    );
    let order = ["uncalibrated"]
        .into_iter()
        .chain(Method::ALL.iter().map(|m| m.name()))
        .chain(["best possible"]);
    for m in order {
        let Some(cols) = table.get_mut(m) else {
            continue;
        };
        let [a, b, c, d] = cols.each_mut().map(|v| median_max(v));
        let (cov, zmax) = match coverage.get_mut(m) {
            Some((inside, n, z)) => (format!("{inside}/{n}"), format!("{:.1}", median_max(z).1)),
            None => ("-".into(), "-".into()),
        };
        let mark = if default.is_some_and(|d| d.name() == m) {
            " (default)"
        } else {
            ""
        };
        println!(
            "{m:<14} {:>11.3} {:>11.3} {:>11.4} {:>11.4} {:>11.3} {:>11.3} {:>11.4} {:>11.4} {cov:>9} {zmax:>6}{mark}",
            a.0, a.1, b.0, b.1, c.0, c.1, d.0, d.1
        );
    }
    Ok(())
}
