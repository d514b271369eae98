//! Our exact inversion of the square model: no small-angle or decoupling approximation.
//!
//! Heading is linear in the wheel travels. A wheel the odometry believes travelled `s` truly
//! travelled `u·s·E_b` (`u = (D_actual/D_configured)/E_b` per wheel), so over any stretch of
//! driving the heading error (sensor minus odometry) is exactly
//!
//! `θ = (G − 1)·T + (2c/b)·D`, with `G = (u_R + u_L)/2`, `c = (u_R − u_L)/2`,
//!
//! where `T` and `D` are the odometry's own turn and forward distance over the stretch and `b`
//! the configured wheelbase: `u_R s_R − u_L s_L = G(s_R − s_L) + c(s_R + s_L)`. A square driven
//! as commanded has `T = ±2π` (counter-clockwise positive) and `D = 4L`, which gives the
//! familiar `θ_ccw = 2π(G − 1) + 8Lc/b`, `θ_cw = −2π(G − 1) + 8Lc/b`. A drive that ends its
//! motions on its own odometry (a ROS robot) overshoots each turn, and its `T` is what it
//! reports ([`super::RunMeasurement::odometry`]). With the two directions' mean `θ`, `T`, `D`
//! the two equations solve for `G − 1` and `2c/b`; with the commanded odometry:
//!
//! `G = 1 − (θ_cw − θ_ccw)/(4π)`, `c = (θ_cw + θ_ccw)·b/(16L)`, `u_R = G + c`, `u_L = G − c`.
//!
//! Heading errors fix only `u_L` and `u_R`, so `E_d = u_R/u_L` under any convention while
//! `E_b` needs the absolute wheel scale from the [`SplitConvention`]: `1/u_L` if the left wheel
//! is nominal, `1/G` if the mean factor is, and a straight-line distance check otherwise.
//!
//! [`SplitConvention`]: crate::kinematics::SplitConvention

use super::{ideal_odometry, CalibrationError, Context, MeanObservation, Method};
use crate::kinematics::{Displacement, SplitConvention};
use std::f64::consts::PI;

/// The two observable combinations `(u_L, u_R)` = `D_L/(D_cfg·E_b)`, `D_R/(D_cfg·E_b)` of
/// squares driven as commanded.
pub fn observables(
    heading_cw_rad: f64,
    heading_ccw_rad: f64,
    side_m: f64,
    wheelbase_m: f64,
) -> (f64, f64) {
    use crate::kinematics::Direction;
    observables_with_odometry(
        (heading_cw_rad, ideal_odometry(Direction::Cw, side_m)),
        (heading_ccw_rad, ideal_odometry(Direction::Ccw, side_m)),
        wheelbase_m,
    )
    .unwrap_or((f64::NAN, f64::NAN))
}

/// `(u_L, u_R)` from each direction's mean heading error and the odometry over the same
/// stretches (see the module); `None` when the two directions' odometry cannot tell the turn
/// term from the leg term (the turns do not differ).
pub fn observables_with_odometry(
    cw: (f64, Displacement),
    ccw: (f64, Displacement),
    wheelbase_m: f64,
) -> Option<(f64, f64)> {
    let (g_minus_1, k) = turn_and_leg_terms(cw, ccw)?;
    let (g, c) = (1.0 + g_minus_1, 0.5 * k * wheelbase_m);
    Some((g - c, g + c))
}

/// `(G − 1, 2c/b)` from two stretches' heading errors and odometry (`θ = (G − 1)·T + (2c/b)·D`
/// for each); `None` when their odometry cannot tell the two terms apart.
pub fn turn_and_leg_terms(a: (f64, Displacement), b: (f64, Displacement)) -> Option<(f64, f64)> {
    let ((ta, oa), (tb, ob)) = (a, b);
    let det = oa.turn_rad * ob.distance_m - ob.turn_rad * oa.distance_m;
    if !(det.is_finite() && det.abs() > 1e-12) {
        return None;
    }
    Some((
        (ta * ob.distance_m - tb * oa.distance_m) / det,
        (oa.turn_rad * tb - ob.turn_rad * ta) / det,
    ))
}

/// `(E_b, E_d)` of the observables `(u_L, u_R)` under `convention` (for a measured scale, the
/// left-nominal `E_b`, which the split then rescales).
pub fn ratios_of(
    u_l: f64,
    u_r: f64,
    method: Method,
    convention: &SplitConvention,
) -> Result<(f64, f64), CalibrationError> {
    if !(u_l > 0.0 && u_r > 0.0) {
        return Err(CalibrationError::NotPhysical {
            method,
            reason: format!(
                "heading errors imply non-positive wheel factors (u_L = {u_l:.6}, u_R = {u_r:.6})"
            ),
        });
    }
    let e_b = match convention {
        SplitConvention::MeanPreserving => 2.0 / (u_l + u_r),
        SplitConvention::LeftNominal | SplitConvention::MeasuredScale { .. } => 1.0 / u_l,
    };
    Ok((e_b, u_r / u_l))
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
    let (u_l, u_r) = observables_with_odometry(
        (obs.heading_cw(), obs.odometry_cw()),
        (obs.heading_ccw(), obs.odometry_ccw()),
        ctx.wheelbase_m,
    )
    .ok_or_else(|| CalibrationError::NotPhysical {
        method: Method::Exact,
        reason: "the two directions' odometry turns do not differ: the turn and leg terms \
                 cannot be told apart"
            .into(),
    })?;
    ratios_of(u_l, u_r, Method::Exact, &ctx.convention)
}
