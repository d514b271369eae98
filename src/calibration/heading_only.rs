//! The paper's heading-error equations without its coupled terms (the dashed line of Fig. 6).
//!
//! Eqs. 6–7 give `α = (θ_cw − θ_ccw)/8` and `β = (θ_cw + θ_ccw)/8` from the mean final heading
//! errors; eq. 10 without `α_εd` gives `E_b`, and eq. 11 with the configured wheelbase (not
//! `b·E_b`) gives `E_d`. This reproduces the paper's 0.392 / 0.016 percentage points.

use super::{
    e_b_from_corner_error, e_d_from_leg_drift, CalibrationError, Context, MeanObservation,
};

/// `(E_b, E_d)` from the mean final heading errors.
pub fn ratios(obs: &MeanObservation, ctx: &Context) -> Result<(f64, f64), CalibrationError> {
    let alpha = (obs.heading_cw() - obs.heading_ccw()) / 8.0;
    let beta = (obs.heading_cw() + obs.heading_ccw()) / 8.0;
    Ok((
        e_b_from_corner_error(alpha),
        e_d_from_leg_drift(beta, ctx.side_m, ctx.wheelbase_m),
    ))
}
