//! Pooling one method's estimates from several recordings of one robot.
//!
//! Recordings of one robot may have been made with different parameters configured on its
//! controller (the OptiOdom sets change both the wheelbase and the wheel diameter between
//! recordings), so estimates are pooled in **physical** terms, never as correction factors: each
//! recording's corrected parameters give the two quantities a heading or square test observes,
//! `r = D_R/D_L` and `s = b/D̄` (wheelbase over mean wheel diameter; heading predictions depend on
//! nothing else, and neither depends on the configuration the recording was made with). The
//! absolute scale is not observable from squares; the split convention supplies it again when the
//! pooled robot is expressed against the parameters it will be written to
//! ([`Pooled::estimate_for`]).
//!
//! Weights come from each recording's own run-to-run scatter, on `ln r` and `ln s`, with the
//! standard random-effects model (DerSimonian & Laird 1986): recording `k` measures
//! `y_k = μ + u_k + e_k` with `var e_k = v_k` (its standard error squared) and a
//! recording-to-recording effect `var u_k = τ²` (wheels settle, the floor changes, a tyre wears).
//! `τ²` is estimated by moments, `τ̂² = max(0, (Q − (K−1)) / (Σw − Σw²/Σw))` with `w = 1/v` and
//! `Q = Σw(y − ȳ_w)²`; the pooled value weights by `1/(v_k + τ̂²)`, and its standard error is
//! `(Σ 1/(v_k + τ̂²))^(−1/2)`. A recording without a standard error (one run per direction)
//! borrows the median per-run variance of the others. `v_k` propagates only `E_b`'s error into
//! `s` and `E_d`'s into `r` (their correlation is not kept by [`Estimate`]); `E_d`'s share of `s`
//! is below a tenth of `E_b`'s on every robot we have seen.

use super::{CalibrationError, Estimate, Method};
use crate::kinematics::{SplitConvention, WheelParams};
use serde::{Deserialize, Serialize};

/// One recording's estimate with the parameters configured while it was recorded.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfiguredEstimate<'a> {
    /// A name for reports (set id, bag file).
    pub name: String,
    /// Parameters configured on the controller during the recording.
    pub configured: WheelParams,
    /// The method's estimate from this recording alone.
    pub estimate: &'a Estimate,
    /// Runs per direction (smaller of the two), to borrow a scatter for a recording without one.
    pub runs_per_direction: usize,
}

/// One pooled physical quantity, on a log scale.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PooledLog {
    /// Pooled value (of the logarithm).
    pub mean: f64,
    /// Standard error from run-to-run scatter alone (fixed-effect, `(Σ1/v)^(−1/2)`).
    pub run_to_run_std_err: f64,
    /// Estimated recording-to-recording standard deviation `τ̂` (0 with one recording).
    pub recording_spread: f64,
    /// Standard error of the pooled value counting both (`(Σ1/(v+τ̂²))^(−1/2)`).
    pub std_err: f64,
    /// Standard deviation of the **next** recording's estimate of this robot around the pooled
    /// value: `√(std_err² + τ̂² + ṽ)`, the pooled value's own error, the recording-to-recording
    /// spread and one recording's scatter (`ṽ`, the median of the recordings' variances). What
    /// a user should expect a new session to read (a prediction interval, Higgins, Thompson &
    /// Spiegelhalter 2009, with the new session's own error added). NaN when no recording has a
    /// scatter.
    #[serde(default = "nan")]
    pub prediction_std: f64,
    /// Per-recording values, in input order.
    pub per_recording: Vec<f64>,
    /// Per-recording standard errors used as weights.
    pub per_recording_std_err: Vec<f64>,
}

/// A method's pooled estimate of one robot's geometry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Pooled {
    /// The method pooled.
    pub method: Method,
    /// Recording names, in input order.
    pub recordings: Vec<String>,
    /// `ln(D_R/D_L)`.
    pub ln_ratio: PooledLog,
    /// `ln(b/D̄)`.
    pub ln_wheelbase_over_diameter: PooledLog,
}

/// Which uncertainty a stated ± is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum UncertaintyKind {
    /// Run-to-run scatter of one recording only (recording-to-recording spread unknown).
    RunToRun,
    /// Run-to-run scatter and the recording-to-recording spread of several recordings.
    RunToRunAndRecordingToRecording,
}

fn physical(p: &WheelParams) -> (f64, f64) {
    let mean_d = 0.5 * (p.left_wheel_diameter_m + p.right_wheel_diameter_m);
    (
        (p.right_wheel_diameter_m / p.left_wheel_diameter_m).ln(),
        (p.wheelbase_m / mean_d).ln(),
    )
}

fn nan() -> f64 {
    f64::NAN
}

/// The upper median (the middle value, the larger of the two middle ones for an even count):
/// what a recording without a scatter borrows and what a typical recording's variance is, and
/// the robust centre of the pose fit's residuals (selected in linear time, not sorted).
pub(crate) fn upper_median(mut v: Vec<f64>) -> Option<f64> {
    let mid = v.len() / 2;
    if v.is_empty() {
        return None;
    }
    v.select_nth_unstable_by(mid, f64::total_cmp);
    Some(v[mid])
}

/// DerSimonian–Laird pooling of one scalar (of any scale, despite the name): the values, their
/// standard errors and the runs behind each.
pub(crate) fn pool_log(y: &[f64], se: &[Option<f64>], runs: &[usize]) -> PooledLog {
    // Per-run variance of the recordings that have one, borrowed by those that do not.
    let borrowed = upper_median(
        se.iter()
            .zip(runs)
            .filter_map(|(s, &n)| s.map(|s| s * s * n.max(1) as f64))
            .filter(|v| v.is_finite() && *v > 0.0)
            .collect(),
    );
    // A recording with no scatter at all (exactly repeated runs) must not take every weight:
    // its variance is held at a millionth of the smallest one stated, relative, so that no
    // absolute floor stands in for what the data say (a variance of zero stays zero when every
    // recording has it, and is reported as such).
    let least = se
        .iter()
        .filter_map(|s| s.map(|s| s * s))
        .filter(|v| v.is_finite() && *v > 0.0)
        .fold(f64::INFINITY, f64::min);
    let floor = if least.is_finite() { 1e-6 * least } else { 0.0 };
    if floor == 0.0 && se.iter().all(|s| s.is_some_and(|s| s == 0.0)) {
        return exact(y);
    }
    let v: Vec<f64> = se
        .iter()
        .zip(runs)
        .map(|(s, &n)| match (s, borrowed) {
            (Some(s), _) if s.is_finite() && *s > 0.0 => (s * s).max(floor),
            (_, Some(b)) => (b / n.max(1) as f64).max(floor),
            // Nobody has a scatter: equal weights.
            _ => 1.0,
        })
        .collect();
    let w: Vec<f64> = v.iter().map(|v| 1.0 / v).collect();
    let sw: f64 = w.iter().sum();
    let fixed = w.iter().zip(y).map(|(w, y)| w * y).sum::<f64>() / sw;
    let k = y.len() as f64;
    let q: f64 = w.iter().zip(y).map(|(w, y)| w * (y - fixed).powi(2)).sum();
    let c = sw - w.iter().map(|w| w * w).sum::<f64>() / sw;
    let tau2 = if y.len() > 1 && c > 0.0 {
        ((q - (k - 1.0)) / c).max(0.0)
    } else {
        0.0
    };
    let w_re: Vec<f64> = v.iter().map(|v| 1.0 / (v + tau2)).collect();
    let sw_re: f64 = w_re.iter().sum();
    let mean = w_re.iter().zip(y).map(|(w, y)| w * y).sum::<f64>() / sw_re;
    let no_scatter = borrowed.is_none() && se.iter().all(Option::is_none);
    let std_err = if no_scatter && y.len() < 2 {
        f64::NAN
    } else {
        sw_re.sqrt().recip()
    };
    let typical_v = upper_median(v.clone()).unwrap_or(f64::NAN);
    PooledLog {
        mean,
        run_to_run_std_err: if no_scatter {
            f64::NAN
        } else {
            sw.sqrt().recip()
        },
        recording_spread: tau2.sqrt(),
        std_err,
        prediction_std: if no_scatter {
            f64::NAN
        } else {
            (std_err * std_err + tau2 + typical_v).sqrt()
        },
        per_recording: y.to_vec(),
        per_recording_std_err: v.iter().map(|v| v.sqrt()).collect(),
    }
}

/// Pooling of values that each state no uncertainty at all (every standard error exactly 0):
/// their plain mean, with the spread between them as the only uncertainty (0 for one value, or
/// for values that agree exactly).
fn exact(y: &[f64]) -> PooledLog {
    let k = y.len().max(1) as f64;
    let mean = y.iter().sum::<f64>() / k;
    let spread = if y.len() > 1 {
        (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (k - 1.0)).sqrt()
    } else {
        0.0
    };
    PooledLog {
        mean,
        run_to_run_std_err: 0.0,
        recording_spread: spread,
        std_err: spread / k.sqrt(),
        prediction_std: spread,
        per_recording: y.to_vec(),
        per_recording_std_err: vec![0.0; y.len()],
    }
}

/// Pools one method's estimates from several recordings of one robot.
pub fn pool(recordings: &[ConfiguredEstimate<'_>]) -> Result<Pooled, CalibrationError> {
    let first = recordings.first().ok_or(CalibrationError::Unsupported(
        "pooling needs at least one recording".into(),
    ))?;
    let method = first.estimate.method;
    if let Some(other) = recordings.iter().find(|r| r.estimate.method != method) {
        return Err(CalibrationError::Unsupported(format!(
            "cannot pool {} with {}",
            method, other.estimate.method
        )));
    }
    let (mut ratio, mut wheelbase) = (Vec::new(), Vec::new());
    let (mut ratio_se, mut wheelbase_se, mut runs) = (Vec::new(), Vec::new(), Vec::new());
    for r in recordings {
        let corrected = r.estimate.correction.apply(&r.configured)?;
        let (lr, ls) = physical(&corrected);
        ratio.push(lr);
        wheelbase.push(ls);
        ratio_se.push(r.estimate.e_d_std_err.map(|s| s / r.estimate.e_d));
        wheelbase_se.push(r.estimate.e_b_std_err.map(|s| s / r.estimate.e_b));
        runs.push(r.runs_per_direction);
    }
    Ok(Pooled {
        method,
        recordings: recordings.iter().map(|r| r.name.clone()).collect(),
        ln_ratio: pool_log(&ratio, &ratio_se, &runs),
        ln_wheelbase_over_diameter: pool_log(&wheelbase, &wheelbase_se, &runs),
    })
}

/// One recording's estimates by every method that succeeded on it.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordingEstimates<'a> {
    /// A name for reports.
    pub name: String,
    /// Parameters configured during the recording.
    pub configured: WheelParams,
    /// The estimates (any methods, any order).
    pub estimates: &'a [Estimate],
    /// Runs per direction (smaller of the two).
    pub runs_per_direction: usize,
}

/// Every method pooled over recordings, expressed against one target configuration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PooledMethods {
    /// Per method that every recording estimated, the pooled physical estimate.
    pub pooled: Vec<Pooled>,
    /// The same against the target configuration, in [`Method::ALL`] order.
    pub estimates: Vec<Estimate>,
    /// Methods some recording lacks, with the recordings that lack them.
    pub missing: Vec<(Method, Vec<String>)>,
    /// Which uncertainty the estimates' standard errors are.
    pub uncertainty: UncertaintyKind,
}

/// Pools every method that all `recordings` estimated; the result is expressed against
/// `target` (the parameters it would be written to).
pub fn pool_methods(
    recordings: &[RecordingEstimates<'_>],
    target: &WheelParams,
    convention: SplitConvention,
) -> Result<PooledMethods, CalibrationError> {
    let mut out = PooledMethods {
        pooled: Vec::new(),
        estimates: Vec::new(),
        missing: Vec::new(),
        uncertainty: UncertaintyKind::of(recordings.len()),
    };
    for method in Method::ALL {
        let mut per = Vec::new();
        let mut lacking = Vec::new();
        for r in recordings {
            match r.estimates.iter().find(|e| e.method == method) {
                Some(e) => per.push(ConfiguredEstimate {
                    name: r.name.clone(),
                    configured: r.configured,
                    estimate: e,
                    runs_per_direction: r.runs_per_direction,
                }),
                None => lacking.push(r.name.clone()),
            }
        }
        if per.is_empty() {
            continue;
        }
        if !lacking.is_empty() {
            out.missing.push((method, lacking));
            continue;
        }
        let p = pool(&per)?;
        out.estimates.push(p.estimate_for(target, convention)?);
        out.pooled.push(p);
    }
    Ok(out)
}

impl UncertaintyKind {
    /// What a pool of `recordings` recordings can state.
    pub fn of(recordings: usize) -> Self {
        if recordings > 1 {
            UncertaintyKind::RunToRunAndRecordingToRecording
        } else {
            UncertaintyKind::RunToRun
        }
    }
}

impl Pooled {
    /// Which uncertainty [`Pooled::estimate_for`] states.
    pub fn uncertainty_kind(&self) -> UncertaintyKind {
        UncertaintyKind::of(self.recordings.len())
    }

    /// The standard deviations `(E_b, E_d)` of the next recording's estimate against
    /// `configured` ([`PooledLog::prediction_std`] on the scale of `estimate`, an
    /// [`Pooled::estimate_for`] of the same configuration); `None` where no recording had a
    /// scatter.
    pub fn prediction_std(&self, estimate: &Estimate) -> (Option<f64>, Option<f64>) {
        let finite = |x: f64| x.is_finite().then_some(x);
        (
            finite(self.ln_wheelbase_over_diameter.prediction_std * estimate.e_b),
            finite(self.ln_ratio.prediction_std * estimate.e_d),
        )
    }

    /// The pooled robot as an estimate against `configured` (the parameters it will be written
    /// to), the absolute scale fixed by `convention` as for a single recording. Standard errors
    /// are the pooled ones (run-to-run and recording-to-recording, see the module).
    pub fn estimate_for(
        &self,
        configured: &WheelParams,
        convention: SplitConvention,
    ) -> Result<Estimate, CalibrationError> {
        let r = self.ln_ratio.mean.exp();
        let s = self.ln_wheelbase_over_diameter.mean.exp();
        let e_d = r / configured.e_d();
        // The convention's diameters for this ratio fix the scale; the wheelbase follows from s.
        let diameters = convention
            .split(1.0, e_d, configured.wheelbase_m)?
            .apply(configured)?;
        let mean_d = 0.5 * (diameters.left_wheel_diameter_m + diameters.right_wheel_diameter_m);
        let e_b = s * mean_d / configured.wheelbase_m;
        let correction = convention.split(e_b, e_d, configured.wheelbase_m)?;
        let finite = |x: f64| x.is_finite().then_some(x);
        Ok(Estimate {
            method: self.method,
            e_b: correction.e_b(),
            e_d: correction.e_d(),
            e_b_std_err: finite(self.ln_wheelbase_over_diameter.std_err * e_b),
            e_d_std_err: finite(self.ln_ratio.std_err * e_d),
            e_b_noise_std_err: None,
            e_d_noise_std_err: None,
            correction,
            convention: convention.name().to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::Correction;

    fn estimate(e_b: f64, e_d: f64, se_b: Option<f64>) -> Estimate {
        Estimate {
            method: Method::Legs,
            e_b,
            e_d,
            e_b_std_err: se_b,
            e_d_std_err: se_b.map(|s| s / 10.0),
            e_b_noise_std_err: None,
            e_d_noise_std_err: None,
            correction: Correction {
                left_diameter_scale: 1.0,
                right_diameter_scale: e_d,
                wheelbase_scale: e_b,
            },
            convention: "left-nominal".into(),
        }
    }

    #[test]
    fn recordings_with_other_configurations_pool_to_one_robot() {
        // One robot: D_L 0.0845, D_R 0.0846, b 0.2031. Recorded once configured with
        // D 0.084 / b 0.2 and once with D 0.085 / b 0.205; each recording's exact estimate.
        let robot = WheelParams {
            left_wheel_diameter_m: 0.0845,
            right_wheel_diameter_m: 0.0846,
            wheelbase_m: 0.2031,
            counts_per_wheel_rev: 2796.8,
        };
        let cfg_a = WheelParams::nominal(0.084, 0.2, 2796.8);
        let cfg_b = WheelParams::nominal(0.085, 0.205, 2796.8);
        // Left-nominal: what each recording would estimate (left diameter kept, s preserved).
        let est = |cfg: &WheelParams| {
            let e_d = robot.e_d();
            let mean_d = 0.5 * cfg.left_wheel_diameter_m * (1.0 + e_d);
            let s = robot.wheelbase_m / (0.5 * (0.0845 + 0.0846));
            estimate(s * mean_d / cfg.wheelbase_m, e_d, Some(0.002))
        };
        let (ea, eb) = (est(&cfg_a), est(&cfg_b));
        // Correction factors differ by far more than their errors…
        assert!((ea.e_b - eb.e_b).abs() > 0.01);
        let recs = [
            ConfiguredEstimate {
                name: "a".into(),
                configured: cfg_a,
                estimate: &ea,
                runs_per_direction: 3,
            },
            ConfiguredEstimate {
                name: "b".into(),
                configured: cfg_b,
                estimate: &eb,
                runs_per_direction: 3,
            },
        ];
        let pooled = pool(&recs).unwrap();
        // …the physical robot is the same: no recording-to-recording spread.
        assert!(pooled.ln_wheelbase_over_diameter.recording_spread < 1e-12);
        // Expressed against either configuration, the pooled estimate is that recording's own.
        for (cfg, e) in [(cfg_a, &ea), (cfg_b, &eb)] {
            let back = pooled
                .estimate_for(&cfg, SplitConvention::LeftNominal)
                .unwrap();
            assert!(
                (back.e_b - e.e_b).abs() < 1e-12,
                "{} vs {}",
                back.e_b,
                e.e_b
            );
            assert!((back.e_d - e.e_d).abs() < 1e-12);
        }
        assert_eq!(
            pooled.uncertainty_kind(),
            UncertaintyKind::RunToRunAndRecordingToRecording
        );
    }

    #[test]
    fn disagreeing_recordings_show_a_spread_and_widen_the_error() {
        let cfg = WheelParams::nominal(0.084, 0.2, 2796.8);
        let es = [
            estimate(1.00, 1.0, Some(0.001)),
            estimate(1.02, 1.0, Some(0.001)),
            estimate(1.04, 1.0, Some(0.001)),
        ];
        let recs: Vec<_> = es
            .iter()
            .enumerate()
            .map(|(i, e)| ConfiguredEstimate {
                name: format!("{i}"),
                configured: cfg,
                estimate: e,
                runs_per_direction: 3,
            })
            .collect();
        let p = pool(&recs).unwrap().ln_wheelbase_over_diameter;
        // Recordings 0.02 apart on ln scale ≈ 0.0196: the spread is about their SD, far above
        // the 0.001 each states.
        assert!(
            (p.recording_spread - 0.0196).abs() < 0.002,
            "{}",
            p.recording_spread
        );
        assert!(p.std_err > 5.0 * p.run_to_run_std_err);
        // Equal weights: the pooled value is the middle one.
        assert!((p.mean - (1.02f64 * 0.2 / 0.084).ln()).abs() < 2e-4);
    }

    #[test]
    fn a_recording_without_scatter_borrows_one_and_mixed_methods_are_refused() {
        let cfg = WheelParams::nominal(0.084, 0.2, 2796.8);
        let (a, b) = (estimate(1.00, 1.0, Some(0.004)), estimate(1.01, 1.0, None));
        let recs = [
            ConfiguredEstimate {
                name: "a".into(),
                configured: cfg,
                estimate: &a,
                runs_per_direction: 4,
            },
            ConfiguredEstimate {
                name: "b".into(),
                configured: cfg,
                estimate: &b,
                runs_per_direction: 1,
            },
        ];
        let p = pool(&recs).unwrap().ln_wheelbase_over_diameter;
        // Per-run variance (0.004²·4) over one run: twice a's standard error.
        assert!((p.per_recording_std_err[1] - 0.008).abs() < 1e-4);
        let mut c = estimate(1.0, 1.0, None);
        c.method = Method::Exact;
        let mixed = [
            recs[0].clone(),
            ConfiguredEstimate {
                estimate: &c,
                ..recs[1].clone()
            },
        ];
        assert!(matches!(
            pool(&mixed),
            Err(CalibrationError::Unsupported(_))
        ));
        assert!(pool(&[]).is_err());
    }
}
