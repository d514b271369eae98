//! The square runs' paths: as the odometry believed them, re-integrated with the written
//! parameters and (in simulation) the truth, one panel per phase; and the true end points with
//! each phase's `E_max,sys`.

use super::*;

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
pub(super) enum PathKind {
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
    pub(super) fn style(self, d: Direction) -> ShapeStyle {
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

    pub(super) fn label(self, d: Direction) -> String {
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
pub(super) fn correction_target(report: &Report) -> (WheelParams, bool) {
    if report.written {
        return (report.final_params, false);
    }
    let proposal = report.rounds.iter().rev().find_map(|r| r.params_after);
    proposal.map_or((report.final_params, false), |p| (p, true))
}

/// One line of the paths plot: what it is, whose colour, its points (m).
pub(super) type Trace = (PathKind, Direction, Vec<[f64; 2]>);

/// Round 1's runs (before) and the verification's (after), one panel each on its own equal
/// scale: what the odometry believed during each run (its configured parameters), the same
/// wheel travel re-integrated with the written parameters where they differ (the proposed
/// ones when nothing was written: [`correction_target`]), and in simulation
/// the true path beneath. On a real robot the belief is always close to a square; the
/// re-integrated path shows where the corrected odometry says the robot went.
pub(super) fn paths_plot(report: &Report, file: &Path) -> PlotResult<bool> {
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

/// "1.226 m" or "4.9 mm".
pub(super) fn metres(v: f64) -> String {
    if v.abs() < 0.1 {
        format!("{:.1} mm", v * 1000.0)
    } else {
        format!("{v:.3} m")
    }
}

/// True end points (simulation only): one panel before (round 1), one after (the
/// verification), each on its own equal scale, with each direction's mean end point (the
/// farther from the start is `E_max,sys`).
pub(super) fn end_points_plot(report: &Report, file: &Path) -> PlotResult<bool> {
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
