//! Rendering what the routine did: the before/after summary, the Markdown report, the report
//! directory (`report.json`, `report.md`, SVG plots with the `plots` feature). The ROS 2
//! export, which writes a store, is `crate::ros::export`.

#[cfg(feature = "plots")]
pub mod plots;
#[cfg(feature = "plots")]
pub mod pose_plots;
pub use crate::calibration::stated;
pub mod text;
pub mod track;

use crate::io::create_new;
use crate::kinematics::Direction;
use crate::routine::config::WritePolicy;
use crate::routine::report::{params_table, Report, RoundReport};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The before/after summary as a plain-text table.
pub fn summary_table(report: &Report) -> String {
    let mut s = String::new();
    let opt =
        |v: Option<f64>, unit: &str| v.map_or("–".to_string(), |v| format!("{v:.4} {unit}"));
    let _ = writeln!(s, "{:<34} {:>14} {:>14}", "", "before", "after");
    // Only a simulated robot has true end points; a real one's report has no such row.
    if report.e_max_sys_before_m.is_some() || report.e_max_sys_after_m.is_some() {
        let _ = writeln!(
            s,
            "{:<34} {:>14} {:>14}",
            "E_max,sys (true end points)",
            opt(report.e_max_sys_before_m, "m"),
            opt(report.e_max_sys_after_m, "m")
        );
    }
    let _ = writeln!(
        s,
        "{:<34} {:>14} {:>14}",
        "mean |final heading error|",
        format!("{:.3}°", report.mean_abs_heading_error_before_deg),
        report
            .mean_abs_heading_error_after_deg
            .map_or("–".to_string(), |v| format!("{v:.3}°"))
    );
    s.push('\n');
    s.push_str(&params_table(&report.original_params, &report.final_params));
    s
}

/// The report as Markdown.
pub fn markdown(report: &Report) -> String {
    let mut s = String::new();
    markdown_intro(&mut s, report);
    markdown_before_after(&mut s, report);
    for r in &report.rounds {
        markdown_round(&mut s, r, report.config.heading_samples);
    }
    markdown_verification(&mut s, report);
    markdown_warnings(&mut s, report);
    markdown_plots(&mut s, report);
    s
}

/// Appends the title and the opening paragraphs: the robot, the routine, what was written.
fn markdown_intro(s: &mut String, report: &Report) {
    let _ = writeln!(s, "# odocal recalibration report\n");
    let b = &report.base;
    let _ = writeln!(
        s,
        "Drive `{}` ({}), heading `{}` ({}), parameters in `{}` ({}); odocal {}.\n",
        b.drive.id,
        b.drive.kind,
        b.heading.id,
        b.heading.kind,
        b.store.id,
        b.store.kind,
        report.odocal_version
    );
    let _ = writeln!(
        s,
        "Squares of {} m, {} per direction per round, convention `{}`, write-back {}. Backup \
         of the original parameters: `{}`.\n",
        report.config.side_m,
        report.config.runs_per_direction,
        report.config.split_convention().name(),
        report.config.write_back.describe(),
        report.backup_path.display()
    );
    let _ = writeln!(s, "{}\n", written_line(report));
    let _ = writeln!(
        s,
        "Heading noise at rest: {:.3}°. Converged: {}.\n",
        report.heading_noise_rad.to_degrees(),
        report.converged,
    );
}

/// Appends the "Before and after" section: the summary table.
fn markdown_before_after(s: &mut String, report: &Report) {
    let _ = writeln!(
        s,
        "## Before and after\n\n```text\n{}```\n",
        summary_table(report)
    );
}

/// Appends one round's section: its runs, its estimates and what became of them.
fn markdown_round(s: &mut String, r: &RoundReport, heading_samples: usize) {
    let _ = writeln!(s, "## Round {}\n", r.round);
    let _ = writeln!(
        s,
        "| run | direction | heading error at rest (°) | along the legs (°) |\n|---|---|---|---|"
    );
    for (i, run) in r.runs.iter().enumerate() {
        let _ = writeln!(
            s,
            "| {} | {} | {:+.3} | {} |",
            i + 1,
            run.direction,
            run.heading_error_deg,
            run.leg_heading_error_rad
                .map_or("–".into(), |v| format!("{:+.3}", v.to_degrees()))
        );
    }
    let _ = writeln!(s, "\n| method | E_b | ± | E_d | ± |\n|---|---|---|---|---|");
    for e in &r.estimates {
        let _ = writeln!(
            s,
            "| {}{} | {:.6} | {} | {:.6} | {} |",
            e.method,
            if e.method == r.chosen.method {
                " (chosen)"
            } else {
                ""
            },
            e.e_b,
            stated::pm_b(e),
            e.e_d,
            stated::pm_d(e)
        );
    }
    let _ = writeln!(s, "\n{}", plus_minus(r, heading_samples));
    let _ = writeln!(
        s,
        "\n{}\n",
        if r.converged {
            "Within tolerance: nothing to write.".to_string()
        } else if r.written {
            "Written and saved.".to_string()
        } else {
            "Not written.".to_string()
        }
    );
}

/// Appends the "Verification" section, if the routine verified.
fn markdown_verification(s: &mut String, report: &Report) {
    if !report.verification.is_empty() {
        let _ = writeln!(
            s,
            "## Verification\n\n| run | direction | heading error (°) |\n|---|---|---|"
        );
        for (i, run) in report.verification.iter().enumerate() {
            let _ = writeln!(
                s,
                "| {} | {} | {:+.3} |",
                i + 1,
                run.direction,
                run.heading_error_deg
            );
        }
        s.push('\n');
    }
}

/// Appends the "Warnings" section, if there are any.
fn markdown_warnings(s: &mut String, report: &Report) {
    if !report.warnings.is_empty() {
        let _ = writeln!(s, "## Warnings\n");
        for w in &report.warnings {
            let _ = writeln!(s, "- {w}");
        }
        s.push('\n');
    }
}

/// Appends the "Plots" section: a link to each plot drawn.
fn markdown_plots(s: &mut String, report: &Report) {
    let _ = writeln!(s, "## Plots\n");
    for (title, file) in plot_links(report) {
        let _ = writeln!(s, "![{title}]({file})\n");
    }
}

/// The plots the Markdown report links: those whose data the report holds (the plots module
/// writes the same set), so that no link points at a file that was never drawn.
fn plot_links(report: &Report) -> Vec<(&'static str, &'static str)> {
    let every = || {
        report
            .rounds
            .iter()
            .flat_map(|r| r.runs.iter())
            .chain(&report.verification)
    };
    // The paths, end points and heading along the legs are drawn for round 1 and the
    // verification only.
    let phases = || {
        report
            .rounds
            .first()
            .into_iter()
            .flat_map(|r| r.runs.iter())
            .chain(&report.verification)
    };
    let mut links = Vec::new();
    if phases().any(|r| {
        r.odometry_path.len() > 1
            || r.samples.len() > 1
            || r.true_path.as_ref().is_some_and(|t| t.len() > 1)
    }) {
        links.push(("paths", "paths.svg"));
    }
    if every().next().is_some() {
        links.push(("heading errors", "heading_errors.svg"));
    }
    if phases().any(|r| r.true_final_xy_m.is_some()) {
        links.push(("end points", "end_points.svg"));
    }
    if !report.rounds.is_empty() {
        links.push(("estimate per round", "estimates.svg"));
    }
    if report.swing.is_some() {
        links.push(("compass deviation", "swing.svg"));
    }
    let with_heading = |r: &crate::routine::report::RunReport| {
        r.samples
            .iter()
            .filter(|s| s.heading_rad.is_some_and(f64::is_finite))
            .count()
            > 1
    };
    if phases().any(with_heading) {
        links.push(("heading along the legs", "heading_along_legs.svg"));
    }
    links
}

/// Which method's estimate was written, from which round(s), and why; or why nothing was.
fn written_line(report: &Report) -> String {
    let written: Vec<&RoundReport> = report.rounds.iter().filter(|r| r.written).collect();
    if let Some(last) = written.last() {
        let mut methods: Vec<String> = written
            .iter()
            .map(|r| format!("`{}`", r.chosen.method))
            .collect();
        methods.dedup();
        let rounds: Vec<String> = written.iter().map(|r| r.round.to_string()).collect();
        return format!(
            "Written: the {} estimate of round{} {}: {}.",
            methods.join(" then "),
            if rounds.len() > 1 { "s" } else { "" },
            rounds.join(", "),
            last.chosen_because
        );
    }
    let why = match report.rounds.last() {
        None => "no round finished".to_string(),
        Some(r) if r.converged => format!(
            "round {}'s `{}` estimate needs no correction ({})",
            r.round,
            r.chosen.method,
            r.converged_because.as_deref().unwrap_or("within tolerance")
        ),
        Some(r) => format!(
            "round {}'s `{}` estimate was {}",
            r.round,
            r.chosen.method,
            match report.config.write_back {
                WritePolicy::DryRun => "not written: a dry run",
                _ => "declined",
            }
        ),
    };
    format!("Nothing written: {why}.")
}

/// What a round's ± is, beside the Cramér–Rao bound, in a sentence.
fn plus_minus(r: &RoundReport, heading_samples: usize) -> String {
    let per_direction = [Direction::Cw, Direction::Ccw]
        .map(|d| r.runs.iter().filter(|run| run.direction == d).count())
        .into_iter()
        .min()
        .unwrap_or(0);
    let bound = r.cramer_rao_std.map_or(String::new(), |[b, d]| {
        format!(
            "the Cramér–Rao bound (E_b {b:.5}, E_d {d:.5}) is the least any method can reach \
             from the headings at rest ({heading_samples} readings at each end of each square)"
        )
    });
    if r.chosen.e_b_std_err.is_none() {
        return format!(
            "No ± with {per_direction} square(s) per direction (no scatter to measure){}.",
            if bound.is_empty() {
                String::new()
            } else {
                format!("; {bound}, and stands in for it")
            }
        );
    }
    format!(
        "± is the standard error from the scatter of the {per_direction} squares per direction, \
         never below what the heading sensor's noise gives for the headings a method uses{}.",
        if bound.is_empty() {
            String::new()
        } else {
            format!(
                "; {bound}, which `legs` and `matched-legs` go below by averaging every reading \
                 along the legs"
            )
        }
    )
}

/// Escapes text for HTML.
fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Inline Markdown of one line: `code` spans (escaped text otherwise).
fn inline(text: &str) -> String {
    let mut out = String::new();
    for (i, part) in text.split('`').enumerate() {
        if i % 2 == 1 {
            let _ = write!(out, "<code>{}</code>", escape(part));
        } else {
            out.push_str(&escape(part));
        }
    }
    out
}

/// The report as one self-contained HTML page: the Markdown report's content, with the plots
/// (`(file name, SVG text)`) inline instead of linked, so the page opens from a file, mailed or
/// copied alone. Only the constructs [`markdown`] emits are converted.
pub fn html(report: &Report, svgs: &[(String, String)]) -> String {
    let md = markdown(report);
    let mut body = String::new();
    let mut lines = md.lines().peekable();
    while let Some(line) = lines.next() {
        if let Some(h) = line.strip_prefix("## ") {
            let _ = writeln!(body, "<h2>{}</h2>", inline(h));
        } else if let Some(h) = line.strip_prefix("# ") {
            let _ = writeln!(body, "<h1>{}</h1>", inline(h));
        } else if line.starts_with("```") {
            body.push_str("<pre>");
            for code in lines.by_ref() {
                if code.starts_with("```") {
                    break;
                }
                let _ = writeln!(body, "{}", escape(code));
            }
            body.push_str("</pre>\n");
        } else if line.starts_with('|') {
            body.push_str("<table>\n");
            let mut row = Some(line);
            let mut header = true;
            while let Some(r) = row {
                let cells: Vec<&str> = r
                    .trim()
                    .trim_matches('|')
                    .split('|')
                    .map(str::trim)
                    .collect();
                if !cells.iter().all(|c| c.chars().all(|ch| ch == '-')) {
                    let tag = if header { "th" } else { "td" };
                    body.push_str("<tr>");
                    for c in cells {
                        let _ = write!(body, "<{tag}>{}</{tag}>", inline(c));
                    }
                    body.push_str("</tr>\n");
                    header = false;
                }
                row = lines.next_if(|l| l.starts_with('|'));
            }
            body.push_str("</table>\n");
        } else if let Some(item) = line.strip_prefix("- ") {
            let _ = write!(body, "<ul><li>{}</li>", inline(item));
            while let Some(more) = lines.next_if(|l| l.starts_with("- ")) {
                let _ = write!(body, "<li>{}</li>", inline(&more[2..]));
            }
            body.push_str("</ul>\n");
        } else if let Some(rest) = line.strip_prefix("![") {
            // An image line: inline its SVG when it was drawn, else leave it out.
            let file = rest
                .split_once("](")
                .map(|(_, f)| f.trim_end_matches(')'))
                .unwrap_or("");
            if let Some((_, svg)) = svgs.iter().find(|(name, _)| name == file) {
                // The SVG's own XML declaration is not valid inside HTML.
                let start = svg.find("<svg").unwrap_or(0);
                let _ = writeln!(body, "<figure>{}</figure>", &svg[start..]);
            }
        } else if !line.trim().is_empty() {
            let _ = writeln!(body, "<p>{}</p>", inline(line));
        }
    }
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <title>odocal recalibration report</title>\n<style>\n\
         body {{ font-family: sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em; }}\n\
         table {{ border-collapse: collapse; margin: 1em 0; }}\n\
         th, td {{ border: 1px solid #999; padding: 0.2em 0.6em; text-align: right; }}\n\
         pre {{ background: #f4f4f4; padding: 0.8em; overflow-x: auto; }}\n\
         figure {{ margin: 1em 0; }} figure svg {{ max-width: 100%; height: auto; }}\n\
         </style>\n</head>\n<body>\n{body}</body>\n</html>\n"
    )
}

pub use crate::routine::report::REPORT_FILES;

/// Where a report goes: `dir` when it holds none of [`REPORT_FILES`] (not even as a link),
/// else the first of `dir-2`, `dir-3`, … that can be created new. An earlier report is never
/// replaced and a planted link is never followed.
pub fn fresh_report_dir(dir: &Path) -> std::io::Result<PathBuf> {
    crate::io::fresh_dir(dir, &REPORT_FILES)
}

/// Writes `report.json`, `report.md`, (with the `plots` feature) the SVG plots and
/// `report.html` (the report with the plots inline) into a fresh report directory
/// ([`fresh_report_dir`]: `dir`, or `dir-N` when `dir` already holds a report). Every file is
/// created new with the process's default permissions (umask); nothing is replaced.
pub fn write_dir(report: &Report, dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let dir = fresh_report_dir(dir)?;
    let dir = dir.as_path();
    let json = dir.join("report.json");
    create_new(
        &json,
        serde_json::to_string_pretty(report)
            .map_err(std::io::Error::other)?
            .as_bytes(),
    )?;
    let md = dir.join("report.md");
    create_new(&md, markdown(report).as_bytes())?;
    #[allow(unused_mut)]
    let mut written = vec![json, md];
    #[cfg(feature = "plots")]
    written.extend(plots::write_all(report, dir)?);
    let mut svgs = Vec::new();
    for path in &written {
        if path.extension().is_some_and(|e| e == "svg") {
            if let Some(name) = path.file_name().and_then(|n| n.to_str()) {
                svgs.push((name.to_string(), std::fs::read_to_string(path)?));
            }
        }
    }
    let page = dir.join("report.html");
    create_new(&page, html(report, &svgs).as_bytes())?;
    written.push(page);
    Ok(written)
}

/// `odocal fit --report DIR`: `fit.json` (`json`, what `fit --json` prints) and, with the
/// `plots` feature, the pose plots of the recordings `calibration` was fitted from, into `dir`
/// (created if missing; these files replaced). Returns the names written.
pub fn write_fit_dir(
    dir: &Path,
    json: &serde_json::Value,
    calibration: &crate::calibration::pose_calibration::PoseCalibration,
    recordings: &[(String, crate::calibration::pose_reference::PoseRecording)],
) -> std::io::Result<Vec<String>> {
    std::fs::create_dir_all(dir)?;
    let text = serde_json::to_string_pretty(json).map_err(std::io::Error::other)? + "\n";
    std::fs::write(dir.join("fit.json"), text)?;
    #[allow(unused_mut)]
    let mut names = vec!["fit.json".to_string()];
    #[cfg(feature = "plots")]
    for f in pose_plots::write_pose_plots(calibration, recordings, dir)? {
        names.extend(f.file_name().map(|n| n.to_string_lossy().into_owned()));
    }
    #[cfg(not(feature = "plots"))]
    let _ = (calibration, recordings);
    Ok(names)
}
