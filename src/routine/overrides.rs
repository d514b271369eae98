//! Settings that override a routine's configuration, as a command line gives them: what the
//! calibration drives and costs ([`Shape`], which `plan` shares) and the rest of a run
//! ([`Overrides`]). With the `cli` feature they are `calibrate`'s and `run`'s flags (their doc
//! comments are the help); an unset field leaves the configuration as it was.

use super::config::{ConfigError, RoutineConfig, WritePolicy};
use crate::calibration::Method;
use crate::kinematics::SplitConvention;
use std::path::PathBuf;

/// The settings that decide what a calibration drives and costs: `calibrate` and `plan` take
/// them alike (they override a routine file).
#[derive(Debug, Clone, Default, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct Shape {
    /// Squares per direction per round [default: 5].
    #[cfg_attr(feature = "cli", arg(long))]
    pub runs: Option<usize>,
    /// Straight-leg speed limit (m/s, at most 1.0) [default: 0.2].
    #[cfg_attr(feature = "cli", arg(long))]
    pub max_speed_m_s: Option<f64>,
    /// Turn-rate limit (rad/s, at most 3.0) [default: 0.5].
    #[cfg_attr(feature = "cli", arg(long))]
    pub max_rate_rad_s: Option<f64>,
    /// Pause before each heading reading for the base to settle (s) [default: 0.5].
    #[cfg_attr(feature = "cli", arg(long))]
    pub settle_s: Option<f64>,
    /// Heading readings averaged at rest before and after each square [default: 5].
    #[cfg_attr(feature = "cli", arg(long))]
    pub heading_samples: Option<usize>,
    /// Estimator to write: umbmark, lee, heading-only, jung-chung, exact, legs or
    /// matched-legs [default: with the heading along the legs, matched-legs for a compass or
    /// an IMU of unknown kind, legs for a gyro or a reference; else exact].
    #[cfg_attr(feature = "cli", arg(long))]
    pub method: Option<Method>,
    /// Skip the compass swing (two slow full turns in place each way before the squares,
    /// which measure the compass's deviation and remove it from every reading).
    #[cfg_attr(feature = "cli", arg(long))]
    pub no_swing: bool,
    /// Verification squares per direction [default: 3].
    #[cfg_attr(feature = "cli", arg(long))]
    pub verification_runs: Option<usize>,
    /// Most calibration rounds [default: 3].
    #[cfg_attr(feature = "cli", arg(long))]
    pub max_rounds: Option<usize>,
    /// Drive squares in clockwise and counter-clockwise pairs until the written estimate's
    /// stated standard error of E_b is at most this (--runs is then unused); a later round
    /// only when the first wrote, stopping once it confirms (its squares are the verification).
    #[cfg_attr(feature = "cli", arg(long))]
    pub target_eb_std: Option<f64>,
    /// As --target-eb-std, for E_d (both when both are given).
    #[cfg_attr(feature = "cli", arg(long))]
    pub target_ed_std: Option<f64>,
    /// With a target, the most squares per direction a round may drive [default: 20].
    #[cfg_attr(feature = "cli", arg(long))]
    pub max_runs: Option<usize>,
}

impl Shape {
    /// Sets what the flags give.
    pub fn apply(&self, cfg: &mut RoutineConfig) {
        macro_rules! set {
            ($($f:ident => $t:ident),*) => { $(if let Some(v) = self.$f { cfg.$t = v; })* };
        }
        set!(runs => runs_per_direction, max_speed_m_s => max_speed_m_s,
             max_rate_rad_s => max_rate_rad_s, verification_runs => verification_runs,
             max_rounds => max_rounds, settle_s => settle_s,
             heading_samples => heading_samples, max_runs => max_runs_per_direction);
        for (flag, setting) in [
            (self.target_eb_std, &mut cfg.target_e_b_std),
            (self.target_ed_std, &mut cfg.target_e_d_std),
        ] {
            if flag.is_some() {
                *setting = flag;
            }
        }
        if self.method.is_some() {
            cfg.method = self.method;
        }
        cfg.swing &= !self.no_swing;
    }
}

/// Routine settings that can be given as flags (they override a routine file).
#[derive(Debug, Clone, Default, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct Overrides {
    /// Square side (m) [default: 4].
    #[cfg_attr(feature = "cli", arg(long))]
    pub side_m: Option<f64>,
    /// What the calibration drives and costs.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub shape: Shape,
    /// Do not turn back to the first square's heading before each square.
    #[cfg_attr(feature = "cli", arg(long))]
    pub no_realign: bool,
    /// The gyro's scale error as `odocal spin` measured it (0.01: the gyro reads 1 % more
    /// than every turn); removed from every heading before estimating.
    #[cfg_attr(feature = "cli", arg(long, allow_hyphen_values = true))]
    pub gyro_scale_error: Option<f64>,
    /// Diameter split for estimation and write-back: left-nominal, mean-preserving or
    /// measured-scale:COMMANDED_M,MEASURED_M [default: left-nominal].
    #[cfg_attr(feature = "cli", arg(long))]
    pub convention: Option<SplitConvention>,
    /// Straight-line check: commanded distance (m); with --straight-measured-m.
    #[cfg_attr(feature = "cli", arg(long, requires = "straight_measured_m"))]
    pub straight_commanded_m: Option<f64>,
    /// Straight-line check: measured distance (m).
    #[cfg_attr(feature = "cli", arg(long, requires = "straight_commanded_m"))]
    pub straight_measured_m: Option<f64>,
    /// Also stop when |E_b − 1| and |E_d − 1| are below this [default: stop when a round's
    /// correction is not significant (within two standard errors) or would change the heading
    /// by less than 0.1° per square].
    #[cfg_attr(feature = "cli", arg(long))]
    pub tolerance: Option<f64>,
    /// Estimate and report only; write nothing (with --yes: move without asking, still write
    /// nothing).
    #[cfg_attr(feature = "cli", arg(long))]
    pub dry_run: bool,
    /// Answer yes to every question: move, and write unless --dry-run.
    #[cfg_attr(feature = "cli", arg(long))]
    pub yes: bool,
    /// Refuse to write any parameter changed by more than this fraction, at most 0.25 unless
    /// --allow-large-change [default: 0.1; 1.0 with --allow-large-change].
    #[cfg_attr(feature = "cli", arg(long))]
    pub max_change: Option<f64>,
    /// Keep the written parameters even when verification does not show them clearly better
    /// (by default they are restored and odocal exits non-zero).
    #[cfg_attr(feature = "cli", arg(long))]
    pub keep_worse: bool,
    /// Allow changes of up to 100 % (skid-steer robots need wheelbase multipliers of 1.5–1.9);
    /// asks you to type LARGE unless --yes.
    #[cfg_attr(feature = "cli", arg(long))]
    pub allow_large_change: bool,
    /// Where to write the backup of the robot's parameters (and a partial report if the run
    /// stops) [default: this run's report directory; without one, beside a profile or YAML,
    /// else the current directory].
    #[cfg_attr(feature = "cli", arg(long))]
    pub backup_dir: Option<PathBuf>,
    /// Where to write report.json, report.md, report.html and the plots (a new directory
    /// beside an earlier report, never over it) [default: odocal-report on a robot; none on
    /// the simulated one].
    #[cfg_attr(feature = "cli", arg(long))]
    pub report_dir: Option<PathBuf>,
}

impl Overrides {
    /// Sets what these settings give, then checks the whole configuration. `--allow-large-change`
    /// is taken as given: a caller that asks people confirms it first ([`Self::needs_large_confirmation`]).
    pub fn apply(&self, cfg: &mut RoutineConfig) -> Result<(), ConfigError> {
        if let Some(s) = self.side_m {
            cfg.side_m = s;
        }
        self.shape.apply(cfg);
        if let Some(t) = self.tolerance {
            cfg.tolerance = Some(t);
        }
        cfg.keep_worse |= self.keep_worse;
        if let Some(g) = self.gyro_scale_error {
            cfg.gyro_scale_error = Some(g);
        }
        cfg.realign &= !self.no_realign;
        if self.allow_large_change {
            cfg.allow_large_change = true;
            cfg.max_change = self.max_change.unwrap_or(1.0);
        } else if let Some(m) = self.max_change {
            cfg.max_change = m;
        }
        if let Some(c) = self.convention {
            cfg.convention = c;
        }
        if let (Some(commanded_m), Some(measured_m)) =
            (self.straight_commanded_m, self.straight_measured_m)
        {
            cfg.convention = SplitConvention::MeasuredScale {
                commanded_m,
                measured_m,
            };
        }
        if self.dry_run || self.yes {
            cfg.write_back = WritePolicy::of_flags(self.dry_run, self.yes);
        }
        if let Some(d) = &self.report_dir {
            cfg.report_dir = Some(d.clone());
        }
        if let Some(d) = &self.backup_dir {
            cfg.backup_dir = Some(d.clone());
        }
        cfg.validate()
    }

    /// The question to ask (the answer must be `LARGE`) before a run with
    /// `--allow-large-change` and without `--yes`, for a configuration these settings were
    /// applied to.
    pub fn needs_large_confirmation(&self, cfg: &RoutineConfig) -> Option<String> {
        (self.allow_large_change && !self.yes).then(|| {
            format!(
                "--allow-large-change lets odocal write parameters up to {:.0} % away from what \
                 the robot holds now. Type LARGE to allow it:",
                100.0 * cfg.max_change
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_what_is_given_changes_and_the_result_is_checked() {
        let mut cfg = RoutineConfig::default();
        let before = cfg.clone();
        Overrides::default().apply(&mut cfg).unwrap();
        assert_eq!(cfg, before);

        let o = Overrides {
            side_m: Some(2.0),
            shape: Shape {
                runs: Some(7),
                no_swing: true,
                target_eb_std: Some(0.002),
                ..Shape::default()
            },
            straight_commanded_m: Some(2.0),
            straight_measured_m: Some(2.02),
            dry_run: true,
            yes: true,
            ..Overrides::default()
        };
        o.apply(&mut cfg).unwrap();
        assert_eq!((cfg.side_m, cfg.runs_per_direction), (2.0, 7));
        assert!(!cfg.swing && cfg.realign);
        assert_eq!(cfg.target_e_b_std, Some(0.002));
        assert_eq!(
            cfg.write_back,
            WritePolicy::DryRun,
            "a dry run writes nothing, --yes or not"
        );
        assert!(
            matches!(cfg.convention, SplitConvention::MeasuredScale { measured_m, .. } if measured_m == 2.02)
        );
        assert_eq!(o.needs_large_confirmation(&cfg), None);

        let bad = Overrides {
            side_m: Some(-4.0),
            ..Overrides::default()
        };
        assert!(bad.apply(&mut RoutineConfig::default()).is_err());
    }

    #[test]
    fn a_large_change_is_allowed_to_100_percent_and_asks_unless_yes() {
        let mut cfg = RoutineConfig::default();
        let o = Overrides {
            allow_large_change: true,
            ..Overrides::default()
        };
        o.apply(&mut cfg).unwrap();
        assert!(cfg.allow_large_change);
        assert_eq!(cfg.max_change, 1.0);
        let q = o.needs_large_confirmation(&cfg).unwrap();
        assert!(q.contains("100 %") && q.contains("LARGE"), "{q}");
        let yes = Overrides { yes: true, ..o };
        assert_eq!(yes.needs_large_confirmation(&cfg), None);
        assert_eq!(cfg.write_back, RoutineConfig::default().write_back);
        yes.apply(&mut cfg).unwrap();
        assert_eq!(cfg.write_back, WritePolicy::Yes);
    }
}
