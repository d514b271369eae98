//! `odocal ports`: the serial ports this machine has, with USB ids where known, so a user can
//! tell the motor controller's adapter from the compass's.

use crate::out::print_json;
use serde_json::json;

/// Arguments of `odocal ports`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

/// Runs `odocal ports`.
pub fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    let ports = odocal::io::serial::list_ports()?;
    if args.json {
        let rows: Vec<_> = ports.iter().map(|p| p.json()).collect();
        return print_json(&json!({ "ports": rows }));
    }
    if ports.is_empty() {
        println!("no serial ports found (is the adapter plugged in, and may this user read it?)");
    }
    ports.iter().for_each(|p| println!("{p}"));
    Ok(())
}
