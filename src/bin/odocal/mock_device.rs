//! `odocal mock-device` and the hidden `kit-device`: simulated controllers of odocal's
//! protocol on pseudo-terminals.

use odocal::mock::{lock, spawn_pty, MockDevice, TimeMode};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Arguments of `odocal mock-device`.
#[derive(Debug, clap::Args)]
pub struct MockArgs {
    #[command(flatten)]
    device: odocal::mock::options::DeviceOptions,
    /// Also write the terminal's path to this file.
    #[arg(long)]
    link: Option<PathBuf>,
    /// Serve until Ctrl-C only (by default closing stdin also stops the device).
    #[arg(long)]
    ignore_stdin: bool,
    #[command(flatten)]
    compass: crate::args::MockCompassArgs,
}

/// Runs `odocal mock-device`.
pub async fn mock_device(args: MockArgs) -> CliResult {
    let (cfg, time) = args.device.config()?;
    let device = MockDevice::new(cfg)?;
    if let Some(why) = device.storage_discarded() {
        eprintln!(
            "warning: the stored parameter copy was discarded and the device starts from its \
             factory defaults: {why}"
        );
    }
    let device = Arc::new(Mutex::new(device));
    let faults = args.device.faults.unwrap_or_default();
    let server = spawn_pty(device.clone(), time, faults)?;
    println!("{}", server.path);
    let scale = match time {
        TimeMode::RealTime { scale } => scale,
        TimeMode::Virtual => 1.0,
    };
    let _compass = args
        .compass
        .spawn(odocal::mock::separate_compass(&device), scale)?;
    if let Some(link) = &args.link {
        std::fs::write(link, format!("{}\n", server.path))?;
    }
    eprintln!(
        "mock device on {} ({}); Ctrl-C{} to stop",
        server.path,
        match time {
            TimeMode::Virtual => "virtual time".to_string(),
            TimeMode::RealTime { scale } => format!("real time ×{scale}"),
        },
        odocal::mock::stop::or_closing_stdin(args.ignore_stdin)
    );
    odocal::mock::stop::until_stopped(args.ignore_stdin).await;
    eprintln!("mock device stopped: {}", lock(&device).counters());
    if let Some(link) = &args.link {
        let _ = std::fs::remove_file(link);
    }
    Ok(())
}

/// Arguments of the hidden `odocal kit-device`.
#[derive(Debug, clap::Args)]
pub struct KitArgs {
    /// Run the device's clock this many times faster than the wall clock.
    #[arg(long = "time-scale", alias = "real-time", default_value_t = 1.0)]
    real_time: f64,
    /// Also write the terminal's path to this file.
    #[arg(long)]
    link: Option<PathBuf>,
    /// Serve until Ctrl-C only (by default closing stdin also stops the device).
    #[arg(long)]
    ignore_stdin: bool,
}

/// Runs `odocal kit-device`: the protocol crate's device kit over its ideal board (a robot
/// with 0.15 m wheels, a 0.39 m wheelbase and 4096 counts per revolution) on a new
/// pseudo-terminal, whose path it prints first.
pub async fn kit_device(args: KitArgs) -> CliResult {
    odocal::ranges::check_range("--time-scale", args.real_time, 0.01, 1000.0)?;
    let device = odocal::mock::kit::kit_device(odocal::mock::kit::IDEAL_ROBOT, args.real_time)?;
    let server = odocal::mock::kit::spawn_kit_pty(device, args.real_time)?;
    println!("{}", server.path);
    if let Some(link) = &args.link {
        std::fs::write(link, format!("{}\n", server.path))?;
    }
    eprintln!(
        "kit device on {} (real time ×{}); Ctrl-C to stop",
        server.path, args.real_time
    );
    odocal::mock::stop::until_stopped(args.ignore_stdin).await;
    if let Some(link) = &args.link {
        let _ = std::fs::remove_file(link);
    }
    Ok(())
}
