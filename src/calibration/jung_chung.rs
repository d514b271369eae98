//! The method Jung & Chung (2011) propose: eqs. 6–11 exactly as printed.
//!
//! `α_εb = (θ_cw − θ_ccw)/8` (eq. 6), `β_εd = (θ_cw + θ_ccw)/8` (eq. 7), the coupled turn term
//! `α_εd = π·b_nom/(4L)·β_εd` (eq. 9, with the configured wheelbase), `E_b = 90°/(90° − (α_εb +
//! α_εd))` (eq. 10, degrees) and `E_d = (R + b_nom·E_b/2)/(R − b_nom·E_b/2)` with
//! `R = (L/2)/sin(β_εd/2)` (eq. 11, radians). Its `E_b` equals the exact inversion's under the
//! left-nominal split; its `E_d` keeps a small approximation (eq. 11 ignores that the turns
//! also change heading through the wheel ratio).

use super::{
    e_b_from_corner_error, e_d_from_leg_drift, CalibrationError, Context, MeanObservation,
};
use std::f64::consts::PI;

/// `(E_b, E_d)` from the mean final heading errors.
pub fn ratios(obs: &MeanObservation, ctx: &Context) -> Result<(f64, f64), CalibrationError> {
    let alpha_eb = (obs.heading_cw() - obs.heading_ccw()) / 8.0;
    let beta_ed = (obs.heading_cw() + obs.heading_ccw()) / 8.0;
    let alpha_ed = PI * ctx.wheelbase_m / (4.0 * ctx.side_m) * beta_ed;
    let e_b = e_b_from_corner_error(alpha_eb + alpha_ed);
    let e_d = e_d_from_leg_drift(beta_ed, ctx.side_m, ctx.wheelbase_m * e_b);
    Ok((e_b, e_d))
}
