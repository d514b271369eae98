//! Lee, Jung & Chung (2011), *reconstructed from the Jung & Chung paper's description*.
//!
//! The original is not available to us. The paper says Lee's method uses the final positions of
//! 2 m × 2 m squares (5 runs each way) and adds the coupled effect of the wheel-diameter error
//! on each 90° turn, but not on the straight legs. We therefore take UMBmark's `α`, `β`
//! (eq. 3), add the paper's eq. 9 turn term `α_εd = π·b/(4L)·β` to `α` before eq. 10, and keep
//! UMBmark's `E_d` with the configured wheelbase. Run it on its own track: the paper uses
//! a 2 m square for it while the other methods use 4 m.

use super::{
    alpha_beta_from_positions, e_b_from_corner_error, e_d_from_leg_drift, CalibrationError,
    Context, MeanObservation, Method,
};
use std::f64::consts::PI;

/// `(E_b, E_d)` from the mean final positions.
pub fn ratios(obs: &MeanObservation, ctx: &Context) -> Result<(f64, f64), CalibrationError> {
    let (Some(cw), Some(ccw)) = (obs.xy_cw(), obs.xy_ccw()) else {
        return Err(CalibrationError::MissingPositions(Method::Lee));
    };
    let (alpha, beta) = alpha_beta_from_positions(cw, ccw, ctx.side_m);
    let alpha_coupled = PI * ctx.wheelbase_m / (4.0 * ctx.side_m) * beta;
    Ok((
        e_b_from_corner_error(alpha + alpha_coupled),
        e_d_from_leg_drift(beta, ctx.side_m, ctx.wheelbase_m),
    ))
}
