//! The recalibration routine from code: a routine configuration, a UI that prints, and the
//! simulated robot (or a real port given as the first argument).
//!
//! `cargo run --release --example scripted_recalibration [-- /dev/ttyUSB0]`

use odocal::base::Base;
use odocal::demo::{run_demo, DemoOptions};
use odocal::hal::open_port;
use odocal::routine::config::{RoutineConfig, WritePolicy};
use odocal::routine::{run, RoutineEvent, RoutineUi};
use tokio_util::sync::CancellationToken;

/// Prints stages and warnings; asks nothing (the policy below decides).
struct Printer;

impl RoutineUi for Printer {
    fn confirm(&mut self, question: &str) -> bool {
        println!("{question} → yes");
        true
    }
    fn event(&mut self, event: &RoutineEvent) {
        match event {
            RoutineEvent::Stage(s) => println!("· {s}"),
            RoutineEvent::Warning(w) => println!("warning: {w}"),
            RoutineEvent::RunDone { heading_error_deg } => {
                println!("  square done: heading error {heading_error_deg:+.3}°")
            }
            _ => {}
        }
    }
}

#[tokio::main]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let cfg = RoutineConfig {
        side_m: 2.0,
        runs_per_direction: 4,
        write_back: WritePolicy::Yes,
        settle_s: 0.0,
        backup_dir: std::env::temp_dir().join("odocal-example"),
        ..RoutineConfig::default()
    };
    let cancel = CancellationToken::new();
    let report = match std::env::args().nth(1) {
        Some(port) => {
            let (client, _) = open_port(&port, cfg.baud).await?;
            run(&Base::single(client), &cfg, None, &mut Printer, &cancel).await?
        }
        None => {
            let opts = DemoOptions {
                routine: cfg,
                ..DemoOptions::default()
            };
            run_demo(&opts, &mut Printer, &cancel).await?.0
        }
    };
    print!("{}", odocal::report::summary_table(&report));
    Ok(())
}
