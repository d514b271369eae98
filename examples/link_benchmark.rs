//! Link figures: request/response round trip over a real pseudo-terminal (and an in-memory
//! duplex for comparison), and telemetry at 200 Hz for 10 s with its loss count.
//!
//! `cargo run --release --example link_benchmark [-- --real-time]`: by default the 10 s of
//! telemetry run in the mock's virtual time (as fast as the link carries them); `--real-time`
//! runs them on the wall clock.

use odocal::hal::link::LinkConfig;
use odocal::hal::{open_port, Client};
use odocal::kinematics::WheelParams;
use odocal::mock::{spawn_duplex, spawn_pty, FaultConfig, MockConfig, MockDevice, TimeMode};
use odocal::protocol::message::MotionMode;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

fn device() -> Result<Arc<Mutex<MockDevice>>> {
    let cfg = MockConfig::with_ratios(WheelParams::nominal(0.15, 0.39, 4096.0), 0.976, 0.992)?;
    Ok(Arc::new(Mutex::new(MockDevice::new(cfg)?)))
}

async fn round_trips(client: &Client, n: usize) -> Result<(f64, f64, f64)> {
    for _ in 0..100 {
        client.status().await?;
    }
    let mut us = Vec::with_capacity(n);
    for _ in 0..n {
        let t = Instant::now();
        client.status().await?;
        us.push(t.elapsed().as_secs_f64() * 1e6);
    }
    us.sort_by(f64::total_cmp);
    Ok((us[n / 2], us[n * 99 / 100], us[n - 1]))
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> Result<()> {
    let real_time = std::env::args().any(|a| a == "--real-time");
    let n = 5000;

    let pty = spawn_pty(device()?, TimeMode::Virtual, FaultConfig::default())?;
    let (client, _) = open_port(&pty.path, 115_200).await?;
    let (median, p99, max) = round_trips(&client, n).await?;
    println!("GET_STATUS round trip over a PTY ({n} calls): median {median:.0} µs, p99 {p99:.0} µs, max {max:.0} µs");
    drop(client);

    let (stream, _task) = spawn_duplex(device()?, TimeMode::Virtual, FaultConfig::default());
    let (client, _) = Client::connect(stream, LinkConfig::default()).await?;
    let (median, p99, max) = round_trips(&client, n).await?;
    println!("GET_STATUS round trip in memory ({n} calls): median {median:.0} µs, p99 {p99:.0} µs, max {max:.0} µs");
    drop(client);

    let time = if real_time {
        TimeMode::RealTime { scale: 1.0 }
    } else {
        TimeMode::Virtual
    };
    let pty = spawn_pty(device()?, time, FaultConfig::default())?;
    let (client, _) = open_port(&pty.path, 115_200).await?;
    let mut rx = client.subscribe();
    client
        .configure_telemetry(Some(Duration::from_millis(5)))
        .await?;
    let start = Instant::now();
    // 2 m at 0.2 m/s: 10 s of driving.
    client.move_straight(2.0, 0.2, MotionMode::Replace).await?;
    let mut received = 0u64;
    let mut last_time = 0.0;
    while last_time < 10.0 {
        match tokio::time::timeout(Duration::from_secs(2), rx.recv()).await {
            Ok(Ok(s)) => {
                received += 1;
                last_time = s.device_time_s;
            }
            _ => break,
        }
    }
    let stats = client.stats();
    println!(
        "telemetry 200 Hz over a PTY for {:.1} s of device time ({}): {} samples received, {} lost, {:.2} s wall",
        last_time,
        if real_time { "real time" } else { "virtual time" },
        received,
        stats.telemetry_dropped,
        start.elapsed().as_secs_f64()
    );
    client.stop().await?;
    Ok(())
}
