//! SVG plots of a report (plotters): the square runs' paths, the heading errors of each phase,
//! the true end points.
//!
//! Every plot follows one key: one colour per direction ([`colour`]: clockwise blue,
//! counter-clockwise orange), before (round 1) drawn in a light tint of it and after (the
//! verification) in full; every run is drawn; where both axes are metres a metre spans as many pixels across as
//! up; legends sit in a margin of their own, never over the data or stretching an axis.

use crate::kinematics::Direction;
use crate::routine::report::{e_max_sys, Report, RunReport};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::ops::Range;
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

/// The colour of a direction's runs in every plot.
pub fn colour(direction: Direction) -> RGBColor {
    match direction {
        Direction::Cw => RGBColor(31, 119, 180),
        Direction::Ccw => RGBColor(230, 115, 0),
    }
}

/// A direction's colour for the runs before calibration (round 1, `before`) or after: the
/// same hue, lighter before. A tint rather than transparency, which would darken where
/// several runs overlap.
pub fn shade(direction: Direction, before: bool) -> RGBColor {
    let RGBColor(r, g, b) = colour(direction);
    let light = |c: u8| {
        if before {
            (f64::from(c) + 0.55 * (255.0 - f64::from(c))).round() as u8
        } else {
            c
        }
    };
    RGBColor(light(r), light(g), light(b))
}

/// Width of the legend margin (px).
const LEGEND_PX: u32 = 250;
/// Heights of the x-axis label area and widths of the y-axis label area (px).
const X_LABELS_PX: u32 = 40;
const Y_LABELS_PX: u32 = 60;

/// The chart type every plot here draws on.
type Chart<'a, 'b> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;
type Area<'b> = DrawingArea<SVGBackend<'b>, Shift>;

/// Whole numbers without a trailing ".0" (run 5, not 5.0), others with what they need.
fn tick(v: &f64) -> String {
    // No "-0" where a tick lands a rounding error below zero.
    let v = if v.abs() < 1e-9 { 0.0 } else { *v };
    if (v - v.round()).abs() < 1e-9 {
        format!("{v:.0}")
    } else {
        let s = format!("{v:.4}");
        s.trim_end_matches('0').to_string()
    }
}

/// A panel's area once its title is drawn, and the size of its plotting area (px).
fn titled<'b>(area: &Area<'b>, title: &str) -> PlotResult<(Area<'b>, (u32, u32))> {
    let area = area
        .margin(10, 10, 10, 20)
        .titled(title, ("sans-serif", 17))?;
    let (w, h) = area.dim_in_pixel();
    Ok((
        area,
        (
            w.saturating_sub(Y_LABELS_PX).max(1),
            h.saturating_sub(X_LABELS_PX).max(1),
        ),
    ))
}

/// A chart on `area` (from [`titled`]) with labelled axes and a light mesh.
fn chart<'a, 'b>(
    area: &'a Area<'b>,
    x: Range<f64>,
    y: Range<f64>,
    x_desc: &str,
    y_desc: &str,
    x_ticks: &dyn Fn(&f64) -> String,
) -> PlotResult<Chart<'a, 'b>> {
    let mut chart = ChartBuilder::on(area)
        .x_label_area_size(X_LABELS_PX)
        .y_label_area_size(Y_LABELS_PX)
        .build_cartesian_2d(x, y)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .x_label_formatter(x_ticks)
        .y_label_formatter(&tick)
        .light_line_style(BLACK.mix(0.04))
        .bold_line_style(BLACK.mix(0.15))
        .draw()?;
    Ok(chart)
}

/// The smallest box around `points` and the origin, padded by 5 % of its larger side.
fn bounds<'a>(points: impl Iterator<Item = &'a [f64; 2]>) -> [Range<f64>; 2] {
    let (mut x0, mut x1, mut y0, mut y1) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for p in points {
        x0 = x0.min(p[0]);
        x1 = x1.max(p[0]);
        y0 = y0.min(p[1]);
        y1 = y1.max(p[1]);
    }
    let pad = 0.05 * (x1 - x0).max(y1 - y0).max(0.002);
    [x0 - pad..x1 + pad, y0 - pad..y1 + pad]
}

/// Axis ranges holding `[x, y]` in a plotting area of `px` pixels with equal scales (a
/// square looks square): the narrower range is widened about its centre.
fn equal_scale([x, y]: [Range<f64>; 2], (w, h): (u32, u32)) -> [Range<f64>; 2] {
    let (w, h) = (f64::from(w), f64::from(h));
    let per_px = ((x.end - x.start) / w).max((y.end - y.start) / h);
    let centred = |r: Range<f64>, px: f64| {
        let c = 0.5 * (r.start + r.end);
        c - 0.5 * per_px * px..c + 0.5 * per_px * px
    };
    [centred(x, w), centred(y, h)]
}

/// How a legend entry is drawn.
enum Mark {
    /// A line sample.
    Line(ShapeStyle),
    /// A filled dot.
    Dot(ShapeStyle),
    /// A ring.
    Ring(ShapeStyle),
    /// A black cross.
    Cross,
    /// An error bar.
    Bar,
    /// No sample: a line of text.
    Note,
}

/// The legend, in its own margin beside the plots.
fn legend(area: &Area<'_>, entries: &[(String, Mark)]) -> PlotResult<()> {
    let area = area.margin(50, 10, 5, 5);
    let font = ("sans-serif", 13).into_font();
    let mut y = 0;
    for (label, mark) in entries {
        let mid = y + 8;
        match mark {
            Mark::Line(style) => area.draw(&PathElement::new(vec![(0, mid), (28, mid)], *style))?,
            Mark::Dot(style) => area.draw(&Circle::new((14, mid), 4, *style))?,
            Mark::Ring(style) => area.draw(&Circle::new((14, mid), 7, *style))?,
            Mark::Cross => area.draw(&Cross::new((14, mid), 6, BLACK.stroke_width(2)))?,
            Mark::Bar => {
                for (a, b) in [
                    ((14, mid - 8), (14, mid + 8)),
                    ((9, mid - 8), (19, mid - 8)),
                    ((9, mid + 8), (19, mid + 8)),
                ] {
                    area.draw(&PathElement::new(vec![a, b], BLACK.stroke_width(1)))?;
                }
                area.draw(&Circle::new((14, mid), 4, BLACK.stroke_width(1)))?;
            }
            Mark::Note => {}
        }
        let x = if matches!(mark, Mark::Note) { 0 } else { 36 };
        area.draw(&Text::new(label.clone(), (x, y), font.clone()))?;
        y += 22;
    }
    Ok(())
}

/// The legend entries of the two phases' colours: each direction before and after.
fn phase_entries(before: &[RunReport], after: &[RunReport], width: u32) -> Vec<(String, Mark)> {
    let mut entries = Vec::new();
    for d in [Direction::Cw, Direction::Ccw] {
        for (runs, phase, is_before) in [
            (before, "before (round 1)", true),
            (after, "after (verification)", false),
        ] {
            let n = runs.iter().filter(|r| r.direction == d).count();
            if n > 0 {
                entries.push((
                    format!("{d} {phase}: {n}"),
                    Mark::Line(shade(d, is_before).stroke_width(width)),
                ));
            }
        }
    }
    entries
}

/// The runs before (round 1) and after (the verification).
fn phases(report: &Report) -> (&[RunReport], &[RunReport]) {
    let before = report.rounds.first().map_or(&[][..], |r| r.runs.as_slice());
    (before, report.verification.as_slice())
}

/// Every run of round 1 (light) and of the verification (full), in its direction's colour
/// ([`shade`]):
/// the odometry and, in simulation, the true path (thick, beneath). Drawn in this order: true
/// paths of round 1's runs then of the verification's, then the odometry in the same order.
fn paths_plot(report: &Report, file: &Path) -> PlotResult<bool> {
    let (before, after) = phases(report);
    let runs = || {
        before
            .iter()
            .map(|r| (r, true))
            .chain(after.iter().map(|r| (r, false)))
    };
    let has_truth = runs().any(|(r, _)| r.true_path.is_some());
    // (points, style): true paths first, so the thin odometry stays visible on top.
    let mut traces: Vec<(&[[f64; 2]], ShapeStyle)> = Vec::new();
    for (r, is_before) in runs() {
        if let Some(t) = r.true_path.as_deref().filter(|t| t.len() > 1) {
            traces.push((t, shade(r.direction, is_before).stroke_width(3)));
        }
    }
    let odometry_width = if has_truth { 1 } else { 2 };
    for (r, is_before) in runs() {
        if r.odometry_path.len() > 1 {
            traces.push((
                &r.odometry_path,
                shade(r.direction, is_before).stroke_width(odometry_width),
            ));
        }
    }
    if traces.is_empty() {
        return Ok(false);
    }
    let size = (1100, 800);
    let root = SVGBackend::new(file, size).into_drawing_area();
    root.fill(&WHITE)?;
    let (plot, side) = root.split_horizontally(size.0 - LEGEND_PX);
    let (area, px) = titled(
        &plot,
        if has_truth {
            "Square runs: true paths (thick) and odometry (thin)"
        } else {
            "Square runs as the odometry saw them (no ground truth on a real robot)"
        },
    )?;
    let [x, y] = equal_scale(bounds(traces.iter().flat_map(|t| t.0.iter())), px);
    let mut chart = chart(&area, x, y, "x (m), first leg", "y (m), left", &tick)?;
    for (pts, style) in &traces {
        chart.draw_series(LineSeries::new(pts.iter().map(|p| (p[0], p[1])), *style))?;
    }
    chart.draw_series([Cross::new((0.0, 0.0), 7, BLACK.stroke_width(2))])?;
    let mut entries = phase_entries(before, after, 3);
    if has_truth {
        let grey = RGBColor(90, 90, 90);
        entries.push((
            "true path (simulation)".into(),
            Mark::Line(grey.stroke_width(3)),
        ));
        entries.push(("odometry".into(), Mark::Line(grey.stroke_width(1))));
    }
    entries.push(("start of every square".into(), Mark::Cross));
    entries.push(("every run drawn; equal scales".into(), Mark::Note));
    legend(&side, &entries)?;
    root.present()?;
    Ok(true)
}

/// Mean and sample standard deviation.
fn mean_std(v: &[f64]) -> Option<(f64, Option<f64>)> {
    let n = v.len() as f64;
    if v.is_empty() {
        return None;
    }
    let mean = v.iter().sum::<f64>() / n;
    let std = (v.len() > 1)
        .then(|| (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt());
    Some((mean, std))
}

/// Every run's final heading error, one panel per phase (round 1 = before, later rounds,
/// verification = after), each on its own scale: the runs as dots by direction, and each
/// direction's mean with a bar of ± 2 standard deviations of its runs.
fn heading_plot(report: &Report, file: &Path) -> PlotResult<()> {
    let mut panels: Vec<(String, &[RunReport])> = Vec::new();
    let rounds = report.rounds.len();
    for r in &report.rounds {
        let title = match r.round {
            1 if rounds > 1 || !report.verification.is_empty() => "round 1 (before)".into(),
            n => format!("round {n}"),
        };
        panels.push((title, &r.runs));
    }
    if !report.verification.is_empty() {
        panels.push(("verification (after)".into(), &report.verification));
    }
    if panels.is_empty() {
        panels.push(("no runs".into(), &[]));
    }
    let size = (LEGEND_PX + 400 * panels.len() as u32, 520);
    let root = SVGBackend::new(file, size).into_drawing_area();
    root.fill(&WHITE)?;
    let (plots, side) = root.split_horizontally(size.0 - LEGEND_PX);
    let directions = [Direction::Cw, Direction::Ccw];
    let x_ticks = |v: &f64| match v.round() as i64 {
        0 if v.abs() < 1e-9 => "clockwise".to_string(),
        1 if (v - 1.0).abs() < 1e-9 => "counter-clockwise".to_string(),
        _ => String::new(),
    };
    for (area, (title, runs)) in plots.split_evenly((1, panels.len())).iter().zip(&panels) {
        let (area, _) = titled(area, title)?;
        let per_direction: Vec<(Direction, Vec<f64>)> = directions
            .iter()
            .map(|&d| {
                let v = runs
                    .iter()
                    .filter(|r| r.direction == d)
                    .map(|r| r.heading_error_deg)
                    .collect();
                (d, v)
            })
            .collect();
        // The scale: every run, every bar and zero.
        let (mut lo, mut hi) = (0.0f64, 0.0f64);
        for (_, v) in &per_direction {
            for &e in v {
                lo = lo.min(e);
                hi = hi.max(e);
            }
            if let Some((m, Some(s))) = mean_std(v) {
                lo = lo.min(m - 2.0 * s);
                hi = hi.max(m + 2.0 * s);
            }
        }
        let pad = (0.12 * (hi - lo)).max(0.05);
        let mut chart = chart(
            &area,
            -0.5..1.8,
            lo - pad..hi + pad,
            "",
            "final heading error (°, CCW positive)",
            &x_ticks,
        )?;
        chart.draw_series(LineSeries::new([(-0.5, 0.0), (1.8, 0.0)], BLACK.mix(0.5)))?;
        for (k, (d, v)) in per_direction.iter().enumerate() {
            let centre = k as f64;
            let n = v.len() as f64;
            let spread = (0.3 / n.max(1.0)).min(0.06);
            let style = colour(*d).mix(0.85).filled();
            chart.draw_series(v.iter().enumerate().map(|(i, &e)| {
                let x = centre + (i as f64 - 0.5 * (n - 1.0)) * spread;
                Circle::new((x, e), 4, style)
            }))?;
            let Some((mean, std)) = mean_std(v) else {
                continue;
            };
            let at = centre + 0.3;
            let two_sigma = 2.0 * std.unwrap_or(0.0);
            chart.draw_series([ErrorBar::new_vertical(
                at,
                mean - two_sigma,
                mean,
                mean + two_sigma,
                BLACK.stroke_width(2),
                14,
            )])?;
            let label = match std {
                Some(s) => format!("{mean:+.2}° ± {:.2}°", 2.0 * s),
                None => format!("{mean:+.2}°"),
            };
            let font = TextStyle::from(("sans-serif", 12).into_font())
                .pos(Pos::new(HPos::Left, VPos::Center));
            chart.draw_series([Text::new(label, (at + 0.06, mean), font)])?;
        }
    }
    legend(
        &side,
        &[
            (
                "clockwise runs".into(),
                Mark::Dot(colour(Direction::Cw).filled()),
            ),
            (
                "counter-clockwise runs".into(),
                Mark::Dot(colour(Direction::Ccw).filled()),
            ),
            ("mean ± 2σ of the runs".into(), Mark::Bar),
            ("each panel on its own scale".into(), Mark::Note),
        ],
    )?;
    root.present()?;
    Ok(())
}

/// "1.226 m" or "4.9 mm".
fn metres(v: f64) -> String {
    if v.abs() < 0.1 {
        format!("{:.1} mm", v * 1000.0)
    } else {
        format!("{v:.3} m")
    }
}

/// True end points (simulation only): one panel before (round 1), one after (the
/// verification), each on its own equal scale, with each direction's mean end point (the
/// farther from the start is `E_max,sys`).
fn end_points_plot(report: &Report, file: &Path) -> PlotResult<bool> {
    let (before, after) = phases(report);
    let panels: Vec<(&str, &[RunReport])> = [
        ("before (round 1)", before),
        ("after (verification)", after),
    ]
    .into_iter()
    .filter(|(_, runs)| runs.iter().any(|r| r.true_final_xy_m.is_some()))
    .collect();
    if panels.is_empty() {
        return Ok(false);
    }
    let size = (LEGEND_PX + 480 * panels.len() as u32, 560);
    let root = SVGBackend::new(file, size).into_drawing_area();
    root.fill(&WHITE)?;
    let (plots, side) = root.split_horizontally(size.0 - LEGEND_PX);
    for (area, (phase, runs)) in plots.split_evenly((1, panels.len())).iter().zip(&panels) {
        let all: Vec<[f64; 2]> = runs.iter().filter_map(|r| r.true_final_xy_m).collect();
        // Millimetres when every end point is within 5 cm: ticks a reader can say aloud.
        let near = all.iter().all(|p| p[0].abs().max(p[1].abs()) < 0.05);
        let (unit, per_m) = if near { ("mm", 1000.0) } else { ("m", 1.0) };
        let ends = |d: Direction| -> Vec<[f64; 2]> {
            runs.iter()
                .filter(|r| r.direction == d)
                .filter_map(|r| r.true_final_xy_m)
                .map(|p| [p[0] * per_m, p[1] * per_m])
                .collect()
        };
        let title = match e_max_sys(runs) {
            Some(e) => format!("{phase}: E_max,sys {}", metres(e)),
            None => phase.to_string(),
        };
        let (area, px) = titled(area, &title)?;
        let scaled: Vec<[f64; 2]> = all.iter().map(|p| [p[0] * per_m, p[1] * per_m]).collect();
        let [x, y] = equal_scale(bounds(scaled.iter()), px);
        let (x_desc, y_desc) = (
            format!("x ({unit}), first leg"),
            format!("y ({unit}), left"),
        );
        let mut chart = chart(&area, x, y, &x_desc, &y_desc, &tick)?;
        chart.draw_series([Cross::new((0.0, 0.0), 8, BLACK.stroke_width(2))])?;
        for d in [Direction::Cw, Direction::Ccw] {
            let pts = ends(d);
            let style = colour(d).filled();
            chart.draw_series(pts.iter().map(|p| Circle::new((p[0], p[1]), 5, style)))?;
            if !pts.is_empty() {
                let n = pts.len() as f64;
                let mean = |i: usize| pts.iter().map(|p| p[i]).sum::<f64>() / n;
                let ring = Circle::new((mean(0), mean(1)), 9, colour(d).stroke_width(2));
                chart.draw_series([ring])?;
            }
        }
    }
    let mut entries = vec![
        (
            "clockwise end points".into(),
            Mark::Dot(colour(Direction::Cw).filled()),
        ),
        (
            "counter-clockwise end points".into(),
            Mark::Dot(colour(Direction::Ccw).filled()),
        ),
        (
            "mean end point of a direction".into(),
            Mark::Ring(BLACK.stroke_width(2)),
        ),
        ("start".into(), Mark::Cross),
        ("E_max,sys: the farther mean".into(), Mark::Note),
    ];
    if panels.len() > 1 {
        entries.push(("each panel on its own".into(), Mark::Note));
        entries.push(("equal scale".into(), Mark::Note));
    }
    legend(&side, &entries)?;
    root.present()?;
    Ok(true)
}
