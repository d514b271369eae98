//! Our exact inversion of the square model: no small-angle or decoupling approximation.
//!
//! With in-place turns and wheel rotations set by the configured parameters, heading is linear
//! in the wheel travels, and a square's final heading error is exactly
//! `θ_ccw = 2π(G − 1) + 8Lc/b` and `θ_cw = −2π(G − 1) + 8Lc/b`, where
//! `G = (u_R + u_L)/2`, `c = (u_R − u_L)/2` and `u = (D_actual/D_configured)/E_b` per wheel.
//! Inverting:
//!
//! `G = 1 − (θ_cw − θ_ccw)/(4π)`, `c = (θ_cw + θ_ccw)·b/(16L)`, `u_R = G + c`, `u_L = G − c`.
//!
//! Heading errors fix only `u_L` and `u_R`, so `E_d = u_R/u_L` under any convention while
//! `E_b` needs the absolute wheel scale from the [`SplitConvention`]: `1/u_L` if the left wheel
//! is nominal, `1/G` if the mean factor is, and a straight-line distance check otherwise.
//!
//! [`SplitConvention`]: crate::kinematics::SplitConvention

use super::{CalibrationError, Context, MeanObservation, Method};
use crate::kinematics::SplitConvention;
use std::f64::consts::PI;

/// The two observable combinations `(u_L, u_R)` = `D_L/(D_cfg·E_b)`, `D_R/(D_cfg·E_b)`.
pub fn observables(
    heading_cw_rad: f64,
    heading_ccw_rad: f64,
    side_m: f64,
    wheelbase_m: f64,
) -> (f64, f64) {
    let g = 1.0 - (heading_cw_rad - heading_ccw_rad) / (4.0 * PI);
    let c = (heading_cw_rad + heading_ccw_rad) * wheelbase_m / (16.0 * side_m);
    (g - c, g + c)
}

/// The exact final heading errors `(θ_cw, θ_ccw)` (rad, unwrapped) of squares driven by a robot
/// whose true parameters are `correction` applied to the configured ones: the forward model
/// that [`observables`] inverts.
pub fn predicted_heading_errors(
    correction: &crate::kinematics::Correction,
    side_m: f64,
    wheelbase_m: f64,
) -> (f64, f64) {
    let u_l = correction.left_diameter_scale / correction.wheelbase_scale;
    let u_r = correction.right_diameter_scale / correction.wheelbase_scale;
    let g = 0.5 * (u_l + u_r);
    let c = 0.5 * (u_r - u_l);
    let turn = 2.0 * PI * (1.0 - g);
    let legs = 8.0 * side_m * c / wheelbase_m;
    (turn + legs, -turn + legs)
}

/// `(E_b, E_d)`; `E_b` is the one the configured convention implies (for a measured scale, the
/// left-nominal value, which the split then rescales).
pub fn ratios(obs: &MeanObservation, ctx: &Context) -> Result<(f64, f64), CalibrationError> {
    let (u_l, u_r) = observables(
        obs.heading_cw(),
        obs.heading_ccw(),
        ctx.side_m,
        ctx.wheelbase_m,
    );
    if !(u_l > 0.0 && u_r > 0.0) {
        return Err(CalibrationError::NotPhysical {
            method: Method::Exact,
            reason: format!(
                "heading errors imply non-positive wheel factors (u_L = {u_l:.6}, u_R = {u_r:.6})"
            ),
        });
    }
    let e_b = match ctx.convention {
        SplitConvention::MeanPreserving => 2.0 / (u_l + u_r),
        SplitConvention::LeftNominal | SplitConvention::MeasuredScale { .. } => 1.0 / u_l,
    };
    Ok((e_b, u_r / u_l))
}
