//! The routine's plan ([`crate::calibration::plan`]) from its settings, shown before the robot
//! moves, and the rounds that drive squares in pairs until a target precision is reached.
//!
//! **The stopping rule.** With a target ([`RoutineConfig::target`]) a round drives clockwise
//! and counter-clockwise squares in pairs; after each pair from
//! [`MIN_RUNS_PER_DIRECTION`] per direction it estimates with the method it will write and
//! stops once that estimate's *stated* standard errors are at most the target, or at
//! [`RoutineConfig::max_runs_per_direction`]. Stopping when the run-to-run scatter happens to
//! be small would bias the stated error low; the stated error is therefore never below what the
//! heading sensor's own noise gives ([`crate::calibration::RunMeasurement::noise_variance_rad2`]:
//! the noise measured at rest for the methods at rest, the noise along each leg for the leg
//! methods), which does not depend on the scatter, so the stop decision rests on it whenever
//! the scatter is small. The coverage of the truth at 2σ over many seeds is checked by
//! `examples/sequential_benchmark.rs`.
//!
//! A later round is driven only when the round before wrote parameters, which the routine does
//! only when the correction was beyond two of its standard errors
//! ([`super::convergence`]); it stops as soon as its correction is not significant (or it
//! reaches the target, when it is), and its squares, driven with the written parameters, are
//! then the verification.

use super::config::RoutineConfig;
use super::report::{Phase, RunReport, Stage};
use super::swing::SWING_RATE_RAD_S;
use super::{RoutineError, RoutineEvent};
use crate::calibration::plan::{
    duration_text, plan, Plan, PlanError, PlanInput, Space, Target, MIN_RUNS_PER_DIRECTION,
};
use crate::calibration::{default_method, estimate, Estimate, HeadingKind, Method};
use crate::kinematics::{Direction, WheelParams};
use std::f64::consts::TAU;

/// A robot's footprint when none is given (m): a typical small base's largest width.
pub const DEFAULT_FOOTPRINT_M: f64 = 0.5;

/// Heading readings per second assumed when the settings stream nothing (the pace of the
/// readings at rest).
pub const READINGS_PER_S_WITHOUT_TELEMETRY: f64 = 10.0;

/// Full turns each way of the compass swing.
pub const SWING_TURNS_PER_DIRECTION: u32 = 2;

/// What a plan needs beyond the routine's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Setting {
    /// The floor; `None`: squares of the configured side.
    pub space: Option<Space>,
    /// The robot's footprint (m).
    pub footprint_m: f64,
    /// Wheelbase configured on the robot (m).
    pub wheelbase_m: f64,
    /// Heading noise per reading at rest (rad).
    pub heading_sigma_rad: f64,
    /// What the heading sensor is (which decides the default method and the swing).
    pub heading_kind: HeadingKind,
    /// Heading readings per second; `None`: the telemetry rate the settings ask for.
    pub readings_per_s: Option<f64>,
    /// Scatter of each run's heading error beyond the sensor's noise (rad).
    pub run_scatter_rad: f64,
    /// Wheel travel of one encoder count (m) when the drive rounds its motions to whole
    /// counts, 0 when it does not or it is unknown ([`PlanInput::m_per_count`]).
    pub m_per_count: f64,
}

/// The wheel travel of one count (m) for [`Setting::m_per_count`] when the drive rounds its
/// motions to whole counts of `params` ([`crate::base::Drive::rounds_to_counts`]), else 0. The
/// larger wheel's: its rounding moves the robot further.
pub fn m_per_count_of(rounds_to_counts: bool, params: &WheelParams) -> f64 {
    if rounds_to_counts {
        params.left_m_per_count().max(params.right_m_per_count())
    } else {
        0.0
    }
}

/// The method the routine will write with these settings and this sensor, before any square
/// has shown whether the heading along the legs arrives: the leg methods when the settings ask
/// for telemetry ([`default_method`]).
pub fn expected_method(cfg: &RoutineConfig, kind: HeadingKind) -> Method {
    cfg.method
        .or_else(|| default_method(cfg.telemetry_ms > 0, false, kind))
        .unwrap_or(Method::Exact)
}

/// Whether the routine swings the compass with these settings and this sensor.
pub fn swings(cfg: &RoutineConfig, kind: HeadingKind) -> bool {
    cfg.swing && kind.may_deviate()
}

/// The swing's turn rate (rad/s).
pub fn swing_rate_rad_s(cfg: &RoutineConfig) -> f64 {
    cfg.max_rate_rad_s.min(SWING_RATE_RAD_S)
}

/// Robot time of the compass swing (s), 0 when there is none.
pub fn swing_time_s(cfg: &RoutineConfig, kind: HeadingKind) -> f64 {
    if swings(cfg, kind) {
        2.0 * f64::from(SWING_TURNS_PER_DIRECTION) * TAU / swing_rate_rad_s(cfg)
    } else {
        0.0
    }
}

/// The plan's input for these settings.
pub fn plan_input(cfg: &RoutineConfig, s: &Setting) -> PlanInput {
    PlanInput {
        space: s.space.unwrap_or(Space::Side(cfg.side_m)),
        footprint_m: s.footprint_m,
        wheelbase_m: s.wheelbase_m,
        ratios: (1.0, 1.0),
        heading_sigma_rad: s.heading_sigma_rad,
        readings_at_rest: cfg.heading_samples,
        readings_per_s: s.readings_per_s.unwrap_or(if cfg.telemetry_ms > 0 {
            1000.0 / cfg.telemetry_ms as f64
        } else {
            READINGS_PER_S_WITHOUT_TELEMETRY
        }),
        run_scatter_rad: s.run_scatter_rad,
        m_per_count: s.m_per_count,
        method: expected_method(cfg, s.heading_kind),
        convention: cfg.convention,
        speed_m_s: cfg.max_speed_m_s,
        rate_rad_s: cfg.max_rate_rad_s,
        settle_s: cfg.settle_s,
        realign: cfg.realign,
        other_motion_s: swing_time_s(cfg, s.heading_kind),
        runs_per_direction: cfg.runs_per_direction,
        max_runs_per_direction: cfg.max_runs_per_direction,
        verification_runs: cfg.verification_runs,
        max_rounds: cfg.max_rounds,
        target: cfg.target().unwrap_or_default(),
    }
}

/// The plan of these settings.
pub fn plan_of(cfg: &RoutineConfig, s: &Setting) -> Result<Plan, PlanError> {
    plan(&plan_input(cfg, s))
}

/// Why a round's squares stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stop {
    /// The stated standard errors reached the target.
    Reached,
    /// A later round's correction is not significant: the written parameters stand.
    Confirmed,
    /// The most runs per direction were driven.
    Ceiling,
}

/// Whether a round that has driven `runs` per direction stops, with its chosen estimate so far
/// (`None`: none yet) and, for a later round, whether its correction is not significant.
pub fn stop(
    target: &Target,
    estimate: Option<&Estimate>,
    runs: usize,
    max_runs: usize,
    confirmed: bool,
) -> Option<Stop> {
    if runs < MIN_RUNS_PER_DIRECTION {
        return None;
    }
    let within = |stated: Option<f64>, target: Option<f64>| match target {
        None => true,
        Some(t) => stated.is_some_and(|s| s <= t),
    };
    if let Some(e) = estimate {
        if within(e.e_b_std_err, target.e_b_std) && within(e.e_d_std_err, target.e_d_std) {
            return Some(Stop::Reached);
        }
        if confirmed {
            return Some(Stop::Confirmed);
        }
    }
    (runs >= max_runs).then_some(Stop::Ceiling)
}

impl Stop {
    /// Why, in words, after `runs` per direction.
    pub fn describe(self, runs: usize) -> String {
        match self {
            Stop::Reached => format!("the target was reached after {runs} runs per direction"),
            Stop::Confirmed => format!(
                "the correction was not significant after {runs} runs per direction: the \
                 written parameters stand"
            ),
            Stop::Ceiling => format!(
                "the target was not reached within {runs} runs per direction \
                 (max_runs_per_direction)"
            ),
        }
    }
}

/// The question asked before the robot first moves: with the plan, its squares, robot time
/// and floor.
pub fn motion_question(cfg: &RoutineConfig, plan: Option<&Plan>) -> String {
    match plan {
        Some(p) => format!(
            "The robot will drive about {} open-loop squares of {} m (at most {}), {} of robot \
             time (at most {}), on {:.1} × {:.1} m of floor, at up to {} m/s and {} rad/s. Is \
             the area clear and may it move?",
            p.squares,
            cfg.side_m,
            p.max_squares,
            duration_text(p.robot_time_s),
            duration_text(p.max_robot_time_s),
            p.floor_m[0],
            p.floor_m[1],
            cfg.max_speed_m_s,
            cfg.max_rate_rad_s
        ),
        None => format!(
            "The robot will drive {} open-loop squares of {} m at up to {} m/s and {} rad/s. Is \
             the area clear and may it move?",
            cfg.runs_per_direction * 2,
            cfg.side_m,
            cfg.max_speed_m_s,
            cfg.max_rate_rad_s
        ),
    }
}

/// The plan's steps of a calibration run.
impl super::Calibration<'_> {
    /// The plan of this run (this module) from the settings and the heading noise just
    /// measured, shown before the robot moves.
    pub(super) fn make_plan(&mut self) {
        let setting = Setting {
            space: None,
            footprint_m: DEFAULT_FOOTPRINT_M,
            wheelbase_m: self.session.original().wheelbase_m,
            heading_sigma_rad: self.noise.std_rad(),
            heading_kind: self.base.heading.kind(),
            readings_per_s: None,
            run_scatter_rad: 0.0,
            m_per_count: m_per_count_of(
                self.base.drive.rounds_to_counts(),
                self.session.original(),
            ),
        };
        match plan_of(self.cfg, &setting) {
            Ok(p) => {
                self.stage(format!("plan: {}", p.to_string().replace('\n', "\n  ")));
                if !p.target_reached {
                    self.warn(format!(
                        "by the heading noise measured, the target is not reached within {} \
                         runs per direction (max_runs_per_direction): the rounds stop there",
                        self.cfg.max_runs_per_direction
                    ));
                }
                self.plan = Some(p);
            }
            Err(e) => self.warn(format!("no plan: {e}")),
        }
    }

    /// **Moves the robot**: clockwise and counter-clockwise squares in pairs until the
    /// stopping rule ends the round ([`stop`]): the target reached, a later round's
    /// correction not significant, or the most runs per direction.
    pub(super) async fn drive_until(
        &mut self,
        phase: Phase,
        target: &Target,
        params: &WheelParams,
    ) -> Result<(Vec<RunReport>, Stop), RoutineError> {
        self.progress.stage = Stage::of(phase);
        let cfg = self.cfg;
        let later = matches!(phase, Phase::Calibration { round } if round > 1);
        let min = MIN_RUNS_PER_DIRECTION;
        let expected = match (&self.plan, later) {
            (Some(p), false) => p.runs_per_direction,
            _ => min,
        }
        .clamp(min, cfg.max_runs_per_direction);
        let pair_s = 2.0 * super::square_motion_time_s(cfg);
        self.ui.event(&RoutineEvent::Plan {
            motions: expected as u64 * 16,
            robot_time_s: expected as f64 * pair_s,
        });
        let mut out: Vec<RunReport> = Vec::new();
        loop {
            let pair = out.len() / 2 + 1;
            if pair > expected {
                self.ui.event(&RoutineEvent::Extend {
                    motions: 16,
                    robot_time_s: pair_s,
                });
            }
            let of = 2 * pair.max(expected);
            for direction in [Direction::Cw, Direction::Ccw] {
                let run = self
                    .drive_square(phase, direction, out.len() + 1, of, params)
                    .await?;
                out.push(run);
            }
            let test = super::square_test(cfg, params, &out, self.noise.std_rad());
            let chosen = estimate(self.method_for(&test), &test, cfg.split_convention()).ok();
            let confirmed = later
                && chosen.as_ref().is_some_and(|e| {
                    let crb = super::cramer_rao_std(
                        cfg,
                        e,
                        self.noise.std_rad(),
                        params.wheelbase_m,
                        pair,
                    );
                    super::convergence(cfg, e, crb, params.wheelbase_m).is_some()
                });
            if let Some(why) = stop(
                target,
                chosen.as_ref(),
                pair,
                cfg.max_runs_per_direction,
                confirmed,
            ) {
                return Ok((out, why));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::{Correction, SplitConvention};

    fn estimate(b: Option<f64>, d: Option<f64>) -> Estimate {
        let c = Correction {
            left_diameter_scale: 1.0,
            right_diameter_scale: 1.0,
            wheelbase_scale: 1.0,
        };
        Estimate::of(Method::Exact, c, b.zip(d), &SplitConvention::LeftNominal)
    }

    #[test]
    fn a_round_stops_at_the_target_a_confirmation_or_the_ceiling() {
        let t = Target {
            e_b_std: Some(1e-4),
            ..Target::default()
        };
        let small = estimate(Some(9e-5), Some(1.0));
        let large = estimate(Some(2e-4), Some(1.0));
        assert_eq!(
            stop(&t, Some(&small), 1, 20, false),
            None,
            "one run has no error"
        );
        assert_eq!(stop(&t, Some(&small), 2, 20, false), Some(Stop::Reached));
        assert_eq!(stop(&t, Some(&large), 2, 20, false), None);
        assert_eq!(stop(&t, Some(&large), 2, 20, true), Some(Stop::Confirmed));
        assert_eq!(stop(&t, Some(&large), 20, 20, false), Some(Stop::Ceiling));
        assert_eq!(stop(&t, None, 3, 20, true), None);
        let both = Target {
            e_d_std: Some(1e-4),
            ..t
        };
        assert_eq!(stop(&both, Some(&small), 2, 20, false), None);
    }

    #[test]
    fn the_plan_follows_the_settings() {
        let cfg = RoutineConfig::default();
        let s = Setting {
            space: None,
            footprint_m: DEFAULT_FOOTPRINT_M,
            wheelbase_m: 0.39,
            heading_sigma_rad: 0.37f64.to_radians(),
            heading_kind: HeadingKind::Magnetic,
            readings_per_s: None,
            run_scatter_rad: 0.0,
            m_per_count: 0.0,
        };
        let p = plan_of(&cfg, &s).unwrap();
        assert_eq!(p.method, Method::MatchedLegs);
        assert_eq!((p.side_m, p.runs_per_direction, p.squares), (4.0, 5, 26));
        // Two turns each way at 0.5 rad/s.
        let swing = 4.0 * TAU / 0.5;
        assert!((p.robot_time_s - swing - 26.0 * p.square_time_s).abs() < 1e-6);
        let gyro = plan_of(
            &cfg,
            &Setting {
                heading_kind: HeadingKind::Gyro,
                ..s
            },
        )
        .unwrap();
        assert_eq!(gyro.method, Method::Legs);
        assert!((gyro.robot_time_s - 26.0 * gyro.square_time_s).abs() < 1e-6);
        let no_stream = RoutineConfig {
            telemetry_ms: 0,
            ..cfg
        };
        assert_eq!(plan_of(&no_stream, &s).unwrap().method, Method::Exact);
    }
}
