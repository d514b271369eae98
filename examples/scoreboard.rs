//! The real-data scoreboard: every method calibrated on one recorded square set and evaluated
//! on every other set of the same side (held-out recordings; calibrated parameters applied in
//! physical terms, so sets recorded with other configured parameters compare), over the shared
//! OptiOdom sets. Prints, per method, the held-out final heading error (deg) and final position
//! error (m): median and worst over all (calibration set, held-out set) pairs.
//!
//! `cargo run --release --example scoreboard [-- DATA_ROOT]` (default ../shared/datasets/optiodom)

use odocal::dataset::{default_optiodom_root, replay, OptiOdomSet};
use odocal::kinematics::SplitConvention;
use std::collections::BTreeMap;

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
    let mut heading: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut position: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut pairs = 0;
    for calib in &sets {
        let others: Vec<OptiOdomSet> = sets
            .iter()
            .filter(|s| s.id != calib.id && s.side_m == calib.side_m)
            .cloned()
            .collect();
        if others.is_empty() {
            continue;
        }
        pairs += others.len();
        let report = replay(calib, &others, SplitConvention::LeftNominal)?;
        for row in &report.evaluations {
            heading
                .entry(row.method.clone())
                .or_default()
                .push(row.heading_error_deg);
            position
                .entry(row.method.clone())
                .or_default()
                .push(row.position_error_m);
        }
    }
    let stats = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let median = if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        };
        (median, v[n - 1])
    };
    println!(
        "{pairs} held-out pairs (calibrate on one set, evaluate on another of the same robot and side)"
    );
    println!(
        "{:<14} {:>12} {:>12} {:>14} {:>14}",
        "method", "heading med°", "heading max°", "position med m", "position max m"
    );
    let order = [
        "uncalibrated",
        "umbmark",
        "lee",
        "heading-only",
        "jung-chung",
        "exact",
        "legs",
    ];
    for m in order {
        let (Some(h), Some(p)) = (heading.get_mut(m), position.get_mut(m)) else {
            continue;
        };
        let (hm, hx) = stats(h);
        let (pm, px) = stats(p);
        println!("{m:<14} {hm:>12.3} {hx:>12.3} {pm:>14.4} {px:>14.4}");
    }
    Ok(())
}
