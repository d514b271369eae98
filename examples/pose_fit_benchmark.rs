//! Time to fit an hour of driving against a pose reference.
//!
//! `cargo run --release --example pose_fit_benchmark [-- MINUTES]`: a simulated drive (wheels
//! at 50 Hz, poses at 10 Hz, the `sim::driving` defaults otherwise), fitted from the nominal
//! geometry as `odocal fit` does (the kind decided from the data: a relative fit, then the
//! absolute one). Prints the simulation's and the fit's wall time. Reading the same drive from
//! a bag is not timed here yet.

use odocal::calibration::pose_fit::{fit_poses, FitConfig};
use odocal::calibration::pose_reference::Geometry;
use odocal::sim::driving::{simulate_drive, DrivingConfig};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let minutes: f64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(60.0);
    let started = Instant::now();
    let drive = simulate_drive(&DrivingConfig {
        duration_s: 60.0 * minutes,
        ..DrivingConfig::default()
    })?;
    let simulated = started.elapsed().as_secs_f64();
    let nominal = Geometry {
        left_diameter_m: 0.1,
        right_diameter_m: 0.1,
        wheelbase_m: 0.3,
    };
    let started = Instant::now();
    let fit = fit_poses(&drive.recording, &FitConfig::full(nominal))?;
    let fitted = started.elapsed().as_secs_f64();
    println!(
        "{minutes} min of driving: {} wheel samples, {} poses; simulated in {simulated:.2} s, \
         fitted in {fitted:.2} s ({} iterations, {})",
        drive.recording.wheels.len(),
        drive.recording.poses.len(),
        fit.iterations,
        fit.kind.kind.name()
    );
    for kind in [
        odocal::calibration::pose_reference::ReferenceKind::Absolute,
        odocal::calibration::pose_reference::ReferenceKind::Relative,
    ] {
        let started = Instant::now();
        let fit = fit_poses(
            &drive.recording,
            &FitConfig {
                kind: Some(kind),
                ..FitConfig::full(nominal)
            },
        )?;
        println!(
            "  given as {}: {:.2} s ({} iterations)",
            kind.name(),
            started.elapsed().as_secs_f64(),
            fit.iterations
        );
    }
    Ok(())
}
