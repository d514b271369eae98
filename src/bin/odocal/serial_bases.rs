//! Serial hardware that does not speak odocal's protocol: `roboclaw:PORT[?address=128&baud=38400]`
//! drives, `nmea:PORT[?baud=4800]` compasses, and `odocal mock-roboclaw`.

use crate::print_json;
use odocal::base::{Base, HeadingSource};
use odocal::nmea::NmeaCompass;
use odocal::profile::{Profile, ProfileStore};
use odocal::roboclaw::client::{RoboClaw, RoboClawConfig};
use serde_json::json;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Splits `scheme:PATH?k=v&k=v` into the path and its options.
pub fn parse_spec(spec: &str, scheme: &str) -> Result<(String, BTreeMap<String, String>), String> {
    let rest = spec
        .strip_prefix(scheme)
        .and_then(|r| r.strip_prefix(':'))
        .ok_or_else(|| format!("{spec:?}: expected {scheme}:PORT[?key=value&…]"))?;
    let (path, query) = rest.split_once('?').unwrap_or((rest, ""));
    if path.is_empty() {
        return Err(format!("{spec:?}: no port"));
    }
    let mut opts = BTreeMap::new();
    for kv in query.split('&').filter(|s| !s.is_empty()) {
        let (k, v) = kv
            .split_once('=')
            .ok_or_else(|| format!("{spec:?}: option {kv:?} is not key=value"))?;
        opts.insert(k.to_string(), v.to_string());
    }
    Ok((path.to_string(), opts))
}

fn number<T: std::str::FromStr>(
    opts: &BTreeMap<String, String>,
    key: &str,
    default: T,
    spec: &str,
) -> Result<T, String> {
    match opts.get(key) {
        None => Ok(default),
        Some(v) => v
            .parse()
            .map_err(|_| format!("{spec:?}: {key}={v} is not a number")),
    }
}

/// Opens `roboclaw:PORT?address=&baud=`.
pub fn open_roboclaw(spec: &str) -> Result<RoboClaw, Box<dyn std::error::Error>> {
    let (path, opts) = parse_spec(spec, "roboclaw")?;
    for k in opts.keys() {
        if k != "address" && k != "baud" {
            return Err(format!("{spec:?}: unknown option {k} (address, baud)").into());
        }
    }
    let cfg = RoboClawConfig {
        address: number(&opts, "address", 0x80u8, spec)?,
        baud: number(&opts, "baud", 38_400u32, spec)?,
        ..RoboClawConfig::default()
    };
    Ok(RoboClaw::open(&path, cfg)?)
}

/// Opens `nmea:PORT?baud=`.
pub fn open_nmea(spec: &str) -> Result<NmeaCompass, Box<dyn std::error::Error>> {
    let (path, opts) = parse_spec(spec, "nmea")?;
    for k in opts.keys() {
        if k != "baud" {
            return Err(format!("{spec:?}: unknown option {k} (baud)").into());
        }
    }
    let baud = number(&opts, "baud", 4800u32, spec)?;
    Ok(NmeaCompass::open(&path, baud, Duration::from_secs(1))?)
}

/// A RoboClaw + a compass + a profile, as one base.
pub async fn roboclaw_base(
    drive: &str,
    heading: Option<&str>,
    profile: Option<&Path>,
) -> Result<Base, Box<dyn std::error::Error>> {
    let heading = heading.ok_or("a RoboClaw base needs --heading nmea:PORT (the compass)")?;
    let profile = profile.ok_or("a RoboClaw base needs --profile robot.toml (its geometry)")?;
    let compass: Arc<dyn HeadingSource> = Arc::new(open_nmea(heading)?);
    let store = ProfileStore::open(profile)?;
    Ok(odocal::roboclaw::base(open_roboclaw(drive)?, compass, store).await?)
}

/// `odocal status --port roboclaw:…`.
pub async fn roboclaw_status(spec: &str, json_out: bool) -> CliResult {
    let claw = open_roboclaw(spec)?;
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

/// `odocal heading --port nmea:…`.
pub async fn nmea_heading(spec: &str, samples: usize, json_out: bool) -> CliResult {
    let compass = open_nmea(spec)?;
    let mean = odocal::routine::heading::mean_heading(&compass, samples).await?;
    if json_out {
        return print_json(
            &json!({"heading_rad": mean, "heading_deg": mean.to_degrees(), "samples": samples.max(1)}),
        );
    }
    println!(
        "heading {:.3}° ({mean:.6} rad, counter-clockwise positive; compass azimuth {:.2}°)",
        mean.to_degrees(),
        (-mean.to_degrees()).rem_euclid(360.0)
    );
    Ok(())
}

/// Arguments of `odocal mock-roboclaw`.
#[derive(Debug, clap::Args)]
pub struct MockArgs {
    /// The robot profile: its geometry is the configured one, its wiring the mock's.
    #[arg(long)]
    profile: PathBuf,
    /// True E_b of the simulated robot.
    #[arg(long, default_value_t = 0.976)]
    true_eb: f64,
    /// True E_d (left wheel nominal).
    #[arg(long, default_value_t = 0.992)]
    true_ed: f64,
    /// Compass noise per sentence (deg).
    #[arg(long, default_value_t = 0.1)]
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
    /// Probability that a write's acknowledgement is lost.
    #[arg(long, default_value_t = 0.0)]
    lose_ack_rate: f64,
    /// Probability of a compass sentence with a bad checksum.
    #[arg(long, default_value_t = 0.0)]
    bad_checksum_rate: f64,
    /// Keep serving when stdin closes.
    #[arg(long)]
    ignore_stdin: bool,
}

/// Runs `odocal mock-roboclaw`: prints `roboclaw:PATH` and `nmea:PATH`, serves until Ctrl-C or
/// stdin closes.
pub async fn mock(args: MockArgs) -> CliResult {
    use odocal::mock::roboclaw::{spawn_ptys, MockRoboClawConfig};
    for (name, v, lo, hi) in [
        ("--true-eb", args.true_eb, 0.5, 2.0),
        ("--true-ed", args.true_ed, 0.8, 1.25),
        ("--compass-sigma-deg", args.compass_sigma_deg, 0.0, 10.0),
        ("--compass-hz", args.compass_hz, 0.1, 100.0),
        ("--time-scale", args.time_scale, 0.01, 100.0),
        ("--lose-ack-rate", args.lose_ack_rate, 0.0, 1.0),
        ("--bad-checksum-rate", args.bad_checksum_rate, 0.0, 1.0),
    ] {
        if !(v.is_finite() && (lo..=hi).contains(&v)) {
            return Err(format!("{name} must be in [{lo}, {hi}], got {v}").into());
        }
    }
    if args.talker.len() != 2 || !args.talker.chars().all(|c| c.is_ascii_uppercase()) {
        return Err(format!("--talker {:?}: two capital letters", args.talker).into());
    }
    let p = Profile::load(&args.profile)?;
    let truth = odocal::kinematics::WheelParams::from_ratios(
        &p.params(),
        args.true_eb,
        args.true_ed,
        &odocal::kinematics::SplitConvention::LeftNominal,
    )?;
    let mut cfg = MockRoboClawConfig::new(truth);
    cfg.left_on_m1 = p.wiring.left_channel == odocal::profile::Channel::M1;
    cfg.left_encoder_sign = p.wiring.left_encoder_sign;
    cfg.right_encoder_sign = p.wiring.right_encoder_sign;
    cfg.noise.compass_sigma_rad = args.compass_sigma_deg.to_radians();
    cfg.compass_hz = args.compass_hz;
    cfg.compass_talker = args.talker.clone();
    cfg.time_scale = args.time_scale;
    cfg.lose_ack_rate = args.lose_ack_rate;
    cfg.bad_checksum_rate = args.bad_checksum_rate;
    let ptys = spawn_ptys(cfg)?;
    println!("roboclaw:{}", ptys.roboclaw_path);
    println!("nmea:{}", ptys.compass_path);
    eprintln!(
        "mock RoboClaw (address 128) and NMEA compass ({}HDT at {} Hz) of one simulated robot \
         (true E_b {}, E_d {}); Ctrl-C{} stops them.",
        args.talker,
        args.compass_hz,
        args.true_eb,
        args.true_ed,
        if args.ignore_stdin {
            ""
        } else {
            " or closing stdin"
        }
    );
    crate::serve_until_stopped(args.ignore_stdin).await;
    drop(ptys);
    Ok(())
}
