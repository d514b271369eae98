//! Levenberg–Marquardt on the whitened residuals of a [`Problem`] (Marquardt 1963: the damped
//! normal equations, the damping raised when a step fails and lowered when one gains).

use super::*;

/// Levenberg–Marquardt at fixed weights from `x` on the whitened cost; converged when an
/// iteration gains less than `tolerance` of the cost. Returns the solution and the iterations
/// used.
pub(super) fn levenberg_marquardt(
    problem: &Problem<'_>,
    mut x: Vec<f64>,
    weights: &[f64],
    scales: Scales,
    max_iterations: usize,
    tolerance: f64,
) -> (Vec<f64>, usize) {
    let mut lambda = 1e-4;
    let mut cost = problem.cost(&x, weights, scales);
    let n = x.len();
    for it in 0..max_iterations {
        let (z, jac) = problem.whitened_jacobian(&x, weights, scales);
        let mut h = DMatrix::<f64>::zeros(n, n);
        let mut g = DVector::<f64>::zeros(n);
        for (i, e) in z.iter().enumerate() {
            if *e == 0.0 && jac.row(i).iter().all(|v| *v == 0.0) {
                continue;
            }
            let row = jac.row(i);
            for a in 0..n {
                let ja = row[a];
                g[a] += ja * e;
                for b in a..n {
                    h[(a, b)] += ja * row[b];
                }
            }
        }
        for a in 0..n {
            for b in 0..a {
                h[(a, b)] = h[(b, a)];
            }
        }
        let mut improved = false;
        for _ in 0..12 {
            let mut damped = h.clone();
            for a in 0..n {
                damped[(a, a)] += lambda * h[(a, a)].max(1e-12);
            }
            let Some(chol) = damped.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            // Residuals are reference minus prediction, J their derivative: the step is
            // −(JᵀWJ)⁻¹ JᵀW r.
            let dx = chol.solve(&(-&g));
            let xn: Vec<f64> = x.iter().zip(dx.iter()).map(|(a, d)| a + d).collect();
            if !problem.physical(&xn) {
                lambda *= 10.0;
                continue;
            }
            let cn = problem.cost(&xn, weights, scales);
            if cn <= cost {
                let small = (cost - cn) <= tolerance * cost.max(1e-300);
                x = xn;
                cost = cn;
                lambda = (lambda / 10.0).max(1e-9);
                improved = true;
                if small {
                    return (x, it + 1);
                }
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            return (x, it + 1);
        }
    }
    (x, max_iterations)
}
