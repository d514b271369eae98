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
//! Then the free runs: per run, the online filter (noise settings for a motion-capture heading:
//! `odocal track --heading-sigma-deg 0.1 --slip-fraction 0.03`) against the pooled
//! square estimates of the robot recorded closest in time (set ids are `ddmmyyyyHHMM`), with
//! the z-score of their difference, and what each estimate leaves of the run's final heading
//! and position error.
//!
//! `cargo run --release --example scoreboard [-- DATA_ROOT]` (default ../shared/datasets/optiodom)

use odocal::calibration::Method;
use odocal::kinematics::{SplitConvention, WheelParams};
use odocal::offline::dataset::{default_optiodom_root, leave_one_recording_out, OptiOdomSet};
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
    free_runs(&root, &sets, convention)
}

/// Heading noise of the motion-capture heading the free runs carry (deg).
const MOCAP_HEADING_SIGMA_DEG: f64 = 0.1;
/// Wheel slip per step on the free runs' floor (relative).
const FREE_RUN_SLIP: f64 = 0.03;

/// Days since an arbitrary epoch of an OptiOdom id `ddmmyyyyHHMM` (for "closest in time").
fn days(id: &str) -> Option<f64> {
    let n = |r: std::ops::Range<usize>| id.get(r)?.parse::<f64>().ok();
    Some(n(4..8)? * 365.25 + n(2..4)? * 30.44 + n(0..2)? + n(8..10)? / 24.0)
}

fn free_runs(
    root: &std::path::Path,
    sets: &[OptiOdomSet],
    convention: SplitConvention,
) -> Result<(), Box<dyn std::error::Error>> {
    use odocal::calibration::online::{OnlineConfig, ScaleSource};
    use odocal::calibration::tracker::Tracker;
    use odocal::offline::dataset::{replay, RecordedRun};
    let mut dirs: Vec<_> = std::fs::read_dir(root.join("free"))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    println!(
        "\nfree runs: online filter (heading σ {MOCAP_HEADING_SIGMA_DEG}°, slip {FREE_RUN_SLIP}) vs the pooled squares of the robot recorded closest in time"
    );
    println!(
        "{:<26} {:>17} {:>6} {:>8} {:>9} {:>17} {:>6} {:>17} {:>6}   {:>22}",
        "run",
        "online E_b",
        "NIS",
        "gated",
        "offset s",
        "squares legs E_b",
        "z",
        "squares exact E_b",
        "z",
        "final hdg° legs/exact/online"
    );
    for dir in dirs {
        let free = OptiOdomSet::load(&dir)?;
        let Some(t) = days(&free.id) else { continue };
        // The square robot closest in time.
        let Some(side) = sets
            .iter()
            .filter_map(|s| Some(((days(&s.id)? - t).abs(), s.side_m)))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, side)| side)
        else {
            continue;
        };
        let robot: Vec<OptiOdomSet> = sets.iter().filter(|s| s.side_m == side).cloned().collect();
        for run in &free.runs {
            let one = OptiOdomSet {
                runs: vec![RecordedRun::clone(run)],
                ..free.clone()
            };
            let squares = replay(&robot, std::slice::from_ref(&one), convention)?;
            let scale = ScaleSource::Convention(convention);
            let mut cfg = OnlineConfig::new(one.configured);
            cfg.heading_sigma_rad = MOCAP_HEADING_SIGMA_DEG.to_radians();
            cfg.slip_fraction = FREE_RUN_SLIP;
            let mut tracker = Tracker::new(cfg, scale, 1.0)?;
            one.feed(&mut tracker);
            let online = tracker.estimate()?;
            let (nis, n) = tracker.filter().nis_mean();
            let gate = tracker.filter().gate_stats();
            let offset = tracker
                .time_offsets
                .first()
                .map_or(f64::NAN, |o| o.offset.offset_s);
            let pooled = |m: Method| {
                squares
                    .pooled
                    .iter()
                    .find(|p| p.method == m)
                    .and_then(|p| p.estimate_for(&one.configured, convention).ok())
            };
            let (Some(legs), Some(exact)) = (pooled(Method::Legs), pooled(Method::Exact)) else {
                continue;
            };
            let z = |e: &odocal::calibration::Estimate| {
                (online.e_b - e.e_b) / online.e_b_std.hypot(e.e_b_std_err.unwrap_or(0.0))
            };
            let final_heading = |params: &WheelParams| one.evaluate(params).0.to_degrees();
            let apply = |c: &odocal::kinematics::Correction| c.apply(&one.configured);
            println!(
                "{:<26} {:>8.5}±{:.5} {:>6.2} {:>8} {:>9.3} {:>8.5}±{:.5} {:>6.1} {:>8.5}±{:.5} {:>6.1}   {:>6.2} / {:>5.2} / {:>5.2}",
                run.name,
                online.e_b,
                online.e_b_std,
                nis,
                format!("{}/{}", gate.rejected, n + gate.rejected),
                offset,
                legs.e_b,
                legs.e_b_std_err.unwrap_or(f64::NAN),
                z(&legs),
                exact.e_b,
                exact.e_b_std_err.unwrap_or(f64::NAN),
                z(&exact),
                final_heading(&apply(&legs.correction)?),
                final_heading(&apply(&exact.correction)?),
                final_heading(&apply(&online.correction)?),
            );
        }
    }
    Ok(())
}
