//! How an estimate's ± is written wherever a person reads it (the terminal, report.md): one
//! standard error as "± 0.00031", one that rounds to zero at five decimals as "± <0.00001" (not
//! the same as none), the noise-only lower bound of a session with one square per direction as
//! "≥ 0.00012", and "—" where a method states nothing.

use crate::calibration::Estimate;

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

#[cfg(test)]
mod tests {
    use super::*;

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
}
