//! Simulated calibration experiments: drive the square test on a mis-calibrated simulated robot,
//! estimate with every method, write each estimate back, drive the squares again and measure
//! what is left (`E_max,sys`). This is the paper's Sec. 3, and what `odocal simulate` prints.

use crate::calibration::{self, CalibrationError, Estimate, Method, RunMeasurement, SquareTest};
use crate::kinematics::{KinematicsError, SplitConvention, WheelParams};
use crate::sim::{NoiseModel, SimError, Simulator, SquareRun};
use serde::Serialize;

/// Errors of a simulated study.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StudyError {
    /// The simulator refused its configuration.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// The truth or a written-back parameter set is impossible.
    #[error(transparent)]
    Kinematics(#[from] KinematicsError),
    /// The measurements could not be calibrated at all.
    #[error(transparent)]
    Calibration(#[from] CalibrationError),
    /// A setting outside what the study can take (the flag and its range are named).
    #[error("{0}")]
    OutOfRange(String),
    /// Zero runs or trials were asked for.
    #[error("{0} must be at least 1")]
    Count(&'static str),
}

/// What to simulate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StudyConfig {
    /// Parameters configured on the controller before calibration (the paper's nominal ones).
    pub nominal: WheelParams,
    /// True `E_b` of the robot relative to `nominal`.
    pub true_e_b: f64,
    /// True `E_d` of the robot relative to `nominal`.
    pub true_e_d: f64,
    /// How the true `E_d` is split into two true diameters.
    pub truth_split: SplitConvention,
    /// Square side for every method but Lee's (m).
    pub side_m: f64,
    /// Square side of Lee's own track (m); the paper uses 2 m.
    pub lee_side_m: f64,
    /// Runs per direction, for calibration and for verification.
    pub runs: usize,
    /// Convention for estimation and write-back.
    pub convention: SplitConvention,
    /// Sensor and wheel noise.
    pub noise: NoiseModel,
}

/// The study as a user sets it (with the `cli` feature, `odocal simulate`'s flags, their doc
/// comments the help).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct StudySettings {
    /// True E_b of the simulated robot.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.976))]
    pub true_eb: f64,
    /// True E_d of the simulated robot.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.992))]
    pub true_ed: f64,
    /// Square side (m).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 4.0))]
    pub side_m: f64,
    /// Square side of Lee's own track (m).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 2.0))]
    pub lee_side_m: f64,
    /// Nominal (configured) wheelbase (m).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.39))]
    pub wheelbase_m: f64,
    /// Nominal (configured) wheel diameter (m).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.15))]
    pub wheel_diameter_m: f64,
    /// Encoder counts per wheel revolution.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 10_000.0))]
    pub counts_per_rev: f64,
    /// How the true E_d splits into two true diameters.
    #[cfg_attr(feature = "cli", arg(long, default_value = "left-nominal"))]
    pub truth_split: SplitConvention,
    /// The split for estimation and write-back.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub convention: crate::calibration::convention::ConventionChoice,
    /// Runs per direction (calibration and verification).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1))]
    pub runs: usize,
    /// The simulated compass's noise per reading (deg; σ; 0 reproduces the paper's noise-free
    /// tables).
    #[cfg_attr(feature = "cli", arg(long = "heading-sigma-deg", alias = "compass-sigma-deg", default_value_t = crate::sim::sensor::SIM_HEADING_SIGMA_DEG))]
    pub compass_sigma_deg: f64,
    /// Constant compass bias (deg).
    #[cfg_attr(
        feature = "cli",
        arg(long, default_value_t = 0.0, allow_hyphen_values = true)
    )]
    pub compass_bias_deg: f64,
    /// Relative wheel slip per motion (standard deviation, e.g. 0.001).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.0))]
    pub slip_sigma: f64,
    /// Noise of each measured final-position axis (m), seen by UMBmark and Lee.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.0))]
    pub position_sigma_m: f64,
    /// Round wheel targets to whole encoder counts.
    #[cfg_attr(feature = "cli", arg(long))]
    pub quantise: bool,
    /// Seed of the first trial (trial k uses seed + k).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1))]
    pub seed: u64,
    /// Independent trials to average.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1))]
    pub trials: usize,
}

impl StudySettings {
    /// Every setting in its range, before anything is simulated (memory and time grow with
    /// runs × trials).
    pub fn check(&self) -> Result<(), StudyError> {
        crate::ranges::check_ranges(&[
            ("--runs", self.runs as f64, 1.0, 1000.0),
            ("--trials", self.trials as f64, 1.0, 100_000.0),
            ("--side-m", self.side_m, 0.01, 100.0),
            ("--lee-side-m", self.lee_side_m, 0.01, 100.0),
            ("--wheelbase-m", self.wheelbase_m, 0.01, 10.0),
            ("--wheel-diameter-m", self.wheel_diameter_m, 0.001, 5.0),
            ("--counts-per-rev", self.counts_per_rev, 1.0, 1e9),
            ("--true-eb", self.true_eb, 0.2, 5.0),
            ("--true-ed", self.true_ed, 0.5, 2.0),
            ("--heading-sigma-deg", self.compass_sigma_deg, 0.0, 45.0),
            ("--compass-bias-deg", self.compass_bias_deg, -180.0, 180.0),
            ("--slip-sigma", self.slip_sigma, 0.0, 0.5),
            ("--position-sigma-m", self.position_sigma_m, 0.0, 10.0),
        ])
        .map_err(StudyError::OutOfRange)
    }

    /// The robot as configured (`counts_per_rev` counts per wheel turn) and as it truly is.
    pub fn robot(&self, counts_per_rev: f64) -> Result<(WheelParams, WheelParams), StudyError> {
        let nominal = WheelParams::nominal(self.wheel_diameter_m, self.wheelbase_m, counts_per_rev);
        let truth =
            WheelParams::from_ratios(&nominal, self.true_eb, self.true_ed, &self.truth_split)?;
        Ok((nominal, truth))
    }

    /// The compass's and the wheels' noise.
    pub fn noise(&self) -> NoiseModel {
        NoiseModel {
            compass_sigma_rad: self.compass_sigma_deg.to_radians(),
            compass_bias_rad: self.compass_bias_deg.to_radians(),
            quantise_encoders: self.quantise,
            wheel_slip_sigma: self.slip_sigma,
            position_sigma_m: self.position_sigma_m,
        }
    }

    /// The study these settings describe.
    pub fn config(&self) -> StudyConfig {
        StudyConfig {
            nominal: WheelParams::nominal(
                self.wheel_diameter_m,
                self.wheelbase_m,
                self.counts_per_rev,
            ),
            true_e_b: self.true_eb,
            true_e_d: self.true_ed,
            truth_split: self.truth_split,
            side_m: self.side_m,
            lee_side_m: self.lee_side_m,
            runs: self.runs,
            convention: self.convention.convention(),
            noise: self.noise(),
        }
    }
}

impl StudyConfig {
    /// The paper's Sec. 3 setup: `D = 0.150 m`, `b = 0.390 m`, 4 m square (Lee 2 m), truth split
    /// left-nominal, write-back left-nominal, one noise-free run each way.
    pub fn paper(true_e_b: f64, true_e_d: f64) -> Self {
        StudyConfig {
            nominal: WheelParams::nominal(0.150, 0.390, 10_000.0),
            true_e_b,
            true_e_d,
            truth_split: SplitConvention::LeftNominal,
            side_m: 4.0,
            lee_side_m: 2.0,
            runs: 1,
            convention: SplitConvention::LeftNominal,
            noise: NoiseModel::default(),
        }
    }

    /// The true robot's parameters.
    pub fn truth(&self) -> Result<WheelParams, KinematicsError> {
        WheelParams::from_ratios(
            &self.nominal,
            self.true_e_b,
            self.true_e_d,
            &self.truth_split,
        )
    }
}

/// A square test built from simulated runs: measured headings and measured final positions.
pub fn square_test(
    side_m: f64,
    wheelbase_m: f64,
    cw: &[SquareRun],
    ccw: &[SquareRun],
) -> SquareTest {
    let measure = |runs: &[SquareRun]| {
        runs.iter()
            .map(|r| RunMeasurement {
                heading_error_rad: r.measured_heading_error_rad,
                final_xy_m: Some(r.measured_final_xy_m),
                ..RunMeasurement::default()
            })
            .collect()
    };
    SquareTest {
        side_m,
        wheelbase_m,
        cw: measure(cw),
        ccw: measure(ccw),
    }
}

/// `E_max,sys` of simulated runs, from their true end points (see [`calibration::e_max_sys`]).
pub fn e_max_sys(cw: &[SquareRun], ccw: &[SquareRun]) -> f64 {
    let ends = |runs: &[SquareRun]| -> Vec<[f64; 2]> {
        runs.iter()
            .map(|r| [r.final_pose.x_m, r.final_pose.y_m])
            .collect()
    };
    calibration::e_max_sys(&ends(cw), &ends(ccw)).unwrap_or(0.0)
}

/// The calibration tests of one trial: the main track and Lee's track.
#[derive(Debug, Clone)]
pub struct SimulatedTests {
    /// The simulator after the tests (its RNG has moved on).
    pub sim: Simulator,
    /// Test on the main track.
    pub main: SquareTest,
    /// Test on Lee's track.
    pub lee: SquareTest,
    /// `E_max,sys` of the main-track runs before calibration (m).
    pub e_max_sys_before_m: f64,
}

/// Drives the calibration squares of one trial.
pub fn simulate_tests(cfg: &StudyConfig, seed: u64) -> Result<SimulatedTests, StudyError> {
    if cfg.runs == 0 {
        return Err(StudyError::Count("runs"));
    }
    let mut sim = Simulator::new(cfg.truth()?, cfg.nominal, cfg.noise, seed)?;
    let b = cfg.nominal.wheelbase_m;
    let (cw, ccw) = sim.run_square_test(cfg.side_m, cfg.runs)?;
    let (lee_cw, lee_ccw) = sim.run_square_test(cfg.lee_side_m, cfg.runs)?;
    Ok(SimulatedTests {
        e_max_sys_before_m: e_max_sys(&cw, &ccw),
        main: square_test(cfg.side_m, b, &cw, &ccw),
        lee: square_test(cfg.lee_side_m, b, &lee_cw, &lee_ccw),
        sim,
    })
}

/// Estimates with one method on the test that method runs on (Lee's own track for Lee).
pub fn estimate_method(
    method: Method,
    tests: &SimulatedTests,
    convention: SplitConvention,
) -> Result<Estimate, CalibrationError> {
    let test = if method == Method::Lee {
        &tests.lee
    } else {
        &tests.main
    };
    calibration::estimate(method, test, convention)
}

/// One method's result in a study.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MethodOutcome {
    /// The estimate.
    pub estimate: Estimate,
    /// `|E_b,est − E_b,true|·100` (percentage points, as the paper's "Error (%)").
    pub e_b_error_pp: f64,
    /// `|E_d,est − E_d,true|·100` (percentage points).
    pub e_d_error_pp: f64,
    /// Parameters written back to the controller.
    pub written: WheelParams,
    /// `E_max,sys` of the verification squares after write-back (m).
    pub e_max_sys_m: f64,
    /// Mean |final heading error| of the verification squares (rad).
    pub mean_abs_heading_error_after_rad: f64,
}

/// A whole study: every method calibrated, written back and verified.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StudyOutcome {
    /// True parameters of the simulated robot.
    pub truth: WheelParams,
    /// `E_max,sys` before calibration (m).
    pub e_max_sys_before_m: f64,
    /// One entry per method that produced an estimate.
    pub outcomes: Vec<MethodOutcome>,
    /// Methods that failed, with the reason.
    pub failures: Vec<(Method, String)>,
}

/// Runs one trial: calibrate, write back with `cfg.convention`, verify on the main track.
///
/// Every method's verification starts from the same simulator state, so all see the same noise.
pub fn run_study(cfg: &StudyConfig, seed: u64) -> Result<StudyOutcome, StudyError> {
    let tests = simulate_tests(cfg, seed)?;
    let truth = *tests.sim.truth();
    let true_e_b = truth.e_b_relative_to(cfg.nominal.wheelbase_m);
    let true_e_d = truth.e_d() / cfg.nominal.e_d();
    let mut outcomes = Vec::new();
    let mut failures = Vec::new();
    // Simulated studies record the heading at rest, not along the legs.
    for method in Method::ALL.into_iter().filter(|m| !m.needs_leg_headings()) {
        let estimate = match estimate_method(method, &tests, cfg.convention) {
            Ok(e) => e,
            Err(e) => {
                failures.push((method, e.to_string()));
                continue;
            }
        };
        let written = estimate.correction.apply(&cfg.nominal)?;
        let mut verify = tests.sim.clone();
        verify.set_configured(written)?;
        let (cw, ccw) = verify.run_square_test(cfg.side_m, cfg.runs)?;
        let all = cw.iter().chain(ccw.iter());
        let mean_abs_heading =
            all.map(|r| r.true_heading_error_rad.abs()).sum::<f64>() / (2 * cfg.runs) as f64;
        outcomes.push(MethodOutcome {
            e_b_error_pp: (estimate.e_b - true_e_b).abs() * 100.0,
            e_d_error_pp: (estimate.e_d - true_e_d).abs() * 100.0,
            written,
            e_max_sys_m: e_max_sys(&cw, &ccw),
            mean_abs_heading_error_after_rad: mean_abs_heading,
            estimate,
        });
    }
    Ok(StudyOutcome {
        truth,
        e_max_sys_before_m: tests.e_max_sys_before_m,
        outcomes,
        failures,
    })
}

/// One method's results averaged over trials.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MethodSummary {
    /// Method name (stable JSON key).
    pub method: Method,
    /// Trials that produced an estimate.
    pub trials: usize,
    /// Mean `E_b` estimate.
    pub e_b: f64,
    /// Mean `E_d` estimate.
    pub e_d: f64,
    /// Mean standard error of `E_b` from run scatter, when available.
    pub e_b_std_err: Option<f64>,
    /// Mean standard error of `E_d` from run scatter, when available.
    pub e_d_std_err: Option<f64>,
    /// Mean `|E_b error|` (percentage points).
    pub e_b_error_pp: f64,
    /// Mean `|E_d error|` (percentage points).
    pub e_d_error_pp: f64,
    /// Mean `E_max,sys` after write-back (m).
    pub e_max_sys_m: f64,
}

/// Runs `trials` studies with seeds `seed, seed+1, …` and averages each method's results.
pub fn run_trials(
    cfg: &StudyConfig,
    seed: u64,
    trials: usize,
) -> Result<(Vec<StudyOutcome>, Vec<MethodSummary>), StudyError> {
    if trials == 0 {
        return Err(StudyError::Count("trials"));
    }
    let studies = (0..trials as u64)
        .map(|k| run_study(cfg, seed.wrapping_add(k)))
        .collect::<Result<Vec<_>, _>>()?;
    let summaries = Method::ALL
        .into_iter()
        .filter_map(|method| {
            let outs: Vec<&MethodOutcome> = studies
                .iter()
                .flat_map(|s| s.outcomes.iter())
                .filter(|o| o.estimate.method == method)
                .collect();
            if outs.is_empty() {
                return None;
            }
            let n = outs.len() as f64;
            let mean =
                |f: &dyn Fn(&MethodOutcome) -> f64| outs.iter().map(|o| f(o)).sum::<f64>() / n;
            let mean_opt = |f: &dyn Fn(&MethodOutcome) -> Option<f64>| {
                outs.iter()
                    .map(|o| f(o))
                    .sum::<Option<f64>>()
                    .map(|s| s / n)
            };
            Some(MethodSummary {
                method,
                trials: outs.len(),
                e_b: mean(&|o| o.estimate.e_b),
                e_d: mean(&|o| o.estimate.e_d),
                e_b_std_err: mean_opt(&|o| o.estimate.e_b_std_err),
                e_d_std_err: mean_opt(&|o| o.estimate.e_d_std_err),
                e_b_error_pp: mean(&|o| o.e_b_error_pp),
                e_d_error_pp: mean(&|o| o.e_d_error_pp),
                e_max_sys_m: mean(&|o| o.e_max_sys_m),
            })
        })
        .collect();
    Ok((studies, summaries))
}

/// One method's spread over many seeded trials, beside the Cramér–Rao bound.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AccuracyRow {
    /// Method.
    pub method: Method,
    /// Runs per direction in each trial.
    pub runs: usize,
    /// Trials that produced an estimate.
    pub trials: usize,
    /// Mean `E_b` estimate minus the truth.
    pub e_b_bias: f64,
    /// Standard deviation of the `E_b` estimates.
    pub e_b_std: f64,
    /// Mean `E_d` estimate minus the truth.
    pub e_d_bias: f64,
    /// Standard deviation of the `E_d` estimates.
    pub e_d_std: f64,
    /// Cramér–Rao bound on the standard deviation of `E_b` (heading noise only).
    pub e_b_crb_std: f64,
    /// Cramér–Rao bound on the standard deviation of `E_d`.
    pub e_d_crb_std: f64,
}

/// Monte-Carlo accuracy of every method: `trials` seeded calibrations of `cfg`, each method's
/// bias and standard deviation, and the Cramér–Rao bound for the configured compass noise (one
/// reading at rest before and after each run).
pub fn accuracy_study(
    cfg: &StudyConfig,
    trials: usize,
    seed: u64,
) -> Result<Vec<AccuracyRow>, StudyError> {
    use crate::calibration::uncertainty::{cramer_rao_bound, heading_error_sigma, TestDesign};
    if trials < 2 {
        return Err(StudyError::Count("trials (at least 2 for a spread)"));
    }
    let truth = cfg.truth()?;
    let true_e_b = truth.e_b_relative_to(cfg.nominal.wheelbase_m);
    let true_e_d = truth.e_d() / cfg.nominal.e_d();
    let mut samples: Vec<Vec<(f64, f64)>> = vec![Vec::new(); Method::ALL.len()];
    for k in 0..trials as u64 {
        let tests = simulate_tests(cfg, seed.wrapping_add(k))?;
        for (i, method) in Method::ALL.into_iter().enumerate() {
            if let Ok(e) = estimate_method(method, &tests, cfg.convention) {
                samples[i].push((e.e_b, e.e_d));
            }
        }
    }
    let design = TestDesign {
        side_m: cfg.side_m,
        wheelbase_m: cfg.nominal.wheelbase_m,
        runs_cw: cfg.runs,
        runs_ccw: cfg.runs,
        heading_error_sigma_rad: heading_error_sigma(cfg.noise.compass_sigma_rad, 1),
    };
    let crb = cramer_rao_bound(true_e_b, true_e_d, cfg.convention, &design)?;
    let stats = |v: &[f64], truth: f64| {
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
        (mean - truth, var.sqrt())
    };
    Ok(Method::ALL
        .into_iter()
        .zip(samples)
        .filter(|(_, s)| s.len() >= 2)
        .map(|(method, s)| {
            let e_b: Vec<f64> = s.iter().map(|p| p.0).collect();
            let e_d: Vec<f64> = s.iter().map(|p| p.1).collect();
            let (e_b_bias, e_b_std) = stats(&e_b, true_e_b);
            let (e_d_bias, e_d_std) = stats(&e_d, true_e_d);
            AccuracyRow {
                method,
                runs: cfg.runs,
                trials: s.len(),
                e_b_bias,
                e_b_std,
                e_d_bias,
                e_d_std,
                e_b_crb_std: crb[(0, 0)].sqrt(),
                e_d_crb_std: crb[(1, 1)].sqrt(),
            }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn paper_settings() -> StudySettings {
        StudySettings {
            true_eb: 0.976,
            true_ed: 0.992,
            side_m: 4.0,
            lee_side_m: 2.0,
            wheelbase_m: 0.39,
            wheel_diameter_m: 0.15,
            counts_per_rev: 10_000.0,
            truth_split: SplitConvention::LeftNominal,
            convention: Default::default(),
            runs: 1,
            compass_sigma_deg: 0.0,
            compass_bias_deg: 0.0,
            slip_sigma: 0.0,
            position_sigma_m: 0.0,
            quantise: false,
            seed: 1,
            trials: 1,
        }
    }

    #[test]
    fn settings_describe_the_papers_study_and_refuse_what_would_not_fit() {
        let s = paper_settings();
        s.check().unwrap();
        assert_eq!(s.config(), StudyConfig::paper(0.976, 0.992));
        let (nominal, truth) = s.robot(1.0).unwrap();
        assert!((truth.wheelbase_m / nominal.wheelbase_m - 0.976).abs() < 1e-12);
        let too_many = StudySettings {
            trials: 1_000_000,
            ..paper_settings()
        };
        assert!(
            matches!(too_many.check(), Err(StudyError::OutOfRange(m)) if m.contains("--trials"))
        );
    }

    #[test]
    fn zero_runs_or_trials_are_refused() {
        let mut cfg = StudyConfig::paper(0.976, 0.992);
        assert!(matches!(
            run_trials(&cfg, 0, 0),
            Err(StudyError::Count("trials"))
        ));
        assert!(matches!(
            accuracy_study(&cfg, 1, 0),
            Err(StudyError::Count(_))
        ));
        cfg.runs = 0;
        assert!(matches!(run_study(&cfg, 0), Err(StudyError::Count("runs"))));
        cfg.runs = 1;
        cfg.true_e_b = -1.0;
        assert!(matches!(run_study(&cfg, 0), Err(StudyError::Kinematics(_))));
    }
}
