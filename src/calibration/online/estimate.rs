//! What the filter says: the estimate in the parameters a user sets (both diameters and the
//! wheelbase, with the scale's source), how far the parameters in use are off, whether the path
//! so far observed each parameter (excitation) and the innovation gate's counts.

use super::*;

impl OnlineEstimator {
    /// The parameters' estimate and uncertainty.
    pub fn estimate(&self, scale: ScaleSource) -> Result<OnlineEstimate, CalibrationError> {
        self.estimate_with(scale, &self.p)
    }

    /// Which parameters the path so far observed (see the module).
    pub fn excitation(&self, scale: ScaleSource) -> Result<Excitation, CalibrationError> {
        let post = self.estimate_with(scale, &self.p)?;
        let prior = self.estimate_with(scale, &self.prior)?;
        let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { 0.0 };
        let (rb, rd) = (
            ratio(post.e_b_std, prior.e_b_std),
            ratio(post.e_d_std, prior.e_d_std),
        );
        Ok(Excitation {
            e_b: Observed::from_ratio(rb),
            e_d: Observed::from_ratio(rd),
            e_b_ratio: rb,
            e_d_ratio: rd,
        })
    }

    pub(super) fn estimate_with(
        &self,
        scale: ScaleSource,
        cov: &Matrix,
    ) -> Result<OnlineEstimate, CalibrationError> {
        let (ul, ur, k) = (self.x[UL], self.x[UR], self.x[K]);
        if !(ul > 0.0 && ur > 0.0 && k > 0.0) {
            return Err(CalibrationError::Unsupported(format!(
                "filter state is not a robot (u_L {ul}, u_R {ur}, k {k})"
            )));
        }
        let e_d = ur / ul;
        // (E_b as a function of u_L, u_R, k) and its gradient.
        let (e_b, grad_b, correction) = match scale {
            ScaleSource::Convention(SplitConvention::MeanPreserving) => {
                let g = 0.5 * (ul + ur);
                let e_b = 1.0 / g;
                (
                    e_b,
                    [-0.5 / (g * g), -0.5 / (g * g), 0.0],
                    SplitConvention::MeanPreserving.split(
                        e_b,
                        e_d,
                        self.cfg.configured.wheelbase_m,
                    )?,
                )
            }
            ScaleSource::Convention(conv) => {
                let e_b = 1.0 / ul;
                (
                    e_b,
                    [-1.0 / (ul * ul), 0.0, 0.0],
                    conv.split(e_b, e_d, self.cfg.configured.wheelbase_m)?,
                )
            }
            ScaleSource::Filter => (
                k,
                [0.0, 0.0, 1.0],
                Correction {
                    left_diameter_scale: k * ul,
                    right_diameter_scale: k * ur,
                    wheelbase_scale: k,
                },
            ),
        };
        let grad_d = [-ur / (ul * ul), 1.0 / ul, 0.0];
        let idx = [UL, UR, K];
        let var = |g: [f64; 3]| {
            let mut v = 0.0;
            for a in 0..3 {
                for b in 0..3 {
                    v += g[a] * cov[(idx[a], idx[b])] * g[b];
                }
            }
            v.max(0.0)
        };
        let correction_std = matches!(scale, ScaleSource::Filter).then(|| {
            [
                var([k, 0.0, ul]).sqrt(),
                var([0.0, k, ur]).sqrt(),
                var([0.0, 0.0, 1.0]).sqrt(),
            ]
        });
        Ok(OnlineEstimate {
            method: "online",
            e_b,
            e_d,
            e_b_std: var(grad_b).sqrt(),
            e_d_std: var(grad_d).sqrt(),
            correction,
            correction_std,
            distance_m: self.distance_m,
        })
    }
}

/// How well the path observed one parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Observed {
    /// Posterior standard deviation below a fifth of the prior's.
    Yes,
    /// Between a fifth and 60 % of the prior's: the estimate leans on the prior.
    Weakly,
    /// Above 60 %: the path did not excite it; the value is the prior's.
    No,
}

impl std::fmt::Display for Observed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Observed::Yes => "observed",
            Observed::Weakly => "weakly observed",
            Observed::No => "not observed",
        })
    }
}

impl Observed {
    pub(super) fn from_ratio(r: f64) -> Self {
        if r < 0.2 {
            Observed::Yes
        } else if r < 0.6 {
            Observed::Weakly
        } else {
            Observed::No
        }
    }
}

/// The excitation verdict: posterior over prior standard deviation per parameter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Excitation {
    /// Verdict on `E_b` (observed by turning).
    pub e_b: Observed,
    /// Verdict on `E_d` (observed by driving straight or along curves).
    pub e_d: Observed,
    /// Posterior/prior standard deviation of `E_b`.
    pub e_b_ratio: f64,
    /// Posterior/prior standard deviation of `E_d`.
    pub e_d_ratio: f64,
}

impl Excitation {
    /// What the user should drive to observe what is not yet observed, if anything.
    pub fn advice(&self) -> Option<&'static str> {
        match (self.e_b, self.e_d) {
            (Observed::Yes, Observed::Yes) => None,
            (Observed::Yes, _) => Some("E_d is not observed: drive straight stretches (a metre or more) while the heading is read"),
            (_, Observed::Yes) => Some("E_b is not observed: turn (in place or tightly), both ways, while the heading is read"),
            _ => Some("neither parameter is observed: drive straight stretches and turns both ways while the heading is read"),
        }
    }
}

/// Counts of the gate (heading readings, or pose fixes when a pose reference is used).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct GateStats {
    /// Readings used.
    pub accepted: u64,
    /// Readings rejected by the gate.
    pub rejected: u64,
    /// Times the heading was re-anchored after `gate_recover_after` rejections in a row.
    pub resets: u64,
}

/// Where the absolute wheel scale comes from when turning the state into parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum ScaleSource {
    /// A split convention (heading-only operation).
    Convention(SplitConvention),
    /// The filter's own scale `k` (meaningful with position fixes).
    Filter,
}

/// The filter's current answer.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct OnlineEstimate {
    /// Always "online".
    pub method: &'static str,
    /// `E_b` under the chosen scale source.
    pub e_b: f64,
    /// `E_d = u_R / u_L`.
    pub e_d: f64,
    /// Standard deviation of `e_b`.
    pub e_b_std: f64,
    /// Standard deviation of `e_d`.
    pub e_d_std: f64,
    /// Factors to apply to the configured parameters.
    pub correction: Correction,
    /// Standard deviations of the factors (left diameter, right diameter, wheelbase) when the
    /// filter observes the absolute scale ([`ScaleSource::Filter`]: pose or position fixes).
    pub correction_std: Option<[f64; 3]>,
    /// Distance driven so far (m, by odometry).
    pub distance_m: f64,
}

/// A parameter's estimate beside the value in use ([`OnlineEstimate::against`]); a drift
/// when they differ by more than the uncertainty allows ([`OnlineEstimate::drift`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Drift {
    /// The parameter (with its unit).
    pub parameter: &'static str,
    /// The value in use (the controller's).
    pub in_use: f64,
    /// The value the drive says.
    pub estimate: f64,
    /// One standard deviation of the estimate.
    pub std: f64,
    /// `(estimate − in_use) / std`.
    pub sigmas: f64,
}

impl OnlineEstimate {
    /// The parameters in use (`configured`) that are off by more than `sigmas` standard
    /// deviations of this estimate ([`OnlineEstimate::against`]).
    pub fn drift(&self, configured: &WheelParams, sigmas: f64) -> Vec<Drift> {
        self.against(configured)
            .into_iter()
            .filter(|d| d.sigmas.abs() > sigmas)
            .collect()
    }

    /// Each parameter's estimate beside its value in use (`configured`): both diameters and
    /// the wheelbase in metres when the scale is observed, else `E_d` and `E_b` (1 in use);
    /// those without a finite positive standard deviation left out.
    pub fn against(&self, configured: &WheelParams) -> Vec<Drift> {
        let c = &self.correction;
        let rows: Vec<(&'static str, f64, f64, f64)> = match self.correction_std {
            Some([sl, sr, sb]) => vec![
                (
                    "left_wheel_diameter_m",
                    configured.left_wheel_diameter_m,
                    c.left_diameter_scale,
                    sl,
                ),
                (
                    "right_wheel_diameter_m",
                    configured.right_wheel_diameter_m,
                    c.right_diameter_scale,
                    sr,
                ),
                ("wheelbase_m", configured.wheelbase_m, c.wheelbase_scale, sb),
            ]
            .into_iter()
            .map(|(name, v, f, sf)| (name, v, v * f, v * sf))
            .collect(),
            None => vec![
                ("E_d", 1.0, self.e_d, self.e_d_std),
                ("E_b", 1.0, self.e_b, self.e_b_std),
            ],
        };
        rows.into_iter()
            .filter(|(_, _, _, std)| *std > 0.0 && std.is_finite())
            .map(|(parameter, in_use, estimate, std)| Drift {
                parameter,
                in_use,
                estimate,
                std,
                sigmas: (estimate - in_use) / std,
            })
            .collect()
    }
}
