//! How every table prints an estimate's ± and says what it is: one standard error within a
//! session, a prediction for the next session when sessions are pooled, a lower bound from the
//! heading noise alone with one square per direction, or "—" where a method states none; and
//! the default method with its reason, and methods that disagree beyond what they state.

use odocal::calibration::agreement::{disagreements, DISAGREEMENT_SIGMAS};
use odocal::calibration::{default_method_reason, Estimate, Method};

pub use odocal::report::stated::{pm, pm_b, pm_d};

/// What the cells of a one-session table mean, one line each, for the kinds present.
pub fn within_session_legend(estimates: &[Estimate]) -> Vec<String> {
    let mut out = vec![
        "± is one standard error within this session (the scatter of its squares, never below \
         what the heading noise gives where it is known); sessions of one robot differ by more \
         than that: pool several sessions for what the next one will read"
            .to_string(),
    ];
    let noise_only = |e: &Estimate| {
        (e.e_b_std_err.is_none() && e.e_b_noise_std_err.is_some())
            || (e.e_d_std_err.is_none() && e.e_d_noise_std_err.is_some())
    };
    let nothing = |e: &Estimate| {
        (e.e_b_std_err.is_none() && e.e_b_noise_std_err.is_none())
            || (e.e_d_std_err.is_none() && e.e_d_noise_std_err.is_none())
    };
    if estimates.iter().any(noise_only) {
        out.push(
            "≥ is the standard error the heading's noise alone gives (one square per \
             direction: the scatter from square to square is unknown, so the true error is \
             larger)"
                .into(),
        );
    }
    if estimates.iter().any(nothing) {
        out.push(
            "— : no error stated (one square per direction, and no heading noise known for what \
             the method uses)"
                .into(),
        );
    }
    out
}

/// The line naming the default method and why it is the default.
pub fn default_line(method: Method) -> String {
    format!(
        "default method (what calibrate writes): {method}, {}",
        default_method_reason(method)
    )
}

/// Which errors a disagreement is measured against, as the warning names them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Basis {
    /// One session's standard errors (what its table shows).
    Session,
    /// The standard errors of pooled values (smaller than the prediction the table shows).
    Pooled,
}

/// A warning per quantity on which a method differs from `reference` (the default, or the
/// method chosen: `role` says which) beyond both stated errors ([`disagreements`]); empty when
/// they agree or there is no reference.
pub fn disagreement_lines(
    reference: Option<Method>,
    role: &str,
    basis: Basis,
    estimates: &[Estimate],
) -> Vec<String> {
    let Some(reference) = reference.and_then(|m| estimates.iter().find(|e| e.method == m)) else {
        return Vec::new();
    };
    let errors = match basis {
        Basis::Session => "more than both state",
        Basis::Pooled => {
            "more than the standard errors of both pooled values (which are smaller than the \
             prediction shown)"
        }
    };
    disagreements(reference, estimates)
        .into_iter()
        .map(|d| {
            format!(
                "warning: {} and {} differ in {} by {:+.5} ({:.1} combined standard errors, more \
                 than {DISAGREEMENT_SIGMAS}): {errors}, so one of them is biased on this robot or \
                 states too small a ±; {} is {role}",
                d.other, d.method, d.quantity, d.difference, d.sigmas, d.method
            )
        })
        .collect()
}
