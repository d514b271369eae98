//! `E_d` and `E_b` from a pose reference's heading alone: what a reference that fuses the wheels
//! with a gyro (robot_localization's `/odometry/filtered`) still measures when its positions are
//! the wheels' own.
//!
//! Over each interval between consecutive reference samples the heading turns by
//! `Δψ = (D_R·Δφ_R − D_L·Δφ_L) / (2b)` (the wheel angles `φ` interpolated at the reference's
//! stamps), linear in `a_R = D_R/(2b)` and `a_L = D_L/(2b)`. These are fitted by least squares
//! (increments beyond four robust standard deviations left out once, then refitted), their
//! covariance `σ̂²(AᵀA)⁻¹` inflated by `(1 + ρ)/(1 − ρ)` for the residuals' lag-one correlation
//! `ρ`. A heading measures turns, not distances: the diameters' mean is held at the nominal,
//! as in Jung & Chung's square test, so that `E_d = a_R/a_L` and `E_b = D̄/((a_R + a_L)·b_nom)`.
//! The gyro's own scale error enters `E_b` one for one.

use super::pool::upper_median;
use super::pose_reference::{Geometry, PoseRecording};
use crate::kinematics::wrap_angle;
use serde::Serialize;

/// `E_d` and `E_b` from the heading, with one standard deviation each.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct HeadingScales {
    /// `E_d = D_R / D_L`.
    pub e_d: f64,
    /// Its standard deviation.
    pub e_d_std: f64,
    /// `E_b = b / b_nominal`, the diameters' mean held at the nominal.
    pub e_b: f64,
    /// Its standard deviation.
    pub e_b_std: f64,
    /// Increments fitted.
    pub increments: usize,
}

/// Fits `E_d` and `E_b` to `recording`'s heading; `None` without a heading, with fewer than
/// twenty increments, or when the turns do not tell the two wheels apart.
pub fn heading_scales(recording: &PoseRecording, nominal: Geometry) -> Option<HeadingScales> {
    let wheels = &recording.wheels;
    let mut k = 0usize;
    let mut at = |t: f64| -> Option<(f64, f64)> {
        while k + 1 < wheels.len() && wheels[k + 1].time_s < t {
            k += 1;
        }
        let (a, b) = (wheels.get(k)?, wheels.get(k + 1)?);
        if t < a.time_s || t > b.time_s {
            return None;
        }
        let f = (t - a.time_s) / (b.time_s - a.time_s).max(f64::MIN_POSITIVE);
        Some((
            a.left_rad + f * (b.left_rad - a.left_rad),
            a.right_rad + f * (b.right_rad - a.right_rad),
        ))
    };
    // (Δφ_R, Δφ_L, Δψ) per interval.
    let mut rows = Vec::new();
    let mut last: Option<((f64, f64), f64)> = None;
    for p in &recording.poses {
        let (Some(w), Some(yaw)) = (at(p.time_s), p.yaw_rad) else {
            last = None;
            continue;
        };
        if let Some(((l0, r0), y0)) = last {
            rows.push((w.1 - r0, w.0 - l0, wrap_angle(yaw - y0)));
        }
        last = Some((w, yaw));
    }
    let first = solve(&rows)?;
    let residual = |r: &(f64, f64, f64), x: (f64, f64)| r.2 - (x.0 * r.0 - x.1 * r.1);
    let scale = 1.4826 * upper_median(rows.iter().map(|r| residual(r, first.0).abs()).collect())?;
    let kept: Vec<(f64, f64, f64)> = rows
        .iter()
        .copied()
        .filter(|r| residual(r, first.0).abs() <= 4.0 * scale)
        .collect();
    let ((a_r, a_l), cov) = solve(&kept)?;
    let mean_d = 0.5 * (nominal.left_diameter_m + nominal.right_diameter_m);
    let s = a_r + a_l;
    let e_d = a_r / a_l;
    let g = [1.0 / a_l, -a_r / (a_l * a_l)];
    let e_d_var = g[0] * g[0] * cov[0] + 2.0 * g[0] * g[1] * cov[1] + g[1] * g[1] * cov[2];
    let e_b = mean_d / (s * nominal.wheelbase_m);
    let e_b_var = (e_b / s).powi(2) * (cov[0] + 2.0 * cov[1] + cov[2]);
    (e_d.is_finite() && e_b.is_finite()).then(|| HeadingScales {
        e_d,
        e_d_std: e_d_var.max(0.0).sqrt(),
        e_b,
        e_b_std: e_b_var.max(0.0).sqrt(),
        increments: kept.len(),
    })
}

/// Least squares of `Δψ = a_R·Δφ_R − a_L·Δφ_L` over `rows`: `(a_R, a_L)` and their covariance
/// `(c_RR, c_RL, c_LL)`, inflated for the residuals' lag-one correlation.
fn solve(rows: &[(f64, f64, f64)]) -> Option<((f64, f64), [f64; 3])> {
    if rows.len() < 20 {
        return None;
    }
    let (mut srr, mut srl, mut sll, mut sry, mut sly) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for &(r, l, y) in rows {
        let l = -l;
        srr += r * r;
        srl += r * l;
        sll += l * l;
        sry += r * y;
        sly += l * y;
    }
    let det = srr * sll - srl * srl;
    // The wheels turned only together (or not at all): the turns cannot tell them apart.
    if det.is_nan() || det <= 1e-12 * srr * sll {
        return None;
    }
    let (a_r, a_l) = ((sll * sry - srl * sly) / det, (srr * sly - srl * sry) / det);
    let res: Vec<f64> = rows
        .iter()
        .map(|&(r, l, y)| y - (a_r * r - a_l * l))
        .collect();
    let n = res.len() as f64;
    let sigma2 = res.iter().map(|e| e * e).sum::<f64>() / (n - 2.0);
    let lag: f64 = res.windows(2).map(|w| w[0] * w[1]).sum::<f64>();
    let rho = if sigma2 > 0.0 {
        (lag / ((n - 1.0) * sigma2)).clamp(0.0, 0.98)
    } else {
        0.0
    };
    let inflation = (1.0 + rho) / (1.0 - rho);
    let f = sigma2 * inflation / det;
    // (AᵀA)⁻¹ of the columns (Δφ_R, −Δφ_L), whose coefficients are (a_R, a_L).
    Some(((a_r, a_l), [f * sll, -f * srl, f * srr]))
}
