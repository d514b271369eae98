//! The text a person reads at the end of a command, rendered from what the library returned
//! (the binary prints it as it is): a calibration's outcome, and its JSON view for stdout.

use super::stated::{
    self, default_line, disagreement_lines, pm, pm_b, pm_d, within_session_legend, Basis,
};
use crate::calibration::by_hand::HandReport;
use crate::offline::dataset::{OptiOdomSet, Replay};
use crate::offline::study::{MethodSummary, StudyConfig, StudyOutcome};
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

/// A hand-typed square test's estimates as stdout's JSON ([`estimates`]'s numbers).
pub fn estimates_json(r: &HandReport) -> serde_json::Value {
    let estimates: Vec<_> = r
        .rows
        .iter()
        .map(|(e, p)| {
            let mut v = serde_json::to_value(e).unwrap_or_default();
            if let (Some(p), Some(obj)) = (p, v.as_object_mut()) {
                obj.insert(
                    "left_wheel_diameter_m".into(),
                    json!(p.left_wheel_diameter_m),
                );
                obj.insert(
                    "right_wheel_diameter_m".into(),
                    json!(p.right_wheel_diameter_m),
                );
                obj.insert("wheelbase_m".into(), json!(p.wheelbase_m));
            }
            v
        })
        .collect();
    json!({
        "convention": r.convention.name(),
        "configured": r.configured,
        "default_method": r.default,
        "warnings": r.warnings,
        "estimates": estimates,
        "failures": r.failures.iter().map(|(m, e)| json!({"method": m.name(), "error": e})).collect::<Vec<_>>(),
        "cramer_rao_std": r.cramer_rao_std.map(|[b, d]| json!({"e_b": b, "e_d": d})),
    })
}

/// A hand-typed square test's estimates as the terminal shows them: every method with its ±
/// and what the ± means, the Cramér–Rao bound, the default method and any disagreement, the
/// corrected parameters, and the methods that could not estimate.
pub fn estimates(r: &HandReport) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "square {} m, wheelbase {} m, {} CW + {} CCW runs, convention {}",
        r.test.side_m,
        r.test.wheelbase_m,
        r.test.cw.len(),
        r.test.ccw.len(),
        r.convention.name()
    );
    let _ = writeln!(
        out,
        "{:<13} {:>9} {:>10} {:>9} {:>10}",
        "method", "E_b", "±", "E_d", "±"
    );
    for (e, _) in &r.rows {
        let _ = writeln!(
            out,
            "{:<13} {:>9.6} {:>10} {:>9.6} {:>10}{}",
            e.method.name(),
            e.e_b,
            pm_b(e),
            e.e_d,
            pm_d(e),
            if Some(e.method) == r.default {
                "  (default)"
            } else {
                ""
            }
        );
    }
    let estimates = r.estimates();
    for line in within_session_legend(&estimates) {
        let _ = writeln!(out, "{line}");
    }
    let _ = match r.cramer_rao_std {
        Some([b, d]) => writeln!(
            out,
            "Cramér–Rao bound (std): E_b {:.5}, E_d {:.5}: the least error any method can have \
             from these headings with {} deg of noise per reading (no stated ± is below what \
             that noise gives)",
            b,
            d,
            r.heading_sigma_deg.unwrap_or(f64::NAN)
        ),
        None => writeln!(
            out,
            "(give --heading-sigma-deg, the sensor's noise per reading, for the Cramér–Rao bound \
             and a ± with one run per direction)"
        ),
    };
    if let Some(m) = r.default {
        let _ = writeln!(out, "{}", default_line(m));
    }
    for line in disagreement_lines(r.default, "the default", Basis::Session, &estimates) {
        let _ = writeln!(out, "{line}");
    }
    if r.configured.is_some() {
        let _ = writeln!(
            out,
            "\ncorrected parameters (left D, right D, wheelbase, m):"
        );
        for (e, p) in &r.rows {
            if let Some(p) = p {
                let _ = writeln!(
                    out,
                    "{:<13} {:.6} {:.6} {:.6}",
                    e.method.name(),
                    p.left_wheel_diameter_m,
                    p.right_wheel_diameter_m,
                    p.wheelbase_m
                );
            }
        }
    }
    for (m, e) in &r.failures {
        let _ = writeln!(out, "{m}: not estimated: {e}");
    }
    out
}

/// A replay as stdout's JSON: the estimates against the first set's configuration, pooled
/// when several sets were given, and the evaluations.
pub fn replay_json(r: &Replay, calibrated_on: &OptiOdomSet) -> serde_json::Value {
    json!({
        "datasets": r.datasets,
        "configured": calibrated_on.configured,
        "estimates": r.estimates,
        "default_method": r.default_method,
        "uncertainty": r.uncertainty,
        "pooled": r.pooled,
        "failures": r.failures.iter().map(|(m, e)| json!({"method": m.name(), "error": e})).collect::<Vec<_>>(),
        "evaluations": r.evaluations,
    })
}

/// A replay as the terminal shows it: what it calibrated on, each method's estimate with its
/// ± (a prediction for the next session when sets are pooled), the default method and any
/// disagreement, the failures, and the odometry errors on each set evaluated.
pub fn replay(r: &Replay, sets: &[OptiOdomSet]) -> String {
    let mut out = String::new();
    let Some(calib) = sets.first() else {
        return out;
    };
    let runs: usize = sets.iter().map(|s| s.runs.len()).sum();
    let pooled = r.datasets.len() > 1;
    replay_intro(&mut out, r, calib, runs, pooled);
    replay_estimates(&mut out, r, pooled);
    replay_default_and_failures(&mut out, r, pooled);
    replay_evaluations(&mut out, r);
    out
}

/// Appends what the replay calibrated on (`calib` first, `runs` runs in all) and, when the sets
/// are pooled, what its ± means.
fn replay_intro(out: &mut String, r: &Replay, calib: &OptiOdomSet, runs: usize, pooled: bool) {
    let _ = writeln!(
        out,
        "calibrated on {} ({runs} runs, side {} m); estimates against {}'s configuration: \
         D_L {} D_R {} b {}",
        r.datasets.join(", "),
        calib.side_m.unwrap_or(f64::NAN),
        calib.id,
        calib.configured.left_wheel_diameter_m,
        calib.configured.right_wheel_diameter_m,
        calib.configured.wheelbase_m
    );
    if pooled {
        let _ = writeln!(
            out,
            "± is one standard deviation of what the next session of this robot will read \
             (a prediction: the pooled value's standard error, the session-to-session spread \
             and one session's own scatter; --json has each quantity's std_err and \
             prediction_std)"
        );
    }
}

/// Appends the table of each method's estimate with its ± and spread, and (one session) the
/// legend of its ±.
fn replay_estimates(out: &mut String, r: &Replay, pooled: bool) {
    let _ = writeln!(
        out,
        "{:<13} {:>9} {:>10} {:>9} {:>10} {:>16}",
        "method", "E_b", "±", "E_d", "±", "E_b spread"
    );
    for (e, p) in r.estimates.iter().zip(&r.pooled) {
        let spread = if pooled {
            format!(
                "{:.5}",
                p.ln_wheelbase_over_diameter.recording_spread * e.e_b
            )
        } else {
            "—".into()
        };
        let mark = if r.default_method == Some(e.method) {
            "  (default)"
        } else {
            ""
        };
        let (b, d) = if pooled {
            let (b, d) = p.prediction_std(e);
            (pm(b), pm(d))
        } else {
            (pm_b(e), pm_d(e))
        };
        let _ = writeln!(
            out,
            "{:<13} {:>9.5} {:>10} {:>9.5} {:>10} {:>16}{mark}",
            e.method.name(),
            e.e_b,
            b,
            e.e_d,
            d,
            spread
        );
    }
    if !pooled {
        for line in within_session_legend(&r.estimates) {
            let _ = writeln!(out, "{line}");
        }
    }
}

/// Appends the default method, any disagreement with it and the methods that failed.
fn replay_default_and_failures(out: &mut String, r: &Replay, pooled: bool) {
    if let Some(m) = r.default_method {
        let _ = writeln!(out, "{}", default_line(m));
    }
    for line in disagreement_lines(
        r.default_method,
        "the default",
        if pooled {
            Basis::Pooled
        } else {
            Basis::Session
        },
        &r.estimates,
    ) {
        let _ = writeln!(out, "{line}");
    }
    for (m, e) in &r.failures {
        let _ = writeln!(out, "{m}: not estimated: {e}");
    }
}

/// Appends the table of odometry errors on each set evaluated, by parameters.
fn replay_evaluations(out: &mut String, r: &Replay) {
    let _ = writeln!(
        out,
        "\n{:<16} {:<13} {:>18} {:>16} {:>18} {:>16}",
        "evaluated on",
        "parameters",
        "|heading err| deg",
        "position err m",
        "systematic hdg deg",
        "systematic pos m"
    );
    for r in &r.evaluations {
        let _ = writeln!(
            out,
            "{:<16} {:<13} {:>18.3} {:>16.4} {:>18.3} {:>16.4}",
            r.dataset,
            r.method,
            r.heading_error_deg,
            r.position_error_m,
            r.systematic_heading_error_deg,
            r.systematic_position_error_m
        );
    }
}

/// The paper's simulation study as run (`odocal simulate`): its settings, the trials, and each
/// method's mean estimate, error and `E_max,sys` after calibration.
pub struct Study<'a> {
    /// The study's settings.
    pub config: &'a StudyConfig,
    /// Trials run.
    pub trials: usize,
    /// Each trial's outcome.
    pub studies: &'a [StudyOutcome],
    /// Each method over the trials.
    pub summaries: &'a [MethodSummary],
}

impl Study<'_> {
    /// Mean `E_max,sys` before calibration over the trials (m).
    fn before_m(&self) -> f64 {
        self.studies
            .iter()
            .map(|s| s.e_max_sys_before_m)
            .sum::<f64>()
            / self.studies.len() as f64
    }

    /// Every method that failed in a trial, with why.
    fn failures(&self) -> Vec<serde_json::Value> {
        self.studies
            .iter()
            .flat_map(|s| s.failures.iter())
            .map(|(m, e)| json!({"method": m.name(), "error": e}))
            .collect()
    }

    /// The study as stdout's JSON.
    pub fn json(&self) -> serde_json::Value {
        json!({
            "truth": self.studies.first().map(|s| s.truth),
            "config": self.config,
            "trials": self.trials,
            "e_max_sys_before_m": self.before_m(),
            "estimates": self.summaries,
            "failures": self.failures(),
        })
    }

    /// The study as the terminal shows it.
    pub fn text(&self) -> String {
        let cfg = self.config;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "true E_b {} E_d {} ({} split), {} m square, {} run(s) each way, {} trial(s), \
             write-back {}",
            cfg.true_e_b,
            cfg.true_e_d,
            cfg.truth_split.name(),
            cfg.side_m,
            cfg.runs,
            self.trials,
            cfg.convention.name()
        );
        let _ = writeln!(
            out,
            "E_max,sys before calibration: {:.4} m",
            self.before_m()
        );
        let _ = writeln!(
            out,
            "{:<13} {:>9} {:>10} {:>9} {:>10} {:>11} {:>11} {:>12}",
            "method", "E_b", "±", "E_d", "±", "E_b err pp", "E_d err pp", "E_max,sys m"
        );
        for s in self.summaries {
            let _ = writeln!(
                out,
                "{:<13} {:>9.6} {:>10} {:>9.6} {:>10} {:>11.4} {:>11.4} {:>12.4}",
                s.method.name(),
                s.e_b,
                pm(s.e_b_std_err),
                s.e_d,
                pm(s.e_d_std_err),
                s.e_b_error_pp,
                s.e_d_error_pp,
                s.e_max_sys_m
            );
        }
        for f in self.failures() {
            let _ = writeln!(out, "not estimated: {f}");
        }
        out
    }
}
