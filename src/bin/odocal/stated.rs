//! How every table prints an estimate's ± and says what it is: one standard error within a
//! session, a prediction for the next session when sessions are pooled, a lower bound from the
//! heading noise alone with one square per direction, or "—" where a method states none; and
//! the default method with its reason, and methods that disagree beyond what they state.

use odocal::calibration::agreement::{disagreements, DISAGREEMENT_SIGMAS};
use odocal::calibration::{default_method_reason, Estimate, Method};

/// A standard error as a table cell: "± 0.00031", "± <0.00001" when it rounds to zero at five
/// decimals (not the same as none), "—" when there is none.
pub fn pm(std_err: Option<f64>) -> String {
    match std_err {
        Some(s) if s.is_finite() && s < 0.000_005 => "± <0.00001".into(),
        Some(s) if s.is_finite() => format!("± {s:.5}"),
        _ => "—".into(),
    }
}

/// `E_b`'s cell: its standard error, else "≥ x" from the noise alone, else "—".
pub fn pm_b(e: &Estimate) -> String {
    cell(e.e_b_std_err, e.e_b_noise_std_err)
}

/// `E_d`'s cell, as [`pm_b`].
pub fn pm_d(e: &Estimate) -> String {
    cell(e.e_d_std_err, e.e_d_noise_std_err)
}

fn cell(std_err: Option<f64>, noise: Option<f64>) -> String {
    match (std_err, noise) {
        (Some(_), _) => pm(std_err),
        (None, Some(n)) if n.is_finite() => format!("≥ {n:.5}"),
        _ => "—".into(),
    }
}

/// What the cells of a one-session table mean, one line each, for the kinds present.
pub fn within_session_legend(estimates: &[Estimate]) -> Vec<String> {
    let mut out = vec![
        "± is one standard error within this session (the scatter of its squares, never below \
         what the heading noise gives); sessions of one robot differ by more than that: pool \
         several sessions for what the next one will read"
            .to_string(),
    ];
    if estimates
        .iter()
        .any(|e| e.e_b_std_err.is_none() && e.e_b_noise_std_err.is_some())
    {
        out.push(
            "≥ is the standard error the heading's measured noise alone gives (one square per \
             direction: the scatter from square to square is unknown, so the true error is \
             larger)"
                .into(),
        );
    }
    if estimates
        .iter()
        .any(|e| e.e_b_std_err.is_none() && e.e_b_noise_std_err.is_none())
    {
        out.push(
            "— : no error stated (one square per direction and no measured heading noise)".into(),
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

/// A warning per quantity on which a method differs from the default beyond both stated
/// errors ([`disagreements`]); empty when they agree or there is no default.
pub fn disagreement_lines(default: Option<Method>, estimates: &[Estimate]) -> Vec<String> {
    let Some(reference) = default.and_then(|m| estimates.iter().find(|e| e.method == m)) else {
        return Vec::new();
    };
    disagreements(reference, estimates)
        .into_iter()
        .map(|d| {
            format!(
                "warning: {} and {} differ in {} by {:+.5} ({:.1} combined standard errors, more \
                 than {DISAGREEMENT_SIGMAS}): more than both state, so one of them is biased on \
                 this robot or states too small a ±; {} is the default",
                d.other, d.method, d.quantity, d.difference, d.sigmas, d.method
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_say_none_rounding_to_zero_and_noise_only_apart() {
        assert_eq!(pm(None), "—");
        assert_eq!(pm(Some(0.0)), "± <0.00001");
        assert_eq!(pm(Some(0.00031)), "± 0.00031");
        assert_eq!(cell(None, Some(0.00012)), "≥ 0.00012");
        assert_eq!(cell(Some(0.0003), Some(0.00012)), "± 0.00030");
        assert_eq!(cell(None, None), "—");
    }
}
