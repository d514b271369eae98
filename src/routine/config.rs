//! The routine's settings: defaults, validation, and the TOML routine file.

use crate::calibration::plan::Target;
use crate::calibration::Method;
use crate::kinematics::SplitConvention;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Fastest straight-leg speed any routine may command (m/s), whatever its file says.
pub const HARD_SPEED_LIMIT_M_S: f64 = 1.0;
/// Fastest turn rate any routine may command (rad/s).
pub const HARD_RATE_LIMIT_RAD_S: f64 = 3.0;

/// What to do with the estimated parameters (the write service's policy).
pub use crate::base::write::WritePolicy;

/// Everything the recalibration routine needs to know: the procedure only. Where the robot is
/// comes from elsewhere (a routine file's `[robot]` table, the command line: see
/// [`crate::spec`]); the routine sees nothing but a [`crate::base::Base`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RoutineConfig {
    /// Square side (m).
    pub side_m: f64,
    /// Squares per direction in each calibration round.
    pub runs_per_direction: usize,
    /// Straight-leg speed limit (m/s).
    pub max_speed_m_s: f64,
    /// Turn-rate limit (rad/s).
    pub max_rate_rad_s: f64,
    /// Heading readings averaged at rest before and after each square.
    pub heading_samples: usize,
    /// Pause for the base to settle before heading readings (s).
    pub settle_s: f64,
    /// **Moves the robot**: before each square, turn in place back to the heading the first
    /// square started at, so every square's legs point the same four ways (what lets
    /// `matched-legs` cancel a compass's deviation).
    pub realign: bool,
    /// **Moves the robot**: before the first square, turn in place two full turns each way,
    /// slowly, to measure the compass's deviation curve and remove it from every reading
    /// after ([`crate::calibration::swing`]); only for a heading that may deviate (magnetic
    /// or unknown) and a base that streams both wheels and heading.
    pub swing: bool,
    /// A gyro heading's measured scale error (`odocal spin`): the gyro reads `1 + s` times every
    /// turn, and each heading change is divided by it before anything uses it
    /// ([`crate::calibration::gyro`]). Without it, `E_b` carries the scale error one to one.
    pub gyro_scale_error: Option<f64>,
    /// Estimator whose result is written; `None`: chosen by the data and the heading sensor
    /// ([`crate::calibration::default_method`]).
    pub method: Option<Method>,
    /// Diameter split for estimation and write-back (see [`SplitConvention`]).
    pub convention: SplitConvention,
    /// Write-back policy.
    pub write_back: WritePolicy,
    /// Ask before the robot first moves (off only for the simulated robot).
    pub confirm_motion: bool,
    /// Squares per direction in the verification after writing.
    pub verification_runs: usize,
    /// Also converged when |E_b − 1| and |E_d − 1| are both below this (a user's choice;
    /// without it, a round converges when its correction is not significant or too small to
    /// see: [`crate::routine::convergence`]).
    pub tolerance: Option<f64>,
    /// Most calibration rounds.
    pub max_rounds: usize,
    /// Drive each round's squares in clockwise and counter-clockwise pairs until the written
    /// estimate's stated standard error of `E_b` is at most this (`runs_per_direction` is then
    /// unused); see [`crate::routine::planning`].
    pub target_e_b_std: Option<f64>,
    /// As `target_e_b_std`, for `E_d` (both when both are given).
    pub target_e_d_std: Option<f64>,
    /// With a target, the most squares per direction a round may drive.
    pub max_runs_per_direction: usize,
    /// Refuse to write any parameter changed by more than this fraction from the backup.
    pub max_change: f64,
    /// Allow `max_change` beyond 25 % (up to 100 %): skid-steer robots need wheelbase
    /// multipliers of 1.5–1.9.
    pub allow_large_change: bool,
    /// Keep written parameters even when the verification does not show them clearly better
    /// (normally they are restored and the routine fails; see `routine::judge`).
    pub keep_worse: bool,
    /// Device watchdog timeout (ms).
    pub watchdog_ms: u64,
    /// Telemetry period (ms), 0 for none (no odometry traces, no compass-sign check).
    pub telemetry_ms: u64,
    /// Where the parameter backup of a store that is not a file (a device) is written; `None`:
    /// the report directory (or `.` without one). A file store's backup always goes beside
    /// its file.
    pub backup_dir: Option<PathBuf>,
    /// Where reports and plots are written, if anywhere.
    pub report_dir: Option<PathBuf>,
}

impl Default for RoutineConfig {
    fn default() -> Self {
        RoutineConfig {
            side_m: 4.0,
            runs_per_direction: 5,
            max_speed_m_s: 0.2,
            max_rate_rad_s: 0.5,
            heading_samples: 5,
            realign: true,
            swing: true,
            gyro_scale_error: None,
            settle_s: 0.5,
            method: None,
            convention: SplitConvention::LeftNominal,
            write_back: WritePolicy::Ask,
            confirm_motion: true,
            verification_runs: 3,
            tolerance: None,
            max_rounds: 3,
            target_e_b_std: None,
            target_e_d_std: None,
            max_runs_per_direction: 20,
            max_change: 0.1,
            allow_large_change: false,
            keep_worse: false,
            watchdog_ms: 500,
            telemetry_ms: 20,
            backup_dir: None,
            report_dir: None,
        }
    }
}

/// A routine file or setting that cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}{message}", line.map(|l| format!("line {l}: ")).unwrap_or_default())]
pub struct ConfigError {
    /// 1-based line of the routine file, when the problem has one.
    pub line: Option<usize>,
    /// What is wrong.
    pub message: String,
}

impl ConfigError {
    /// A setting that cannot be used, with no line of a file to point at.
    pub fn new(message: impl Into<String>) -> Self {
        ConfigError {
            line: None,
            message: message.into(),
        }
    }
}

/// A turn-rate limit a robot may be given: in (0, 3] rad/s
/// ([`HARD_RATE_LIMIT_RAD_S`]).
pub fn check_rate_limit(rate_rad_s: f64) -> Result<(), ConfigError> {
    if rate_rad_s.is_finite() && rate_rad_s > 0.0 && rate_rad_s <= HARD_RATE_LIMIT_RAD_S {
        return Ok(());
    }
    Err(ConfigError::new(format!(
        "--max-rate-rad-s {rate_rad_s}: must be in (0, 3]"
    )))
}

impl RoutineConfig {
    /// What a calibration on the robot at `place` will do, said before it connects and moves.
    pub fn motion_notice(&self, place: &str) -> String {
        format!(
            "odocal calibrate: this MOVES THE ROBOT on {place}: squares of {} m, {} per direction \
             per round, at up to {} m/s (the plan, with time and floor, follows the pre-flight \
             checks). Ctrl-C stops it at any time.",
            self.side_m,
            match self.target() {
                Some(_) => format!("until the target (at most {})", self.max_runs_per_direction),
                None => self.runs_per_direction.to_string(),
            },
            self.max_speed_m_s
        )
    }

    /// The precision the settings ask for, when they ask for one (the round's squares then stop
    /// once it is reached).
    pub fn target(&self) -> Option<Target> {
        let t = Target {
            e_b_std: self.target_e_b_std,
            e_d_std: self.target_e_d_std,
            end_point_m: None,
        };
        t.any().then_some(t)
    }

    /// The split convention these settings select.
    pub fn split_convention(&self) -> SplitConvention {
        self.convention
    }

    /// Parses a file of routine settings; errors name the line.
    pub fn from_toml(text: &str) -> Result<Self, ConfigError> {
        Self::from_table(parse_table(text)?, text)
    }

    /// The settings of `table`, parsed from `text` (which gives errors their line): the part
    /// of a routine file that is the procedure.
    pub fn from_table(table: toml::Table, text: &str) -> Result<Self, ConfigError> {
        let cfg: RoutineConfig = table.try_into().map_err(|e| table_error(&e, text))?;
        cfg.validate().map_err(|mut e| {
            e.line = e.line.or_else(|| key_line(text, &e.message));
            e
        })?;
        Ok(cfg)
    }

    /// Checks every setting; the error's message starts with the key's name.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.check_motion()?;
        self.check_readings()?;
        self.check_estimation()?;
        self.check_rounds()?;
        self.check_max_change()?;
        self.check_device()?;
        Ok(())
    }

    /// Checks the square and how fast it is driven (side, runs, speed and turn-rate limits).
    fn check_motion(&self) -> Result<(), ConfigError> {
        // Lower bounds too: a 1e-308 m square or speed is no test (its time is infinite).
        if !(self.side_m.is_finite() && (0.05..=20.0).contains(&self.side_m)) {
            return bad(
                "side_m",
                format!("must be in [0.05, 20] m, got {}", self.side_m),
            );
        }
        if !(1..=50).contains(&self.runs_per_direction) {
            return bad(
                "runs_per_direction",
                format!("must be 1..=50, got {}", self.runs_per_direction),
            );
        }
        if !(self.max_speed_m_s.is_finite()
            && (0.01..=HARD_SPEED_LIMIT_M_S).contains(&self.max_speed_m_s))
        {
            return bad(
                "max_speed_m_s",
                format!(
                    "must be in [0.01, {HARD_SPEED_LIMIT_M_S}] m/s, got {}",
                    self.max_speed_m_s
                ),
            );
        }
        if !(self.max_rate_rad_s.is_finite()
            && (0.01..=HARD_RATE_LIMIT_RAD_S).contains(&self.max_rate_rad_s))
        {
            return bad(
                "max_rate_rad_s",
                format!(
                    "must be in [0.01, {HARD_RATE_LIMIT_RAD_S}] rad/s, got {}",
                    self.max_rate_rad_s
                ),
            );
        }
        Ok(())
    }

    /// Checks how heading readings are taken at rest: how many, after how long a settle.
    fn check_readings(&self) -> Result<(), ConfigError> {
        if !(1..=100).contains(&self.heading_samples) {
            return bad(
                "heading_samples",
                format!("must be 1..=100, got {}", self.heading_samples),
            );
        }
        if !(self.settle_s.is_finite() && (0.0..=10.0).contains(&self.settle_s)) {
            return bad(
                "settle_s",
                format!("must be in [0, 10] s, got {}", self.settle_s),
            );
        }
        Ok(())
    }

    /// Checks what the estimation takes as given: split convention and gyro scale error.
    fn check_estimation(&self) -> Result<(), ConfigError> {
        if let Err(e) = self.convention.validate() {
            return bad("convention", e.to_string());
        }
        if let Some(g) = self.gyro_scale_error {
            if !(g.is_finite() && g.abs() < 0.1) {
                return bad(
                    "gyro_scale_error",
                    format!("must be within ±0.1 (a fraction: 0.01 is 1 %), got {g}"),
                );
            }
        }
        Ok(())
    }

    /// Checks how many squares and rounds are driven, and the tolerance and targets that end them.
    fn check_rounds(&self) -> Result<(), ConfigError> {
        if self.verification_runs > 50 {
            return bad(
                "verification_runs",
                format!("at most 50, got {}", self.verification_runs),
            );
        }
        if let Some(t) = self.tolerance {
            if !(positive(t) && t < 0.1) {
                return bad("tolerance", format!("must be in (0, 0.1), got {t}"));
            }
        }
        for (key, target) in [
            ("target_e_b_std", self.target_e_b_std),
            ("target_e_d_std", self.target_e_d_std),
        ] {
            if let Some(t) = target.filter(|t| !(t.is_finite() && (1e-7..0.1).contains(t))) {
                return bad(key, format!("must be in [1e-7, 0.1), got {t}"));
            }
        }
        if !(crate::calibration::plan::MIN_RUNS_PER_DIRECTION..=50)
            .contains(&self.max_runs_per_direction)
        {
            return bad(
                "max_runs_per_direction",
                format!("must be 2..=50, got {}", self.max_runs_per_direction),
            );
        }
        if !(1..=10).contains(&self.max_rounds) {
            return bad(
                "max_rounds",
                format!("must be 1..=10, got {}", self.max_rounds),
            );
        }
        Ok(())
    }

    /// Checks the largest change a write may make (up to 1.0 only with `allow_large_change`).
    fn check_max_change(&self) -> Result<(), ConfigError> {
        let limit = if self.allow_large_change { 1.0 } else { 0.25 };
        if !(positive(self.max_change) && self.max_change <= limit) {
            return bad(
                "max_change",
                format!(
                    "must be in (0, {limit}], got {}{}",
                    self.max_change,
                    if self.allow_large_change || self.max_change > 1.0 {
                        ""
                    } else {
                        " (up to 1.0 with allow_large_change / --allow-large-change, for \
                         skid-steer robots)"
                    }
                ),
            );
        }
        Ok(())
    }

    /// Checks the device's settings: watchdog timeout and telemetry period.
    fn check_device(&self) -> Result<(), ConfigError> {
        if !(50..=10_000).contains(&self.watchdog_ms) {
            return bad(
                "watchdog_ms",
                format!("must be 50..=10000, got {}", self.watchdog_ms),
            );
        }
        if self.telemetry_ms != 0 && !(5..=1000).contains(&self.telemetry_ms) {
            return bad(
                "telemetry_ms",
                format!("must be 0 or 5..=1000, got {}", self.telemetry_ms),
            );
        }
        Ok(())
    }
}

/// A setting that cannot be used, as `key: why` (no line: the caller looks the key up).
fn bad(key: &str, why: String) -> Result<(), ConfigError> {
    Err(ConfigError::new(format!("{key}: {why}")))
}

/// Whether `v` is a finite number above zero.
fn positive(v: f64) -> bool {
    v.is_finite() && v > 0.0
}

/// Parses TOML text into a table; a syntax error names its line.
pub fn parse_table(text: &str) -> Result<toml::Table, ConfigError> {
    toml::from_str(text).map_err(|e: toml::de::Error| ConfigError {
        line: e.span().map(|s| line_of(text, s.start)),
        message: e.message().to_string(),
    })
}

/// A deserialisation error of a table parsed from `text`, named by its key and line (a table
/// keeps no spans: the key the error names is looked up in the text).
pub fn table_error(e: &toml::de::Error, text: &str) -> ConfigError {
    let shown = e.to_string();
    let quoted = |after: &str| {
        let rest = &shown[shown.rfind(after)? + after.len()..];
        Some(rest[..rest.find('`')?].to_string())
    };
    let key = quoted("in `").or_else(|| quoted("unknown field `"));
    let message = match (&key, e.message()) {
        (Some(k), m) if !m.contains(k.as_str()) => format!("{k}: {m}"),
        (_, m) => m.to_string(),
    };
    ConfigError {
        line: key.and_then(|k| key_line(text, &k)),
        message,
    }
}

fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

/// The line that sets the key a message starts with (`key: ...`), or the key itself.
pub fn key_line(text: &str, message: &str) -> Option<usize> {
    let key = message.split(':').next()?.trim();
    text.lines()
        .position(|l| {
            let l = l.trim_start();
            l.strip_prefix(key)
                .is_some_and(|rest| rest.trim_start().starts_with('=') || rest.starts_with(']'))
                || l.trim_start_matches('[').starts_with(key) && l.starts_with('[')
        })
        .map(|i| i + 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_file_parses() {
        let cfg = RoutineConfig::from_toml(
            "side_m = 2.0\nruns_per_direction = 3\nmethod = \"jung-chung\"\n\
             write_back = \"dry-run\"\n\
             convention = { measured-scale = { commanded_m = 2.0, measured_m = 1.98 } }\n",
        )
        .unwrap();
        assert_eq!(cfg.method, Some(Method::JungChung));
        assert_eq!(cfg.write_back, WritePolicy::DryRun);
        assert!(matches!(
            cfg.split_convention(),
            SplitConvention::MeasuredScale { .. }
        ));
        let plain = RoutineConfig::from_toml("convention = \"mean-preserving\"\n").unwrap();
        assert_eq!(plain.convention, SplitConvention::MeanPreserving);
        let e = RoutineConfig::from_toml(
            "side_m = 2.0\nconvention = { measured-scale = { commanded_m = 2.0, measured_m = 1.0 } }\n",
        )
        .unwrap_err();
        assert!(e.to_string().contains("convention"), "{e}");
    }

    #[test]
    fn errors_name_the_line() {
        let e =
            RoutineConfig::from_toml("side_m = 2.0\nruns_per_direction = \"five\"\n").unwrap_err();
        assert_eq!(e.line, Some(2), "{e}");
        let e = RoutineConfig::from_toml("side_m = 2.0\n\nspeed = 3\n").unwrap_err();
        assert_eq!(e.line, Some(3), "{e}");
        assert!(e.message.contains("speed"), "{e}");
        let e = RoutineConfig::from_toml("# c\nside_m = 2.0\nmax_speed_m_s = 5.0\n").unwrap_err();
        assert_eq!(e.line, Some(3), "{e}");
        assert!(e.to_string().starts_with("line 3: max_speed_m_s"), "{e}");
        let e = RoutineConfig::from_toml("side_m = [\n").unwrap_err();
        assert!(e.line.is_some(), "{e}");
    }
}

#[cfg(test)]
mod notice_tests {
    use super::*;

    #[test]
    fn the_motion_notice_says_what_moves_and_how_far() {
        let mut cfg = RoutineConfig::default();
        let n = cfg.motion_notice("/dev/ttyUSB0");
        assert!(
            n.contains("MOVES THE ROBOT on /dev/ttyUSB0: squares of 4 m, 5 per direction"),
            "{n}"
        );
        cfg.target_e_b_std = Some(0.001);
        let n = cfg.motion_notice("x");
        assert!(n.contains("until the target (at most 20)"), "{n}");
    }
}
