//! The noise model's scales: robust (median absolute deviation) and inlier estimates of the
//! position and yaw scales, the random walk found by maximum likelihood, the `χ²` gate that leaves
//! out gross failures, and the lag-one correlation that inflates the covariance.

use super::*;

/// Noise of the residuals: white noise of one position component and of the yaw (the
/// reference's own, and the odometry's per interval), and, for an absolute reference, the
/// variance per second of a random walk (the odometry's slip accumulating between alignments).
#[derive(Debug, Clone, Copy)]
pub(super) struct Scales {
    pub(super) position: f64,
    pub(super) yaw: f64,
    pub(super) walk_position: f64,
    pub(super) walk_yaw: f64,
}

impl Scales {
    pub(super) fn white(position: f64, yaw: f64) -> Self {
        Self {
            position,
            yaw,
            walk_position: 0.0,
            walk_yaw: 0.0,
        }
    }

    pub(super) fn walks(&self) -> bool {
        self.walk_position > 0.0 || self.walk_yaw > 0.0
    }

    /// White σ and walk variance rate of component `c`.
    pub(super) fn of(&self, c: usize) -> (f64, f64) {
        if c < 2 {
            (self.position, self.walk_position)
        } else {
            (self.yaw, self.walk_yaw)
        }
    }
}

/// Median of absolute values, scaled to a Gaussian standard deviation.
pub(super) fn mad_std(values: impl Iterator<Item = f64>) -> f64 {
    let v: Vec<f64> = values.map(f64::abs).filter(|v| v.is_finite()).collect();
    upper_median(v).map_or(0.0, |m| 1.4826 * m)
}

/// Scales from residuals, robustly (median absolute value), over the blocks weighted > 0; no
/// random walk.
pub(super) fn robust_scales(problem: &Problem<'_>, r: &[f64], weights: &[f64]) -> Scales {
    let dim = problem.dim;
    let pick = |c_lo: usize, c_hi: usize| {
        mad_std(r.chunks(dim).enumerate().flat_map(|(b, e)| {
            let keep = weights[b] > 0.0;
            (c_lo..c_hi)
                .filter(move |_| keep)
                .map(move |c| e[c] / problem.stated(b, c))
        }))
    };
    Scales::white(
        pick(0, 2).max(1e-9),
        if dim == 3 { pick(2, 3).max(1e-9) } else { 1.0 },
    )
}

/// White noise and random walk of an absolute reference's residuals by maximum likelihood:
/// for each class (positions, yaw) the ratio `λ = q/σ²` of the walk's variance per second to
/// the white variance, with `σ²` profiled out (`σ̂² = Σν²/s / n` for innovations `ν` of
/// normalised variance `s`, so `−2 log L = n log σ̂² + Σ log s`), searched on a logarithmic
/// grid and refined; a walk is kept only when it lowers `−2 log L` by more than [`WALK_LR`]
/// (the 95 % quantile of χ² with one degree of freedom, Wilks; conservative, as the walk's
/// variance sits on the boundary at zero), so that noise in the search does not invent one.
pub(super) fn walk_scales(
    problem: &Problem<'_>,
    r: &[f64],
    weights: &[f64],
    white: Scales,
) -> Scales {
    let dim = problem.dim;
    // Σν²/s, Σ log s and the count over components `cs` for ratio `lambda` (σ² = 1).
    let innovations = |cs: &[usize], lambda: f64| -> (f64, f64, usize) {
        let (mut sum, mut logs, mut n) = (0.0, 0.0, 0usize);
        for &(a, b) in &problem.windows {
            for &c in cs {
                let (mut m, mut var) = (0.0f64, 0.0f64);
                let mut t_prev: Option<f64> = None;
                for blk in a..b {
                    let t = problem.block_time(blk);
                    if let Some(tp) = t_prev {
                        var += lambda * (t - tp).max(0.0);
                    }
                    t_prev = Some(t);
                    if weights[blk] <= 0.0 {
                        continue;
                    }
                    let meas = problem.stated(blk, c).powi(2);
                    let nu = r[blk * dim + c] - m;
                    let s = var + meas;
                    sum += nu * nu / s;
                    logs += s.ln();
                    n += 1;
                    let k = var / s;
                    m += k * nu;
                    var *= 1.0 - k;
                }
            }
        }
        (sum, logs, n)
    };
    // −2 log L (up to a constant) with σ² profiled out.
    let profile = |cs: &[usize], lambda: f64| -> f64 {
        let (sum, logs, n) = innovations(cs, lambda);
        if n == 0 || sum <= 0.0 {
            return f64::INFINITY;
        }
        n as f64 * (sum / n as f64).ln() + logs
    };
    let search = |cs: &[usize], sigma: f64| -> (f64, f64) {
        let none = profile(cs, 0.0);
        let mut best = (none, 0.0);
        let mut k = -10.0;
        while k <= 3.0 {
            let lambda = 10f64.powf(k);
            let v = profile(cs, lambda);
            if v < best.0 {
                best = (v, lambda);
            }
            k += 0.25;
        }
        if best.1 > 0.0 {
            // Golden-section refinement on log λ within one grid step each side.
            let (mut lo, mut hi) = (best.1.log10() - 0.25, best.1.log10() + 0.25);
            let g = 0.5 * (5f64.sqrt() - 1.0);
            for _ in 0..20 {
                let (a, b) = (hi - g * (hi - lo), lo + g * (hi - lo));
                if profile(cs, 10f64.powf(a)) < profile(cs, 10f64.powf(b)) {
                    hi = b;
                } else {
                    lo = a;
                }
            }
            let lambda = 10f64.powf(0.5 * (lo + hi));
            let v = profile(cs, lambda);
            if v < best.0 {
                best = (v, lambda);
            }
        }
        if none - best.0 < WALK_LR {
            return (sigma, 0.0);
        }
        // σ̂² at the best λ (in units of the stated σ²), then q = λσ̂².
        let (sum, _, n) = innovations(cs, best.1);
        let sigma2 = (sum / n.max(1) as f64).max(1e-24);
        (sigma2.sqrt(), best.1 * sigma2)
    };
    let (position, walk_position) = search(&[0, 1], white.position);
    let (yaw, walk_yaw) = if dim == 3 {
        search(&[2], white.yaw)
    } else {
        (1.0, 0.0)
    };
    Scales {
        position,
        yaw,
        walk_position,
        walk_yaw,
    }
}

/// Least drop of `−2 log L` that keeps a random walk: χ²₁'s 95 % quantile.
pub(super) const WALK_LR: f64 = 3.84;

/// `χ²` 99.9 % quantiles for 2 and 3 degrees of freedom.
pub(super) fn gate(dim: usize) -> f64 {
    if dim == 3 {
        16.27
    } else {
        13.82
    }
}

/// Normalised squared innovation of each block.
pub(super) fn block_chi2(
    problem: &Problem<'_>,
    r: &[f64],
    weights: &[f64],
    scales: Scales,
) -> Vec<f64> {
    let raw = problem.whiten(r, weights, scales).1;
    raw.chunks(problem.dim)
        .map(|z| z.iter().map(|v| v * v).sum())
        .collect()
}

/// The scales of a gated stage: white noise and random walk by maximum likelihood for an
/// absolute reference, white noise for a relative one; then one common factor per class that
/// makes the inliers' whitened residuals unit.
pub(super) fn settle_scales(
    problem: &Problem<'_>,
    r: &[f64],
    weights: &[f64],
    config: &FitConfig,
) -> Scales {
    let shape = match problem.kind {
        ReferenceKind::Absolute if config.weighting == Weighting::Estimated => {
            let white = robust_scales(problem, r, weights);
            walk_scales(problem, r, weights, white)
        }
        _ => robust_scales(problem, r, weights),
    };
    inlier_scales(problem, r, weights, shape)
}

/// `shape` rescaled per class so that the inliers' whitened residuals have unit variance,
/// corrected for the parameters and alignments fitted.
pub(super) fn inlier_scales(
    problem: &Problem<'_>,
    r: &[f64],
    weights: &[f64],
    shape: Scales,
) -> Scales {
    let dim = problem.dim;
    let raw = problem.whiten(r, weights, shape).1;
    let (mut sp, mut np, mut sy, mut ny) = (0.0, 0usize, 0.0, 0usize);
    for (b, z) in raw.chunks(dim).enumerate() {
        if weights[b] <= 0.0 {
            continue;
        }
        for (c, v) in z.iter().enumerate() {
            if c < 2 {
                sp += v * v;
                np += 1;
            } else {
                sy += v * v;
                ny += 1;
            }
        }
    }
    let nuisance = match problem.kind {
        ReferenceKind::Absolute => 3 * problem.windows.len(),
        ReferenceKind::Relative => 0,
    };
    let lost = (problem.free.len() + nuisance) as f64;
    let total = (np + ny).max(1) as f64;
    let dof = |n: usize| (n as f64 - lost * n as f64 / total).max(1.0);
    let fp = (sp / dof(np)).max(1e-24);
    let fy = if ny > 0 {
        (sy / dof(ny)).max(1e-24)
    } else {
        1.0
    };
    Scales {
        position: (shape.position * fp.sqrt()).max(1e-12),
        yaw: if ny > 0 {
            (shape.yaw * fy.sqrt()).max(1e-12)
        } else {
            1.0
        },
        walk_position: shape.walk_position * fp,
        walk_yaw: shape.walk_yaw * fy,
    }
}

/// Lag-one correlation of the whitened residuals `z` of consecutive inlier blocks, pooled over
/// components.
pub(super) fn lag_one_correlation(problem: &Problem<'_>, z: &[f64], weights: &[f64]) -> f64 {
    let dim = problem.dim;
    let (mut num, mut den) = (0.0, 0.0);
    for b in 0..problem.blocks() {
        if weights[b] <= 0.0 {
            continue;
        }
        for c in 0..dim {
            den += z[b * dim + c].powi(2);
            if b > 0 && weights[b - 1] > 0.0 {
                num += z[b * dim + c] * z[(b - 1) * dim + c];
            }
        }
    }
    if den > 0.0 {
        (num / den).clamp(-1.0, 0.98)
    } else {
        0.0
    }
}
