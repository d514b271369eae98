//! The report's plots read as data: the paths re-integrated with the written parameters say
//! where the robot went, each plot is written exactly when the report holds its data, and
//! every legend entry's style is drawn by a series.

mod common;

use odocal::report::plots::{reintegrated, write_all};
use odocal::routine::config::{RoutineConfig, WritePolicy};
use odocal::routine::Report;
use std::collections::BTreeSet;
use std::path::Path;

/// One calibration on the simulated base (ground truth, a compass, streamed travel).
async fn calibrated(name: &str) -> Report {
    let sim = common::sim_base(0.37, 3);
    let cfg = RoutineConfig {
        write_back: WritePolicy::Yes,
        confirm_motion: false,
        settle_s: 0.0,
        backup_dir: Some(common::scratch(&format!("plots-{name}"))),
        ..RoutineConfig::default()
    };
    common::routine_on(&sim, &cfg)
        .await
        .unwrap_or_else(|e| panic!("routine: {e}"))
}

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

#[tokio::test]
async fn the_written_parameters_re_integrate_round_1_to_where_the_robot_went() {
    let report = calibrated("reintegrate").await;
    assert!(report.written, "the simulated robot needs a correction");
    let written = report.final_params;
    for run in &report.rounds[0].runs {
        assert_ne!(run.params, written);
        let believed = reintegrated(run, &run.params).expect("samples in the report");
        let corrected = reintegrated(run, &written).expect("samples in the report");
        let truth = run.true_final_xy_m.expect("a simulation knows the truth");
        let (b_end, c_end) = (believed[believed.len() - 1], corrected[corrected.len() - 1]);
        // The belief is the odometry's own path: it agrees with the path the routine
        // integrated from every sample, and it believes it closed the square.
        let odometry_end = run.odometry_path[run.odometry_path.len() - 1];
        assert!(
            distance(b_end, odometry_end) < 0.005,
            "{b_end:?} {odometry_end:?}"
        );
        // The written parameters put the same wheel travel where the robot really ended,
        // metres from where the odometry believed it was.
        assert!(
            distance(b_end, truth) > 0.5,
            "believed {b_end:?}, true {truth:?}"
        );
        assert!(
            distance(c_end, truth) < 0.1 * distance(b_end, truth),
            "corrected {c_end:?}, believed {b_end:?}, true {truth:?}"
        );
    }
    // The verification ran with the written parameters: nothing to re-integrate.
    for run in &report.verification {
        assert_eq!(run.params, written);
    }
}

/// The `.svg` files in `dir`.
fn svgs_in(dir: &Path) -> BTreeSet<String> {
    std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .filter_map(Result::ok)
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.ends_with(".svg"))
                .collect()
        })
        .unwrap_or_default()
}

/// Writes the plots of `report` into a fresh directory; returns the names written, after
/// checking that `write_all` named exactly the files that are there.
fn plots_of(report: &Report, name: &str) -> BTreeSet<String> {
    let dir = common::scratch(&format!("plots-files-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    let written = write_all(report, &dir).unwrap_or_else(|e| panic!("plots: {e}"));
    let named: BTreeSet<String> = written
        .iter()
        .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .collect();
    assert_eq!(named.len(), written.len(), "{written:?}");
    assert_eq!(named, svgs_in(&dir), "write_all returns the files written");
    for f in &named {
        check_legend(&dir.join(f));
    }
    // The Markdown report links exactly the plots drawn.
    let linked: BTreeSet<String> = odocal::report::markdown(report)
        .split("](")
        .skip(1)
        .filter_map(|rest| rest.split(')').next())
        .filter(|f| f.ends_with(".svg"))
        .map(str::to_string)
        .collect();
    assert_eq!(linked, named, "report.md links the plots drawn");
    if std::env::var_os("KEEP_PLOTS").is_none() {
        let _ = std::fs::remove_dir_all(&dir);
    }
    named
}

fn set(names: &[&str]) -> BTreeSet<String> {
    names.iter().map(|s| s.to_string()).collect()
}

/// Every run of a report: each round's, then the verification's.
fn runs_mut(r: &mut Report) -> impl Iterator<Item = &mut odocal::routine::report::RunReport> {
    r.rounds
        .iter_mut()
        .flat_map(|round| round.runs.iter_mut())
        .chain(r.verification.iter_mut())
}

#[tokio::test]
async fn each_plot_is_written_exactly_when_its_data_is_there() {
    let full = calibrated("files").await;
    assert!(full.swing.is_some(), "the simulated compass swings");
    assert!(full
        .swing
        .as_ref()
        .is_some_and(|s| s.measured.len() > 100 && s.measured.len() <= s.points));
    // Every plot a report directory may hold.
    let all: Vec<&str> = odocal::report::REPORT_FILES
        .into_iter()
        .filter(|f| f.ends_with(".svg"))
        .collect();
    assert_eq!(all.len(), 6, "{all:?}");
    assert_eq!(plots_of(&full, "full"), set(&all));

    // No swing: no deviation curve.
    let mut r = full.clone();
    r.swing = None;
    assert_eq!(
        plots_of(&r, "no-swing"),
        set(&all).into_iter().filter(|f| f != "swing.svg").collect()
    );

    // A report from before the samples (or a drive that did not stream them): the paths from
    // what the odometry integrated at the time, no heading along the legs.
    let mut r = full.clone();
    for run in runs_mut(&mut r) {
        run.samples.clear();
    }
    assert!(!plots_of(&r, "no-samples").contains("heading_along_legs.svg"));
    assert!(plots_of(&r, "no-samples-2").contains("paths.svg"));

    // A heading that does not stream: samples without a heading.
    let mut r = full.clone();
    for run in runs_mut(&mut r) {
        for s in &mut run.samples {
            s.heading_rad = None;
        }
    }
    assert!(!plots_of(&r, "no-heading").contains("heading_along_legs.svg"));

    // A real robot: no true end points, no true paths.
    let mut r = full.clone();
    for run in runs_mut(&mut r) {
        run.true_final_xy_m = None;
        run.true_path = None;
    }
    let real = plots_of(&r, "real");
    assert!(!real.contains("end_points.svg") && real.contains("paths.svg"));

    // Nothing driven: nothing drawn.
    let mut r = full.clone();
    r.rounds.clear();
    r.verification.clear();
    r.swing = None;
    assert_eq!(plots_of(&r, "nothing"), BTreeSet::new());
    // The Markdown links only what is drawn.
    let md = odocal::report::markdown(&r);
    assert!(!md.contains(".svg"), "{md}");
    let md = odocal::report::markdown(&full);
    for f in all {
        assert!(md.contains(&format!("({f})")), "{f} not linked");
    }
}

/// An SVG element's attribute.
fn attr<'a>(element: &'a str, name: &str) -> Option<&'a str> {
    element
        .split(&format!(" {name}=\""))
        .nth(1)
        .and_then(|rest| rest.split('"').next())
}

/// What makes two marks look alike: their stroke, its width and their opacity, and for a dot
/// its fill (a line's fill is `none` as a polyline and absent as a plain line).
fn style(element: &str) -> Vec<Option<&str>> {
    let mut names = vec!["stroke", "stroke-width", "opacity"];
    if !element.contains("points=") && !element.contains("x1=") {
        names.push("fill");
    }
    names.iter().map(|a| attr(element, a)).collect()
}

fn points(element: &str) -> Vec<[f64; 2]> {
    attr(element, "points")
        .unwrap_or("")
        .split_whitespace()
        .filter_map(|xy| {
            let (x, y) = xy.split_once(',')?;
            Some([x.parse().ok()?, y.parse().ok()?])
        })
        .collect()
}

/// Every line and dot sample in the legend (the margin at the right, 250 px) has its style
/// drawn by a line or a dot among the plot's series, and no series style is without an entry
/// (apart from the black zero lines and mean bars, and circles of error bars).
fn check_legend(file: &Path) {
    let svg = std::fs::read_to_string(file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
    let width: f64 = svg
        .split("<svg")
        .nth(1)
        .and_then(|e| attr(e, "width"))
        .and_then(|w| w.parse().ok())
        .unwrap_or_else(|| panic!("{}: no width", file.display()));
    let margin = width - 250.0;
    let (mut legend_lines, mut series_lines) = (Vec::new(), Vec::new());
    for e in svg.split("<polyline").skip(1) {
        let e = e.split('>').next().unwrap_or("");
        let pts = points(e);
        if pts.iter().all(|p| p[0] >= margin) {
            legend_lines.push(style(e));
        } else if pts.len() > 1 {
            series_lines.push(style(e));
        }
    }
    // The series drawn as polylines, before the error bars' and crosses' plain lines join.
    let coloured_series = series_lines.clone();
    for e in svg.split("<line").skip(1) {
        series_lines.push(style(e.split('>').next().unwrap_or("")));
    }
    let (mut legend_dots, mut series_dots) = (Vec::new(), Vec::new());
    for e in svg.split("<circle").skip(1) {
        let e = e.split('>').next().unwrap_or("");
        let x: f64 = attr(e, "cx").and_then(|x| x.parse().ok()).unwrap_or(0.0);
        if x >= margin {
            legend_dots.push(style(e));
        } else {
            series_dots.push(style(e));
        }
    }
    let name = file.display();
    assert!(
        !legend_lines.is_empty() || !legend_dots.is_empty(),
        "{name}: no legend"
    );
    for l in &legend_lines {
        // An error bar's sample is three black strokes; its series are black strokes too.
        assert!(
            series_lines.contains(l),
            "{name}: legend line {l:?} drawn by no series"
        );
    }
    for d in &legend_dots {
        assert!(
            series_dots.contains(d) || series_lines.contains(d),
            "{name}: legend dot {d:?} drawn by no series"
        );
    }
    // Every coloured series line has its legend entry (black and grey lines are reference
    // lines and error bars, explained by a bar or line entry of their own).
    for s in &coloured_series {
        let stroke = s[0].unwrap_or("");
        if stroke != "#000000" && stroke != "#888888" {
            assert!(
                legend_lines.contains(s),
                "{name}: series {s:?} without a legend entry"
            );
        }
    }
    // Every axis says its unit (or that it is a ratio or a count).
    let texts: Vec<&str> = svg
        .split("<text")
        .skip(1)
        .filter_map(|t| t.split('>').nth(1)?.split('<').next())
        .collect();
    assert!(
        texts.iter().any(|t| t.contains("(m)")
            || t.contains("(°")
            || t.contains("(ratio")
            || t.contains("(m),")),
        "{name}: no unit on an axis: {texts:?}"
    );
}

#[tokio::test]
async fn the_estimate_of_each_round_carries_its_standard_error() {
    let report = calibrated("estimates").await;
    assert!(report.rounds.len() >= 2);
    let dir = common::scratch("plots-estimates");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
    write_all(&report, &dir).unwrap_or_else(|e| panic!("{e}"));
    let svg = std::fs::read_to_string(dir.join("estimates.svg")).unwrap_or_else(|e| panic!("{e}"));
    // Two panels (E_b, E_d), a mark per round in each (the ring of its error bar, or a ring
    // alone without a ±), and the legend's marks in the 250 px margin.
    let width: f64 = svg
        .split("<svg")
        .nth(1)
        .and_then(|e| attr(e, "width"))
        .and_then(|w| w.parse().ok())
        .unwrap_or(0.0);
    let marks = svg
        .split("<circle")
        .skip(1)
        .filter(|e| attr(e, "cx").and_then(|x| x.parse::<f64>().ok()) < Some(width - 250.0))
        .count();
    assert_eq!(marks, 2 * report.rounds.len());
    assert!(report.rounds.iter().any(|r| r.chosen.e_b_std_err.is_some()));
    assert!(svg.contains("± 1 standard error"), "what the ± is");
    assert!(svg.contains("within the round"), "what the ± is");
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test]
async fn without_a_write_the_paths_show_the_proposal_and_say_so() {
    let mut report = calibrated("proposed").await;
    // As a dry run leaves it: the store unchanged, round 1's proposal not written.
    report.written = false;
    report.final_params = report.original_params;
    for round in &mut report.rounds {
        round.written = false;
    }
    let proposal = report.rounds[0]
        .params_after
        .expect("round 1 proposes a correction");
    let dir = common::scratch("plots-proposed");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
    write_all(&report, &dir).unwrap_or_else(|e| panic!("{e}"));
    check_legend(&dir.join("paths.svg"));
    let svg = std::fs::read_to_string(dir.join("paths.svg")).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        svg.contains("with proposed parameters"),
        "named as a proposal"
    );
    assert!(svg.contains("proposed: not written"));
    assert!(!svg.contains("with written parameters"));
    // The proposal moves round 1's ends as the written parameters did.
    for run in &report.rounds[0].runs {
        let c = reintegrated(run, &proposal).expect("samples");
        let truth = run.true_final_xy_m.expect("simulation");
        assert!(
            distance(c[c.len() - 1], truth) < 0.2,
            "{:?}",
            c[c.len() - 1]
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
