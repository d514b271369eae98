//! `odocal mock-roboclaw`: a mock RoboClaw and its compass on two pseudo-terminals.

use odocal::roboclaw::profile::Profile;
use std::path::PathBuf;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Arguments of `odocal mock-roboclaw`.
#[derive(Debug, clap::Args)]
pub struct MockArgs {
    /// The robot profile: its geometry is the configured one, its wiring the mock's.
    #[arg(long)]
    profile: PathBuf,
    #[command(flatten)]
    robot: odocal::mock::options::RoboClawOptions,
    /// Keep serving when stdin closes.
    #[arg(long)]
    ignore_stdin: bool,
}

/// Runs `odocal mock-roboclaw`: prints `roboclaw:PATH` and `nmea:PATH`, serves until Ctrl-C or
/// stdin closes.
pub async fn mock(args: MockArgs) -> CliResult {
    let o = &args.robot;
    o.check()?;
    let cfg = o.config(&Profile::load(&args.profile)?)?;
    let ptys = odocal::mock::roboclaw::spawn_ptys(cfg)?;
    println!("roboclaw:{}", ptys.roboclaw_path);
    println!("nmea:{}", ptys.compass_path);
    let address = match o.address {
        Some(a) => format!("address {a}"),
        None => "any address 128-135, as over USB".into(),
    };
    eprintln!(
        "mock RoboClaw ({address}) and NMEA compass ({}HDT at {} Hz) of one simulated robot \
         (true E_b {}, E_d {}); Ctrl-C{} stops them.",
        o.talker,
        o.compass_hz,
        o.truth.true_eb,
        o.truth.true_ed,
        odocal::mock::stop::or_closing_stdin(args.ignore_stdin)
    );
    odocal::mock::stop::until_stopped(args.ignore_stdin).await;
    drop(ptys);
    Ok(())
}
