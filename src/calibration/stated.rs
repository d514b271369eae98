//! How every table prints an estimate's ± and says what it is, wherever a person reads it (the
//! terminal, report.md): one standard error within a session as "± 0.00031", one that rounds
//! to zero at five decimals as "± <0.00001" (not the same as none), the noise-only lower bound
//! of a session with one square per direction as "≥ 0.00012", a prediction for the next
//! session when sessions are pooled, and "—" where a method states nothing; the default method
//! with its reason; and methods that disagree beyond what they state.

use super::agreement::{disagreements, DISAGREEMENT_SIGMAS};
use super::{default_method_reason, Estimate, Method};

/// A standard error as a table cell: "± 0.00031", "± <0.00001", or "—" when there is none.
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

/// A standard error, else a noise-only lower bound, else "—".
pub fn cell(std_err: Option<f64>, noise: Option<f64>) -> String {
    match (std_err, noise) {
        (Some(_), _) => pm(std_err),
        (None, Some(n)) if n.is_finite() && n >= 0.000_005 => format!("≥ {n:.5}"),
        (None, Some(n)) if n.is_finite() && n > 0.0 => format!("≥ {n:.0e}"),
        _ => "—".into(),
    }
}

/// What the cells of a one-session table mean, one line each, for the kinds present.
pub fn within_session_legend(estimates: &[Estimate]) -> Vec<String> {
    let mut out = vec![
        "± is one standard error within this session (the scatter of its squares, never below \
         what the heading noise gives where it is known); sessions of one robot differ by more \
         than that: pool several sessions for what the next one will read"
            .to_string(),
    ];
    // The legend explains the cells the table shows, read from the cells themselves.
    let cells: Vec<String> = estimates.iter().flat_map(|e| [pm_b(e), pm_d(e)]).collect();
    if cells.iter().any(|c| c.starts_with('≥')) {
        out.push(
            "≥ is the standard error the heading's noise alone gives (one square per \
             direction: the scatter from square to square is unknown, so the true error is \
             larger)"
                .into(),
        );
    }
    if cells.iter().any(|c| c == "—") {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::{Correction, SplitConvention};

    #[test]
    fn cells_say_none_rounding_to_zero_and_noise_only_apart() {
        assert_eq!(pm(None), "—");
        assert_eq!(pm(Some(0.0)), "± <0.00001");
        assert_eq!(pm(Some(0.00031)), "± 0.00031");
        assert_eq!(cell(None, Some(0.00012)), "≥ 0.00012");
        assert_eq!(cell(None, Some(0.000003)), "≥ 3e-6");
        assert_eq!(cell(None, Some(0.0)), "—");
        assert_eq!(cell(Some(0.0003), Some(0.00012)), "± 0.00030");
        assert_eq!(cell(None, None), "—");
    }

    fn estimate(method: Method, std_err: Option<(f64, f64)>) -> Estimate {
        let c = Correction {
            left_diameter_scale: 1.0,
            right_diameter_scale: 1.0,
            wheelbase_scale: 1.01,
        };
        Estimate::of(method, c, std_err, &SplitConvention::LeftNominal)
    }

    #[test]
    fn the_legend_explains_exactly_the_cells_shown() {
        let scatter = estimate(Method::Legs, Some((3e-4, 5e-5)));
        assert_eq!(
            within_session_legend(std::slice::from_ref(&scatter)).len(),
            1
        );
        let noise = estimate(Method::Exact, None).with_noise_std_err(Some((2e-4, 3e-5)));
        let none = estimate(Method::Umbmark, None);
        let legend = within_session_legend(&[scatter, noise, none]);
        assert_eq!(legend.len(), 3, "{legend:?}");
        assert!(
            legend[1].starts_with('≥') && legend[2].starts_with('—'),
            "{legend:?}"
        );
    }

    #[test]
    fn a_disagreement_names_the_role_and_what_it_is_measured_against() {
        let legs = estimate(Method::Legs, Some((1e-4, 1e-5)));
        let mut far = estimate(Method::JungChung, Some((1e-4, 1e-5)));
        far.e_b += 0.002;
        let lines = disagreement_lines(
            Some(Method::Legs),
            "the method chosen",
            Basis::Pooled,
            &[legs.clone(), far.clone()],
        );
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(
            lines[0].contains("jung-chung and legs differ in E_b by +0.00200")
                && lines[0].contains("pooled values")
                && lines[0].ends_with("legs is the method chosen"),
            "{}",
            lines[0]
        );
        assert!(disagreement_lines(None, "the default", Basis::Session, &[legs, far]).is_empty());
    }
}
