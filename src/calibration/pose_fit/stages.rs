//! One kind's fit in stages: Huber-weighted iterations to find the basin, the `χ²` gate, the
//! scales settled, the final tight solve and its covariance.

use super::*;

/// Reference samples the kind decision's relative fit uses at most (ten minutes at 10 Hz).
pub(super) const DECISION_POSES: usize = 6000;

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
    let blocks = problem.blocks();
    let dim = problem.dim;
    let mut weights = vec![1.0; blocks];
    let mut p0 = problem.fixed;
    if let Some(s) = start {
        for q in &problem.free {
            p0[q.index()] = s[q.index()];
        }
    }
    let unit = Scales::white(1.0, 1.0);
    let mut iterations_before = 0;
    let residual_at = |p: &[f64; PARAMS], w: &[f64], s: Scales| {
        let odo = Odometry::integrate(&recording.wheels, Problem::geometry(p));
        problem.residuals(&odo, p, w, s)
    };
    let mut scales = match config.weighting {
        Weighting::Unit => unit,
        Weighting::Estimated => {
            robust_scales(&problem, &residual_at(&p0, &weights, unit), &weights)
        }
    };
    // The time offset's basin: a lever arm along the direction of travel looks like a delay
    // while the robot drives straight, so the geometry and mounting are fitted first with the
    // offset held at zero, then the offset is searched on a coarse grid from there.
    if problem.free.contains(&Param::TimeOffset) && start.is_none() {
        let mut held = Problem::new(recording, config, kind)?;
        held.free.retain(|q| *q != Param::TimeOffset);
        let (xa, it) =
            levenberg_marquardt(&held, held.free_values(&p0), &weights, scales, 20, LOOSE);
        iterations_before = it;
        p0 = held.full(&xa);
        if config.weighting == Weighting::Estimated {
            scales = robust_scales(&problem, &residual_at(&p0, &weights, unit), &weights);
        }
        let odo = Odometry::integrate(&recording.wheels, Problem::geometry(&p0));
        let steps = (problem.max_offset / 0.02).ceil() as i64;
        let mut best = (f64::INFINITY, 0.0);
        for k in -steps..=steps {
            let mut p = p0;
            p[6] = (k as f64 * 0.02).clamp(-problem.max_offset, problem.max_offset);
            let r = problem.residuals(&odo, &p, &weights, scales);
            let cost: f64 = block_chi2(&problem, &r, &weights, scales)
                .iter()
                .map(|d| d.min(25.0))
                .sum();
            if cost < best.0 {
                best = (cost, p[6]);
            }
        }
        p0[6] = best.1;
        if config.weighting == Weighting::Estimated {
            scales = robust_scales(&problem, &residual_at(&p0, &weights, unit), &weights);
        }
    }
    let mut x = problem.free_values(&p0);
    let mut iterations = iterations_before;
    let stages = if config.robust { 12 } else { 1 };
    for stage in 0..stages {
        // The stages before the weights settle need not converge far: their weights and scales
        // change after them. The last is converged tightly, below.
        let tolerance = if config.robust { LOOSE } else { TIGHT };
        let (xn, it) = levenberg_marquardt(&problem, x, &weights, scales, 50, tolerance);
        x = xn;
        iterations += it;
        if !config.robust {
            break;
        }
        let p = problem.full(&x);
        let r = residual_at(&p, &weights, scales);
        let huber = stage < 2;
        let k2 = gate(dim);
        let ones = vec![1.0; blocks];
        let new_scales = if huber {
            robust_scales(&problem, &r, &ones)
        } else if weights.iter().any(|w| *w > 0.0 && *w < 1.0) {
            // The first gated stage follows Huber's, whose weights leave no block out: its
            // scales come from the blocks that the robust scales' gate keeps, or the outliers
            // would inflate them (by seven times on a localization's jumps) and the gate let
            // them in for a stage.
            let robust = robust_scales(&problem, &r, &ones);
            let kept: Vec<f64> = block_chi2(&problem, &r, &ones, robust)
                .iter()
                .map(|d2| if *d2 <= k2 { 1.0 } else { 0.0 })
                .collect();
            settle_scales(&problem, &r, &kept, config)
        } else {
            settle_scales(&problem, &r, &weights, config)
        };
        let chi2 = block_chi2(&problem, &r, &weights, new_scales);
        let new_weights: Vec<f64> = chi2
            .iter()
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
            .collect();
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-3 * a.abs().max(b.abs()).max(1e-300);
        let settled = !huber
            && new_weights == weights
            && close(new_scales.position, scales.position)
            && close(new_scales.yaw, scales.yaw)
            && close(new_scales.walk_position, scales.walk_position)
            && close(new_scales.walk_yaw, scales.walk_yaw);
        weights = new_weights;
        scales = new_scales;
        if settled || stage + 1 == stages {
            // Converged tightly under the settled (or the last) weights and scales.
            let (xn, it) = levenberg_marquardt(&problem, x, &weights, scales, 50, TIGHT);
            x = xn;
            iterations += it;
            break;
        }
    }
    let p = problem.full(&x);
    // Final scales and covariance at the solution, inliers only.
    let n_free = problem.free.len();
    let outliers = weights.iter().filter(|w| **w == 0.0).count();
    let r = residual_at(&p, &weights, scales);
    if config.robust || config.weighting == Weighting::Estimated {
        scales = inlier_scales(&problem, &r, &weights, scales);
    } else {
        // Unweighted least squares: one variance for every component.
        let n = r
            .len()
            .saturating_sub(n_free + 3 * problem.windows.len())
            .max(1);
        let s = (r.iter().map(|e| e * e).sum::<f64>() / n as f64)
            .sqrt()
            .max(1e-12);
        scales = Scales::white(s, s);
    }
    let (z, jac) = problem.whitened_jacobian(&x, &weights, scales);
    let h = jac.transpose() * &jac;
    let rho = lag_one_correlation(&problem, &z, &weights);
    let inflation = ((1.0 + rho) / (1.0 - rho)).clamp(1.0, 100.0);
    let cov_free = h
        .clone()
        .try_inverse()
        .unwrap_or_else(|| DMatrix::from_element(n_free, n_free, f64::INFINITY));
    let mut covariance = [[0.0; PARAMS]; PARAMS];
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
            covariance[ia][ib] = cov_free[(a, b)] * inflation;
        }
    }
    let span_s = {
        let first = recording.poses[problem.selected[0]].time_s;
        let last = recording.poses[problem.selected[problem.selected.len() - 1]].time_s;
        last - first
    };
    Ok(PoseFit {
        geometry: Problem::geometry(&p),
        params: p,
        covariance,
        free: problem.free.clone(),
        kind: decision,
        residual_std_position_m: scales.position * problem.stated_rms(0),
        stated_scale: problem.use_stated.then_some(scales.position),
        stated_scale_yaw: (problem.use_stated && dim == 3).then_some(scales.yaw),
        residual_std_yaw_rad: (dim == 3).then_some(scales.yaw * problem.stated_rms(2)),
        walk_position_m2_s: scales.walk_position,
        walk_yaw_rad2_s: (dim == 3).then_some(scales.walk_yaw),
        compared: blocks,
        outliers,
        windows: match kind {
            ReferenceKind::Absolute => problem.windows.len(),
            ReferenceKind::Relative => 0,
        },
        lag_one_correlation: rho,
        variance_inflation: inflation,
        iterations,
        span_s,
        nominal_wheelbase_m: config.nominal.wheelbase_m,
        warnings: if problem.free.contains(&Param::TimeOffset)
            && p[6].abs() >= 0.95 * problem.max_offset
        {
            vec![format!(
                "the time offset {:.3} s is at its limit (±{:.2} s): the streams may be further \
                 apart, and the geometry then absorbs the rest; raise --max-time-offset-s and fit \
                 again",
                p[6], problem.max_offset
            )]
        } else {
            Vec::new()
        },
    })
}
