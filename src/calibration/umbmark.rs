//! UMBmark (Borenstein & Feng 1996), as the paper summarises it in eqs. 1–3.
//!
//! Small-angle geometry turns the mean final positions of the CW and CCW runs into a per-corner
//! turn error `α` and a per-leg drift `β`; then `E_b = 90°/(90° − α)` and
//! `E_d = (R + b/2)/(R − b/2)` with `R = (L/2)/sin(β/2)` and the configured wheelbase `b`.
//! Both approximations grow with the track size and the error magnitude, which is what the
//! paper's Fig. 5 shows.

use super::{
    alpha_beta_from_positions, e_b_from_corner_error, e_d_from_leg_drift, CalibrationError,
    Context, MeanObservation, Method,
};

/// `(E_b, E_d)` from the mean final positions.
pub fn ratios(obs: &MeanObservation, ctx: &Context) -> Result<(f64, f64), CalibrationError> {
    let (Some(cw), Some(ccw)) = (obs.xy_cw(), obs.xy_ccw()) else {
        return Err(CalibrationError::MissingPositions(Method::Umbmark));
    };
    let (alpha, beta) = alpha_beta_from_positions(cw, ccw, ctx.side_m);
    Ok((
        e_b_from_corner_error(alpha),
        e_d_from_leg_drift(beta, ctx.side_m, ctx.wheelbase_m),
    ))
}
