//! One kind's fit in stages: Huber-weighted iterations to find the basin, the `χ²` gate, the
//! scales settled, the final tight solve and its covariance.

use super::*;

/// Convergence of the final stage: an iteration gaining less than a part in 10⁹ of the cost
/// (for 10⁵ residuals, 10⁻⁴ in χ²: a hundredth of a standard deviation in the parameters), far
/// below what the noise lets them tell apart.
pub(super) const TIGHT: f64 = 1e-9;

/// Convergence of the stages before it, whose weights and scales change after them.
pub(super) const LOOSE: f64 = 1e-6;

pub(super) fn fit_kind(
    recording: &PoseRecording,
    config: &FitConfig,
    kind: ReferenceKind,
    start: Option<[f64; PARAMS]>,
    decision: KindDecision,
) -> Result<PoseFit, CalibrationError> {
    let problem = Problem::new(recording, config, kind)?;
    let weights = vec![1.0; problem.blocks()];
    let p0 = start_params(&problem, start);
    let unit = Scales::white(1.0, 1.0);
    let scales = match config.weighting {
        Weighting::Unit => unit,
        Weighting::Estimated => robust_scales(
            &problem,
            &problem.residuals_at(&p0, &weights, unit),
            &weights,
        ),
    };
    let (p0, scales, iterations_before) =
        if problem.free.contains(&Param::TimeOffset) && start.is_none() {
            offset_basin(config, &problem, p0, &weights, scales)?
        } else {
            (p0, scales, 0)
        };
    let x = problem.free_values(&p0);
    let mut solved = reweighted_solve(&problem, config, x, weights, scales, iterations_before);
    let p = problem.full(&solved.x);
    // Final scales and covariance at the solution, inliers only.
    let r = problem.residuals_at(&p, &solved.weights, solved.scales);
    solved.scales = final_scales(&problem, config, &r, &solved.weights, solved.scales);
    let covariance = inflated_covariance(&problem, &solved);
    let drift = super::clock_rate::clock_drift(
        &problem,
        &p,
        &solved.weights,
        solved.scales,
        covariance.inflation,
    );
    let mut fit = report(&problem, config, decision, p, &solved, covariance);
    fit.warnings
        .extend(drift.filter(|d| d.significant()).map(|d| d.warning()));
    Ok(fit)
}

/// Where the stages ended: the free values, the blocks' weights (0: an outlier), the scales
/// and the Levenberg–Marquardt iterations used.
struct Solved {
    x: Vec<f64>,
    weights: Vec<f64>,
    scales: Scales,
    iterations: usize,
}

/// The parameters' covariance, inflated for the residuals' lag-one correlation `rho`.
struct Covariance {
    matrix: [[f64; PARAMS]; PARAMS],
    rho: f64,
    inflation: f64,
}

/// The full parameter vector the fit starts from: the fixed values, the free ones from `start`.
fn start_params(problem: &Problem<'_>, start: Option<[f64; PARAMS]>) -> [f64; PARAMS] {
    let mut p0 = problem.fixed;
    if let Some(s) = start {
        for q in &problem.free {
            p0[q.index()] = s[q.index()];
        }
    }
    p0
}

/// The time offset's basin: a lever arm along the direction of travel looks like a delay while
/// the robot drives straight, so the geometry and mounting are fitted first with the offset held
/// at zero, then the offset is searched on a coarse grid from there. Returns the start, its
/// scales and the iterations used.
fn offset_basin(
    config: &FitConfig,
    problem: &Problem<'_>,
    mut p0: [f64; PARAMS],
    weights: &[f64],
    mut scales: Scales,
) -> Result<([f64; PARAMS], Scales, usize), CalibrationError> {
    let unit = Scales::white(1.0, 1.0);
    let mut held = Problem::new(problem.recording, config, problem.kind)?;
    held.free.retain(|q| *q != Param::TimeOffset);
    let (xa, it) = levenberg_marquardt(&held, held.free_values(&p0), weights, scales, 20, LOOSE);
    p0 = held.full(&xa);
    if config.weighting == Weighting::Estimated {
        scales = robust_scales(problem, &problem.residuals_at(&p0, weights, unit), weights);
    }
    p0[6] = grid_offset(problem, &p0, weights, scales);
    if config.weighting == Weighting::Estimated {
        scales = robust_scales(problem, &problem.residuals_at(&p0, weights, unit), weights);
    }
    Ok((p0, scales, it))
}

/// The time offset on a 20 ms grid within its limit whose χ² (each block's capped at 25, so
/// that outliers do not pick it) is least, the other parameters held at `p0`.
fn grid_offset(problem: &Problem<'_>, p0: &[f64; PARAMS], weights: &[f64], scales: Scales) -> f64 {
    let odo = Odometry::integrate(&problem.recording.wheels, Problem::geometry(p0));
    let steps = (problem.max_offset / 0.02).ceil() as i64;
    let mut best = (f64::INFINITY, 0.0);
    for k in -steps..=steps {
        let mut p = *p0;
        p[6] = (k as f64 * 0.02).clamp(-problem.max_offset, problem.max_offset);
        let r = problem.residuals(&odo, &p, weights, scales);
        let cost: f64 = block_chi2(problem, &r, weights, scales)
            .iter()
            .map(|d| d.min(25.0))
            .sum();
        if cost < best.0 {
            best = (cost, p[6]);
        }
    }
    best.1
}

/// Iteratively reweighted least squares from `x`: Huber stages to find the basin, then gated
/// stages until the weights and scales settle, the last converged tightly (one tight solve
/// when the fit is not robust).
fn reweighted_solve(
    problem: &Problem<'_>,
    config: &FitConfig,
    mut x: Vec<f64>,
    mut weights: Vec<f64>,
    mut scales: Scales,
    iterations_before: usize,
) -> Solved {
    let mut iterations = iterations_before;
    let stages = if config.robust { 12 } else { 1 };
    for stage in 0..stages {
        // The stages before the weights settle need not converge far: their weights and scales
        // change after them. The last is converged tightly, below.
        let tolerance = if config.robust { LOOSE } else { TIGHT };
        let (xn, it) = levenberg_marquardt(problem, x, &weights, scales, 50, tolerance);
        x = xn;
        iterations += it;
        if !config.robust {
            break;
        }
        let p = problem.full(&x);
        let r = problem.residuals_at(&p, &weights, scales);
        let huber = stage < 2;
        let new_scales = stage_scales(problem, config, &r, &weights, huber);
        let chi2 = block_chi2(problem, &r, &weights, new_scales);
        let new_weights = stage_weights(&chi2, huber, problem.dim);
        let settled = !huber && new_weights == weights && scales_close(new_scales, scales);
        weights = new_weights;
        scales = new_scales;
        if settled || stage + 1 == stages {
            // Converged tightly under the settled (or the last) weights and scales.
            let (xn, it) = levenberg_marquardt(problem, x, &weights, scales, 50, TIGHT);
            x = xn;
            iterations += it;
            break;
        }
    }
    Solved {
        x,
        weights,
        scales,
        iterations,
    }
}

/// The scales for the next stage's weights from residuals `r` under the current `weights`:
/// robust over every block in a Huber stage, settled over the gated inliers after.
fn stage_scales(
    problem: &Problem<'_>,
    config: &FitConfig,
    r: &[f64],
    weights: &[f64],
    huber: bool,
) -> Scales {
    let k2 = gate(problem.dim);
    let ones = vec![1.0; problem.blocks()];
    if huber {
        robust_scales(problem, r, &ones)
    } else if weights.iter().any(|w| *w > 0.0 && *w < 1.0) {
        // The first gated stage follows Huber's, whose weights leave no block out: its
        // scales come from the blocks that the robust scales' gate keeps, or the outliers
        // would inflate them (by seven times on a localization's jumps) and the gate let
        // them in for a stage.
        let robust = robust_scales(problem, r, &ones);
        let kept: Vec<f64> = block_chi2(problem, r, &ones, robust)
            .iter()
            .map(|d2| if *d2 <= k2 { 1.0 } else { 0.0 })
            .collect();
        settle_scales(problem, r, &kept, config)
    } else {
        settle_scales(problem, r, weights, config)
    }
}

/// Each block's weight from its χ²: Huber's on its distance in a Huber stage, else 1 inside
/// the gate and 0 outside.
fn stage_weights(chi2: &[f64], huber: bool, dim: usize) -> Vec<f64> {
    let k2 = gate(dim);
    chi2.iter()
        .map(|d2| {
            if huber {
                // Huber on the block's distance, k at the χ² 95 % quantile.
                let k = if dim == 3 {
                    7.81f64.sqrt()
                } else {
                    5.99f64.sqrt()
                };
                let d = d2.sqrt();
                if d <= k {
                    1.0
                } else {
                    k / d
                }
            } else if *d2 <= k2 {
                1.0
            } else {
                0.0
            }
        })
        .collect()
}

/// Whether every scale of `new` is within a part in a thousand of `old`'s.
fn scales_close(new: Scales, old: Scales) -> bool {
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-3 * a.abs().max(b.abs()).max(1e-300);
    close(new.position, old.position)
        && close(new.yaw, old.yaw)
        && close(new.walk_position, old.walk_position)
        && close(new.walk_yaw, old.walk_yaw)
}

/// The scales at the solution from its residuals `r`: the inliers' (robust or estimated
/// weighting), else one variance for every component.
fn final_scales(
    problem: &Problem<'_>,
    config: &FitConfig,
    r: &[f64],
    weights: &[f64],
    scales: Scales,
) -> Scales {
    if config.robust || config.weighting == Weighting::Estimated {
        inlier_scales(problem, r, weights, scales)
    } else {
        // Unweighted least squares: one variance for every component.
        let n_free = problem.free.len();
        let n = r
            .len()
            .saturating_sub(n_free + 3 * problem.windows.len())
            .max(1);
        let s = (r.iter().map(|e| e * e).sum::<f64>() / n as f64)
            .sqrt()
            .max(1e-12);
        Scales::white(s, s)
    }
}

/// `(Jᵀ W J)⁻¹` over the inliers at the solution, inflated by `(1 + ρ)/(1 − ρ)` (held between
/// 1 and 100) for the lag-one
/// correlation of the whitened residuals; spread over the full parameter vector (zero where
/// not fitted, the tied right diameter taking the left's).
fn inflated_covariance(problem: &Problem<'_>, solved: &Solved) -> Covariance {
    let n_free = problem.free.len();
    let (z, jac) = problem.whitened_jacobian(&solved.x, &solved.weights, solved.scales);
    let h = jac.transpose() * &jac;
    let rho = lag_one_correlation(problem, &z, &solved.weights);
    let inflation = ((1.0 + rho) / (1.0 - rho)).clamp(1.0, 100.0);
    let cov_free = h
        .clone()
        .try_inverse()
        .unwrap_or_else(|| DMatrix::from_element(n_free, n_free, f64::INFINITY));
    let mut matrix = [[0.0; PARAMS]; PARAMS];
    let mut index: Vec<(usize, usize)> = problem
        .free
        .iter()
        .enumerate()
        .map(|(j, q)| (j, q.index()))
        .collect();
    if problem.tie {
        index.push((0, 1));
    }
    for &(a, ia) in &index {
        for &(b, ib) in &index {
            matrix[ia][ib] = cov_free[(a, b)] * inflation;
        }
    }
    Covariance {
        matrix,
        rho,
        inflation,
    }
}

/// The fit's result at parameters `p`, with its noise model, covariance and warnings.
fn report(
    problem: &Problem<'_>,
    config: &FitConfig,
    decision: KindDecision,
    p: [f64; PARAMS],
    solved: &Solved,
    covariance: Covariance,
) -> PoseFit {
    let dim = problem.dim;
    let scales = solved.scales;
    let recording = problem.recording;
    // The mounting's yaw as every angle odocal prints: wrapped to (−π, π].
    let mut p = p;
    p[Param::SensorYaw.index()] = wrap_angle(p[Param::SensorYaw.index()]);
    let span_s = {
        let first = recording.poses[problem.selected[0]].time_s;
        let last = recording.poses[problem.selected[problem.selected.len() - 1]].time_s;
        last - first
    };
    PoseFit {
        geometry: Problem::geometry(&p),
        params: p,
        covariance: covariance.matrix,
        free: problem.free.clone(),
        kind: decision,
        residual_std_position_m: scales.position * problem.stated_rms(0),
        stated_scale: problem.use_stated.then_some(scales.position),
        stated_scale_yaw: (problem.use_stated && dim == 3).then_some(scales.yaw),
        residual_std_yaw_rad: (dim == 3).then_some(scales.yaw * problem.stated_rms(2)),
        walk_position_m2_s: scales.walk_position,
        walk_yaw_rad2_s: (dim == 3).then_some(scales.walk_yaw),
        compared: problem.blocks(),
        outliers: solved.weights.iter().filter(|w| **w == 0.0).count(),
        windows: match problem.kind {
            ReferenceKind::Absolute => problem.windows.len(),
            ReferenceKind::Relative => 0,
        },
        lag_one_correlation: covariance.rho,
        variance_inflation: covariance.inflation,
        iterations: solved.iterations,
        span_s,
        nominal_wheelbase_m: config.nominal.wheelbase_m,
        warnings: offset_warnings(problem, &p)
            .into_iter()
            .chain(exact_warning(scales.position * problem.stated_rms(0)))
            .collect(),
    }
}

/// Position residuals below this (m) are no sensor's: a tenth of a micrometre.
const EXACT_RESIDUAL_M: f64 = 1e-7;

/// A finding when the odometry reproduces the reference exactly: its ± then measure the
/// arithmetic's rounding, not the robot.
fn exact_warning(residual_m: f64) -> Option<String> {
    (residual_m < EXACT_RESIDUAL_M).then(|| {
        format!(
            "the odometry reproduces the reference exactly (residual σ {residual_m:.1e} m, \
             below any sensor's noise): a reference without noise is a simulation or made from \
             the wheels themselves, and the ± say only how exactly"
        )
    })
}

/// A warning when the fitted time offset sits at its limit: the streams may be further apart.
fn offset_warnings(problem: &Problem<'_>, p: &[f64; PARAMS]) -> Vec<String> {
    if problem.free.contains(&Param::TimeOffset) && p[6].abs() >= 0.95 * problem.max_offset {
        vec![format!(
            "the time offset {:.3} s is at its limit (±{:.2} s): the streams may be further \
             apart, and the geometry then absorbs the rest; raise --max-time-offset-s and fit \
             again",
            p[6], problem.max_offset
        )]
    } else {
        Vec::new()
    }
}
