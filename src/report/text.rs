//! The text a person reads at the end of a command, rendered from what the library returned
//! (the binary prints it as it is): a calibration's outcome, and its JSON view for stdout.

use super::stated;
use crate::routine::report::Report;
use serde_json::json;
use std::fmt::Write as _;
use std::path::PathBuf;

/// The report as stdout's JSON: everything but the paths and samples (hundreds of points per
/// run, most of the report's size), which stay in the report directory's report.json; with
/// the files written.
pub fn outcome_json(report: &Report, files: &[PathBuf]) -> serde_json::Result<serde_json::Value> {
    let mut v = serde_json::to_value(report)?;
    // The paths (hundreds of points per run, most of the report's size) stay in the report
    // directory's report.json; stdout gets everything else.
    let strip = |runs: Option<&mut serde_json::Value>| {
        for run in runs.and_then(|r| r.as_array_mut()).into_iter().flatten() {
            if let Some(obj) = run.as_object_mut() {
                obj.remove("odometry_path");
                obj.remove("true_path");
                obj.remove("samples");
            }
        }
    };
    if let Some(rounds) = v.get_mut("rounds").and_then(|r| r.as_array_mut()) {
        for round in rounds {
            strip(round.get_mut("runs"));
        }
    }
    strip(v.get_mut("verification"));
    if let Some(swing) = v.get_mut("swing").and_then(|s| s.as_object_mut()) {
        swing.remove("measured");
    }
    if let Some(obj) = v.as_object_mut() {
        obj.insert("report_files".into(), json!(files));
        obj.insert(
            "paths".into(),
            json!(
                "odometry_path, true_path and samples of each run, and the swing's measured \
                 points, are in report.json"
            ),
        );
    }
    Ok(v)
}

/// The outcome of a calibration as the terminal shows it: the last round's estimates with
/// their ± and the chosen method, the rounds, old → new, the backup and the files.
pub fn outcome(report: &Report, files: &[PathBuf]) -> String {
    let mut out = String::new();
    if let Some(r) = report.rounds.last() {
        let _ = writeln!(out, "estimates (round {}):", r.round);
        let _ = writeln!(
            out,
            "{:<13} {:>9} {:>10} {:>9} {:>10}",
            "method", "E_b", "±", "E_d", "±"
        );
        for e in &r.estimates {
            let _ = writeln!(
                out,
                "{:<13} {:>9.6} {:>10} {:>9.6} {:>10}{}",
                e.method.name(),
                e.e_b,
                stated::pm_b(e),
                e.e_d,
                stated::pm_d(e),
                if e.method == r.chosen.method {
                    "  ← chosen"
                } else {
                    ""
                }
            );
        }
        for line in stated::within_session_legend(&r.estimates) {
            let _ = writeln!(out, "{line}");
        }
        let _ = writeln!(out, "chosen: {}, {}", r.chosen.method, r.chosen_because);
        for line in stated::disagreement_lines(
            Some(r.chosen.method),
            "the method chosen",
            stated::Basis::Session,
            &r.estimates,
        ) {
            let _ = writeln!(out, "{line}");
        }
        let _ = writeln!(out);
    }
    let _ = writeln!(
        out,
        "{} round(s), {}, {}",
        report.rounds.len(),
        if report.converged {
            "converged"
        } else {
            "not converged"
        },
        if report.written {
            "parameters written and committed"
        } else {
            "nothing written"
        }
    );
    let _ = write!(out, "{}", super::summary_table(report));
    let _ = writeln!(
        out,
        "backup of the original parameters: {}",
        report.backup_path.display()
    );
    for f in files {
        let _ = writeln!(out, "wrote {}", f.display());
    }
    for w in &report.warnings {
        let _ = writeln!(out, "warning: {w}");
    }
    out
}
