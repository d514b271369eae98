//! RoboClaw controllers: `odocal status --port roboclaw:…` and `odocal mock-roboclaw`.

use crate::args::SIM_HEADING_SIGMA_DEG;
use crate::out::print_json;
use odocal::roboclaw::client::{RoboClaw, RoboClawConfig};
use odocal::roboclaw::profile::Profile;
use serde_json::json;
use std::path::PathBuf;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// `odocal status --port roboclaw:…`.
pub async fn roboclaw_status(
    spec: &str,
    port: &str,
    address: u8,
    baud: u32,
    json_out: bool,
) -> CliResult {
    let claw = RoboClaw::open(
        port,
        RoboClawConfig {
            address,
            baud,
            ..RoboClawConfig::default()
        },
    )?;
    let version = claw.version().await.map_err(|e| {
        format!("{spec}: no answer to the version request ({e}): not a RoboClaw, or the wrong baud or address")
    })?;
    let battery = claw.battery_v().await?;
    let status = claw.status().await?;
    let (m1, s1) = claw.encoder(1).await?;
    let (m2, s2) = claw.encoder(2).await?;
    if json_out {
        return print_json(&json!({
            "firmware": version, "battery_v": battery, "status": status,
            "encoders": [{"count": m1, "status": s1}, {"count": m2, "status": s2}],
        }));
    }
    println!("{}", version.escape_debug());
    println!("main battery       {battery:.1} V");
    println!("status bits        0x{status:08X}");
    println!("encoder M1         {m1} (status 0x{s1:02X})");
    println!("encoder M2         {m2} (status 0x{s2:02X})");
    Ok(())
}

/// Arguments of `odocal mock-roboclaw`.
#[derive(Debug, clap::Args)]
pub struct MockArgs {
    /// The robot profile: its geometry is the configured one, its wiring the mock's.
    #[arg(long)]
    profile: PathBuf,
    #[command(flatten)]
    truth: crate::args::TrueRobotArgs,
    /// The simulated compass's noise per sentence (deg; σ).
    #[arg(long = "heading-sigma-deg", alias = "compass-sigma-deg", default_value_t = SIM_HEADING_SIGMA_DEG)]
    compass_sigma_deg: f64,
    /// Compass sentences per second.
    #[arg(long, default_value_t = 10.0)]
    compass_hz: f64,
    /// Compass talker id (two letters).
    #[arg(long, default_value = "HC")]
    talker: String,
    /// Robot seconds per wall-clock second.
    #[arg(long, default_value_t = 1.0)]
    time_scale: f64,
    /// Answer only this packet address (128–135), as a controller on a shared TTL serial bus
    /// [default: every address, as a RoboClaw on USB].
    #[arg(long, value_parser = clap::value_parser!(u8).range(128..=135))]
    address: Option<u8>,
    /// Probability that a write's acknowledgement is lost.
    #[arg(long, default_value_t = 0.0)]
    lose_ack_rate: f64,
    /// Every answer leaves this many milliseconds late (a slow USB adapter, a busy controller).
    #[arg(long, default_value_t = 0)]
    answer_delay_ms: u64,
    /// Probability of a compass sentence with a bad checksum.
    #[arg(long, default_value_t = 0.0)]
    bad_checksum_rate: f64,
    /// Keep serving when stdin closes.
    #[arg(long)]
    ignore_stdin: bool,
    #[command(flatten)]
    sensor: crate::args::HeadingModelArgs,
}

/// Runs `odocal mock-roboclaw`: prints `roboclaw:PATH` and `nmea:PATH`, serves until Ctrl-C or
/// stdin closes.
pub async fn mock(args: MockArgs) -> CliResult {
    use odocal::mock::roboclaw::{spawn_ptys, MockRoboClawConfig};
    args.truth.check()?;
    odocal::ranges::check_ranges(&[
        ("--heading-sigma-deg", args.compass_sigma_deg, 0.0, 10.0),
        ("--compass-hz", args.compass_hz, 0.1, 100.0),
        ("--time-scale", args.time_scale, 0.01, 100.0),
        ("--lose-ack-rate", args.lose_ack_rate, 0.0, 1.0),
        ("--bad-checksum-rate", args.bad_checksum_rate, 0.0, 1.0),
    ])?;
    if args.talker.len() != 2 || !args.talker.chars().all(|c| c.is_ascii_uppercase()) {
        return Err(format!("--talker {:?}: two capital letters", args.talker).into());
    }
    let p = Profile::load(&args.profile)?;
    let truth = odocal::kinematics::WheelParams::from_ratios(
        &p.params(),
        args.truth.true_eb,
        args.truth.true_ed,
        &odocal::kinematics::SplitConvention::LeftNominal,
    )?;
    let mut cfg = MockRoboClawConfig::new(truth);
    cfg.left_on_m1 = p.wiring.left_channel == odocal::roboclaw::profile::Channel::M1;
    cfg.left_encoder_sign = p.wiring.left_encoder_sign;
    cfg.right_encoder_sign = p.wiring.right_encoder_sign;
    cfg.noise.compass_sigma_rad = args.compass_sigma_deg.to_radians();
    cfg.heading_model = args.sensor.model()?;
    cfg.compass_hz = args.compass_hz;
    cfg.compass_talker = args.talker.clone();
    cfg.time_scale = args.time_scale;
    cfg.lose_ack_rate = args.lose_ack_rate;
    cfg.answer_delay = std::time::Duration::from_millis(args.answer_delay_ms.min(10_000));
    cfg.address = args.address;
    cfg.bad_checksum_rate = args.bad_checksum_rate;
    let ptys = spawn_ptys(cfg)?;
    println!("roboclaw:{}", ptys.roboclaw_path);
    println!("nmea:{}", ptys.compass_path);
    let address = match args.address {
        Some(a) => format!("address {a}"),
        None => "any address 128-135, as over USB".into(),
    };
    eprintln!(
        "mock RoboClaw ({address}) and NMEA compass ({}HDT at {} Hz) of one simulated robot \
         (true E_b {}, E_d {}); Ctrl-C{} stops them.",
        args.talker,
        args.compass_hz,
        args.truth.true_eb,
        args.truth.true_ed,
        if args.ignore_stdin {
            ""
        } else {
            " or closing stdin"
        }
    );
    crate::args::serve_until_stopped(args.ignore_stdin).await;
    drop(ptys);
    Ok(())
}
