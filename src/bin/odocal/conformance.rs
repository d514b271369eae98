//! `odocal conformance` (**moves the robot**): a device checked against SPEC.md §7 in real
//! time.

type CliResult = Result<(), Box<dyn std::error::Error>>;
use odocal::hal::conformance::{self, Options};

/// Arguments of `odocal conformance`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Serial port of the device (e.g. /dev/ttyUSB0, or the path `odocal mock-device` printed).
    #[arg(long)]
    port: String,
    /// Baud rate.
    #[arg(long, default_value_t = 115_200)]
    baud: u32,
    #[command(flatten)]
    options: Options,
    /// Print JSON instead of one line per rule.
    #[arg(long)]
    json: bool,
    /// Do not ask before moving the robot.
    #[arg(long)]
    yes: bool,
}

/// Stops the base on its own link (after an error or Ctrl-C ended the checks' link).
async fn stop_base(port: &str, baud: u32) {
    if let Err(e) = odocal::hal::stop_over_new_link(port, baud).await {
        eprintln!("warning: could not send STOP over {port}: {e}");
    }
}

/// Runs `odocal conformance`: **moves the robot**.
pub async fn run(args: Args) -> CliResult {
    let options = &args.options;
    options.check()?;
    crate::sensor::confirm(
        args.yes,
        &format!(
            "odocal conformance MOVES THE ROBOT: short drives and turns in place (one of them \
             up to two full turns, stopped at once) at up to {} m/s per wheel, for a minute or \
             so. Ctrl-C stops the base.",
            options.max_speed_m_s
        ),
    )?;
    let json = args.json;
    let checks = conformance::run_port(&args.port, args.baud, options, |r| {
        if !json {
            println!("{r}");
        }
    });
    let report = tokio::select! {
        r = checks => r,
        name = crate::prompt::signal() => {
            stop_base(&args.port, args.baud).await;
            let name = name.unwrap_or("a signal");
            return Err(format!("interrupted ({name}): the base was stopped").into());
        }
    };
    let report = match report {
        Ok(r) => r,
        Err(e) => {
            stop_base(&args.port, args.baud).await;
            return Err(format!("conformance stopped: {e} (the base was stopped)").into());
        }
    };
    summarise(&report, &args)
}

/// The last line (or the JSON report), and an error naming each rule that failed.
fn summarise(report: &conformance::Report, args: &Args) -> CliResult {
    if args.json {
        crate::out::print_json(&serde_json::to_value(report)?)?;
    } else {
        println!("{}", report.summary(&args.port));
    }
    match report.failure(if args.json { "in the JSON" } else { "above" }) {
        Some(failed) => Err(failed.into()),
        None => Ok(()),
    }
}
