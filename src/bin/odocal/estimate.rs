//! `odocal estimate`: calibrate from measurements typed in by hand.

use crate::out::print_json;
use odocal::calibration::by_hand::{estimate_by_hand, HandInput};

/// Arguments of `odocal estimate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    input: HandInput,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
}

/// Runs `odocal estimate`.
pub fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    let report = estimate_by_hand(&args.input)?;
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
    if args.json {
        return print_json(&odocal::report::text::estimates_json(&report));
    }
    print!("{}", odocal::report::text::estimates(&report));
    Ok(())
}
