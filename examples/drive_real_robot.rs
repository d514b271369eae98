//! Open a serial port, drive one open-loop square and print the headings.
//!
//! `cargo run --release --example drive_real_robot -- /dev/ttyUSB0 [side_m] [ccw]`
//!
//! THIS MOVES THE ROBOT: one square of `side_m` (default 1 m) at 0.2 m/s and 0.5 rad/s. Ctrl-C
//! stops it (the motion guard sends STOP). Without a port argument it drives the built-in
//! simulated robot on a pseudo-terminal instead.

use odocal::base::Base;
use odocal::hal::open_port;
use odocal::kinematics::{Direction, WheelParams};
use odocal::mock::{spawn_pty, FaultConfig, MockConfig, MockDevice, TimeMode};
use odocal::routine::square::{run_square, SquareCommand};
use std::sync::{Arc, Mutex};
use std::time::Duration;

#[tokio::main]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    // Keeps the simulated robot alive when no port is given.
    let mut _mock = None;
    let port = match args.first() {
        Some(p) => p.clone(),
        None => {
            let cfg =
                MockConfig::with_ratios(WheelParams::nominal(0.15, 0.39, 4096.0), 0.976, 0.992)?;
            let dev = Arc::new(Mutex::new(MockDevice::new(cfg)?));
            let server = spawn_pty(dev, TimeMode::Virtual, FaultConfig::default())?;
            println!(
                "no port given: using the simulated robot on {}",
                server.path
            );
            let path = server.path.clone();
            _mock = Some(server);
            path
        }
    };
    let side_m: f64 = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(1.0);
    let direction = if args.get(2).is_some_and(|s| s == "ccw") {
        Direction::Ccw
    } else {
        Direction::Cw
    };
    let (client, info) = open_port(&port, 115_200).await?;
    println!(
        "connected to {} (protocol {}.{}); driving a {side_m} m {direction} square",
        info.firmware_id, info.major, info.minor
    );
    client
        .configure_watchdog(Some(Duration::from_millis(500)))
        .await?;
    let cmd = SquareCommand {
        side_m,
        direction,
        max_speed_m_s: 0.2,
        max_rate_rad_s: 0.5,
        heading_samples: 5,
        settle: Duration::from_millis(500),
        stream_period: Duration::from_millis(20),
    };
    let base = Base::single(client.clone());
    let rec = tokio::select! {
        r = run_square(&base, &cmd, |_| {}) => r?,
        _ = tokio::signal::ctrl_c() => {
            client.stop().await?;
            return Err("interrupted: robot stopped".into());
        }
    };
    println!(
        "heading before: {:+.3}°",
        rec.heading_before_rad.to_degrees()
    );
    println!(
        "heading after:  {:+.3}°",
        rec.heading_after_rad.to_degrees()
    );
    println!(
        "final heading error: {:+.3}° (counter-clockwise positive)",
        rec.heading_error_rad.to_degrees()
    );
    Ok(())
}
