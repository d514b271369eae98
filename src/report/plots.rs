//! SVG plots of a report (plotters): paths, heading errors per run, end points before/after.

use crate::kinematics::Direction;
use crate::routine::report::{Report, RunReport};
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

type PlotResult<T> = Result<T, Box<dyn std::error::Error>>;

fn io(e: Box<dyn std::error::Error>) -> std::io::Error {
    std::io::Error::other(e.to_string())
}

/// Writes every plot the report has data for; returns the files written.
pub fn write_all(report: &Report, dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    let paths = dir.join("paths.svg");
    if paths_plot(report, &paths).map_err(io)? {
        out.push(paths);
    }
    let headings = dir.join("heading_errors.svg");
    heading_plot(report, &headings).map_err(io)?;
    out.push(headings);
    let ends = dir.join("end_points.svg");
    if end_points_plot(report, &ends).map_err(io)? {
        out.push(ends);
    }
    Ok(out)
}

/// The chart type every plot here draws on.
type Chart<'a, 'b> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// One chart in its own SVG file in the house style (caption, labelled axes, legend top
/// right); `body` draws the series.
#[allow(clippy::too_many_arguments)]
fn draw_chart(
    file: &Path,
    size: (u32, u32),
    caption: &str,
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
    x_desc: &str,
    y_desc: &str,
    body: impl FnOnce(&mut Chart<'_, '_>) -> PlotResult<()>,
) -> PlotResult<()> {
    let root = SVGBackend::new(file, size).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(caption, ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(x, y)?;
    // Whole numbers without a trailing ".0" (run 5, not 5.0), others with what they need.
    let tick = |v: &f64| {
        if (v - v.round()).abs() < 1e-9 {
            format!("{v:.0}")
        } else {
            let s = format!("{v:.3}");
            s.trim_end_matches('0').to_string()
        }
    };
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .draw()?;
    body(&mut chart)?;
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

fn bounds<'a>(paths: impl Iterator<Item = &'a [f64; 2]>) -> (f64, f64, f64, f64) {
    let (mut x0, mut x1, mut y0, mut y1) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for p in paths {
        x0 = x0.min(p[0]);
        x1 = x1.max(p[0]);
        y0 = y0.min(p[1]);
        y1 = y1.max(p[1]);
    }
    let pad = 0.05 * (x1 - x0).max(y1 - y0).max(0.1);
    (x0 - pad, x1 + pad, y0 - pad, y1 + pad)
}

/// The first CW and CCW run of round 1 and of the verification: odometry and, in simulation,
/// the true path.
fn paths_plot(report: &Report, file: &Path) -> PlotResult<bool> {
    let first = |runs: &[RunReport], d: Direction| runs.iter().find(|r| r.direction == d).cloned();
    let mut series: Vec<(String, Vec<[f64; 2]>, RGBColor)> = Vec::new();
    let round1 = report
        .rounds
        .first()
        .map(|r| r.runs.as_slice())
        .unwrap_or(&[]);
    for (label, runs, odo_colour, true_colours) in [
        (
            "before",
            round1,
            RGBColor(150, 150, 150),
            [RED, RGBColor(230, 120, 0)],
        ),
        (
            "after",
            report.verification.as_slice(),
            RGBColor(40, 40, 40),
            [BLUE, RGBColor(0, 150, 150)],
        ),
    ] {
        for (d, true_colour) in [Direction::Cw, Direction::Ccw]
            .into_iter()
            .zip(true_colours)
        {
            if let Some(r) = first(runs, d) {
                if r.odometry_path.len() > 1 {
                    series.push((
                        format!("{label} {d}: odometry"),
                        r.odometry_path.clone(),
                        odo_colour,
                    ));
                }
                if let Some(t) = r.true_path.clone().filter(|t| t.len() > 1) {
                    series.push((format!("{label} {d}: true path"), t, true_colour));
                }
            }
        }
    }
    if series.is_empty() {
        return Ok(false);
    }
    let has_truth = series.iter().any(|s| s.0.contains("true"));
    let (x0, x1, y0, y1) = bounds(series.iter().flat_map(|s| s.1.iter()));
    // Room on the right for the legend, so it never hides data.
    let x1 = x1 + 0.5 * (x1 - x0);
    // Equal scales on both axes (a square must look square): widen the narrower range to the
    // plotting area's aspect (1100 × 800 less margins, caption and label areas).
    let (w_px, h_px) = (1100.0 - 30.0 - 55.0, 800.0 - 30.0 - 40.0 - 35.0);
    let per_px = ((x1 - x0) / w_px).max((y1 - y0) / h_px);
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let (x0, x1) = (cx - 0.5 * per_px * w_px, cx + 0.5 * per_px * w_px);
    let (y0, y1) = (cy - 0.5 * per_px * h_px, cy + 0.5 * per_px * h_px);
    // True paths first (thick), odometry on top (thin), so both stay visible where they agree.
    series.sort_by_key(|s| !s.0.contains("true"));
    draw_chart(
        file,
        (1100, 800),
        if has_truth {
            "Square runs: odometry vs true path"
        } else {
            "Square runs as the odometry saw them (no ground truth on a real robot)"
        },
        x0..x1,
        y0..y1,
        "x (m), first leg",
        "y (m), left",
        |chart| {
            for (label, pts, colour) in series {
                let width = if label.contains("true") { 3 } else { 1 };
                chart
                    .draw_series(LineSeries::new(
                        pts.iter().map(|p| (p[0], p[1])),
                        colour.stroke_width(width),
                    ))?
                    .label(label)
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(width))
                    });
            }
            Ok(())
        },
    )?;
    Ok(true)
}

/// Every run's final heading error, calibration rounds then verification.
fn heading_plot(report: &Report, file: &Path) -> PlotResult<()> {
    let mut points: Vec<(String, Direction, f64)> = Vec::new();
    for r in &report.rounds {
        for run in &r.runs {
            points.push((
                format!("round {}", r.round),
                run.direction,
                run.heading_error_deg,
            ));
        }
    }
    for run in &report.verification {
        points.push(("verification".into(), run.direction, run.heading_error_deg));
    }
    let ymax = points.iter().map(|p| p.2.abs()).fold(0.5f64, f64::max) * 1.15;
    let n = points.len().max(1) as f64;
    draw_chart(
        file,
        (900, 500),
        "Final heading error per run",
        0.0..1.4 * n + 1.0,
        -ymax..ymax,
        "run (calibration rounds, then verification)",
        "heading error (deg, CCW positive)",
        |chart| {
            let colours = [RED, MAGENTA, CYAN, GREEN, BLUE];
            let mut phases: Vec<String> = points.iter().map(|p| p.0.clone()).collect();
            phases.dedup();
            for (k, phase) in phases.iter().enumerate() {
                let colour = if phase == "verification" {
                    BLUE
                } else {
                    colours[k % 4]
                };
                for (d, label) in [(Direction::Cw, "CW"), (Direction::Ccw, "CCW")] {
                    let pts: Vec<(f64, f64)> = points
                        .iter()
                        .enumerate()
                        .filter(|(_, p)| &p.0 == phase && p.1 == d)
                        .map(|(i, p)| (i as f64 + 1.0, p.2))
                        .collect();
                    if pts.is_empty() {
                        continue;
                    }
                    let name = format!("{phase} {label}");
                    if d == Direction::Cw {
                        chart
                            .draw_series(pts.iter().map(|&p| Circle::new(p, 5, colour.filled())))?
                            .label(name)
                            .legend(move |(x, y)| Circle::new((x + 10, y), 5, colour.filled()));
                    } else {
                        chart
                            .draw_series(
                                pts.iter()
                                    .map(|&p| TriangleMarker::new(p, 6, colour.filled())),
                            )?
                            .label(name)
                            .legend(move |(x, y)| {
                                TriangleMarker::new((x + 10, y), 6, colour.filled())
                            });
                    }
                }
            }
            chart.draw_series(LineSeries::new(
                [(0.0, 0.0), (1.4 * n + 1.0, 0.0)],
                BLACK.mix(0.4),
            ))?;
            Ok(())
        },
    )
}

/// True end points of round 1 and of the verification (simulation only).
fn end_points_plot(report: &Report, file: &Path) -> PlotResult<bool> {
    let round1 = report
        .rounds
        .first()
        .map(|r| r.runs.as_slice())
        .unwrap_or(&[]);
    let ends = |runs: &[RunReport], d: Direction| -> Vec<[f64; 2]> {
        runs.iter()
            .filter(|r| r.direction == d)
            .filter_map(|r| r.true_final_xy_m)
            .collect()
    };
    let sets = [
        ("before CW", ends(round1, Direction::Cw), RED),
        ("before CCW", ends(round1, Direction::Ccw), MAGENTA),
        ("after CW", ends(&report.verification, Direction::Cw), BLUE),
        (
            "after CCW",
            ends(&report.verification, Direction::Ccw),
            CYAN,
        ),
    ];
    if sets.iter().all(|s| s.1.is_empty()) {
        return Ok(false);
    }
    let (x0, x1, y0, y1) = bounds(sets.iter().flat_map(|s| s.1.iter()));
    let x1 = x1 + 0.4 * (x1 - x0);
    draw_chart(
        file,
        (900, 700),
        "True end points (start at the origin)",
        x0..x1,
        y0..y1,
        "x (m)",
        "y (m)",
        |chart| {
            chart.draw_series([Cross::new((0.0, 0.0), 8, BLACK.stroke_width(2))])?;
            for (label, pts, colour) in sets {
                if pts.is_empty() {
                    continue;
                }
                chart
                    .draw_series(
                        pts.iter()
                            .map(|p| Circle::new((p[0], p[1]), 5, colour.filled())),
                    )?
                    .label(label)
                    .legend(move |(x, y)| Circle::new((x + 10, y), 5, colour.filled()));
            }
            Ok(())
        },
    )?;
    Ok(true)
}
