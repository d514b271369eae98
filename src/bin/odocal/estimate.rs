//! `odocal estimate`: calibrate from measurements typed in by hand.

use crate::args::ConventionArgs;
use crate::out::print_json;
use odocal::calibration::by_hand::{estimate_by_hand, HandInput};

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

/// Runs `odocal estimate`.
pub fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    let input = HandInput {
        side_m: args.side_m,
        wheelbase_m: args.wheelbase_m,
        cw_heading_deg: args.cw_heading_deg,
        ccw_heading_deg: args.ccw_heading_deg,
        cw_xy_m: args.cw_xy_m.map(|l| l.0),
        ccw_xy_m: args.ccw_xy_m.map(|l| l.0),
        method: args.method,
        convention: args.convention.convention(),
        wheel_diameter_m: args.wheel_diameter_m,
        heading_sigma_deg: args.compass_sigma_deg,
    };
    let report = estimate_by_hand(&input)?;
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
    if args.json {
        return print_json(&odocal::report::text::estimates_json(&report));
    }
    print!("{}", odocal::report::text::estimates(&report));
    Ok(())
}
