//! Accuracy and 2σ coverage of `odocal fit` over many simulated drives.
//!
//! `cargo run --release --example pose_fit_coverage [-- SEEDS [absolute|relative [SLIP]]]`: drives of
//! five minutes of normal driving (`sim::driving`'s defaults: wheels at 50 Hz, the reference
//! at 10 Hz with 3 mm / 0.3° noise, 1 % outliers, a lever arm of (0.12, −0.05) m and 0.1 rad,
//! 60 ms of delay), each fitted from the nominal geometry with the kind decided from the data.
//! With `relative`, the reference is chained scan matching instead: 1 mm and 0.1° per
//! increment, 2 % gross failures of 5–15 cm that stay in the chain.
//! Prints, per parameter, the worst error, the root-mean-square of error over stated σ, and the
//! share of seeds whose truth lies within 2σ (an honest covariance gives about 95 %).

use odocal::calibration::pose_fit::{fit_poses, FitConfig, Param};
use odocal::calibration::pose_reference::{Geometry, ReferenceKind};
use odocal::sim::driving::{simulate_drive, DrivingConfig};
use std::time::Instant;

fn main() {
    let mut args = std::env::args().skip(1);
    let seeds: u64 = args.next().and_then(|s| s.parse().ok()).unwrap_or(200);
    let kind = match args.next().as_deref() {
        Some("relative") => ReferenceKind::Relative,
        _ => ReferenceKind::Absolute,
    };
    let slip: f64 = args.next().and_then(|s| s.parse().ok()).unwrap_or(0.0);
    let nominal = Geometry {
        left_diameter_m: 0.1,
        right_diameter_m: 0.1,
        wheelbase_m: 0.3,
    };
    let base = DrivingConfig {
        // Optional third argument: the wheels' random slip per interval (relative σ), with
        // encoders of 4096 counts per revolution.
        wheel_slip_sigma: slip,
        encoder_counts_per_rev: (slip > 0.0).then_some(4096.0),
        ..DrivingConfig::with_reference(kind)
    };
    let truth = [
        (Param::LeftDiameter, base.truth.left_diameter_m),
        (Param::RightDiameter, base.truth.right_diameter_m),
        (Param::Wheelbase, base.truth.wheelbase_m),
        (Param::SensorX, base.sensor_x_m),
        (Param::SensorY, base.sensor_y_m),
        (Param::SensorYaw, base.sensor_yaw_rad),
        (Param::TimeOffset, base.delay_s),
    ];
    let started = Instant::now();
    let mut worst = [0.0f64; 7];
    let mut z2 = [0.0f64; 7];
    let mut covered = [0usize; 7];
    let mut kinds_right = 0;
    let mut failures = 0;
    for seed in 0..seeds {
        let config = DrivingConfig {
            seed,
            ..base.clone()
        };
        let Ok(drive) = simulate_drive(&config) else {
            failures += 1;
            continue;
        };
        let fit = match fit_poses(&drive.recording, &FitConfig::full(nominal)) {
            Ok(f) => f,
            Err(e) => {
                eprintln!("seed {seed}: {e}");
                failures += 1;
                continue;
            }
        };
        if std::env::var_os("ODOCAL_COVERAGE_VERBOSE").is_some() {
            eprintln!(
                "seed {seed}: σ {:.2e} m, {:.2e} rad; walk {:.2e} m²/s, {:.2e} rad²/s; ρ {:.2}; outliers {}",
                fit.residual_std_position_m,
                fit.residual_std_yaw_rad.unwrap_or(f64::NAN),
                fit.walk_position_m2_s,
                fit.walk_yaw_rad2_s.unwrap_or(f64::NAN),
                fit.lag_one_correlation,
                fit.outliers
            );
        }
        if fit.kind.kind == kind {
            kinds_right += 1;
        }
        for (i, (p, t)) in truth.iter().enumerate() {
            let err = fit.value(*p) - t;
            let s = fit.std(*p).unwrap_or(f64::NAN);
            let rel = match p {
                Param::LeftDiameter | Param::RightDiameter | Param::Wheelbase => err / t,
                _ => err,
            };
            worst[i] = worst[i].max(rel.abs());
            z2[i] += (err / s).powi(2);
            if err.abs() <= 2.0 * s {
                covered[i] += 1;
            }
        }
    }
    // A failed fit counts as not covered: leaving it out would flatter the coverage.
    let n = (seeds as usize).max(1);
    let fitted = (seeds as usize - failures).max(1);
    println!(
        "{seeds} simulated drives, {} reference; {failures} failed; kind decided right in {kinds_right}; {:.1} s",
        kind.name(),
        started.elapsed().as_secs_f64()
    );
    println!(
        "{:<24} {:>16} {:>14} {:>12}",
        "parameter", "worst error", "rms(err/σ)", "2σ coverage"
    );
    for (i, (p, _)) in truth.iter().enumerate() {
        let unit = match p {
            Param::LeftDiameter | Param::RightDiameter | Param::Wheelbase => {
                format!("{:.4} %", 100.0 * worst[i])
            }
            Param::SensorX | Param::SensorY => format!("{:.2} mm", 1e3 * worst[i]),
            Param::SensorYaw => format!("{:.3}°", worst[i].to_degrees()),
            Param::TimeOffset => format!("{:.2} ms", 1e3 * worst[i]),
        };
        println!(
            "{:<24} {:>16} {:>14.2} {:>11.1}%",
            p.name(),
            unit,
            (z2[i] / fitted as f64).sqrt(),
            100.0 * covered[i] as f64 / n as f64
        );
    }
}
