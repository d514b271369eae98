//! The estimate of each round, with its stated uncertainty, and the compass swing's deviation
//! curve.

use super::*;

/// Picks a quantity's value and its standard error, if any, from an estimate.
type Pick = fn(&crate::calibration::Estimate) -> (f64, Option<f64>);

/// Each round's estimate by the method it chose: `E_b` and `E_d` (ratios to that round's
/// configured parameters, 1 = nothing to correct) with a bar of ± 1 standard error within the
/// round, or a ring where the round had no ±.
pub(super) fn estimates_plot(report: &Report, file: &Path) -> PlotResult<bool> {
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
    for (area, quantity) in plots.split_evenly((1, 2)).iter().zip(&quantities) {
        let (bar, ring) = estimate_panel(area, report, quantity, n, &x_ticks)?;
        bars |= bar;
        rings |= ring;
    }
    legend(&side, &estimates_legend(report, bars, rings))?;
    root.present()?;
    Ok(true)
}

/// Draws one quantity's panel (`title`, axis label, pick) for the `n` rounds: the line at 1 and
/// each round's estimate; returns whether it drew a bar and whether it drew a ring.
fn estimate_panel(
    area: &Area<'_>,
    report: &Report,
    quantity: &(&str, &str, Pick),
    n: f64,
    x_ticks: &dyn Fn(&f64) -> String,
) -> PlotResult<(bool, bool)> {
    let (title, y_desc, pick) = *quantity;
    let (mut bars, mut rings) = (false, false);
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
        x_ticks,
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
    Ok((bars, rings))
}

/// The estimates plot's legend: the line at 1, the marks drawn (`bars`, `rings`) and the
/// methods the rounds chose.
fn estimates_legend(report: &Report, bars: bool, rings: bool) -> Vec<(String, Mark)> {
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
    entries
}

/// The compass swing's deviation curve: the fitted `d(ψ)` over a turn and, where the report
/// keeps them, the deviation each reading measured (the reading less its turn's fitted line).
pub(super) fn swing_plot(report: &Report, file: &Path) -> PlotResult<bool> {
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
