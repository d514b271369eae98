//! SVG plots of a calibration against a pose reference (`odocal fit --report DIR`), in the key
//! and layout of [`super::plots`]: for each recording (up to [`MAX_PANELS`]) the reference's
//! path beside dead reckoning with the nominal and with the fitted geometry (each started on the
//! reference's first pose, the fitted one through the fitted mounting and delay:
//! [`reckoned_path`]), the distance between them over time, and the fitted mounting of the
//! reference frame on the robot.

use super::plots::{canvas, chart, equal_scale, io, legend, tick, titled, Mark, PlotResult};
use crate::calibration::pose_calibration::PoseCalibration;
use crate::calibration::pose_reference::{reckoned_path, Pose2, PoseRecording};
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// Recordings drawn, one panel each.
pub const MAX_PANELS: usize = 4;

/// The reference's colour, the nominal odometry's and the fitted one's.
const REFERENCE: RGBColor = RGBColor(40, 40, 40);
const NOMINAL: RGBColor = RGBColor(214, 39, 40);
const FITTED: RGBColor = RGBColor(31, 119, 180);

/// The three paths of one recording in the reference's world frame: the reference's own
/// (`(t_s, [x, y])`), and dead reckoning with the nominal and with the fitted geometry at the
/// same stamps; `None` when the recording cannot be dead-reckoned (no yaw, no overlap).
type Paths = (Vec<(f64, [f64; 2])>, Vec<[f64; 2]>, Vec<[f64; 2]>);

fn paths(recording: &PoseRecording, calibration: &PoseCalibration) -> Option<Paths> {
    let nominal = reckoned_path(recording, calibration.nominal, Pose2::default(), 0.0)?;
    let fitted = reckoned_path(
        recording,
        calibration.geometry,
        calibration.mount(),
        calibration.time_offset_s(),
    )?;
    let reference = fitted
        .iter()
        .map(|(i, _)| {
            let p = &recording.poses[*i];
            (p.time_s, [p.x_m, p.y_m])
        })
        .collect();
    let xy = |v: Vec<(usize, Pose2)>| v.into_iter().map(|(_, p)| [p.x, p.y]).collect();
    Some((reference, xy(nominal), xy(fitted)))
}

/// Writes `pose_paths.svg`, `pose_errors.svg` and `pose_mounting.svg` into `dir` for the
/// recordings `calibration` was fitted from; returns the files written.
pub fn write_pose_plots(
    calibration: &PoseCalibration,
    recordings: &[(String, PoseRecording)],
    dir: &Path,
) -> std::io::Result<Vec<PathBuf>> {
    let drawn: Vec<(&str, Paths)> = recordings
        .iter()
        .take(MAX_PANELS)
        .filter_map(|(name, rec)| Some((name.as_str(), paths(rec, calibration)?)))
        .collect();
    let mut out = Vec::new();
    if !drawn.is_empty() {
        let file = dir.join("pose_paths.svg");
        paths_plot(&drawn, &file).map_err(io)?;
        out.push(file);
        let file = dir.join("pose_errors.svg");
        errors_plot(&drawn, &file).map_err(io)?;
        out.push(file);
    }
    let file = dir.join("pose_mounting.svg");
    mounting_plot(calibration, &file).map_err(io)?;
    out.push(file);
    Ok(out)
}

fn line_entries() -> Vec<(String, Mark)> {
    vec![
        ("reference".into(), Mark::Line(REFERENCE.stroke_width(2))),
        (
            "odometry, nominal geometry".into(),
            Mark::Line(NOMINAL.stroke_width(2)),
        ),
        (
            "odometry, fitted geometry".into(),
            Mark::Line(FITTED.stroke_width(2)),
        ),
    ]
}

/// The smallest box around `points` (the reference's world frame has its origin anywhere),
/// padded by 5 % of its larger side.
fn extent<'a>(points: impl Iterator<Item = &'a [f64; 2]>) -> [std::ops::Range<f64>; 2] {
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for p in points.filter(|p| p[0].is_finite() && p[1].is_finite()) {
        x0 = x0.min(p[0]);
        x1 = x1.max(p[0]);
        y0 = y0.min(p[1]);
        y1 = y1.max(p[1]);
    }
    if x0 > x1 {
        return [-1.0..1.0, -1.0..1.0];
    }
    let pad = 0.05 * (x1 - x0).max(y1 - y0).max(0.01);
    [x0 - pad..x1 + pad, y0 - pad..y1 + pad]
}

/// Each recording's three paths, equal scales on both axes.
fn paths_plot(drawn: &[(&str, Paths)], file: &Path) -> PlotResult<()> {
    let (root, plots, side) = canvas(file, (1000, 420 * drawn.len() as u32))?;
    let panels = plots.split_evenly((drawn.len(), 1));
    for (area, (name, (reference, nominal, fitted))) in panels.iter().zip(drawn) {
        let (area, px) = titled(
            area,
            &format!("{name}: path in the reference's world frame"),
        )?;
        let r: Vec<[f64; 2]> = reference.iter().map(|(_, p)| *p).collect();
        let range = equal_scale(extent(r.iter().chain(nominal).chain(fitted)), px);
        let [x, y] = range;
        let mut c = chart(&area, x, y, "x (m)", "y (m)", &tick)?;
        for (points, colour) in [(&r, REFERENCE), (nominal, NOMINAL), (fitted, FITTED)] {
            c.draw_series(LineSeries::new(
                points.iter().map(|p| (p[0], p[1])),
                colour.stroke_width(2),
            ))?;
        }
    }
    let mut entries = line_entries();
    entries.push(("each started on the reference's".into(), Mark::Note));
    entries.push(("first pose".into(), Mark::Note));
    legend(&side, &entries)?;
    root.present()?;
    Ok(())
}

/// The distance from the reference of each dead reckoning over time (m).
fn errors_plot(drawn: &[(&str, Paths)], file: &Path) -> PlotResult<()> {
    let (root, plots, side) = canvas(file, (1000, 320 * drawn.len() as u32))?;
    let panels = plots.split_evenly((drawn.len(), 1));
    for (area, (name, (reference, nominal, fitted))) in panels.iter().zip(drawn) {
        let (area, _) = titled(area, &format!("{name}: distance from the reference"))?;
        let t0 = reference.first().map_or(0.0, |(t, _)| *t);
        let series = |path: &[[f64; 2]]| -> Vec<(f64, f64)> {
            reference
                .iter()
                .zip(path)
                .map(|((t, r), p)| (t - t0, (p[0] - r[0]).hypot(p[1] - r[1])))
                .collect()
        };
        let (n, f) = (series(nominal), series(fitted));
        let t1 = reference.last().map_or(1.0, |(t, _)| (t - t0).max(1e-3));
        let top = n
            .iter()
            .chain(&f)
            .map(|(_, e)| *e)
            .filter(|e| e.is_finite())
            .fold(1e-3f64, f64::max);
        let mut c = chart(
            &area,
            0.0..t1,
            0.0..1.05 * top,
            "time since the first pose (s)",
            "distance (m)",
            &tick,
        )?;
        for (points, colour) in [(&n, NOMINAL), (&f, FITTED)] {
            c.draw_series(LineSeries::new(
                points.iter().copied(),
                colour.stroke_width(2),
            ))?;
        }
    }
    let mut entries: Vec<(String, Mark)> = line_entries().into_iter().skip(1).collect();
    entries.push(("a spike: a reference pose the".into(), Mark::Note));
    entries.push(("fit left out as an outlier".into(), Mark::Note));
    legend(&side, &entries)?;
    root.present()?;
    Ok(())
}

/// `base_link` (the axle's midpoint, x forward), the wheels, and the fitted reference frame on
/// it (its origin and x axis).
fn mounting_plot(calibration: &PoseCalibration, file: &Path) -> PlotResult<()> {
    let (root, plots, side) = canvas(file, (800, 600))?;
    let m = calibration.mount();
    let b = calibration.geometry.wheelbase_m;
    // Room for the wheels, the frame and its arrow.
    let reach = (0.6 * b).max(m.x.abs().max(m.y.abs()) + 0.35 * b);
    let (area, px) = titled(&plots, "the reference frame in base_link")?;
    let [x, y] = equal_scale([-reach..reach, -reach..reach], px);
    let mut c = chart(&area, x, y, "x forward (m)", "y left (m)", &tick)?;
    // The wheels, on the axle.
    for side_y in [0.5 * b, -0.5 * b] {
        c.draw_series(std::iter::once(PathElement::new(
            vec![(-0.15 * b, side_y), (0.15 * b, side_y)],
            BLACK.stroke_width(6),
        )))?;
    }
    let arrow = |p: Pose2, len: f64| {
        let (s, co) = p.theta.sin_cos();
        vec![(p.x, p.y), (p.x + len * co, p.y + len * s)]
    };
    c.draw_series(std::iter::once(PathElement::new(
        arrow(Pose2::default(), 0.3 * b),
        BLACK.stroke_width(2),
    )))?;
    c.draw_series(std::iter::once(PathElement::new(
        arrow(m, 0.3 * b),
        FITTED.stroke_width(3),
    )))?;
    c.draw_series(std::iter::once(Circle::new((m.x, m.y), 5, FITTED.filled())))?;
    let entries = vec![
        (
            "base_link (x forward)".into(),
            Mark::Line(BLACK.stroke_width(2)),
        ),
        ("the wheels".into(), Mark::Line(BLACK.stroke_width(6))),
        (
            "reference frame (x axis)".into(),
            Mark::Line(FITTED.stroke_width(3)),
        ),
        (format!("x {:.4} m, y {:.4} m", m.x, m.y), Mark::Note),
        (format!("yaw {:.2}°", m.theta.to_degrees()), Mark::Note),
    ];
    legend(&side, &entries)?;
    root.present()?;
    Ok(())
}
