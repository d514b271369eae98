//! `odocal record` and `odocal track`: telemetry logs and the online estimator.

use crate::print_json;
use clap::ArgGroup;
use odocal::calibration::online::{OnlineConfig, OnlineEstimate, ScaleSource};
use odocal::dataset::OptiOdomSet;
use odocal::hal::open_port;
use odocal::kinematics::SplitConvention;
use odocal::protocol::message::ParamSource;
use odocal::routine::config::WritePolicy;
use odocal::routine::{write_parameters, RoutineEvent, RoutineUi};
use odocal::track::{read_log, LogHeader, LogWriter, Tracker};
use serde_json::json;
use std::io::BufRead;
use std::path::PathBuf;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Arguments of `odocal record`.
#[derive(Debug, clap::Args)]
pub struct RecordArgs {
    /// Serial port of the motor controller.
    #[arg(long)]
    port: String,
    /// Baud rate.
    #[arg(long, default_value_t = 115_200)]
    baud: u32,
    /// The log to write (JSON lines).
    #[arg(long)]
    out: PathBuf,
    /// Telemetry period (ms).
    #[arg(long, default_value_t = 20)]
    period_ms: u64,
    /// Stop after this long (default: until Ctrl-C).
    #[arg(long)]
    duration_s: Option<f64>,
}

async fn until_stopped(duration_s: Option<f64>) {
    match duration_s {
        Some(s) => {
            tokio::select! {
                () = tokio::time::sleep(Duration::from_secs_f64(s.max(0.0))) => {}
                _ = tokio::signal::ctrl_c() => {}
            }
        }
        None => {
            let _ = tokio::signal::ctrl_c().await;
        }
    }
}

/// Streams live telemetry into `on_sample` until Ctrl-C or `duration_s`, then turns telemetry
/// off again.
async fn stream_telemetry(
    client: &odocal::hal::Client,
    period_ms: u64,
    duration_s: Option<f64>,
    mut on_sample: impl FnMut(&odocal::hal::TelemetrySample) -> CliResult,
) -> CliResult {
    let mut rx = client.subscribe();
    client
        .configure_telemetry(Some(Duration::from_millis(period_ms)))
        .await?;
    let stop = until_stopped(duration_s);
    tokio::pin!(stop);
    let result = loop {
        tokio::select! {
            () = &mut stop => break Ok(()),
            s = rx.recv() => match s {
                Ok(s) => if let Err(e) = on_sample(&s) { break Err(e) },
                Err(tokio::sync::broadcast::error::RecvError::Lagged(k)) => {
                    eprintln!("warning: {k} telemetry samples lost (host too slow)");
                }
                Err(_) => break Ok(()),
            }
        }
    };
    let _ = client.configure_telemetry(None).await;
    result
}

/// Runs `odocal record`.
pub async fn record(args: RecordArgs) -> CliResult {
    let (client, info) = open_port(&args.port, args.baud).await?;
    let params = client.get_params(ParamSource::Active).await?;
    let mut log = LogWriter::create(
        &args.out,
        LogHeader {
            odocal_version: env!("CARGO_PKG_VERSION").into(),
            device: Some(info),
            params,
            period_ms: args.period_ms,
        },
    )?;
    eprintln!(
        "recording telemetry to {} (Ctrl-C to stop)",
        args.out.display()
    );
    let mut n = 0u64;
    stream_telemetry(&client, args.period_ms, args.duration_s, |s| {
        n += 1;
        log.sample(s).map_err(Into::into)
    })
    .await?;
    log.flush()?;
    let stats = client.stats();
    if n == 0 {
        return Err(format!(
            "no telemetry arrived in {:.1} s ({} written with its header only). The device \
             answers but sends no samples: a controller may stream only while the robot moves \
             (drive it while recording), and `odocal mock-device` in virtual time (the default) \
             never advances while idle: start it with --real-time 1 to record from it",
            args.duration_s.unwrap_or(f64::NAN),
            args.out.display()
        )
        .into());
    }
    println!(
        "recorded {n} samples to {} ({} lost on the link)",
        args.out.display(),
        stats.telemetry_dropped
    );
    Ok(())
}

/// Live samples kept for the clock-offset check (an hour at 50 Hz).
const LIVE_SAMPLES_KEPT: usize = 180_000;

/// Arguments of `odocal track`.
#[derive(Debug, clap::Args)]
#[command(group(ArgGroup::new("source").required(true).args(["port", "log", "dataset"])))]
pub struct TrackArgs {
    /// Live: the motor controller's serial port (the robot is driven by something else).
    #[arg(long)]
    port: Option<String>,
    /// Baud rate.
    #[arg(long, default_value_t = 115_200)]
    baud: u32,
    /// A telemetry log written by `odocal record`.
    #[arg(long)]
    log: Option<PathBuf>,
    /// A recorded OptiOdom set (ground-truth heading plays the compass).
    #[arg(long)]
    dataset: Option<PathBuf>,
    /// Diameter split for E_b.
    #[arg(long, default_value = "left-nominal")]
    convention: SplitConvention,
    /// Relative wheel slip per step assumed by the filter.
    #[arg(long, default_value_t = 0.01)]
    slip_fraction: f64,
    /// Heading noise per reading assumed by the filter (deg).
    #[arg(long, default_value_t = 0.37)]
    heading_sigma_deg: f64,
    /// Print an estimate every this many metres driven.
    #[arg(long, default_value_t = 1.0)]
    every_m: f64,
    /// Live: telemetry period (ms).
    #[arg(long, default_value_t = 20)]
    period_ms: u64,
    /// Live: stop after this long (default: until Ctrl-C).
    #[arg(long)]
    duration_s: Option<f64>,
    /// Live: write the estimate back when both standard deviations are below --max-std.
    #[arg(long, requires = "port")]
    write_back: bool,
    /// Largest standard deviation of E_b and E_d that justifies a write-back.
    #[arg(long, default_value_t = 0.002)]
    max_std: f64,
    /// Write back without asking.
    #[arg(long)]
    yes: bool,
    /// Where the parameter backup goes before a write-back.
    #[arg(long, default_value = ".")]
    backup_dir: PathBuf,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

fn show(e: &OnlineEstimate, json_out: bool, label: &str) {
    if !json_out {
        println!(
            "{label:>9} {:>8.2} m   E_b {:.5} ± {:.5}   E_d {:.6} ± {:.6}",
            e.distance_m, e.e_b, e.e_b_std, e.e_d, e.e_d_std
        );
    }
}

struct StdinUi {
    yes: bool,
}

impl RoutineUi for StdinUi {
    fn confirm(&mut self, question: &str) -> bool {
        if self.yes {
            return true;
        }
        eprint!("{question} [y/N] ");
        let mut line = String::new();
        tokio::task::block_in_place(|| std::io::stdin().lock().read_line(&mut line)).is_ok()
            && matches!(line.trim(), "y" | "Y" | "yes")
    }
    fn event(&mut self, event: &RoutineEvent) {
        eprintln!("{event:?}");
    }
}

/// Runs `odocal track`.
pub async fn track(args: TrackArgs) -> CliResult {
    let scale = ScaleSource::Convention(args.convention);
    let config = |configured| {
        let mut c = OnlineConfig::new(configured);
        c.slip_fraction = args.slip_fraction;
        c.heading_sigma_rad = args.heading_sigma_deg.to_radians();
        c
    };
    if !args.json {
        println!("{:>9} {:>10}   estimate", "", "driven");
    }
    let mut write_back = None;
    let (tracker, configured) = if let Some(dir) = &args.dataset {
        let set = OptiOdomSet::load(dir)?;
        let mut t = Tracker::new(config(set.configured), scale, args.every_m)?;
        for e in t.feed_dataset(&set) {
            show(&e, args.json, "");
        }
        (t, set.configured)
    } else if let Some(path) = &args.log {
        let (header, samples) = read_log(path)?;
        let mut t = Tracker::new(config(header.params), scale, args.every_m)?;
        for e in t.feed_log(&samples) {
            show(&e, args.json, "");
        }
        (t, header.params)
    } else if let Some(port) = &args.port {
        let (client, _) = open_port(port, args.baud).await?;
        let configured = client.get_params(ParamSource::Active).await?;
        let mut t = Tracker::new(config(configured), scale, args.every_m)?;
        // Kept for the clock-offset check at the end; an hour at 50 Hz, then the oldest go.
        let mut kept = std::collections::VecDeque::new();
        stream_telemetry(&client, args.period_ms, args.duration_s, |s| {
            if let Some(e) = t.feed_sample(s) {
                show(&e, args.json, "");
            }
            if kept.len() == LIVE_SAMPLES_KEPT {
                kept.pop_front();
            }
            kept.push_back(*s);
            Ok(())
        })
        .await?;
        t.check_time_offset("live", kept.make_contiguous());
        write_back = Some(client);
        (t, configured)
    } else {
        return Err("give --port, --log or --dataset".into());
    };
    let last = tracker.estimate()?;
    show(&last, args.json, "final");
    let (nis, updates) = tracker.filter().nis_mean();
    let gate = tracker.filter().gate_stats();
    let excitation = tracker.filter().excitation(scale)?;
    let mut written = None;
    if let (true, Some(client)) = (args.write_back, &write_back) {
        if last.e_b_std < args.max_std && last.e_d_std < args.max_std {
            let new = last.correction.apply(&configured)?;
            let policy = if args.yes {
                WritePolicy::Yes
            } else {
                WritePolicy::Ask
            };
            let (applied, backup) = write_parameters(
                &odocal::base::Base::single(client.clone()),
                &new,
                policy,
                0.1,
                &args.backup_dir,
                &mut StdinUi { yes: args.yes },
                &CancellationToken::new(),
            )
            .await?;
            eprintln!("written and committed; backup in {}", backup.display());
            written = Some(applied);
        } else {
            eprintln!(
                "not written: uncertainty (E_b ± {:.5}, E_d ± {:.5}) above --max-std {}; drive more",
                last.e_b_std, last.e_d_std, args.max_std
            );
        }
    }
    if args.json {
        let mut estimates: Vec<_> = tracker.checkpoints.clone();
        estimates.push(last);
        return print_json(&json!({
            "configured": configured,
            "estimates": estimates,
            "heading_updates": updates,
            "heading_nis_mean": nis,
            "heading_gate": gate,
            "excitation": excitation,
            "time_offsets": tracker.time_offsets,
            "written": written,
        }));
    }
    println!(
        "{updates} heading updates, mean NIS {nis:.2} (≈ 1 when the noise settings fit the robot); \
         {} reading(s) rejected by the gate, {} heading re-anchor(s)",
        gate.rejected, gate.resets
    );
    println!(
        "observed: E_b {:?} (σ {:.0} % of prior), E_d {:?} (σ {:.0} % of prior)",
        excitation.e_b,
        100.0 * excitation.e_b_ratio,
        excitation.e_d,
        100.0 * excitation.e_d_ratio
    );
    if let Some(advice) = excitation.advice() {
        println!("warning: {advice}");
    }
    for o in &tracker.time_offsets {
        let what = if o.corrected {
            "corrected"
        } else if o.offset.significant() {
            "NOT corrected (live); fix the clocks or the sensor delay"
        } else {
            "below the warning threshold"
        };
        let prefix = if o.offset.significant() {
            "warning: "
        } else {
            ""
        };
        println!(
            "{prefix}{}: heading stream {} the encoders by {:.3} s (rate correlation {:.2}, {:.2} at 0 s): {what}",
            o.run,
            if o.offset.offset_s >= 0.0 { "lags" } else { "leads" },
            o.offset.offset_s.abs(),
            o.offset.correlation,
            o.offset.correlation_at_zero
        );
    }
    Ok(())
}
