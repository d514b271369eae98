//! `odocal plan`: what a calibration will cost and reach before anything moves (it moves
//! nothing): the side that fits the floor, the runs per direction, rounds, robot time and
//! distance, and the predicted standard errors ([`odocal::calibration::plan`]).

use crate::out::print_json;
use odocal::routine::plan_answer::PlanRequest;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Arguments of `odocal plan`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    request: PlanRequest,
    /// Print the plan as one JSON object.
    #[arg(long)]
    json: bool,
}

/// Runs `odocal plan`.
pub fn run(args: Args) -> CliResult {
    let answer = odocal::routine::plan_answer::answer(args.request)?;
    if args.json {
        print_json(&answer.json())?;
    } else {
        print!("{}", answer.text());
    }
    Ok(answer.check_reached()?)
}
