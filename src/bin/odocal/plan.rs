//! `odocal plan`: what a calibration will cost and reach before anything moves (it moves
//! nothing): the side that fits the floor, the runs per direction, rounds, robot time and
//! distance, and the predicted standard errors ([`odocal::calibration::plan`]).

use crate::out::print_json;
use odocal::calibration::HeadingKind;
use odocal::routine::config::RoutineConfig;
use odocal::routine::overrides::Shape;
use odocal::routine::plan_answer::PlanRequest;
use odocal::routine::planning::DEFAULT_FOOTPRINT_M;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Arguments of `odocal plan`.
#[derive(Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("space").required(true).multiple(true).args(["floor_m", "side_max_m", "side_m"])))]
pub struct Args {
    /// The free floor, WIDTH,LENGTH (m, either way round): the clockwise and counter-clockwise
    /// squares lie either side of the first leg.
    #[arg(long, value_name = "W,L")]
    floor_m: Option<String>,
    /// The longest square side to consider (m), instead of --floor-m.
    #[arg(long, conflicts_with = "floor_m")]
    side_max_m: Option<f64>,
    /// Squares of exactly this side (m) instead of the largest that fits (with --floor-m: it
    /// must fit).
    #[arg(long, conflicts_with = "side_max_m")]
    side_m: Option<f64>,
    /// The heading sensor's noise per reading at rest (deg): `odocal heading --heading-samples 50`
    /// prints it.
    #[arg(long)]
    heading_sigma_deg: f64,
    /// The wheelbase configured on the robot (m).
    #[arg(long)]
    wheelbase_m: f64,
    /// The wheel diameter configured on the robot (m): with --counts-per-rev, the end point
    /// counts the rounding of every motion to whole encoder counts (a controller that drives to
    /// wheel targets in counts: our protocol's devices, a RoboClaw).
    #[arg(long, requires = "counts_per_rev")]
    wheel_diameter_m: Option<f64>,
    /// Encoder counts per wheel revolution (with --wheel-diameter-m).
    #[arg(long, requires = "wheel_diameter_m")]
    counts_per_rev: Option<f64>,
    /// What the heading sensor is (decides the default method and the compass swing):
    /// magnetic, gyro, reference or unknown.
    #[arg(long, default_value = "unknown")]
    heading_kind: HeadingKind,
    /// Heading readings per second [default: the telemetry rate, 50].
    #[arg(long)]
    heading_hz: Option<f64>,
    /// The robot's largest width (m), added to the floor the squares need.
    #[arg(long, default_value_t = DEFAULT_FOOTPRINT_M)]
    footprint_m: f64,
    /// Scatter of a run's heading error beyond the sensor's noise (deg), from an earlier
    /// calibration of this robot on this floor (slip, bumps); 0 when unknown.
    #[arg(long, default_value_t = 0.0)]
    run_scatter_deg: f64,
    /// Target RMS end-point error (m) of one square of the plan's side driven with the
    /// calibrated parameters (the rounding to whole encoder counts included when known).
    #[arg(long)]
    target_end_m: Option<f64>,
    #[command(flatten)]
    shape: Shape,
    /// Print the plan as one JSON object.
    #[arg(long)]
    json: bool,
}

/// Runs `odocal plan`.
pub fn run(args: Args) -> CliResult {
    let mut cfg = RoutineConfig::default();
    args.shape.apply(&mut cfg);
    let answer = odocal::routine::plan_answer::answer(PlanRequest {
        cfg,
        floor: args.floor_m,
        side_max_m: args.side_max_m,
        side_m: args.side_m,
        heading_sigma_deg: args.heading_sigma_deg,
        wheelbase_m: args.wheelbase_m,
        wheel: args.wheel_diameter_m.zip(args.counts_per_rev),
        heading_kind: args.heading_kind,
        heading_hz: args.heading_hz,
        footprint_m: args.footprint_m,
        run_scatter_deg: args.run_scatter_deg,
        target_end_m: args.target_end_m,
    })?;
    if args.json {
        print_json(&answer.json())?;
    } else {
        print!("{}", answer.text());
    }
    Ok(answer.check_reached()?)
}
