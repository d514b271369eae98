//! The whole calibration, in real time, over a pseudo-terminal whose mock device corrupts 1 % of
//! bytes and loses 5 % of frames in both directions: prints each run's outcome and how many of
//! the runs completed, with the link's retry and loss counters.
//!
//! `cargo run --release --example lossy_link [-- RUNS [TIME_SCALE]]` (default 5 runs, the mock's
//! clock ×5 so a run takes seconds; the host's timing is real).

use odocal::base::Base;
use odocal::calibration::Method;
use odocal::demo::MockTruth;
use odocal::hal::open_port;
use odocal::kinematics::WheelParams;
use odocal::mock::{lock, spawn_pty, FaultConfig, MockConfig, MockDevice, TimeMode};
use odocal::routine::config::{RoutineConfig, WritePolicy};
use odocal::routine::{run, Unattended};
use std::sync::{Arc, Mutex};
use std::time::Instant;
use tokio_util::sync::CancellationToken;

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let runs: u64 = args.next().map_or(Ok(5), |a| a.parse())?;
    let scale: f64 = args.next().map_or(Ok(5.0), |a| a.parse())?;
    let backups = std::env::temp_dir().join(format!("odocal-lossy-{}", std::process::id()));
    let mut completed = 0;
    for seed in 0..runs {
        let cfg = MockConfig::with_ratios(WheelParams::nominal(0.15, 0.39, 4096.0), 0.976, 0.992)?;
        let device = Arc::new(Mutex::new(MockDevice::new(cfg)?));
        let faults = FaultConfig {
            corrupt_byte_rate: 0.01,
            drop_frame_rate: 0.05,
            seed,
            ..FaultConfig::default()
        };
        let pty = spawn_pty(device.clone(), TimeMode::RealTime { scale }, faults)?;
        let started = Instant::now();
        let outcome = async {
            let (client, _) = open_port(&pty.path, 115_200).await?;
            let routine = RoutineConfig {
                side_m: 1.0,
                runs_per_direction: 2,
                max_speed_m_s: 1.0,
                max_rate_rad_s: 3.0,
                settle_s: 0.0,
                write_back: WritePolicy::Yes,
                confirm_motion: false,
                verification_runs: 1,
                method: Some(Method::Exact),
                backup_dir: Some(backups.clone()),
                ..RoutineConfig::default()
            };
            let truth = MockTruth(device.clone());
            let link = client.clone();
            let report = run(
                &Base::single(client),
                &routine,
                Some(&truth),
                &mut Unattended,
                &CancellationToken::new(),
            )
            .await?;
            Ok::<_, Box<dyn std::error::Error>>((report, link.stats()))
        }
        .await;
        let counters = lock(&device).counters();
        match outcome {
            Ok((report, stats)) => {
                completed += 1;
                println!(
                    "run {seed}: completed in {:.1} s, E_b {:.5} E_d {:.5}, {} motions each run once ({} accepted), {} retries, {} telemetry samples lost",
                    started.elapsed().as_secs_f64(),
                    report.rounds[0].chosen.e_b,
                    report.rounds[0].chosen.e_d,
                    counters.motions_completed,
                    counters.motions_accepted,
                    stats.retries,
                    stats.telemetry_dropped
                );
            }
            Err(e) => println!(
                "run {seed}: FAILED after {:.1} s: {e}",
                started.elapsed().as_secs_f64()
            ),
        }
    }
    println!(
        "{completed} of {runs} runs completed (1 % bytes corrupted, 5 % frames lost, both ways)"
    );
    let _ = std::fs::remove_dir_all(&backups);
    if completed == runs {
        Ok(())
    } else {
        Err(format!("{} run(s) failed", runs - completed).into())
    }
}
