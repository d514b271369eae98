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

mod estimates;
mod headings;
mod paths;

use estimates::*;
use headings::*;
pub use paths::*;

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
