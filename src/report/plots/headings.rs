//! Headings: the heading errors of each phase (mean and spread per direction) and the heading
//! along the legs of every run.

use super::*;

/// One run's heading along the square: `(distance along the square (m), heading less the
/// odometry's turn (deg))` at every sample with a heading, both from the first such sample,
/// and that first sample's heading less turn (rad) to put the leg means on the same zero.
pub(super) fn heading_along(run: &RunReport) -> Option<(Vec<(f64, f64)>, f64)> {
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
pub(super) fn heading_along_plot(report: &Report, file: &Path) -> PlotResult<bool> {
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
pub(super) fn mean_std(v: &[f64]) -> Option<(f64, Option<f64>)> {
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
pub(super) fn heading_plot(report: &Report, file: &Path) -> PlotResult<bool> {
    let panels = heading_panels(report);
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
        heading_panel(area, title, runs, directions, &x_ticks)?;
    }
    legend(&side, &heading_legend(&panels, directions))?;
    root.present()?;
    Ok(true)
}

/// The heading-error plot's panels, titled: each round's runs, then the verification's.
fn heading_panels(report: &Report) -> Vec<(String, &[RunReport])> {
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
    panels
}

/// Draws one phase's panel: its runs' final heading errors by direction, on a scale holding
/// every run, every bar and zero.
fn heading_panel(
    area: &Area<'_>,
    title: &str,
    runs: &[RunReport],
    directions: [Direction; 2],
    x_ticks: &dyn Fn(&f64) -> String,
) -> PlotResult<()> {
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
        x_ticks,
    )?;
    chart.draw_series(LineSeries::new([(-0.5, 0.0), (1.8, 0.0)], BLACK.mix(0.5)))?;
    for (k, (d, v)) in per_direction.iter().enumerate() {
        direction_errors(&mut chart, k as f64, *d, v)?;
    }
    Ok(())
}

/// Draws one direction's heading errors `v` about `centre`: its runs as dots, then its mean
/// with a bar of ± 2 standard deviations and their values as a label.
fn direction_errors(
    chart: &mut Chart<'_, '_>,
    centre: f64,
    d: Direction,
    v: &[f64],
) -> PlotResult<()> {
    let n = v.len() as f64;
    let spread = (0.3 / n.max(1.0)).min(0.06);
    let style = colour(d).mix(0.85).filled();
    chart.draw_series(v.iter().enumerate().map(|(i, &e)| {
        let x = centre + (i as f64 - 0.5 * (n - 1.0)) * spread;
        Circle::new((x, e), 4, style)
    }))?;
    let Some((mean, std)) = mean_std(v) else {
        return Ok(());
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
    let font =
        TextStyle::from(("sans-serif", 12).into_font()).pos(Pos::new(HPos::Left, VPos::Center));
    chart.draw_series([Text::new(label, (at + 0.06, mean), font)])?;
    Ok(())
}

/// The heading-error plot's legend entries for the runs in `panels`.
fn heading_legend(
    panels: &[(String, &[RunReport])],
    directions: [Direction; 2],
) -> Vec<(String, Mark)> {
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
    entries
}
