//! `odocal estimate`: calibrate from measurements typed in by hand.

use crate::args::ConventionArgs;
use crate::out::print_json;
use odocal::calibration::uncertainty::{cramer_rao_bound, heading_error_sigma, TestDesign};
use odocal::calibration::{self, Estimate, Method, RunMeasurement, SquareTest};
use odocal::kinematics::WheelParams;
use odocal::report::stated::{
    default_line, disagreement_lines, pm_b, pm_d, within_session_legend, Basis,
};
use serde_json::json;

/// Arguments of `odocal estimate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Square side (m).
    #[arg(long)]
    side_m: f64,
    /// Wheelbase configured on the controller during the test (m).
    #[arg(long)]
    wheelbase_m: f64,
    /// Final-minus-start heading error of each clockwise run (deg, counter-clockwise positive;
    /// negate a compass azimuth), comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        required = true
    )]
    cw_heading_deg: Vec<f64>,
    /// Same for each counter-clockwise run.
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        required = true
    )]
    ccw_heading_deg: Vec<f64>,
    /// Final position of each clockwise run in the start frame (x along the first leg, y to its
    /// left), as "x,y;x,y" (m). Enables UMBmark and Lee.
    #[arg(long, allow_hyphen_values = true, value_parser = parse_xy_list)]
    cw_xy_m: Option<XyList>,
    /// Same for each counter-clockwise run.
    #[arg(long, allow_hyphen_values = true, value_parser = parse_xy_list)]
    ccw_xy_m: Option<XyList>,
    /// Method to run: all, umbmark, lee, heading-only, jung-chung or exact.
    #[arg(long, default_value = "all")]
    method: String,
    #[command(flatten)]
    convention: ConventionArgs,
    /// Wheel diameter configured during the test (m); prints the corrected parameters.
    #[arg(long)]
    wheel_diameter_m: Option<f64>,
    /// The heading sensor's noise per reading (deg; σ); prints the Cramér–Rao bound for this
    /// test.
    #[arg(long = "heading-sigma-deg", alias = "compass-sigma-deg")]
    compass_sigma_deg: Option<f64>,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
}

/// A list of (x, y) positions.
#[derive(Debug, Clone)]
pub struct XyList(Vec<[f64; 2]>);

fn parse_xy_list(s: &str) -> Result<XyList, String> {
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
        .map(XyList)
}

fn runs(headings_deg: &[f64], xy: Option<&XyList>) -> Result<Vec<RunMeasurement>, String> {
    if let Some(xy) = xy {
        if xy.0.len() != headings_deg.len() {
            return Err(format!(
                "{} headings but {} positions: give one position per run",
                headings_deg.len(),
                xy.0.len()
            ));
        }
    }
    Ok(headings_deg
        .iter()
        .enumerate()
        .map(|(i, h)| RunMeasurement {
            heading_error_rad: h.to_radians(),
            final_xy_m: xy.map(|l| l.0[i]),
            ..RunMeasurement::default()
        })
        .collect())
}

/// Runs `odocal estimate`.
pub fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    // The bounds of a square test a robot can drive (a 1e-308 m wheelbase makes every
    // derivative overflow); NaN is the calibration's own check (SquareTest::validate) and
    // gets its message.
    for (flag, v, lo, hi) in [
        ("--side-m", args.side_m, 0.05, 100.0),
        ("--wheelbase-m", args.wheelbase_m, 0.01, 10.0),
    ] {
        if v > hi || (v > 0.0 && v < lo) {
            return Err(format!(
                "{flag} must be in [{lo}, {hi}] m, got {}",
                odocal::io::compact(v)
            )
            .into());
        }
    }
    if let Some(d) = args.wheel_diameter_m {
        let (lo, hi) = odocal::kinematics::PHYSICAL_DIAMETER_M;
        odocal::io::check_range("--wheel-diameter-m", d, lo, hi)?;
    }
    let mut test = SquareTest {
        side_m: args.side_m,
        wheelbase_m: args.wheelbase_m,
        cw: runs(&args.cw_heading_deg, args.cw_xy_m.as_ref())?,
        ccw: runs(&args.ccw_heading_deg, args.ccw_xy_m.as_ref())?,
    };
    // A stated sensor noise is each run's noise: a ± is never below what it gives (a few runs'
    // scatter is often far below it by chance), and one run per direction still gets one.
    // One reading at each end of a run: the run's heading error has √2 times its noise.
    let run_sigma_rad = match args.compass_sigma_deg {
        // Below a millionth of a degree no sensor reads, and its square would underflow.
        Some(s) if !(s.is_finite() && (1e-6..=45.0).contains(&s)) => {
            return Err(format!(
                "--heading-sigma-deg must be in [1e-6, 45] deg (the sensor's noise per \
                 reading), got {}",
                odocal::io::compact(s)
            )
            .into());
        }
        s => s.map(|s| heading_error_sigma(s.to_radians(), 1)),
    };
    if let Some(sigma) = run_sigma_rad {
        for run in test.cw.iter_mut().chain(test.ccw.iter_mut()) {
            run.noise_variance_rad2 = Some(sigma * sigma);
        }
    }
    let convention = args.convention.convention();
    let results: Vec<(Method, Result<Estimate, _>)> = if args.method == "all" {
        // Input no square test can produce is refused before anything is estimated.
        test.validate()?;
        calibration::estimate_all(&test, convention)?
    } else {
        let m: Method = args.method.parse()?;
        vec![(m, calibration::estimate(m, &test, convention))]
    };
    // By hand: what the heading sensor is, is not said.
    let default = calibration::default_method(
        test.has_leg_headings(),
        test.has_positions(),
        calibration::HeadingKind::Unknown,
    );
    let configured = args
        .wheel_diameter_m
        .map(|d| WheelParams::nominal(d, args.wheelbase_m, 1.0));
    let crb = run_sigma_rad
        .map(|sigma| {
            // The bound is evaluated at the exact estimate; reuse it when it was computed.
            let exact = match results.iter().find(|(m, _)| *m == Method::Exact) {
                Some((_, r)) => r.clone()?,
                None => calibration::estimate(Method::Exact, &test, convention)?,
            };
            let design = TestDesign {
                side_m: test.side_m,
                wheelbase_m: test.wheelbase_m,
                runs_cw: test.cw.len(),
                runs_ccw: test.ccw.len(),
                heading_error_sigma_rad: sigma,
            };
            cramer_rao_bound(exact.e_b, exact.e_d, convention, &design)
        })
        .transpose()?;

    let mut rows = Vec::new();
    let mut failures = Vec::new();
    for (method, r) in &results {
        match r {
            Ok(e) => {
                let params = configured.map(|c| e.correction.apply(&c)).transpose()?;
                rows.push((e.clone(), params));
            }
            Err(err) => failures.push((*method, err.to_string())),
        }
    }
    if rows.is_empty() {
        let why: Vec<String> = failures.iter().map(|(m, e)| format!("{m}: {e}")).collect();
        return Err(format!("no method produced an estimate ({})", why.join("; ")).into());
    }
    let warnings = test.large_heading_warnings();
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    if args.json {
        let estimates: Vec<_> = rows
            .iter()
            .map(|(e, p)| {
                let mut v = serde_json::to_value(e).unwrap_or_default();
                if let (Some(p), Some(obj)) = (p, v.as_object_mut()) {
                    obj.insert(
                        "left_wheel_diameter_m".into(),
                        json!(p.left_wheel_diameter_m),
                    );
                    obj.insert(
                        "right_wheel_diameter_m".into(),
                        json!(p.right_wheel_diameter_m),
                    );
                    obj.insert("wheelbase_m".into(), json!(p.wheelbase_m));
                }
                v
            })
            .collect();
        return print_json(&json!({
            "convention": convention.name(),
            "configured": configured,
            "default_method": default,
            "warnings": warnings,
            "estimates": estimates,
            "failures": failures.iter().map(|(m, e)| json!({"method": m.name(), "error": e})).collect::<Vec<_>>(),
            "cramer_rao_std": crb.map(|c| json!({"e_b": c[(0, 0)].sqrt(), "e_d": c[(1, 1)].sqrt()})),
        }));
    }
    println!(
        "square {} m, wheelbase {} m, {} CW + {} CCW runs, convention {}",
        test.side_m,
        test.wheelbase_m,
        test.cw.len(),
        test.ccw.len(),
        convention.name()
    );
    println!(
        "{:<13} {:>9} {:>10} {:>9} {:>10}",
        "method", "E_b", "±", "E_d", "±"
    );
    for (e, _) in &rows {
        println!(
            "{:<13} {:>9.6} {:>10} {:>9.6} {:>10}{}",
            e.method.name(),
            e.e_b,
            pm_b(e),
            e.e_d,
            pm_d(e),
            if Some(e.method) == default {
                "  (default)"
            } else {
                ""
            }
        );
    }
    let estimates: Vec<Estimate> = rows.iter().map(|(e, _)| e.clone()).collect();
    for line in within_session_legend(&estimates) {
        println!("{line}");
    }
    match crb {
        Some(c) => println!(
            "Cramér–Rao bound (std): E_b {:.5}, E_d {:.5}: the least error any method can have \
             from these headings with {} deg of noise per reading (no stated ± is below what \
             that noise gives)",
            c[(0, 0)].sqrt(),
            c[(1, 1)].sqrt(),
            args.compass_sigma_deg.unwrap_or(f64::NAN)
        ),
        None => println!(
            "(give --heading-sigma-deg, the sensor's noise per reading, for the Cramér–Rao bound \
             and a ± with one run per direction)"
        ),
    }
    if let Some(m) = default {
        println!("{}", default_line(m));
    }
    for line in disagreement_lines(default, "the default", Basis::Session, &estimates) {
        println!("{line}");
    }
    if configured.is_some() {
        println!("\ncorrected parameters (left D, right D, wheelbase, m):");
        for (e, p) in &rows {
            if let Some(p) = p {
                println!(
                    "{:<13} {:.6} {:.6} {:.6}",
                    e.method.name(),
                    p.left_wheel_diameter_m,
                    p.right_wheel_diameter_m,
                    p.wheelbase_m
                );
            }
        }
    }
    for (m, e) in failures {
        println!("{m}: not estimated: {e}");
    }
    Ok(())
}
