//! SVG plots of a report (plotters): this module owns drawing a [`Report`] as SVG files. The
//! square runs' paths (as the odometry believed them and re-integrated with the written
//! parameters), the heading errors of each phase, the true end points (simulation), the
//! estimate of each round, the compass swing's deviation curve and the heading along the legs.
//! Each plot is written only when the report holds its data.
//!
//! Every plot follows one key: one colour per direction ([`colour`]: clockwise blue,
//! counter-clockwise orange). Where phases share a chart, before (round 1) is a light tint of
//! it and after (the verification) full; the paths give each phase a panel and use the tints
//! for the truth, the belief and the correction instead. Every run is drawn; where both axes
//! are metres a metre spans as many pixels across as up; legends sit in a margin of their own,
//! never over the data or stretching an axis, and list only the styles drawn.

use crate::kinematics::{Direction, Displacement, Pose, WheelParams};
use crate::routine::report::{e_max_sys, Report, RunReport};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::ops::Range;
use std::path::{Path, PathBuf};

pub(super) type PlotResult<T> = Result<T, Box<dyn std::error::Error>>;

pub(super) fn io(e: Box<dyn std::error::Error>) -> std::io::Error {
    std::io::Error::other(e.to_string())
}

/// Draws one plot into a file; `false` (and no file) when the report has no data for it.
type Plot = fn(&Report, &Path) -> PlotResult<bool>;

/// Every plot, by the file it goes to ([`crate::routine::report::REPORT_FILES`]).
const PLOTS: [(&str, Plot); 6] = [
    ("paths.svg", paths_plot),
    ("heading_errors.svg", heading_plot),
    ("end_points.svg", end_points_plot),
    ("estimates.svg", estimates_plot),
    ("swing.svg", swing_plot),
    ("heading_along_legs.svg", heading_along_plot),
];

/// Writes every plot the report has data for, and no other; returns the files written.
pub fn write_all(report: &Report, dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for (name, draw) in PLOTS {
        let file = dir.join(name);
        if draw(report, &file).map_err(io)? {
            out.push(file);
        }
    }
    Ok(out)
}

/// A white canvas of `size` pixels in `file`: the whole (to present), the plots' part and the
/// legend's column at the right.
pub(super) fn canvas(file: &Path, size: (u32, u32)) -> PlotResult<(Area<'_>, Area<'_>, Area<'_>)> {
    let root = SVGBackend::new(file, size).into_drawing_area();
    root.fill(&WHITE)?;
    let (plots, side) = root.split_horizontally(size.0 - LEGEND_PX);
    Ok((root, plots, side))
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
pub(super) type Area<'b> = DrawingArea<SVGBackend<'b>, Shift>;

/// Whole numbers without a trailing ".0" (run 5, not 5.0), others with what they need.
pub(super) fn tick(v: &f64) -> String {
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
pub(super) fn titled<'b>(area: &Area<'b>, title: &str) -> PlotResult<(Area<'b>, (u32, u32))> {
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
pub(super) fn chart<'a, 'b>(
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
pub(super) fn bounds<'a>(points: impl Iterator<Item = &'a [f64; 2]>) -> [Range<f64>; 2] {
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
pub(super) fn equal_scale([x, y]: [Range<f64>; 2], (w, h): (u32, u32)) -> [Range<f64>; 2] {
    let (w, h) = (f64::from(w), f64::from(h));
    let per_px = ((x.end - x.start) / w).max((y.end - y.start) / h);
    let centred = |r: Range<f64>, px: f64| {
        let c = 0.5 * (r.start + r.end);
        c - 0.5 * per_px * px..c + 0.5 * per_px * px
    };
    [centred(x, w), centred(y, h)]
}

/// How a legend entry is drawn.
pub(super) enum Mark {
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
pub(super) fn legend(area: &Area<'_>, entries: &[(String, Mark)]) -> PlotResult<()> {
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
            // Drawn as the plots draw theirs ([`ErrorBar`] 14 px wide, 2 px strokes).
            Mark::Bar => {
                for (a, b) in [
                    ((14, mid - 8), (14, mid + 8)),
                    ((7, mid - 8), (21, mid - 8)),
                    ((7, mid + 8), (21, mid + 8)),
                ] {
                    area.draw(&PathElement::new(vec![a, b], BLACK.stroke_width(2)))?;
                }
                area.draw(&Circle::new((14, mid), 7, BLACK.stroke_width(2)))?;
            }
            Mark::Note => {}
        }
        let x = if matches!(mark, Mark::Note) { 0 } else { 36 };
        area.draw(&Text::new(label.clone(), (x, y), font.clone()))?;
        y += 22;
    }
    Ok(())
}

/// The runs before (round 1) and after (the verification).
fn phases(report: &Report) -> (&[RunReport], &[RunReport]) {
    let before = report.rounds.first().map_or(&[][..], |r| r.runs.as_slice());
    (before, report.verification.as_slice())
}

/// A run's path as odometry with `params` would have integrated its recorded wheel travel
/// ([`RunReport::samples`], measured with the run's configured parameters and rescaled by each
/// wheel's metres per count), from the origin in the run's start frame; `None` without at
/// least two samples. With the run's own parameters it is what the odometry believed.
pub fn reintegrated(run: &RunReport, params: &WheelParams) -> Option<Vec<[f64; 2]>> {
    if run.samples.len() < 2 {
        return None;
    }
    let left = params.left_m_per_count() / run.params.left_m_per_count();
    let right = params.right_m_per_count() / run.params.right_m_per_count();
    let mut pose = Pose::default();
    let (mut l0, mut r0) = (0.0, 0.0);
    let mut out = Vec::with_capacity(run.samples.len() + 1);
    out.push([0.0, 0.0]);
    for s in &run.samples {
        pose = pose.advance(
            (s.left_m - l0) * left,
            (s.right_m - r0) * right,
            params.wheelbase_m,
        );
        (l0, r0) = (s.left_m, s.right_m);
        out.push([pose.x_m, pose.y_m]);
    }
    Some(out)
}

/// What a line on the paths plot is.
#[derive(Clone, Copy, PartialEq, Eq)]
enum PathKind {
    /// The simulator's true path.
    Truth,
    /// What the odometry believed, with the parameters configured during the run.
    Believed,
    /// The same wheel travel integrated with the written parameters.
    Corrected,
}

impl PathKind {
    /// Its line in a direction's colour: the truth a wide pale band beneath, the belief a
    /// light tint, the corrected odometry full colour, each wide enough to be seen.
    fn style(self, d: Direction) -> ShapeStyle {
        let RGBColor(r, g, b) = colour(d);
        let tint = |f: f64| {
            let t = |c: u8| (f64::from(c) + f * (255.0 - f64::from(c))).round() as u8;
            RGBColor(t(r), t(g), t(b))
        };
        match self {
            PathKind::Truth => tint(0.8).stroke_width(8),
            PathKind::Believed => tint(0.5).stroke_width(2),
            PathKind::Corrected => colour(d).stroke_width(2),
        }
    }

    fn label(self, d: Direction) -> String {
        match self {
            PathKind::Truth => format!("{d}: true path (simulation)"),
            PathKind::Believed => format!("{d}: odometry as it believed"),
            PathKind::Corrected => format!("{d}: with written parameters"),
        }
    }
}

/// The parameters the paths are re-integrated with, and whether they were only proposed: the
/// written ones (the store's at the end), or when nothing was written the last proposal (a
/// dry run or a declined write still shows what it would have changed), else the final ones.
fn correction_target(report: &Report) -> (WheelParams, bool) {
    if report.written {
        return (report.final_params, false);
    }
    let proposal = report.rounds.iter().rev().find_map(|r| r.params_after);
    proposal.map_or((report.final_params, false), |p| (p, true))
}

/// One line of the paths plot: what it is, whose colour, its points (m).
type Trace = (PathKind, Direction, Vec<[f64; 2]>);

/// Round 1's runs (before) and the verification's (after), one panel each on its own equal
/// scale: what the odometry believed during each run (its configured parameters), the same
/// wheel travel re-integrated with the written parameters where they differ (the proposed
/// ones when nothing was written: [`correction_target`]), and in simulation
/// the true path beneath. On a real robot the belief is always close to a square; the
/// re-integrated path shows where the corrected odometry says the robot went.
fn paths_plot(report: &Report, file: &Path) -> PlotResult<bool> {
    let (before, after) = phases(report);
    let (target, proposed) = correction_target(report);
    let written = &target;
    // (panel title, traces as (kind, direction, points)), in drawing order: truth beneath.
    let mut panels: Vec<(String, Vec<Trace>)> = Vec::new();
    for (phase, runs) in [
        ("before (round 1)", before),
        ("after (verification)", after),
    ] {
        let mut traces = Vec::new();
        for r in runs {
            if let Some(t) = r.true_path.as_ref().filter(|t| t.len() > 1) {
                traces.push((PathKind::Truth, r.direction, t.clone()));
            }
        }
        for r in runs {
            // From the samples where the report has them, so that belief and correction are
            // the same decimated travel and differ only by the parameters.
            let believed = reintegrated(r, &r.params)
                .or_else(|| (r.odometry_path.len() > 1).then(|| r.odometry_path.clone()));
            if let Some(b) = believed {
                traces.push((PathKind::Believed, r.direction, b));
            }
        }
        for r in runs.iter().filter(|r| r.params != *written) {
            if let Some(c) = reintegrated(r, written) {
                traces.push((PathKind::Corrected, r.direction, c));
            }
        }
        if !traces.is_empty() {
            panels.push((phase.to_string(), traces));
        }
    }
    if panels.is_empty() {
        return Ok(false);
    }
    for (title, traces) in &mut panels {
        if !traces.iter().any(|t| t.0 == PathKind::Corrected) {
            title.push_str(if proposed {
                ": ran with the proposed parameters"
            } else {
                ": ran with the written parameters"
            });
        }
    }
    let size = (LEGEND_PX + 560 * panels.len() as u32, 620);
    let (root, plots, side) = canvas(file, size)?;
    let mut used: Vec<(PathKind, Direction)> = Vec::new();
    for (area, (title, traces)) in plots.split_evenly((1, panels.len())).iter().zip(&panels) {
        let (area, px) = titled(area, title)?;
        let [x, y] = equal_scale(bounds(traces.iter().flat_map(|t| t.2.iter())), px);
        let mut chart = chart(&area, x, y, "x (m), first leg", "y (m), left", &tick)?;
        for (kind, d, pts) in traces {
            chart.draw_series(LineSeries::new(
                pts.iter().map(|p| (p[0], p[1])),
                kind.style(*d),
            ))?;
            if !used.contains(&(*kind, *d)) {
                used.push((*kind, *d));
            }
        }
        chart.draw_series([Cross::new((0.0, 0.0), 7, BLACK.stroke_width(2))])?;
    }
    // Only the styles drawn, in a fixed order.
    let mut entries = Vec::new();
    for d in [Direction::Cw, Direction::Ccw] {
        for kind in [PathKind::Truth, PathKind::Believed, PathKind::Corrected] {
            if used.contains(&(kind, d)) {
                let mut label = kind.label(d);
                if proposed && kind == PathKind::Corrected {
                    label = format!("{d}: with proposed parameters");
                }
                entries.push((label, Mark::Line(kind.style(d))));
            }
        }
    }
    entries.push(("start of every square".into(), Mark::Cross));
    if proposed {
        entries.push(("proposed: not written".into(), Mark::Note));
    }
    entries.push(("every run drawn; equal scales".into(), Mark::Note));
    legend(&side, &entries)?;
    root.present()?;
    Ok(true)
}

/// Each round's estimate by the method it chose: `E_b` and `E_d` (ratios to that round's
/// configured parameters, 1 = nothing to correct) with a bar of ± 1 standard error within the
/// round, or a ring where the round had no ±.
fn estimates_plot(report: &Report, file: &Path) -> PlotResult<bool> {
    if report.rounds.is_empty() {
        return Ok(false);
    }
    let size = (LEGEND_PX + 2 * 420, 480);
    let (root, plots, side) = canvas(file, size)?;
    let n = report.rounds.len() as f64;
    let x_ticks = |v: &f64| {
        let k = v.round();
        if (v - k).abs() < 1e-9 && k >= 1.0 && k <= n {
            format!("{k:.0}")
        } else {
            String::new()
        }
    };
    type Pick = fn(&crate::calibration::Estimate) -> (f64, Option<f64>);
    let quantities: [(&str, &str, Pick); 2] = [
        (
            "E_b = b_actual / b_configured",
            "E_b (ratio, 1 = no correction)",
            |e| (e.e_b, e.e_b_std_err),
        ),
        (
            "E_d = D_R / D_L, to the configured ratio",
            "E_d (ratio, 1 = no correction)",
            |e| (e.e_d, e.e_d_std_err),
        ),
    ];
    let (mut bars, mut rings) = (false, false);
    for (area, (title, y_desc, pick)) in plots.split_evenly((1, 2)).iter().zip(&quantities) {
        let (area, _) = titled(area, title)?;
        let values: Vec<(f64, f64, Option<f64>)> = report
            .rounds
            .iter()
            .map(|r| {
                let (v, se) = pick(&r.chosen);
                (r.round as f64, v, se.filter(|s| s.is_finite()))
            })
            .collect();
        let (mut lo, mut hi) = (1.0f64, 1.0f64);
        for &(_, v, se) in &values {
            let s = se.unwrap_or(0.0);
            lo = lo.min(v - s);
            hi = hi.max(v + s);
        }
        let pad = (0.12 * (hi - lo)).max(2e-4);
        let x = 0.5..n + 0.5;
        let mut chart = chart(
            &area,
            x.clone(),
            lo - pad..hi + pad,
            "round",
            y_desc,
            &x_ticks,
        )?;
        chart.draw_series(LineSeries::new(
            [(x.start, 1.0), (x.end, 1.0)],
            BLACK.mix(0.5),
        ))?;
        for &(round, v, se) in &values {
            match se {
                Some(s) => {
                    bars = true;
                    chart.draw_series([ErrorBar::new_vertical(
                        round,
                        v - s,
                        v,
                        v + s,
                        BLACK.stroke_width(2),
                        14,
                    )])?;
                }
                None => {
                    rings = true;
                    chart.draw_series([Circle::new((round, v), 7, BLACK.stroke_width(2))])?;
                }
            }
        }
    }
    let mut entries = vec![(
        "1: nothing to correct".to_string(),
        Mark::Line(BLACK.mix(0.5).stroke_width(1)),
    )];
    if bars {
        entries.push(("estimate ± 1 standard error".into(), Mark::Bar));
        entries.push(("within the round".into(), Mark::Note));
    }
    if rings {
        entries.push((
            "estimate without ± (no scatter)".into(),
            Mark::Ring(BLACK.stroke_width(2)),
        ));
    }
    let mut methods: Vec<String> = report
        .rounds
        .iter()
        .map(|r| r.chosen.method.to_string())
        .collect();
    methods.dedup();
    entries.push((format!("method: {}", methods.join(", ")), Mark::Note));
    entries.push(("each round to its own".into(), Mark::Note));
    entries.push(("configured parameters".into(), Mark::Note));
    legend(&side, &entries)?;
    root.present()?;
    Ok(true)
}

/// The compass swing's deviation curve: the fitted `d(ψ)` over a turn and, where the report
/// keeps them, the deviation each reading measured (the reading less its turn's fitted line).
fn swing_plot(report: &Report, file: &Path) -> PlotResult<bool> {
    let Some(fit) = &report.swing else {
        return Ok(false);
    };
    let curve: Vec<(f64, f64)> = (0..=360)
        .map(|k| {
            let psi = f64::from(k);
            (psi, fit.deviation.at(psi.to_radians()).to_degrees())
        })
        .collect();
    let measured: Vec<(f64, f64)> = fit
        .measured
        .iter()
        .map(|p| (p[0].to_degrees(), p[1].to_degrees()))
        .filter(|p| p.0.is_finite() && p.1.is_finite())
        .collect();
    let (mut lo, mut hi) = (0.0f64, 0.0f64);
    for p in curve.iter().chain(&measured) {
        lo = lo.min(p.1);
        hi = hi.max(p.1);
    }
    let pad = (0.1 * (hi - lo)).max(0.05);
    let size = (LEGEND_PX + 720, 480);
    let (root, plot, side) = canvas(file, size)?;
    let (area, _) = titled(
        &plot,
        &format!(
            "Compass deviation: up to {:.2}°, residual {:.2}° rms",
            fit.amplitude_rad.to_degrees(),
            fit.residual_rms_rad.to_degrees()
        ),
    )?;
    let mut chart = chart(
        &area,
        0.0..360.0,
        lo - pad..hi + pad,
        "heading ψ (°, counter-clockwise)",
        "deviation d(ψ) (°)",
        &tick,
    )?;
    let grey = RGBColor(120, 120, 120);
    chart.draw_series(
        measured
            .iter()
            .map(|&p| Circle::new(p, 2, grey.mix(0.7).filled())),
    )?;
    chart.draw_series(LineSeries::new(curve, BLACK.stroke_width(2)))?;
    let mut entries = Vec::new();
    if !measured.is_empty() {
        entries.push((
            "measured: reading less the".to_string(),
            Mark::Dot(grey.mix(0.7).filled()),
        ));
        entries.push(("fitted line of its turn".into(), Mark::Note));
    }
    entries.push((
        "fitted curve d(ψ)".into(),
        Mark::Line(BLACK.stroke_width(2)),
    ));
    entries.push((
        format!("{} readings, turns both ways", fit.points),
        Mark::Note,
    ));
    legend(&side, &entries)?;
    root.present()?;
    Ok(true)
}

/// One run's heading along the square: `(distance along the square (m), heading less the
/// odometry's turn (deg))` at every sample with a heading, both from the first such sample,
/// and that first sample's heading less turn (rad) to put the leg means on the same zero.
fn heading_along(run: &RunReport) -> Option<(Vec<(f64, f64)>, f64)> {
    let b = run.params.wheelbase_m;
    let mut zero: Option<(f64, f64)> = None;
    let mut out = Vec::new();
    for s in &run.samples {
        let Some(h) = s.heading_rad.filter(|h| h.is_finite()) else {
            continue;
        };
        // The odometry from the run's start, as the `legs` method counts it.
        let odometry = Displacement::of_wheels(s.left_m, s.right_m, b);
        let (distance, error) = (odometry.distance_m, h - odometry.turn_rad);
        let (d0, e0) = *zero.get_or_insert((distance, error));
        out.push((distance - d0, (error - e0).to_degrees()));
    }
    (out.len() > 1).then(|| (out, zero.map_or(0.0, |z| z.1)))
}

/// The heading along the legs of round 1's runs (light) and the verification's (full): the
/// heading less the odometry's turn against the distance along the square, each run from its
/// first reading, and the leg means the `legs` and `matched-legs` methods use. A wheelbase
/// error shows as steps at the corners, a diameter error as a slope along the legs.
fn heading_along_plot(report: &Report, file: &Path) -> PlotResult<bool> {
    let (before, after) = phases(report);
    // The leg means hold a removed gyro scale that the raw samples do not: drawn only when
    // they are on the same footing.
    let leg_dots = report.config.gyro_scale_error.is_none();
    let mut lines = Vec::new();
    let mut dots = Vec::new();
    for (runs, is_before) in [(before, true), (after, false)] {
        for r in runs {
            let Some((pts, e0)) = heading_along(r) else {
                continue;
            };
            // A leg's mean odometry counts from the run's first reading, as the line does.
            if let (true, Some(legs)) = (leg_dots, r.legs) {
                for leg in legs.legs {
                    let at = (leg.odometry.distance_m, (leg.error_rad - e0).to_degrees());
                    dots.push((r.direction, is_before, at));
                }
            }
            lines.push((r.direction, is_before, pts));
        }
    }
    if lines.is_empty() {
        return Ok(false);
    }
    let (mut x0, mut x1, mut y0, mut y1) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for p in lines
        .iter()
        .flat_map(|l| l.2.iter())
        .chain(dots.iter().map(|d| &d.2))
    {
        x0 = x0.min(p.0);
        x1 = x1.max(p.0);
        y0 = y0.min(p.1);
        y1 = y1.max(p.1);
    }
    let ypad = (0.08 * (y1 - y0)).max(0.05);
    let xpad = 0.02 * (x1 - x0).max(0.01);
    let size = (LEGEND_PX + 820, 520);
    let (root, plot, side) = canvas(file, size)?;
    let (area, _) = titled(&plot, "Heading along the square, less the odometry's turn")?;
    let mut chart = chart(
        &area,
        x0 - xpad..x1 + xpad,
        y0 - ypad..y1 + ypad,
        "distance along the square (m), odometry",
        "heading − odometry turn (°, CCW positive)",
        &tick,
    )?;
    let mut used: Vec<(Direction, bool)> = Vec::new();
    for (d, is_before, pts) in &lines {
        chart.draw_series(LineSeries::new(
            pts.iter().copied(),
            shade(*d, *is_before).stroke_width(2),
        ))?;
        if !used.contains(&(*d, *is_before)) {
            used.push((*d, *is_before));
        }
    }
    chart.draw_series(
        dots.iter()
            .map(|(_, _, p)| Circle::new(*p, 4, BLACK.filled())),
    )?;
    let mut entries = Vec::new();
    for d in [Direction::Cw, Direction::Ccw] {
        for (is_before, phase) in [(true, "before (round 1)"), (false, "after (verification)")] {
            if used.contains(&(d, is_before)) {
                let n = lines
                    .iter()
                    .filter(|l| l.0 == d && l.1 == is_before)
                    .count();
                entries.push((
                    format!("{d} {phase}: {n}"),
                    Mark::Line(shade(d, is_before).stroke_width(2)),
                ));
            }
        }
    }
    if !dots.is_empty() {
        entries.push(("mean of each leg".into(), Mark::Dot(BLACK.filled())));
    }
    entries.push(("each run from its first reading".into(), Mark::Note));
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
fn heading_plot(report: &Report, file: &Path) -> PlotResult<bool> {
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
    if panels.iter().all(|(_, runs)| runs.is_empty()) {
        return Ok(false);
    }
    let size = (LEGEND_PX + 400 * panels.len() as u32, 520);
    let (root, plots, side) = canvas(file, size)?;
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
    // Only the directions drawn: each has its dots and its bar.
    let mut entries = Vec::new();
    for d in directions {
        let runs = || panels.iter().flat_map(|(_, runs)| runs.iter());
        if runs().any(|r| r.direction == d) {
            entries.push((format!("{d} runs"), Mark::Dot(colour(d).mix(0.85).filled())));
        }
    }
    entries.push(("mean ± 2σ of the runs".into(), Mark::Bar));
    entries.push(("each panel on its own scale".into(), Mark::Note));
    legend(&side, &entries)?;
    root.present()?;
    Ok(true)
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
    let (root, plots, side) = canvas(file, size)?;
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
    // Only the directions drawn.
    let mut entries = Vec::new();
    for d in [Direction::Cw, Direction::Ccw] {
        let drawn = panels
            .iter()
            .flat_map(|(_, runs)| runs.iter())
            .any(|r| r.direction == d && r.true_final_xy_m.is_some());
        if drawn {
            entries.push((format!("{d} end points"), Mark::Dot(colour(d).filled())));
        }
    }
    for d in [Direction::Cw, Direction::Ccw] {
        if entries.iter().any(|(l, _)| l.starts_with(&format!("{d} "))) {
            entries.push((
                format!("{d} mean end point"),
                Mark::Ring(colour(d).stroke_width(2)),
            ));
        }
    }
    entries.extend([
        ("start".into(), Mark::Cross),
        ("E_max,sys: the farther mean".into(), Mark::Note),
    ]);
    if panels.len() > 1 {
        entries.push(("each panel on its own".into(), Mark::Note));
        entries.push(("equal scale".into(), Mark::Note));
    }
    legend(&side, &entries)?;
    root.present()?;
    Ok(true)
}
