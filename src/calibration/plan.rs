//! Planning a square test before anything moves: the side that fits the floor, the runs per
//! direction a target precision needs, how long the robot drives, and the standard errors of
//! `E_b` and `E_d` it will reach.
//!
//! **Precision.** With a heading noise of `σ_c` per reading averaged over `k` readings at rest,
//! each run's final heading error has `σ_run = σ_c·√(2/k)`, and `n` runs per direction give, to
//! first order,
//!
//! `σ(E_b) ≈ E_b²·σ_run/(2√2·π·√n)`, `σ(E_d) ≈ (b/L)·σ_run/(4√2·√n)`,
//!
//! which for one reading at each end is `E_b²·σ_c/(2π√n)` and `(b/L)·σ_c/(4√n)` (under
//! left-nominal `E_b = 1/u_L` also carries the leg term: a few per cent more on short sides).
//! The plan takes them from the Cramér–Rao bound ([`cramer_rao_bound`]) at `E_b = E_d = 1` (or
//! the ratios given), which the methods at rest (`exact`, `jung-chung`) attain. The leg methods read
//! the heading along the legs instead: with `m` independent readings per leg (its duration
//! times the sensor's rate) a leg's mean heading has `σ_c/√m`, and each method is the exact test
//! of an equivalent per-run error: `legs` compares the first and last legs, ¾ of the square
//! (`σ_run = (4/3)·σ_c·√(2/m)`); `matched-legs` takes the turn term from legs 1 and 3 and the
//! leg term from legs 2 and 4, each half a square (`σ_run = 2·σ_c·√(2/m)`). A sensor whose
//! readings along a leg are correlated (one that filters) averages less than `m` says, and the
//! leg methods' prediction is then optimistic; the routine's stopping rule does not rely on it.
//! Scatter from run to run beyond the sensor's noise (slip, a bump), when known, is added to
//! `σ_run` in quadrature. Under a measured scale (`--straight-measured-m`) the prediction is the
//! heading part, the left-nominal one.
//!
//! **Robot time.** Per square: four legs at the speed limit, four quarter turns at the rate
//! limit, a settle and `k` readings at rest before and after, and `k` more before it when the
//! robot turns back to the first square's heading (that turn, the last square's heading error,
//! is not counted);
//! accelerations are not modelled. Readings at rest take `1/rate` each. Other motion (a compass
//! swing) is added once.
//!
//! **Rounds.** Without a target: `n` per direction, a second round to confirm (the routine
//! writes after round 1 and repeats until a round's correction is not significant), then the
//! verification. With a target: the fewest runs per direction the prediction needs, then,
//! when round 1 wrote, a confirmation round of [`MIN_RUNS_PER_DIRECTION`] per direction whose
//! squares, driven with the written parameters, are the verification.
//!
//! **Floor.** The clockwise square lies right of the first leg and the counter-clockwise one
//! left of it: both need `L` along the first leg and `2L` across. The plan adds the robot's
//! footprint and [`DRIFT_FRACTION`] of every length for the drift of an uncalibrated robot,
//! which does not close its squares (the demo robot, 2.4 % off in wheelbase, ends a 4 m square
//! 1.2 m from its start: put it back on its mark when it wanders further).

use super::uncertainty::{cramer_rao_bound, heading_error_sigma, TestDesign};
use super::Method;
use crate::kinematics::{Correction, Direction, Pose, SplitConvention};
use serde::Serialize;
use std::f64::consts::{FRAC_PI_2, PI};
use std::fmt;

/// Shortest side a plan chooses (m): shorter legs are mostly acceleration, and too short for
/// the leg methods to tell legs from turns.
pub const MIN_SIDE_M: f64 = 1.0;
/// Fewest runs per direction with a standard error (two each way give a scatter).
pub const MIN_RUNS_PER_DIRECTION: usize = 2;
/// Floor added to every length of the squares for the drift of an uncalibrated robot.
pub const DRIFT_FRACTION: f64 = 0.1;

/// How much floor there is.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Space {
    /// A free rectangle of floor (m), either way round.
    Floor {
        /// One side (m).
        width_m: f64,
        /// The other (m).
        length_m: f64,
    },
    /// Squares of at most this side (m).
    MaxSide(f64),
    /// Squares of exactly this side (m): the routine's configured one.
    Side(f64),
}

/// The precision asked for; `None` everywhere: the fixed number of runs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Target {
    /// Standard error of `E_b`.
    pub e_b_std: Option<f64>,
    /// Standard error of `E_d`.
    pub e_d_std: Option<f64>,
    /// RMS end-point error (m) of one square of the plan's side driven with the calibrated
    /// parameters (the larger direction's): the standard errors' part and the rounding to
    /// whole encoder counts ([`Plan::predicted_end_point_m`]).
    pub end_point_m: Option<f64>,
}

impl Target {
    /// Whether any target is set.
    pub fn any(&self) -> bool {
        self.e_b_std.is_some() || self.e_d_std.is_some() || self.end_point_m.is_some()
    }
}

/// Everything a plan depends on.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PlanInput {
    /// The floor.
    pub space: Space,
    /// The robot's footprint (m): its largest width, added to the floor the squares need.
    pub footprint_m: f64,
    /// Wheelbase configured on the robot (m).
    pub wheelbase_m: f64,
    /// Where the bound is evaluated: the robot's `(E_b, E_d)` if known, else `(1, 1)`.
    pub ratios: (f64, f64),
    /// Heading noise per reading (rad), as `odocal heading --heading-samples N` measures it at rest.
    pub heading_sigma_rad: f64,
    /// Readings averaged at rest before and after each square.
    pub readings_at_rest: usize,
    /// Heading readings per second (along the legs, and the pace of readings at rest).
    pub readings_per_s: f64,
    /// Scatter of each run's heading error beyond the sensor's noise (rad; 0 if unknown).
    pub run_scatter_rad: f64,
    /// Wheel travel of one encoder count (m) when the drive rounds every motion's wheel
    /// targets to whole counts, as a controller that counts wheel targets does; 0 when it does
    /// not or it is unknown (the end point then leaves the rounding out).
    pub m_per_count: f64,
    /// The estimate whose standard errors are predicted (the one the routine writes).
    pub method: Method,
    /// The diameter split.
    pub convention: SplitConvention,
    /// Straight-leg speed (m/s).
    pub speed_m_s: f64,
    /// Turn rate (rad/s).
    pub rate_rad_s: f64,
    /// Settle before each reading at rest (s).
    pub settle_s: f64,
    /// Whether the robot turns back to the first square's heading before each square.
    pub realign: bool,
    /// Robot time outside the squares (a compass swing), s.
    pub other_motion_s: f64,
    /// Runs per direction without a target.
    pub runs_per_direction: usize,
    /// With a target, the most runs per direction a round may drive.
    pub max_runs_per_direction: usize,
    /// Verification squares per direction after a write (without a target).
    pub verification_runs: usize,
    /// Most calibration rounds.
    pub max_rounds: usize,
    /// The precision asked for.
    pub target: Target,
}

/// A plan that cannot be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    /// A number out of its physical range.
    #[error("{name} must be {range}, got {value}")]
    BadInput {
        /// Which input.
        name: &'static str,
        /// Its allowed range, in words.
        range: &'static str,
        /// The value.
        value: f64,
    },
    /// The floor has no room for the shortest square.
    #[error(
        "a floor of {width_m} × {length_m} m has no room for two {MIN_SIDE_M} m squares (they \
         need {needed_m:.1} × {across_m:.1} m with the robot's footprint and drift)"
    )]
    NoRoom {
        /// One side (m).
        width_m: f64,
        /// The other (m).
        length_m: f64,
        /// Floor needed along the first leg (m).
        needed_m: f64,
        /// Floor needed across it (m).
        across_m: f64,
    },
    /// The method has no prediction (it needs final positions).
    #[error("no precision can be predicted for method {0}: it uses final positions")]
    Unpredictable(Method),
}

/// A planned square test.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Plan {
    /// The estimate the standard errors are for.
    pub method: Method,
    /// Square side (m).
    pub side_m: f64,
    /// Runs per direction of the first round.
    pub runs_per_direction: usize,
    /// Whether the runs stop once a target is reached (else a fixed number).
    pub sequential: bool,
    /// Calibration rounds expected (a robot that needs a correction: one that writes, one that
    /// confirms).
    pub rounds: usize,
    /// Runs per direction of each later round.
    pub later_runs_per_direction: usize,
    /// Verification runs per direction driven on their own (0 when the confirmation round is
    /// the verification).
    pub verification_runs_per_direction: usize,
    /// Squares expected.
    pub squares: usize,
    /// Squares at most (every round to its limit).
    pub max_squares: usize,
    /// Robot time of one square (s).
    pub square_time_s: f64,
    /// Robot time expected (s): squares and other motion.
    pub robot_time_s: f64,
    /// Robot time at most (s).
    pub max_robot_time_s: f64,
    /// Distance driven, expected (m).
    pub distance_m: f64,
    /// Floor the squares need (m): along the first leg, and across it.
    pub floor_m: [f64; 2],
    /// Predicted standard error of `E_b` after the first round.
    pub predicted_std_e_b: f64,
    /// Predicted standard error of `E_d` after the first round.
    pub predicted_std_e_d: f64,
    /// Predicted RMS end-point error (m) of one square of `side_m` driven with the calibrated
    /// parameters (the larger direction's): the standard errors' part and the rounding's, in
    /// quadrature.
    pub predicted_end_point_m: f64,
    /// The part of [`Plan::predicted_end_point_m`] from the standard errors of `E_b` and `E_d`
    /// (m, RMS over calibrations).
    pub end_point_from_estimate_m: f64,
    /// The part from rounding every motion's wheel targets to whole encoder counts (m, RMS
    /// over where the roundings fall; 0 when [`PlanInput::m_per_count`] is). For one robot and
    /// one set of parameters the roundings are the same in every square: this part repeats
    /// exactly, and no calibration removes it.
    pub end_point_from_rounding_m: f64,
    /// The most the rounding can move the end point (m): every wheel target off by half a
    /// count the worst way.
    pub end_point_rounding_max_m: f64,
    /// Why this side: the floor, the longest side allowed, or the side asked for.
    pub space: Space,
    /// Whether the prediction meets every target (always, without one).
    pub target_reached: bool,
}

/// Each run's equivalent final heading error `σ_run` (rad) for `method` on squares of `side_m`
/// (see the module).
pub fn run_sigma(input: &PlanInput, side_m: f64) -> Result<f64, PlanError> {
    let s = input.heading_sigma_rad;
    let per_leg = (side_m / input.speed_m_s * input.readings_per_s).max(1.0);
    let legs = s * (2.0 / per_leg).sqrt();
    let sensor = match input.method {
        Method::HeadingOnly | Method::JungChung | Method::Exact => {
            heading_error_sigma(s, input.readings_at_rest)
        }
        Method::Legs => 4.0 / 3.0 * legs,
        Method::MatchedLegs => 2.0 * legs,
        m @ (Method::Umbmark | Method::Lee) => return Err(PlanError::Unpredictable(m)),
    };
    Ok(sensor.hypot(input.run_scatter_rad))
}

/// Predicted standard errors `(E_b, E_d)` of `runs` per direction on squares of `side_m`.
pub fn predicted_std(input: &PlanInput, side_m: f64, runs: usize) -> Result<(f64, f64), PlanError> {
    let sigma = run_sigma(input, side_m)?;
    if sigma == 0.0 {
        return Ok((0.0, 0.0));
    }
    let convention = match input.convention {
        SplitConvention::MeasuredScale { .. } => SplitConvention::LeftNominal,
        c => c,
    };
    let design = TestDesign {
        side_m,
        wheelbase_m: input.wheelbase_m,
        runs_cw: runs.max(1),
        runs_ccw: runs.max(1),
        heading_error_sigma_rad: sigma,
    };
    let cov =
        cramer_rao_bound(input.ratios.0, input.ratios.1, convention, &design).map_err(|_| {
            PlanError::BadInput {
                name: "ratios",
                range: "those of a robot",
                value: input.ratios.0,
            }
        })?;
    Ok((cov[(0, 0)].sqrt(), cov[(1, 1)].sqrt()))
}

/// The end point of one square (m from its start) driven by a robot whose true parameters are
/// `c` applied to the configured ones.
fn square_end(c: &Correction, side_m: f64, wheelbase_m: f64, direction: Direction) -> [f64; 2] {
    square_end_off(c, side_m, wheelbase_m, direction, [0.0; 4])
}

/// [`square_end`] with every leg's wheel targets off by `off[0]` (left) and `off[1]` (right),
/// and every turn's by `off[2]` and `off[3]` (m of commanded wheel travel) in the
/// counter-clockwise square: a controller that rounds its targets to whole counts rounds every
/// leg alike and every turn alike, and the other direction's turns, the same targets negated,
/// the other way.
fn square_end_off(
    c: &Correction,
    side_m: f64,
    wheelbase_m: f64,
    direction: Direction,
    off: [f64; 4],
) -> [f64; 2] {
    let b_true = wheelbase_m * c.wheelbase_scale;
    let sign = direction.turn_sign();
    let turn = sign * FRAC_PI_2 * 0.5 * wheelbase_m;
    let mut pose = Pose::default();
    for _ in 0..4 {
        pose = pose.advance(
            (side_m + off[0]) * c.left_diameter_scale,
            (side_m + off[1]) * c.right_diameter_scale,
            b_true,
        );
        pose = pose.advance(
            (-turn + sign * off[2]) * c.left_diameter_scale,
            (turn + sign * off[3]) * c.right_diameter_scale,
            b_true,
        );
    }
    [pose.x_m, pose.y_m]
}

/// Grid points per offset when [`rounding_end_point`] averages over the offsets.
const ROUNDING_GRID: usize = 12;

/// The end-point error (m) of a square of `side_m` from rounding each motion's wheel targets to
/// whole counts of `m_per_count` (m of wheel travel): `(rms, max)` of the farther of the two
/// directions' end points, as `E_max,sys` takes it.
///
/// Each leg's left and right targets and each turn's are rounded once (the four legs alike,
/// the four turns alike; the clockwise turns the other way), each off by up to half a count:
/// four offsets, spread evenly over `±m_per_count/2` as where a target falls within its count
/// is unknown before the parameters are. The RMS is over them (a grid); the max puts every
/// offset at half a count the worst way. For one robot the offsets are fixed by its
/// parameters: its squares all end alike, and a calibration's written parameters move the
/// offsets only when they move a target across half a count.
pub fn rounding_end_point(side_m: f64, wheelbase_m: f64, m_per_count: f64) -> (f64, f64) {
    if !(m_per_count.is_finite() && m_per_count > 0.0) {
        return (0.0, 0.0);
    }
    let ideal = Correction {
        left_diameter_scale: 1.0,
        right_diameter_scale: 1.0,
        wheelbase_scale: 1.0,
    };
    // The end point is linear in offsets this small (a count against metres of travel): one
    // 2 × 4 map per direction.
    let h = 1e-6;
    let jacobian = |d: Direction| -> [[f64; 2]; 4] {
        let mut jac = [[0.0; 2]; 4];
        for (j, col) in jac.iter_mut().enumerate() {
            let mut off = [0.0; 4];
            off[j] = h;
            let p = square_end_off(&ideal, side_m, wheelbase_m, d, off);
            off[j] = -h;
            let m = square_end_off(&ideal, side_m, wheelbase_m, d, off);
            *col = [(p[0] - m[0]) / (2.0 * h), (p[1] - m[1]) / (2.0 * h)];
        }
        jac
    };
    let maps = [jacobian(Direction::Cw), jacobian(Direction::Ccw)];
    // The farther direction's squared end point for offsets `u` (counts).
    let farther = |u: [f64; 4]| {
        maps.iter()
            .map(|jac| {
                let mut e = [0.0; 2];
                for (col, uk) in jac.iter().zip(u) {
                    e[0] += uk * m_per_count * col[0];
                    e[1] += uk * m_per_count * col[1];
                }
                e[0] * e[0] + e[1] * e[1]
            })
            .fold(0.0, f64::max)
    };
    let n = ROUNDING_GRID;
    let at = |i: usize| (i as f64 + 0.5) / n as f64 - 0.5;
    let mut sum = 0.0;
    for k in 0..n.pow(4) {
        sum += farther([
            at(k % n),
            at(k / n % n),
            at(k / n / n % n),
            at(k / n / n / n),
        ]);
    }
    let rms = (sum / n.pow(4) as f64).sqrt();
    // The norm of a linear map is largest at a corner of the box of offsets.
    let max = (0..16u32)
        .map(|signs| {
            let corner = |k: u32| if signs & (1 << k) == 0 { 0.5 } else { -0.5 };
            farther([corner(0), corner(1), corner(2), corner(3)]).sqrt()
        })
        .fold(0.0, f64::max);
    (rms, max)
}

/// RMS end-point error (m) of a square of `side_m` driven with parameters whose `E_b`, `E_d`
/// are off by independent errors of these standard deviations: the larger direction's.
pub fn end_point_rms(side_m: f64, wheelbase_m: f64, std_e_b: f64, std_e_d: f64) -> f64 {
    let at = |db: f64, dd: f64, d: Direction| {
        let c = SplitConvention::LeftNominal
            .split(1.0 + db, 1.0 + dd, wheelbase_m)
            .unwrap_or(Correction {
                left_diameter_scale: 1.0,
                right_diameter_scale: 1.0,
                wheelbase_scale: 1.0,
            });
        square_end(&c, side_m, wheelbase_m, d)
    };
    let h = 1e-6;
    [Direction::Cw, Direction::Ccw]
        .into_iter()
        .map(|d| {
            let (pb, mb) = (at(h, 0.0, d), at(-h, 0.0, d));
            let (pd, md) = (at(0.0, h, d), at(0.0, -h, d));
            (0..2)
                .map(|k| {
                    let jb = (pb[k] - mb[k]) / (2.0 * h);
                    let jd = (pd[k] - md[k]) / (2.0 * h);
                    (jb * std_e_b).powi(2) + (jd * std_e_d).powi(2)
                })
                .sum::<f64>()
                .sqrt()
        })
        .fold(0.0, f64::max)
}

/// Floor needed by the two squares of side `side_m` (m): along the first leg, and across it.
pub fn floor_needed(side_m: f64, footprint_m: f64) -> [f64; 2] {
    let grow = 1.0 + DRIFT_FRACTION;
    [
        side_m * grow + footprint_m,
        2.0 * side_m * grow + footprint_m,
    ]
}

/// The largest side whose two squares fit the space (m).
pub fn largest_side(space: Space, footprint_m: f64) -> f64 {
    match space {
        Space::Floor { width_m, length_m } => {
            let grow = 1.0 + DRIFT_FRACTION;
            let fit = |along: f64, across: f64| {
                ((along - footprint_m) / grow).min((across - footprint_m) / (2.0 * grow))
            };
            fit(width_m, length_m).max(fit(length_m, width_m))
        }
        Space::MaxSide(s) | Space::Side(s) => s,
    }
}

/// Robot time of one square of `side_m` (s), see the module.
pub fn square_time_s(input: &PlanInput, side_m: f64) -> f64 {
    let reading_s = input.readings_at_rest as f64 / input.readings_per_s;
    let rests = if input.realign { 3.0 } else { 2.0 };
    4.0 * side_m / input.speed_m_s
        + 2.0 * PI / input.rate_rad_s
        + 2.0 * input.settle_s
        + rests * reading_s
}

impl PlanInput {
    /// Rejects inputs no robot or floor has.
    pub fn validate(&self) -> Result<(), PlanError> {
        let bad = |name, range, value| Err(PlanError::BadInput { name, range, value });
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let non_negative = |v: f64| v.is_finite() && v >= 0.0;
        match self.space {
            Space::Floor { width_m, length_m } => {
                for v in [width_m, length_m] {
                    if !(positive(v) && v <= 1000.0) {
                        return bad("floor", "in (0, 1000] m", v);
                    }
                }
            }
            Space::MaxSide(s) | Space::Side(s) => {
                if !(positive(s) && s <= 20.0) {
                    return bad("side", "in (0, 20] m", s);
                }
            }
        }
        for (name, v, ok, range) in [
            (
                "footprint",
                self.footprint_m,
                non_negative(self.footprint_m),
                ">= 0 m",
            ),
            (
                "wheelbase",
                self.wheelbase_m,
                positive(self.wheelbase_m),
                "> 0 m",
            ),
            (
                "heading noise",
                self.heading_sigma_rad,
                non_negative(self.heading_sigma_rad),
                ">= 0",
            ),
            (
                "readings per second",
                self.readings_per_s,
                positive(self.readings_per_s),
                "> 0",
            ),
            (
                "run scatter",
                self.run_scatter_rad,
                non_negative(self.run_scatter_rad),
                ">= 0",
            ),
            (
                "wheel travel per count",
                self.m_per_count,
                non_negative(self.m_per_count),
                ">= 0 m",
            ),
            ("speed", self.speed_m_s, positive(self.speed_m_s), "> 0 m/s"),
            (
                "turn rate",
                self.rate_rad_s,
                positive(self.rate_rad_s),
                "> 0 rad/s",
            ),
            (
                "settle",
                self.settle_s,
                non_negative(self.settle_s),
                ">= 0 s",
            ),
            (
                "other motion",
                self.other_motion_s,
                non_negative(self.other_motion_s),
                ">= 0 s",
            ),
        ] {
            if !ok {
                return bad(name, range, v);
            }
        }
        for (name, v) in [
            ("target E_b standard error", self.target.e_b_std),
            ("target E_d standard error", self.target.e_d_std),
            ("target end-point error", self.target.end_point_m),
        ] {
            if let Some(v) = v.filter(|v| !positive(*v)) {
                return bad(name, "> 0", v);
            }
        }
        for (name, v) in [
            ("readings at rest", self.readings_at_rest),
            ("runs per direction", self.runs_per_direction),
            ("most runs per direction", self.max_runs_per_direction),
            ("most rounds", self.max_rounds),
        ] {
            if v == 0 {
                return bad(name, ">= 1", 0.0);
            }
        }
        Ok(())
    }
}

/// The runs per direction that meet every target on squares of `side_m` (at least
/// [`MIN_RUNS_PER_DIRECTION`]): the standard errors fall as `1/√n`; the rounding's part of the
/// end point does not, so an end-point target at or below it is never reached (the most runs).
fn runs_needed(input: &PlanInput, side_m: f64) -> Result<usize, PlanError> {
    let (b1, d1) = predicted_std(input, side_m, 1)?;
    let e1 = end_point_rms(side_m, input.wheelbase_m, b1, d1);
    let (rounding, _) = rounding_end_point(side_m, input.wheelbase_m, input.m_per_count);
    let need = |one: f64, target: Option<f64>| {
        target.map_or(0.0, |t| ((one / t).powi(2) * (1.0 - 1e-9)).ceil())
    };
    let t = input.target;
    // What the estimate's part may leave of an end-point target after the rounding's.
    let end_left = t.end_point_m.map(|e| {
        let left = e * e - rounding * rounding;
        if left > 0.0 {
            left.sqrt()
        } else {
            f64::MIN_POSITIVE
        }
    });
    let n = need(b1, t.e_b_std)
        .max(need(d1, t.e_d_std))
        .max(need(e1, end_left))
        .min(1e6) as usize;
    Ok(n.max(MIN_RUNS_PER_DIRECTION))
}

/// Plans the square test: see the module. The side is the largest the space holds, in tenths
/// of a metre (or the side asked for): a longer side measures `E_d` and the end point better,
/// costs nothing in `E_b`, and is the side the calibrated robot is judged on.
pub fn plan(input: &PlanInput) -> Result<Plan, PlanError> {
    input.validate()?;
    let largest = largest_side(input.space, input.footprint_m);
    let fixed_side = matches!(input.space, Space::Side(_));
    if !fixed_side && largest < MIN_SIDE_M {
        let [needed_m, across_m] = floor_needed(MIN_SIDE_M, input.footprint_m);
        let (width_m, length_m) = match input.space {
            Space::Floor { width_m, length_m } => (width_m, length_m),
            _ => (largest, largest),
        };
        return Err(PlanError::NoRoom {
            width_m,
            length_m,
            needed_m,
            across_m,
        });
    }
    // Tenths of a metre: a side to mark on a floor.
    let side_m = if fixed_side {
        largest
    } else {
        (largest * 10.0 + 1e-9).floor() / 10.0
    };
    plan_for_side(input, side_m)
}

/// The plan on squares of `side_m`.
fn plan_for_side(input: &PlanInput, side_m: f64) -> Result<Plan, PlanError> {
    let sequential = input.target.any();
    let (runs, reached) = if sequential {
        let n = runs_needed(input, side_m)?;
        let max = input.max_runs_per_direction.max(MIN_RUNS_PER_DIRECTION);
        (n.min(max), n <= max)
    } else {
        (input.runs_per_direction, true)
    };
    let (std_e_b, std_e_d) = predicted_std(input, side_m, runs)?;
    let later_rounds = input.max_rounds.min(2) - 1;
    let (later_runs, verification) = if sequential && later_rounds > 0 {
        (MIN_RUNS_PER_DIRECTION, 0)
    } else {
        (runs, input.verification_runs)
    };
    let squares = 2 * (runs + later_rounds * later_runs + verification);
    let max_per_round = if sequential {
        input.max_runs_per_direction.max(runs)
    } else {
        runs
    };
    let max_squares = 2 * (input.max_rounds * max_per_round + input.verification_runs);
    let square_time_s = square_time_s(input, side_m);
    let from_estimate = end_point_rms(side_m, input.wheelbase_m, std_e_b, std_e_d);
    let (from_rounding, rounding_max) =
        rounding_end_point(side_m, input.wheelbase_m, input.m_per_count);
    Ok(Plan {
        method: input.method,
        side_m,
        runs_per_direction: runs,
        sequential,
        rounds: 1 + later_rounds,
        later_runs_per_direction: later_runs,
        verification_runs_per_direction: verification,
        squares,
        max_squares,
        square_time_s,
        robot_time_s: input.other_motion_s + squares as f64 * square_time_s,
        max_robot_time_s: input.other_motion_s + max_squares as f64 * square_time_s,
        distance_m: squares as f64 * 4.0 * side_m,
        floor_m: floor_needed(side_m, input.footprint_m),
        predicted_std_e_b: std_e_b,
        predicted_std_e_d: std_e_d,
        predicted_end_point_m: from_estimate.hypot(from_rounding),
        end_point_from_estimate_m: from_estimate,
        end_point_from_rounding_m: from_rounding,
        end_point_rounding_max_m: rounding_max,
        space: input.space,
        target_reached: reached,
    })
}

/// Seconds as minutes and seconds ("12 min 30 s").
pub fn duration_text(s: f64) -> String {
    let s = s.max(0.0).round() as u64;
    match (s / 60, s % 60) {
        (0, s) => format!("{s} s"),
        (m, 0) => format!("{m} min"),
        (m, s) => format!("{m} min {s} s"),
    }
}

impl fmt::Display for Plan {
    /// The plan in a few lines: squares, time, floor, precision.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [along, across] = self.floor_m;
        let mut parts = vec![if self.sequential {
            format!(
                "about {} per direction (in pairs until the target is reached)",
                self.runs_per_direction
            )
        } else {
            format!("{} per direction", self.runs_per_direction)
        }];
        if self.rounds > 1 {
            parts.push(format!(
                "{} per direction to confirm{}",
                self.later_runs_per_direction,
                if self.verification_runs_per_direction == 0 {
                    ", which verify"
                } else {
                    ""
                }
            ));
        }
        if self.verification_runs_per_direction > 0 {
            parts.push(format!(
                "{} per direction to verify",
                self.verification_runs_per_direction
            ));
        }
        writeln!(
            f,
            "squares of {:.2} m: {}: {} squares in {} round(s), {} of robot time, {:.0} m \
             driven (at most {} squares, {})",
            self.side_m,
            parts.join(", then "),
            self.squares,
            self.rounds,
            duration_text(self.robot_time_s),
            self.distance_m,
            self.max_squares,
            duration_text(self.max_robot_time_s),
        )?;
        let why = match self.space {
            Space::Floor { width_m, length_m } => format!(
                "the largest square that fits {width_m} × {length_m} m of floor (a longer side \
                 measures E_d and the end point better)"
            ),
            Space::MaxSide(s) => format!(
                "the longest side allowed, {s} m (a longer side measures E_d and the end point \
                 better)"
            ),
            Space::Side(_) => "the side asked for".to_string(),
        };
        writeln!(
            f,
            "floor: {along:.1} m along the first leg × {across:.1} m across (both squares, the \
             robot's footprint and 10 % for drift): {why}"
        )?;
        write!(
            f,
            "predicted standard errors ({}): E_b ± {:.2e}, E_d ± {:.2e} (± one standard error \
             after the first round)",
            self.method, self.predicted_std_e_b, self.predicted_std_e_d,
        )?;
        let mm = |m: f64| 1000.0 * m;
        if self.end_point_from_rounding_m > 0.0 {
            write!(
                f,
                "\nend point of a {:.2} m square after calibration: {:.1} mm RMS, of which {:.1} \
                 mm from those standard errors and {:.1} mm from rounding every motion to whole \
                 encoder counts (the same in every square of one robot, never calibrated away; \
                 at most {:.1} mm)",
                self.side_m,
                mm(self.predicted_end_point_m),
                mm(self.end_point_from_estimate_m),
                mm(self.end_point_from_rounding_m),
                mm(self.end_point_rounding_max_m),
            )?;
        } else {
            write!(
                f,
                "\nend point of a {:.2} m square after calibration: {:.1} mm RMS from those \
                 standard errors (rounding to whole encoder counts not counted)",
                self.side_m,
                mm(self.predicted_end_point_m),
            )?;
        }
        if !self.target_reached {
            write!(
                f,
                " — the target is NOT reached within the most runs per direction"
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn input() -> PlanInput {
        PlanInput {
            space: Space::MaxSide(4.0),
            footprint_m: 0.5,
            wheelbase_m: 0.39,
            ratios: (1.0, 1.0),
            heading_sigma_rad: 0.37f64.to_radians(),
            readings_at_rest: 1,
            readings_per_s: 50.0,
            run_scatter_rad: 0.0,
            m_per_count: 0.0,
            method: Method::Exact,
            convention: SplitConvention::LeftNominal,
            speed_m_s: 0.2,
            rate_rad_s: 0.5,
            settle_s: 0.5,
            realign: true,
            other_motion_s: 0.0,
            runs_per_direction: 5,
            max_runs_per_direction: 20,
            verification_runs: 3,
            max_rounds: 3,
            target: Target::default(),
        }
    }

    #[test]
    fn the_closed_forms_are_the_bound() {
        // σ(E_b) ≈ E_b²·σ_c/(2π√n), σ(E_d) ≈ (b/L)·σ_c/(4√n) with one reading at each end.
        let i = input();
        // (E_b also holds the leg term under left-nominal, a few per cent at 2 m.)
        for (side, n, e_b) in [(4.0, 5, 1.0), (2.0, 3, 0.976), (3.0, 20, 1.02)] {
            let i = PlanInput {
                ratios: (e_b, 1.0),
                ..i
            };
            let (b, d) = predicted_std(&i, side, n).unwrap();
            let s = i.heading_sigma_rad / (n as f64).sqrt();
            let b_closed = e_b * e_b * s / (2.0 * PI);
            let d_closed = i.wheelbase_m / side * s / 4.0;
            assert!((b / b_closed - 1.0).abs() < 0.03, "{b} vs {b_closed}");
            assert!((d / d_closed - 1.0).abs() < 0.03, "{d} vs {d_closed}");
        }
    }

    #[test]
    fn a_target_sets_the_runs_and_the_side() {
        let with = |target| plan(&PlanInput { target, ..input() }).unwrap();
        let fixed = plan(&input()).unwrap();
        assert!(!fixed.sequential && fixed.runs_per_direction == 5 && fixed.side_m == 4.0);
        // Today's default: 2 rounds of 5 + 5 and 3 + 3 verification.
        assert_eq!(fixed.squares, 26);
        assert_eq!(fixed.max_squares, 36);
        // E_b hardly depends on the side; it would be reached sooner on shorter squares, but the
        // plan keeps the longest side allowed (E_d and the end point are better there): a
        // target sets the runs, not the side.
        let (b5, d5) = predicted_std(&input(), 4.0, 5).unwrap();
        let eb = with(Target {
            e_b_std: Some(b5),
            ..Target::default()
        });
        assert!(eb.sequential && eb.target_reached);
        assert_eq!((eb.side_m, eb.runs_per_direction), (4.0, 5));
        assert!(eb.predicted_std_e_b <= b5 * (1.0 + 1e-9));
        // E_d falls as 1/L: the longest side that fits.
        let ed = with(Target {
            e_d_std: Some(d5),
            ..Target::default()
        });
        assert_eq!((ed.side_m, ed.runs_per_direction), (4.0, 5));
        // Squares: 5 + 5, then 2 + 2 that confirm and verify.
        assert_eq!(ed.squares, 14);
        // Out of reach: said, with the most runs.
        let far = with(Target {
            e_d_std: Some(d5 / 100.0),
            ..Target::default()
        });
        assert!(!far.target_reached && far.runs_per_direction == 20);
        assert!(far.to_string().contains("NOT reached"));
    }

    #[test]
    fn the_floor_sets_the_largest_side() {
        // 4 m squares need 4.4 + 0.5 by 8.8 + 0.5, either way round.
        for (width_m, length_m) in [(9.3, 4.9), (4.9, 9.3)] {
            let s = largest_side(Space::Floor { width_m, length_m }, 0.5);
            assert!((s - 4.0).abs() < 1e-9, "{s}");
        }
        let p = plan(&PlanInput {
            space: Space::Floor {
                width_m: 9.5,
                length_m: 5.0,
            },
            ..input()
        })
        .unwrap();
        assert!(p.floor_m[0] <= 5.0 && p.floor_m[1] <= 9.5, "{p:?}");
        let e = plan(&PlanInput {
            space: Space::Floor {
                width_m: 1.0,
                length_m: 2.0,
            },
            ..input()
        })
        .unwrap_err();
        assert!(matches!(e, PlanError::NoRoom { .. }), "{e}");
        assert!(plan(&PlanInput {
            heading_sigma_rad: -1.0,
            ..input()
        })
        .is_err());
        assert!(matches!(
            plan(&PlanInput {
                method: Method::Umbmark,
                ..input()
            }),
            Err(PlanError::Unpredictable(Method::Umbmark))
        ));
    }

    #[test]
    fn robot_time_counts_legs_turns_settles_and_readings() {
        let i = PlanInput {
            readings_at_rest: 5,
            ..input()
        };
        // 4 × 20 s of legs, 4 × π s of turns, 2 × 0.5 s settles, 3 × 0.1 s of readings.
        let t = square_time_s(&i, 4.0);
        assert!((t - (80.0 + 4.0 * PI + 1.0 + 0.3)).abs() < 1e-9, "{t}");
        let p = plan(&PlanInput {
            other_motion_s: 50.0,
            ..i
        })
        .unwrap();
        assert!((p.robot_time_s - (50.0 + 26.0 * t)).abs() < 1e-6);
        assert_eq!(duration_text(4460.0), "74 min 20 s");
    }

    #[test]
    fn an_end_point_target_is_met() {
        let p = plan(&PlanInput {
            target: Target {
                end_point_m: Some(0.01),
                ..Target::default()
            },
            ..input()
        })
        .unwrap();
        assert!(p.target_reached && p.predicted_end_point_m <= 0.01, "{p:?}");
        // The end point is of the largest square whatever side is driven: one run less misses.
        let fewer = predicted_std(&input(), p.side_m, p.runs_per_direction - 1).unwrap();
        assert!(end_point_rms(4.0, 0.39, fewer.0, fewer.1) > 0.01, "{p:?}");
        // An error of E_b moves a square's end by about (π/2)·L·δ per corner's worth.
        let e = end_point_rms(4.0, 0.39, 1e-3, 0.0);
        assert!(e > 1e-3 && e < 0.05, "{e}");
    }

    #[test]
    fn a_target_on_a_floor_drives_the_largest_square_that_fits_and_says_why() {
        // The README's floor: 5 × 9.5 m holds two 4.0 m squares (4.9 × 9.3 m with a 0.5 m
        // footprint and 10 % for drift); an E_b target sets the runs, not the side.
        let p = plan(&PlanInput {
            space: Space::Floor {
                width_m: 5.0,
                length_m: 9.5,
            },
            method: Method::MatchedLegs,
            target: Target {
                e_b_std: Some(3e-5),
                ..Target::default()
            },
            ..input()
        })
        .unwrap();
        assert_eq!(p.side_m, 4.0, "{p:?}");
        assert!(p.target_reached && p.sequential);
        let text = p.to_string();
        assert!(
            text.contains("the largest square that fits 5 × 9.5 m of floor"),
            "{text}"
        );
        assert!(
            text.contains("rounding to whole encoder counts not counted"),
            "{text}"
        );
    }

    #[test]
    fn the_rounding_to_whole_counts_is_the_simulators() {
        use crate::kinematics::WheelParams;
        use crate::sim::{NoiseModel, Simulator};
        // Robots calibrated perfectly (configured = true parameters), whose targets round to
        // whole counts as the mock device's do: the end points left are the rounding's alone.
        // Their diameters and wheelbases spread over many counts, so where each target falls
        // within its count is spread evenly, as the prediction assumes.
        let (side, counts) = (4.0, 4096.0);
        let m_per_count = PI * 0.15 / counts;
        let (rms, max) = rounding_end_point(side, 0.39, m_per_count);
        let noise = NoiseModel {
            quantise_encoders: true,
            ..NoiseModel::default()
        };
        let golden = [0.618_034, 0.754_878, 0.569_840];
        let mut ends = Vec::new();
        for k in 1..=400 {
            let u = |d: usize| (k as f64 * golden[d]).fract() - 0.5;
            let p = WheelParams {
                left_wheel_diameter_m: 0.15 * (1.0 + 2e-3 * u(0)),
                right_wheel_diameter_m: 0.15 * (1.0 + 2e-3 * u(1)),
                wheelbase_m: 0.39 * (1.0 + 2e-2 * u(2)),
                counts_per_wheel_rev: counts,
            };
            let mut sim = Simulator::new(p, p, noise, 1).unwrap();
            let end = [Direction::Cw, Direction::Ccw]
                .into_iter()
                .map(|d| sim.run_square(side, d).unwrap().final_pose.distance_m())
                .fold(0.0, f64::max);
            assert!(end <= max * 1.05, "{end} m beyond the most, {max} m");
            ends.push(end);
        }
        let seen = (ends.iter().map(|e| e * e).sum::<f64>() / ends.len() as f64).sqrt();
        assert!(
            (seen / rms - 1.0).abs() < 0.2,
            "RMS {seen} m, predicted {rms} m"
        );
        // Millimetres on the demo robot's 4 m squares, far above what its standard errors leave.
        assert!(rms > 1e-3 && rms < 3e-3, "{rms}");
        // Counted in the plan, in quadrature with the estimate's part.
        let p = plan(&PlanInput {
            m_per_count,
            ..input()
        })
        .unwrap();
        assert!((p.end_point_from_rounding_m - rms).abs() < 1e-12);
        let total = p.end_point_from_estimate_m.hypot(rms);
        assert!((p.predicted_end_point_m - total).abs() < 1e-12);
        assert!(p
            .to_string()
            .contains("rounding every motion to whole encoder counts"));
        // An end-point target below the rounding's part is never reached, however many runs.
        let below = plan(&PlanInput {
            m_per_count,
            target: Target {
                end_point_m: Some(rms * 0.9),
                ..Target::default()
            },
            ..input()
        })
        .unwrap();
        assert!(!below.target_reached, "{below:?}");
    }
}
