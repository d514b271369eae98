//! Offline calibration from bi-directional square tests: pure functions, no I/O.
//!
//! The input is one [`SquareTest`]: the square's side, the wheelbase the controller used, and per
//! run the final-minus-start heading error (and optionally the final position) of each clockwise
//! and counter-clockwise run. Five estimators turn it into `E_b`, `E_d` and a [`Correction`] for
//! the controller's parameters:
//!
//! | [`Method`] | uses | source |
//! |---|---|---|
//! | `umbmark` | final positions | Borenstein & Feng 1996, the paper's eqs. 1–3 |
//! | `lee` | final positions | Lee, Jung & Chung 2011, reconstructed (see [`lee`]) |
//! | `heading-only` | final headings | the paper's eqs. 6–7, 10 without `α_εd`, 11 with `b_nom` |
//! | `jung-chung` | final headings | the paper's eqs. 6–11 as printed |
//! | `exact` | final headings | our closed-form inversion of the exact square model |
//!
//! Methods see the *means* of the runs in each direction (the paper's "c.g."). Standard errors
//! come from the run-to-run scatter propagated through each estimator's own Jacobian; the
//! Cramér–Rao bound for a given heading noise is in [`uncertainty`].
//!
//! Heading errors follow the crate's convention (see [`crate::kinematics`]): radians,
//! counter-clockwise positive, final minus start, wrapped. A compass azimuth is clockwise
//! positive and must be negated before it gets here.

pub mod agreement;
pub mod by_hand;
pub mod convention;
pub mod error;
pub mod exact;
pub mod gyro;
pub mod heading_only;
pub mod heading_reference;
pub mod holes;
pub mod independence;
pub mod jung_chung;
pub mod lee;
pub mod legs;
pub mod matched_legs;
pub mod multiplier_fit;
pub mod observability;
pub mod online;
pub mod plan;
pub mod plausibility;
pub mod pool;
pub mod pose_calibration;
pub mod pose_fit;
pub mod pose_reference;
pub mod recording;
pub mod segment;
pub mod stated;
pub mod swing;
pub mod time_offset;
pub mod tracker;
pub mod umbmark;
pub mod uncertainty;

pub use crate::samples::HeadingKind;
pub use error::CalibrationError;

use crate::kinematics::{Correction, Direction, Displacement, SplitConvention};
use nalgebra::{SMatrix, SVector};
use serde::{Deserialize, Serialize};
use std::f64::consts::{FRAC_PI_2, PI};
use std::fmt;
use std::str::FromStr;

/// One square run's measurements.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct RunMeasurement {
    /// Final-minus-start heading error (rad, CCW positive, wrapped to (-π, π]).
    pub heading_error_rad: f64,
    /// Final position in the start frame (m): x along the first leg, y to its left.
    pub final_xy_m: Option<[f64; 2]>,
    /// The heading along the legs, when it was recorded ([`legs`]): each leg's mean heading
    /// error (sensor minus odometry) and odometry.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub legs: Option<legs::LegMeasurement>,
    /// The odometry's turn and distance over the run, from rest to rest, when measured (a
    /// drive that ends its motions on its own odometry does not turn exactly ±2π); `None`: as
    /// commanded ([`ideal_odometry`]). See [`exact`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub odometry: Option<Displacement>,
    /// Variance of `heading_error_rad` from the heading sensor's own noise (rad²), when the
    /// readings tell it: a floor under the run-to-run scatter in the standard errors, which
    /// two runs estimate badly.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise_variance_rad2: Option<f64>,
}

impl RunMeasurement {
    /// Whether the heading along the legs was measured.
    pub fn has_leg_heading(&self) -> bool {
        self.legs
            .is_some_and(|l| l.legs.iter().all(|m| m.error_rad.is_finite()))
    }

    /// A run with only its final heading error (rad).
    pub fn heading(heading_error_rad: f64) -> Self {
        RunMeasurement {
            heading_error_rad,
            ..RunMeasurement::default()
        }
    }
}

/// The odometry of a square of side `side_m` in `direction` executed as commanded: four sides
/// forward and a turn of ±2π (counter-clockwise positive).
pub fn ideal_odometry(direction: Direction, side_m: f64) -> Displacement {
    Displacement {
        distance_m: 4.0 * side_m,
        turn_rad: direction.turn_sign() * 2.0 * PI,
    }
}

/// A bi-directional square test: everything the estimators need.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SquareTest {
    /// Side of the square (m).
    pub side_m: f64,
    /// Wheelbase configured on the controller while the test ran (m): the paper's `b_nominal`.
    pub wheelbase_m: f64,
    /// Clockwise runs.
    pub cw: Vec<RunMeasurement>,
    /// Counter-clockwise runs.
    pub ccw: Vec<RunMeasurement>,
}

impl SquareTest {
    /// The test of `runs`, each with its direction, on squares of `side_m` driven with
    /// `wheelbase_m` configured.
    pub fn from_runs(
        side_m: f64,
        wheelbase_m: f64,
        runs: impl IntoIterator<Item = (Direction, RunMeasurement)>,
    ) -> Self {
        let (mut cw, mut ccw) = (Vec::new(), Vec::new());
        for (direction, m) in runs {
            match direction {
                Direction::Cw => cw.push(m),
                Direction::Ccw => ccw.push(m),
            }
        }
        SquareTest {
            side_m,
            wheelbase_m,
            cw,
            ccw,
        }
    }

    /// The same test without final positions (heading-only data, as from a compass).
    pub fn without_positions(mut self) -> Self {
        for r in self.cw.iter_mut().chain(self.ccw.iter_mut()) {
            r.final_xy_m = None;
        }
        self
    }

    /// Warnings for runs whose heading error is 90° or more in size: the exact inversion is
    /// still valid there (up to 180°), but the paper's small-angle methods are not, an error of
    /// that size more often means a sign or unit mistake, and beyond 180° it would wrap.
    pub fn large_heading_warnings(&self) -> Vec<String> {
        let mut out = Vec::new();
        for (direction, runs) in [(Direction::Cw, &self.cw), (Direction::Ccw, &self.ccw)] {
            for (i, r) in runs.iter().enumerate() {
                if r.heading_error_rad.abs() >= FRAC_PI_2 {
                    out.push(format!(
                        "{direction} run {}: heading error {:.1}° is 90° or more: check the sign \
                         convention and units; trust `exact` only (the paper's methods assume \
                         small errors), and an error beyond 180° would have wrapped",
                        i + 1,
                        r.heading_error_rad.to_degrees()
                    ));
                }
            }
        }
        out
    }

    /// Rejects input no real square test can produce.
    pub fn validate(&self) -> Result<(), CalibrationError> {
        for (name, value) in [("side_m", self.side_m), ("wheelbase_m", self.wheelbase_m)] {
            if !(value.is_finite() && value > 0.0) {
                return Err(CalibrationError::BadGeometry { name, value });
            }
        }
        let mut with = 0;
        for (direction, runs) in [(Direction::Cw, &self.cw), (Direction::Ccw, &self.ccw)] {
            if runs.is_empty() {
                return Err(CalibrationError::NoRuns(direction));
            }
            for (index, r) in runs.iter().enumerate() {
                if !r.heading_error_rad.is_finite() {
                    return Err(CalibrationError::NonFinite {
                        what: "heading error",
                        direction,
                        index,
                    });
                }
                // Wrapped errors lie in (−π, π]; anything larger was not wrapped (or is in
                // degrees). The exact inversion holds up to 180°: larger-than-90° errors are
                // accepted, with [`SquareTest::large_heading_warnings`].
                if r.heading_error_rad.abs() > PI {
                    return Err(CalibrationError::HeadingTooLarge {
                        direction,
                        index,
                        degrees: r.heading_error_rad.to_degrees(),
                    });
                }
                if let Some(xy) = r.final_xy_m {
                    if !(xy[0].is_finite() && xy[1].is_finite()) {
                        return Err(CalibrationError::NonFinite {
                            what: "final position",
                            direction,
                            index,
                        });
                    }
                    // A square run cannot end farther away than its whole perimeter.
                    let distance_m = xy[0].hypot(xy[1]);
                    if distance_m > 4.0 * self.side_m {
                        return Err(CalibrationError::FarEndPoint {
                            direction,
                            index,
                            distance_m,
                            side_m: self.side_m,
                        });
                    }
                    with += 1;
                }
            }
        }
        let total = self.cw.len() + self.ccw.len();
        if with != 0 && with != total {
            return Err(CalibrationError::InconsistentPositions { with, total });
        }
        Ok(())
    }

    /// Whether at least one run in each direction has its heading along the legs (what the leg
    /// method needs; it leaves out the runs without).
    pub fn has_leg_headings(&self) -> bool {
        let with = |runs: &[RunMeasurement]| runs.iter().any(RunMeasurement::has_leg_heading);
        with(&self.cw) && with(&self.ccw)
    }

    /// Runs without the heading along the legs, of all runs: the leg method leaves them out (a
    /// stream that lost the end of a run), and says so.
    pub fn runs_without_leg_headings(&self) -> (usize, usize) {
        let all: Vec<&RunMeasurement> = self.cw.iter().chain(self.ccw.iter()).collect();
        (
            all.iter().filter(|r| !r.has_leg_heading()).count(),
            all.len(),
        )
    }

    /// Whether every run has a final position.
    pub fn has_positions(&self) -> bool {
        self.cw
            .iter()
            .chain(self.ccw.iter())
            .all(|r| r.final_xy_m.is_some())
    }
}

/// An estimator of `E_b`, `E_d` from a square test.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Borenstein & Feng's UMBmark (final positions).
    Umbmark,
    /// Lee, Jung & Chung's method, reconstructed (final positions).
    Lee,
    /// The paper's heading-error equations without the coupled terms.
    HeadingOnly,
    /// The paper's proposed method, eqs. 6–11 as printed.
    JungChung,
    /// Our exact closed-form inversion (heading errors).
    Exact,
    /// The exact inversion on the heading along the legs ([`legs`]).
    Legs,
    /// The exact inversion on legs matched by azimuth: immune to a compass's deviation
    /// ([`matched_legs`]).
    MatchedLegs,
}

impl Method {
    /// Every method, in the order reports list them.
    pub const ALL: [Method; 7] = [
        Method::Umbmark,
        Method::Lee,
        Method::HeadingOnly,
        Method::JungChung,
        Method::Exact,
        Method::Legs,
        Method::MatchedLegs,
    ];

    /// The method's stable name (CLI and JSON).
    pub fn name(self) -> &'static str {
        match self {
            Method::Umbmark => "umbmark",
            Method::Lee => "lee",
            Method::HeadingOnly => "heading-only",
            Method::JungChung => "jung-chung",
            Method::Exact => "exact",
            Method::Legs => "legs",
            Method::MatchedLegs => "matched-legs",
        }
    }

    /// Whether the method needs the heading along the legs.
    pub fn needs_leg_headings(self) -> bool {
        matches!(self, Method::Legs | Method::MatchedLegs)
    }

    /// Whether the method needs final positions (otherwise it uses final headings only).
    pub fn needs_positions(self) -> bool {
        matches!(self, Method::Umbmark | Method::Lee)
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                format!("unknown method {s:?}; expected one of umbmark, lee, heading-only, jung-chung, exact, legs, matched-legs")
            })
    }
}

/// The means of a test's runs: `[θ_cw, x_cw, y_cw, θ_ccw, x_ccw, y_ccw]` (positions 0 if absent).
///
/// Estimators are functions of this vector alone, which is what lets one numerical Jacobian
/// give every method its standard error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeanObservation {
    v: SVector<f64, 6>,
    has_positions: bool,
    odometry: [Displacement; 2],
}

impl MeanObservation {
    /// The means of a (validated) test.
    pub fn of(test: &SquareTest) -> Self {
        let mut v = SVector::<f64, 6>::zeros();
        let mut odometry = [Displacement::default(); 2];
        for (k, (offset, runs, direction)) in
            [(0, &test.cw, Direction::Cw), (3, &test.ccw, Direction::Ccw)]
                .into_iter()
                .enumerate()
        {
            let n = runs.len() as f64;
            for r in runs {
                v[offset] += r.heading_error_rad / n;
                if let Some(xy) = r.final_xy_m {
                    v[offset + 1] += xy[0] / n;
                    v[offset + 2] += xy[1] / n;
                }
                let o = r
                    .odometry
                    .unwrap_or_else(|| ideal_odometry(direction, test.side_m));
                odometry[k].distance_m += o.distance_m / n;
                odometry[k].turn_rad += o.turn_rad / n;
            }
        }
        MeanObservation {
            v,
            has_positions: test.has_positions(),
            odometry,
        }
    }

    /// Mean odometry of the clockwise runs (their turn and distance).
    pub fn odometry_cw(&self) -> Displacement {
        self.odometry[0]
    }
    /// Mean odometry of the counter-clockwise runs.
    pub fn odometry_ccw(&self) -> Displacement {
        self.odometry[1]
    }

    /// Mean clockwise heading error (rad).
    pub fn heading_cw(&self) -> f64 {
        self.v[0]
    }
    /// Mean counter-clockwise heading error (rad).
    pub fn heading_ccw(&self) -> f64 {
        self.v[3]
    }
    /// Mean clockwise final position (m), if measured.
    pub fn xy_cw(&self) -> Option<[f64; 2]> {
        self.has_positions.then(|| [self.v[1], self.v[2]])
    }
    /// Mean counter-clockwise final position (m), if measured.
    pub fn xy_ccw(&self) -> Option<[f64; 2]> {
        self.has_positions.then(|| [self.v[4], self.v[5]])
    }
}

/// Geometry and convention every estimator needs besides the means.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Context {
    /// Square side (m).
    pub side_m: f64,
    /// Wheelbase configured during the test (m).
    pub wheelbase_m: f64,
    /// How the ratio estimate becomes wheel diameters (also fixes `E_b` for `exact`).
    pub convention: SplitConvention,
}

/// One method's result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    /// Which estimator.
    pub method: Method,
    /// `E_b = b_actual / b_configured`.
    pub e_b: f64,
    /// `E_d = D_R / D_L`, relative to the configured ratio.
    pub e_d: f64,
    /// Standard error of `e_b` from run-to-run scatter (needs ≥ 2 runs per direction), never
    /// below what the heading's own noise gives when the runs state it.
    pub e_b_std_err: Option<f64>,
    /// Standard error of `e_d`, as `e_b_std_err`.
    pub e_d_std_err: Option<f64>,
    /// With one run in a direction (no scatter to measure): the standard error of `e_b` that
    /// the heading's measured noise alone gives. A lower bound: what changes from run to run on
    /// a real floor (slip, a bump, the start) is not in it. `None` when there is a scatter, or
    /// when the runs do not state their noise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub e_b_noise_std_err: Option<f64>,
    /// As `e_b_noise_std_err`, for `e_d`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub e_d_noise_std_err: Option<f64>,
    /// Factors to apply to the configured parameters.
    pub correction: Correction,
    /// The split convention used.
    pub convention: String,
}

impl Estimate {
    /// The estimate `method` gives as `correction`, with standard errors `(E_b, E_d)` when
    /// known, under `convention`.
    pub fn of(
        method: Method,
        correction: Correction,
        std_err: Option<(f64, f64)>,
        convention: &SplitConvention,
    ) -> Estimate {
        Estimate {
            method,
            e_b: correction.e_b(),
            e_d: correction.e_d(),
            e_b_std_err: std_err.map(|s| s.0),
            e_d_std_err: std_err.map(|s| s.1),
            e_b_noise_std_err: None,
            e_d_noise_std_err: None,
            correction,
            convention: convention.name().to_string(),
        }
    }

    /// The same estimate with the noise-only standard errors `(E_b, E_d)` that stand in when
    /// there is no scatter; ignored when the estimate has a standard error already. A zero
    /// (a method that uses nothing the noise touches, UMBmark's end points) states nothing.
    pub fn with_noise_std_err(mut self, noise: Option<(f64, f64)>) -> Estimate {
        let stated = |x: f64| (x.is_finite() && x > 0.0).then_some(x);
        if self.e_b_std_err.is_none() && self.e_d_std_err.is_none() {
            self.e_b_noise_std_err = noise.and_then(|n| stated(n.0));
            self.e_d_noise_std_err = noise.and_then(|n| stated(n.1));
        }
        self
    }
}

/// The estimator's point value as a correction.
fn point(
    method: Method,
    obs: &MeanObservation,
    ctx: &Context,
) -> Result<Correction, CalibrationError> {
    let (e_b, e_d) = match method {
        Method::Umbmark => umbmark::ratios(obs, ctx)?,
        Method::Lee => lee::ratios(obs, ctx)?,
        Method::HeadingOnly => heading_only::ratios(obs, ctx)?,
        Method::JungChung => jung_chung::ratios(obs, ctx)?,
        // On the test `legs::equivalent_test` made of the leg headings.
        Method::Exact | Method::Legs => exact::ratios(obs, ctx)?,
        // Estimated on its own ([`matched_legs::estimate`]); never reached.
        Method::MatchedLegs => return Err(CalibrationError::MissingLegHeadings),
    };
    if !(e_b.is_finite() && e_b > 0.0 && e_d.is_finite() && e_d > 0.0) {
        return Err(CalibrationError::NotPhysical {
            method,
            reason: format!("estimate E_b = {e_b}, E_d = {e_d} is not a robot"),
        });
    }
    Ok(ctx.convention.split(e_b, e_d, ctx.wheelbase_m)?)
}

/// Estimates `E_b`, `E_d` with one method, with standard errors when each direction has ≥ 2 runs.
pub fn estimate(
    method: Method,
    test: &SquareTest,
    convention: SplitConvention,
) -> Result<Estimate, CalibrationError> {
    test.validate()?;
    if method.needs_positions() && !test.has_positions() {
        return Err(CalibrationError::MissingPositions(method));
    }
    if method == Method::MatchedLegs {
        return matched_legs::estimate(test, convention);
    }
    let equivalent;
    let test = if method.needs_leg_headings() {
        equivalent = legs::equivalent_test(test)?;
        &equivalent
    } else {
        test
    };
    let ctx = Context {
        side_m: test.side_m,
        wheelbase_m: test.wheelbase_m,
        convention,
    };
    let obs = MeanObservation::of(test);
    let correction = point(method, &obs, &ctx)?;
    let std_err = standard_errors(method, test, &obs, &ctx, false);
    // The noise alone stands in only where there is no scatter to measure.
    let noise = std_err
        .is_none()
        .then(|| standard_errors(method, test, &obs, &ctx, true))
        .flatten();
    Ok(Estimate::of(method, correction, std_err, &ctx.convention).with_noise_std_err(noise))
}

/// The method to write back unless the user names one, by what the data holds and what the
/// heading sensor is.
///
/// With the heading along the legs: `matched-legs` for a sensor that may deviate (a compass):
/// it compares legs that point the same way, so a deviation curve cancels ([`matched_legs`]);
/// `legs` for a gyro or a reference, which cannot deviate and where comparing the first and
/// last legs uses more of the square (see [`legs`] and the real-data scoreboard in docs/research.md).
/// Both leave out the start transient real robots show. With final headings only, `exact`.
/// `None` never happens today; it is kept so a caller handles a test no method can use.
pub fn default_method(
    has_leg_headings: bool,
    has_positions: bool,
    kind: HeadingKind,
) -> Option<Method> {
    let _ = has_positions;
    Some(match (has_leg_headings, kind.may_deviate()) {
        (false, _) => Method::Exact,
        (true, true) => Method::MatchedLegs,
        (true, false) => Method::Legs,
    })
}

/// Why [`default_method`] picks `method`, as a clause for reports.
pub fn default_method_reason(method: Method) -> &'static str {
    match method {
        Method::MatchedLegs => {
            "the default with the heading along the legs from a sensor that may deviate (a \
             compass, or an IMU of unknown kind): it compares legs pointing the same way, so a \
             deviation cancels"
        }
        Method::Legs => {
            "the default with the heading along the legs from a sensor that cannot deviate (a \
             gyro or a reference): the first leg against the last, past the start transient"
        }
        _ => {
            "the default when the heading along the legs was not recorded in both directions: \
             the exact inversion of the headings at rest"
        }
    }
}

/// One method's estimate or the reason it has none.
pub type MethodResult = (Method, Result<Estimate, CalibrationError>);

/// Every method the data supports (position methods only with positions), in [`Method::ALL`]
/// order; a method that fails is returned as its error beside the others.
pub fn estimate_all(
    test: &SquareTest,
    convention: SplitConvention,
) -> Result<Vec<MethodResult>, CalibrationError> {
    test.validate()?;
    Ok(Method::ALL
        .into_iter()
        .filter(|m| !m.needs_positions() || test.has_positions())
        .filter(|m| !m.needs_leg_headings() || test.has_leg_headings())
        .map(|m| (m, estimate(m, test, convention)))
        .collect())
}

/// Standard errors of `(E_b, E_d)` by the delta method: the sample covariance of each
/// direction's runs, divided by the run count, pushed through the estimator's numerical
/// Jacobian with respect to the means.
///
/// The heading's variance is floored by what the sensor's own noise gives when every run of a
/// direction states it ([`RunMeasurement::noise_variance_rad2`]): two runs' scatter is often
/// far below the truth by chance. One run has no standard error: its noise alone would leave
/// out what changes from run to run on a real floor (slip, a bump, the start), which on
/// motion-capture recordings is most of it. With `noise_only`, the errors the stated noise
/// alone gives (every run of both directions must state it), for a test with one run in a
/// direction ([`Estimate::e_b_noise_std_err`]).
fn standard_errors(
    method: Method,
    test: &SquareTest,
    obs: &MeanObservation,
    ctx: &Context,
    noise_only: bool,
) -> Option<(f64, f64)> {
    let mut cov = SMatrix::<f64, 6, 6>::zeros();
    for (offset, runs) in [(0, &test.cw), (3, &test.ccw)] {
        let n = runs.len() as f64;
        let noise = noise_variance_of_mean(runs);
        if noise_only {
            cov[(offset, offset)] = noise?;
            continue;
        }
        if runs.len() < 2 {
            return None;
        }
        let rows: Vec<[f64; 3]> = runs
            .iter()
            .map(|r| {
                let xy = r.final_xy_m.unwrap_or([0.0, 0.0]);
                [r.heading_error_rad, xy[0], xy[1]]
            })
            .collect();
        let mean = [0, 1, 2].map(|k| rows.iter().map(|r| r[k]).sum::<f64>() / n);
        for i in 0..3 {
            for j in 0..3 {
                let s: f64 = rows
                    .iter()
                    .map(|r| (r[i] - mean[i]) * (r[j] - mean[j]))
                    .sum();
                // Covariance of the mean: sample covariance / n.
                cov[(offset + i, offset + j)] = s / (n - 1.0) / n;
            }
        }
        if let Some(v) = noise {
            cov[(offset, offset)] = cov[(offset, offset)].max(v);
        }
    }
    let mut jac = SMatrix::<f64, 2, 6>::zeros();
    for k in 0..6 {
        let h = 1e-7 * obs.v[k].abs().max(1.0);
        let mut plus = *obs;
        let mut minus = *obs;
        plus.v[k] += h;
        minus.v[k] -= h;
        let (Ok(p), Ok(m)) = (point(method, &plus, ctx), point(method, &minus, ctx)) else {
            return None;
        };
        jac[(0, k)] = (p.e_b() - m.e_b()) / (2.0 * h);
        jac[(1, k)] = (p.e_d() - m.e_d()) / (2.0 * h);
    }
    let out = jac * cov * jac.transpose();
    Some((out[(0, 0)].max(0.0).sqrt(), out[(1, 1)].max(0.0).sqrt()))
}

/// The variance of the mean heading error of `runs` from the sensor's noise (rad²), when every
/// run states it.
pub(crate) fn noise_variance_of_mean(runs: &[RunMeasurement]) -> Option<f64> {
    let n = runs.len() as f64;
    let sum = runs
        .iter()
        .map(|r| r.noise_variance_rad2)
        .sum::<Option<f64>>()?;
    (n > 0.0).then(|| sum / (n * n))
}

/// `E_max,sys` (Borenstein & Feng): the larger distance from the start of the CW and the CCW
/// runs' mean end points (m). `None` when a direction has no end points.
pub fn e_max_sys(cw_xy_m: &[[f64; 2]], ccw_xy_m: &[[f64; 2]]) -> Option<f64> {
    let centre = |pts: &[[f64; 2]]| -> Option<f64> {
        if pts.is_empty() {
            return None;
        }
        let n = pts.len() as f64;
        let x = pts.iter().map(|p| p[0]).sum::<f64>() / n;
        let y = pts.iter().map(|p| p[1]).sum::<f64>() / n;
        Some(x.hypot(y))
    };
    Some(centre(cw_xy_m)?.max(centre(ccw_xy_m)?))
}

/// `E_d` from a per-leg heading drift `β` (rad) on a straight leg of `side_m` (paper eq. 11 and
/// Borenstein's form): the leg is an arc of radius `R = (L/2)/sin(β/2)` and
/// `E_d = (R + b/2)/(R − b/2)`, written with `1/R` so that `β = 0` gives exactly 1.
pub(crate) fn e_d_from_leg_drift(beta_rad: f64, side_m: f64, wheelbase_m: f64) -> f64 {
    let half_b_over_r = 0.5 * wheelbase_m * (0.5 * beta_rad).sin() / (0.5 * side_m);
    (1.0 + half_b_over_r) / (1.0 - half_b_over_r)
}

/// `E_b` from a per-corner turn error `α` (rad) of a nominal 90° turn (paper eq. 10, whose "90"
/// is in degrees: `E_b = 90°/(90° − α)`).
pub(crate) fn e_b_from_corner_error(alpha_rad: f64) -> f64 {
    let ninety = 90.0;
    ninety / (ninety - alpha_rad.to_degrees())
}

/// Borenstein's eq. 3: the per-corner (`α`) and per-leg (`β`) errors from the mean final
/// positions, each the average of an x-based and a y-based estimate. The CCW square lies to the
/// left of the first leg and the CW square is its mirror, both in the start frame.
pub(crate) fn alpha_beta_from_positions(
    xy_cw: [f64; 2],
    xy_ccw: [f64; 2],
    side_m: f64,
) -> (f64, f64) {
    let [x_cw, y_cw] = xy_cw;
    let [x_ccw, y_ccw] = xy_ccw;
    let k = -4.0 * side_m;
    let alpha = 0.5 * ((x_cw + x_ccw) / k + (y_cw - y_ccw) / k);
    let beta = 0.5 * ((x_cw - x_ccw) / k + (y_cw + y_ccw) / k);
    (alpha, beta)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn test_with(cw: &[f64], ccw: &[f64]) -> SquareTest {
        let runs = |v: &[f64]| {
            v.iter()
                .map(|&h| RunMeasurement {
                    heading_error_rad: h,
                    final_xy_m: None,
                    ..RunMeasurement::default()
                })
                .collect()
        };
        SquareTest {
            side_m: 4.0,
            wheelbase_m: 0.39,
            cw: runs(cw),
            ccw: runs(ccw),
        }
    }

    #[test]
    fn impossible_input_is_rejected_with_a_reason() {
        assert_eq!(
            test_with(&[], &[0.01]).validate(),
            Err(CalibrationError::NoRuns(Direction::Cw))
        );
        assert!(matches!(
            test_with(&[0.01, f64::NAN], &[0.01]).validate(),
            Err(CalibrationError::NonFinite { index: 1, .. })
        ));
        assert!(matches!(
            test_with(&[0.01], &[-3.2]).validate(),
            Err(CalibrationError::HeadingTooLarge {
                direction: Direction::Ccw,
                ..
            })
        ));
        // 90°–180°: accepted, with a warning naming the run.
        let big = test_with(&[0.01], &[-1.6]);
        assert_eq!(big.validate(), Ok(()));
        let w = big.large_heading_warnings();
        assert!(
            w.len() == 1 && w[0].contains("counter-clockwise run 1"),
            "{w:?}"
        );
        let mut t = test_with(&[0.01, 0.02], &[0.01]);
        t.cw[0].final_xy_m = Some([0.1, 0.2]);
        assert_eq!(
            t.validate(),
            Err(CalibrationError::InconsistentPositions { with: 1, total: 3 })
        );
        let mut t = test_with(&[0.01], &[0.01]);
        t.side_m = 0.0;
        assert!(matches!(
            t.validate(),
            Err(CalibrationError::BadGeometry { .. })
        ));
        assert_eq!(
            estimate(
                Method::Umbmark,
                &test_with(&[0.01], &[0.01]),
                SplitConvention::LeftNominal
            ),
            Err(CalibrationError::MissingPositions(Method::Umbmark))
        );
    }

    #[test]
    fn an_impossible_robot_is_not_estimated() {
        // A 1 cm "square" on a 0.39 m base with 40° of leg drift each way implies a negative
        // left wheel factor: no robot does that.
        let mut t = test_with(&[0.7], &[0.7]);
        t.side_m = 0.01;
        assert!(matches!(
            estimate(Method::Exact, &t, SplitConvention::LeftNominal),
            Err(CalibrationError::NotPhysical {
                method: Method::Exact,
                ..
            })
        ));
    }

    #[test]
    fn method_names_round_trip() {
        for m in Method::ALL {
            assert_eq!(m.name().parse::<Method>(), Ok(m));
        }
        assert!("borenstein".parse::<Method>().is_err());
    }

    #[test]
    fn standard_error_needs_two_runs_and_scales_with_scatter() {
        let one = estimate(
            Method::Exact,
            &test_with(&[-0.1], &[0.05]),
            SplitConvention::LeftNominal,
        )
        .unwrap();
        assert!(one.e_b_std_err.is_none());
        let tight = estimate(
            Method::Exact,
            &test_with(&[-0.099, -0.101], &[0.049, 0.051]),
            SplitConvention::LeftNominal,
        )
        .unwrap();
        let wide = estimate(
            Method::Exact,
            &test_with(&[-0.09, -0.11], &[0.04, 0.06]),
            SplitConvention::LeftNominal,
        )
        .unwrap();
        let (t, w) = (tight.e_b_std_err.unwrap(), wide.e_b_std_err.unwrap());
        // Same means, ten times the spread: ten times the standard error.
        assert!((w / t - 10.0).abs() < 1e-6, "ratio {}", w / t);
    }
}
