//! Whether methods agree within the errors they state.
//!
//! Every method estimates the same two numbers from one session, so on a robot the model fits
//! their differences stay within their stated standard errors. On real robots they often do
//! not: `legs` and `jung-chung` read the start transient differently, a compass's deviation
//! moves `jung-chung` and not `matched-legs`, and a session's runs share what changes between
//! sessions. A difference beyond the stated errors means at least one ± is too small for this
//! robot, which a user must be told rather than shown two confident numbers.
//!
//! The test is `|x₁ − x₂| / √(σ₁² + σ₂²)` for each quantity. The two estimates come from the
//! same runs, so their errors are positively correlated and the true standard deviation of the
//! difference is smaller than this: the test flags fewer pairs than a correlated one would, and
//! a flagged pair disagrees at least this much.

use super::{Estimate, Method};
use serde::Serialize;

/// Differences beyond this many combined standard errors are reported.
pub const DISAGREEMENT_SIGMAS: f64 = 3.0;

/// One quantity on which two methods disagree beyond their stated errors.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Disagreement {
    /// The method compared against (the default).
    pub method: Method,
    /// The method that disagrees with it.
    pub other: Method,
    /// `"E_b"` or `"E_d"`.
    pub quantity: &'static str,
    /// `other − method` (ratio, dimensionless).
    pub difference: f64,
    /// `|difference|` in combined standard errors `√(σ₁² + σ₂²)`.
    pub sigmas: f64,
}

/// Every quantity on which an estimate in `others` differs from `reference` by more than
/// [`DISAGREEMENT_SIGMAS`] combined standard errors. Pairs where either side states no
/// standard error are not compared (nothing is claimed, nothing can be contradicted).
pub fn disagreements(reference: &Estimate, others: &[Estimate]) -> Vec<Disagreement> {
    let mut out = Vec::new();
    for o in others.iter().filter(|o| o.method != reference.method) {
        for (quantity, a, sa, b, sb) in [
            (
                "E_b",
                reference.e_b,
                reference.e_b_std_err,
                o.e_b,
                o.e_b_std_err,
            ),
            (
                "E_d",
                reference.e_d,
                reference.e_d_std_err,
                o.e_d,
                o.e_d_std_err,
            ),
        ] {
            let (Some(sa), Some(sb)) = (sa, sb) else {
                continue;
            };
            let combined = sa.hypot(sb);
            if !(combined.is_finite() && combined > 0.0) {
                continue;
            }
            let sigmas = (b - a).abs() / combined;
            if sigmas > DISAGREEMENT_SIGMAS {
                out.push(Disagreement {
                    method: reference.method,
                    other: o.method,
                    quantity,
                    difference: b - a,
                    sigmas,
                });
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::Correction;

    fn est(method: Method, e_b: f64, se_b: Option<f64>) -> Estimate {
        Estimate::of(
            method,
            Correction {
                left_diameter_scale: 1.0,
                right_diameter_scale: 1.0,
                wheelbase_scale: e_b,
            },
            se_b.map(|s| (s, 1e-4)),
            &crate::kinematics::SplitConvention::LeftNominal,
        )
    }

    #[test]
    fn a_difference_beyond_three_combined_errors_is_reported_and_one_within_is_not() {
        let legs = est(Method::Legs, 1.00822, Some(0.00027));
        // 0.0020 apart against √(0.00027² + 0.0005²) = 0.00057: 3.5 σ.
        let far = est(Method::JungChung, 1.01022, Some(0.0005));
        // 0.0010 apart: 1.8 σ.
        let near = est(Method::MatchedLegs, 1.00922, Some(0.0005));
        let unknown = est(Method::Exact, 1.1, None);
        let d = disagreements(&legs, &[legs.clone(), far, near, unknown]);
        assert_eq!(d.len(), 1, "{d:?}");
        assert_eq!((d[0].other, d[0].quantity), (Method::JungChung, "E_b"));
        assert!((d[0].sigmas - 0.002 / 0.00027f64.hypot(0.0005)).abs() < 1e-3);
        assert!(d[0].difference > 0.0);
    }
}
