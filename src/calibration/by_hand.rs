//! A square test typed in by hand (`odocal estimate`): headings (and perhaps end points) of
//! runs measured with a compass and a tape, estimated by every method or one, with the default
//! method for what was measured, the corrected parameters when the wheel diameter is given, and
//! the Cramér–Rao bound when the heading sensor's noise is.
//!
//! Heading errors are final minus start, counter-clockwise positive (degrees here, radians in
//! [`RunMeasurement`]); end points are in the start frame, x along the first leg, y to its
//! left (m).

use super::uncertainty::{cramer_rao_bound, heading_error_sigma, TestDesign};
use super::{CalibrationError, Estimate, HeadingKind, Method, RunMeasurement, SquareTest};
use crate::kinematics::{SplitConvention, WheelParams, PHYSICAL_DIAMETER_M};

/// What was measured, as typed (with the `cli` feature, `odocal estimate`'s flags, their doc
/// comments the help).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct HandInput {
    /// Square side (m).
    #[cfg_attr(feature = "cli", arg(long))]
    pub side_m: f64,
    /// Wheelbase configured on the controller during the test (m).
    #[cfg_attr(feature = "cli", arg(long))]
    pub wheelbase_m: f64,
    /// Final-minus-start heading error of each clockwise run (deg, counter-clockwise positive;
    /// negate a compass azimuth), comma-separated.
    #[cfg_attr(
        feature = "cli",
        arg(
            long,
            value_delimiter = ',',
            allow_hyphen_values = true,
            required = true
        )
    )]
    pub cw_heading_deg: Vec<f64>,
    /// Same for each counter-clockwise run.
    #[cfg_attr(
        feature = "cli",
        arg(
            long,
            value_delimiter = ',',
            allow_hyphen_values = true,
            required = true
        )
    )]
    pub ccw_heading_deg: Vec<f64>,
    /// Final position of each clockwise run in the start frame (x along the first leg, y to its
    /// left), as "x,y;x,y" (m). Enables UMBmark and Lee.
    #[cfg_attr(feature = "cli", arg(long, allow_hyphen_values = true))]
    pub cw_xy_m: Option<EndPoints>,
    /// Same for each counter-clockwise run.
    #[cfg_attr(feature = "cli", arg(long, allow_hyphen_values = true))]
    pub ccw_xy_m: Option<EndPoints>,
    /// Method to run: all, umbmark, lee, heading-only, jung-chung or exact.
    #[cfg_attr(feature = "cli", arg(long, default_value = "all"))]
    pub method: String,
    /// How the diameter correction is split between the wheels.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub convention: super::convention::ConventionChoice,
    /// Wheel diameter configured during the test (m); prints the corrected parameters.
    #[cfg_attr(feature = "cli", arg(long))]
    pub wheel_diameter_m: Option<f64>,
    /// The heading sensor's noise per reading (deg; σ); prints the Cramér–Rao bound for this
    /// test.
    #[cfg_attr(
        feature = "cli",
        arg(
            long = "heading-sigma-deg",
            alias = "compass-sigma-deg",
            value_name = "COMPASS_SIGMA_DEG"
        )
    )]
    pub heading_sigma_deg: Option<f64>,
}

/// End points of runs, typed as `x,y;x,y` (m).
#[derive(Debug, Clone, PartialEq)]
pub struct EndPoints(pub Vec<[f64; 2]>);

impl std::str::FromStr for EndPoints {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        s.split(';')
            .filter(|p| !p.trim().is_empty())
            .map(|pair| {
                let v: Vec<&str> = pair.split(',').map(str::trim).collect();
                match v.as_slice() {
                    [x, y] => Ok([
                        x.parse::<f64>().map_err(|e| format!("{x:?}: {e}"))?,
                        y.parse::<f64>().map_err(|e| format!("{y:?}: {e}"))?,
                    ]),
                    _ => Err(format!("{pair:?} is not \"x,y\"")),
                }
            })
            .collect::<Result<Vec<_>, _>>()
            .map(EndPoints)
    }
}

/// What came of it.
#[derive(Debug, Clone, PartialEq)]
pub struct HandReport {
    /// The test as estimated.
    pub test: SquareTest,
    /// The split convention used.
    pub convention: SplitConvention,
    /// The parameters configured during the test, when the wheel diameter was given.
    pub configured: Option<WheelParams>,
    /// The default method for what was measured (the sensor's kind unknown).
    pub default: Option<Method>,
    /// Each estimate, with its corrected parameters when configured ones are known.
    pub rows: Vec<(Estimate, Option<WheelParams>)>,
    /// Methods that could not estimate, with why.
    pub failures: Vec<(Method, String)>,
    /// The Cramér–Rao bound's standard deviations of E_b and E_d, when the noise was given.
    pub cramer_rao_std: Option<[f64; 2]>,
    /// The sensor noise the bound used (deg per reading).
    pub heading_sigma_deg: Option<f64>,
    /// Heading errors large enough to doubt.
    pub warnings: Vec<String>,
}

impl HandReport {
    /// The estimates alone.
    pub fn estimates(&self) -> Vec<Estimate> {
        self.rows.iter().map(|(e, _)| e.clone()).collect()
    }
}

/// Runs of one direction from their headings (deg) and end points.
fn runs(headings_deg: &[f64], xy: Option<&Vec<[f64; 2]>>) -> Result<Vec<RunMeasurement>, String> {
    if let Some(xy) = xy {
        if xy.len() != headings_deg.len() {
            return Err(format!(
                "{} headings but {} positions: give one position per run",
                headings_deg.len(),
                xy.len()
            ));
        }
    }
    Ok(headings_deg
        .iter()
        .enumerate()
        .map(|(i, h)| RunMeasurement {
            heading_error_rad: h.to_radians(),
            final_xy_m: xy.map(|l| l[i]),
            ..RunMeasurement::default()
        })
        .collect())
}

/// Refuses numbers no square test a robot can drive has (a 1e-308 m wheelbase makes every
/// derivative overflow); NaN is [`SquareTest::validate`]'s to name.
fn check_ranges(input: &HandInput) -> Result<(), String> {
    for (flag, v, lo, hi) in [
        ("--side-m", input.side_m, 0.05, 100.0),
        ("--wheelbase-m", input.wheelbase_m, 0.01, 10.0),
    ] {
        if v > hi || (v > 0.0 && v < lo) {
            return Err(format!(
                "{flag} must be in [{lo}, {hi}] m, got {}",
                crate::ranges::compact(v)
            ));
        }
    }
    if let Some(d) = input.wheel_diameter_m {
        let (lo, hi) = PHYSICAL_DIAMETER_M;
        crate::ranges::check_range("--wheel-diameter-m", d, lo, hi)?;
    }
    Ok(())
}

/// Refuses a sensor noise no sensor has (checked after the runs, as `odocal estimate` always
/// did: a count of positions that does not match the runs is named first).
fn check_sigma(input: &HandInput) -> Result<(), String> {
    match input.heading_sigma_deg {
        // Below a millionth of a degree no sensor reads, and its square would underflow.
        Some(s) if !(s.is_finite() && (1e-6..=45.0).contains(&s)) => Err(format!(
            "--heading-sigma-deg must be in [1e-6, 45] deg (the sensor's noise per reading), \
             got {}",
            crate::ranges::compact(s)
        )),
        _ => Ok(()),
    }
}

/// Estimates a test typed in by hand.
pub fn estimate_by_hand(input: &HandInput) -> Result<HandReport, CalibrationError> {
    check_ranges(input).map_err(CalibrationError::OutOfRange)?;
    let mut test = SquareTest {
        side_m: input.side_m,
        wheelbase_m: input.wheelbase_m,
        cw: runs(&input.cw_heading_deg, input.cw_xy_m.as_ref().map(|e| &e.0))
            .map_err(CalibrationError::OutOfRange)?,
        ccw: runs(
            &input.ccw_heading_deg,
            input.ccw_xy_m.as_ref().map(|e| &e.0),
        )
        .map_err(CalibrationError::OutOfRange)?,
    };
    check_sigma(input).map_err(CalibrationError::OutOfRange)?;
    // A stated sensor noise is each run's noise: a ± is never below what it gives (a few runs'
    // scatter is often far below it by chance), and one run per direction still gets one.
    // One reading at each end of a run: the run's heading error has √2 times its noise.
    let run_sigma_rad = input
        .heading_sigma_deg
        .map(|s| heading_error_sigma(s.to_radians(), 1));
    if let Some(sigma) = run_sigma_rad {
        for run in test.cw.iter_mut().chain(test.ccw.iter_mut()) {
            run.noise_variance_rad2 = Some(sigma * sigma);
        }
    }
    let convention = input.convention.convention();
    let method = match input.method.as_str() {
        "all" => None,
        name => Some(
            name.parse::<Method>()
                .map_err(|e| CalibrationError::OutOfRange(e.to_string()))?,
        ),
    };
    let results: Vec<(Method, Result<Estimate, CalibrationError>)> = match method {
        None => {
            // Input no square test can produce is refused before anything is estimated.
            test.validate()?;
            super::estimate_all(&test, convention)?
        }
        Some(m) => vec![(m, super::estimate(m, &test, convention))],
    };
    // By hand: what the heading sensor is, is not said.
    let default = super::default_method(
        test.has_leg_headings(),
        test.has_positions(),
        HeadingKind::Unknown,
    );
    let configured = input
        .wheel_diameter_m
        .map(|d| WheelParams::nominal(d, input.wheelbase_m, 1.0));
    let cramer_rao_std = run_sigma_rad
        .map(|sigma| {
            // The bound is evaluated at the exact estimate; reuse it when it was computed.
            let exact = match results.iter().find(|(m, _)| *m == Method::Exact) {
                Some((_, r)) => r.clone()?,
                None => super::estimate(Method::Exact, &test, convention)?,
            };
            let design = TestDesign {
                side_m: test.side_m,
                wheelbase_m: test.wheelbase_m,
                runs_cw: test.cw.len(),
                runs_ccw: test.ccw.len(),
                heading_error_sigma_rad: sigma,
            };
            cramer_rao_bound(exact.e_b, exact.e_d, convention, &design)
                .map(|c| [c[(0, 0)].sqrt(), c[(1, 1)].sqrt()])
        })
        .transpose()?;
    let mut rows = Vec::new();
    let mut failures = Vec::new();
    for (method, r) in results {
        match r {
            Ok(e) => {
                let params = configured.map(|c| e.correction.apply(&c)).transpose()?;
                rows.push((e, params));
            }
            Err(err) => failures.push((method, err.to_string())),
        }
    }
    if rows.is_empty() {
        let why: Vec<String> = failures.iter().map(|(m, e)| format!("{m}: {e}")).collect();
        return Err(CalibrationError::OutOfRange(format!(
            "no method produced an estimate ({})",
            why.join("; ")
        )));
    }
    let warnings = test.large_heading_warnings();
    Ok(HandReport {
        test,
        convention,
        configured,
        default,
        rows,
        failures,
        cramer_rao_std,
        heading_sigma_deg: input.heading_sigma_deg,
        warnings,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn end_points_are_typed_as_x_y_pairs() {
        let e: EndPoints = "0.1,-0.2; 0.3,0.4;".parse().unwrap();
        assert_eq!(e, EndPoints(vec![[0.1, -0.2], [0.3, 0.4]]));
        assert!("0.1"
            .parse::<EndPoints>()
            .unwrap_err()
            .contains("is not \"x,y\""));
        assert!("a,1".parse::<EndPoints>().is_err());
    }

    fn input() -> HandInput {
        HandInput {
            side_m: 4.0,
            wheelbase_m: 0.5,
            cw_heading_deg: vec![-2.0, -2.2, -1.9],
            ccw_heading_deg: vec![1.0, 1.1, 0.9],
            cw_xy_m: None,
            ccw_xy_m: None,
            method: "all".into(),
            convention: Default::default(),
            wheel_diameter_m: Some(0.15),
            heading_sigma_deg: Some(0.5),
        }
    }

    #[test]
    fn headings_alone_give_the_heading_methods_their_parameters_and_the_bound() {
        let r = estimate_by_hand(&input()).unwrap();
        assert!(!r.rows.is_empty());
        assert!(r.rows.iter().all(|(_, p)| p.is_some()), "{:?}", r.rows);
        // Without end points the position methods do not run; the heading methods do.
        let methods: Vec<Method> = r.rows.iter().map(|(e, _)| e.method).collect();
        assert!(methods.contains(&Method::Exact) && methods.contains(&Method::JungChung));
        assert!(!methods.contains(&Method::Umbmark), "{methods:?}");
        let [b, d] = r.cramer_rao_std.unwrap();
        assert!(b > 0.0 && d > 0.0);
        assert!(r.default.is_some());
    }

    #[test]
    fn impossible_numbers_are_refused_by_flag() {
        let mut i = input();
        i.wheelbase_m = 1e-308;
        let e = estimate_by_hand(&i).unwrap_err().to_string();
        assert!(e.contains("--wheelbase-m must be in"), "{e}");
        let mut i = input();
        i.heading_sigma_deg = Some(0.0);
        let e = estimate_by_hand(&i).unwrap_err().to_string();
        assert!(e.contains("--heading-sigma-deg"), "{e}");
        let mut i = input();
        i.cw_xy_m = Some(EndPoints(vec![[0.0, 0.0]]));
        let e = estimate_by_hand(&i).unwrap_err().to_string();
        assert!(e.contains("3 headings but 1 positions"), "{e}");
    }
}
