//! The recalibration routine from code: a routine configuration, a UI that prints, and the
//! simulated robot (or a real robot given as the first argument: any drive spec, e.g. a
//! serial port of an odocal-protocol controller; a second argument names a heading source such
//! as `nmea:/dev/ttyUSB1`).
//!
//! `cargo run --release --example scripted_recalibration [-- /dev/ttyUSB0 [nmea:/dev/ttyUSB1]]`

use odocal::demo::{run_demo, DemoOptions};
use odocal::routine::config::{RoutineConfig, WritePolicy};
use odocal::routine::{run, RoutineEvent, RoutineUi};
use odocal::spec::RobotSection;
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
            RoutineEvent::RunDone {
                heading_error_deg, ..
            } => {
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
        backup_dir: Some(std::env::temp_dir().join("odocal-example")),
        ..RoutineConfig::default()
    };
    let cancel = CancellationToken::new();
    let report = match std::env::args().nth(1) {
        Some(drive) => {
            let robot = RobotSection {
                drive: Some(drive),
                heading: std::env::args().nth(2),
                ..RobotSection::default()
            };
            let base = robot.spec()?.open().await?;
            run(&base, &cfg, None, &mut Printer, &cancel).await?
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
