//! What each kind of heading sensor does to the calibration, and what odocal does about it: the
//! whole routine over our protocol (the mock device in virtual time, the default 4 m squares,
//! 5 per direction, compass σ 0.2°) under one sensor defect at a time, and the written
//! parameters checked against the simulated truth in the two combinations a heading observes.
//!
//! `cargo run --release --example heading_sensors [-- SEEDS]` (default 4 seeds; every deviating
//! case starts from a different azimuth per seed). The table in docs/estimation.md ("Your heading sensor") is
//! this output.

use odocal::base::Base;
use odocal::calibration::Method;
use odocal::demo::MockTruth;
use odocal::hal::link::LinkConfig;
use odocal::hal::Client;
use odocal::kinematics::{Pose, WheelParams};
use odocal::mock::{lock, spawn_duplex, FaultConfig, MockConfig, MockDevice, TimeMode};
use odocal::routine::config::{RoutineConfig, WritePolicy};
use odocal::routine::report::Report;
use odocal::routine::{run, Unattended};
use odocal::sim::sensor::{HeadingModel, SensorKind};
use std::sync::{Arc, Mutex};
use tokio_util::sync::CancellationToken;

/// One row: a sensor defect, the routine's settings for it, and the link.
struct Case {
    name: &'static str,
    model: HeadingModel,
    faults: FaultConfig,
    tweak: fn(&mut RoutineConfig),
}

fn deviating() -> HeadingModel {
    HeadingModel {
        deviation: "2.2,0,0,0.7".parse().expect("a deviation"),
        ..HeadingModel::default()
    }
}

fn gyro() -> HeadingModel {
    HeadingModel {
        kind: SensorKind::Gyro,
        gyro_scale_error: 0.01,
        ..HeadingModel::default()
    }
}

/// `D_R/D_L` and `b/D̄` of `written` relative to `truth`, minus one.
fn combination_errors(written: &WheelParams, truth: &WheelParams) -> (f64, f64) {
    let b_over_d = |p: &WheelParams| {
        2.0 * p.wheelbase_m / (p.left_wheel_diameter_m + p.right_wheel_diameter_m)
    };
    (
        written.e_d() / truth.e_d() - 1.0,
        b_over_d(written) / b_over_d(truth) - 1.0,
    )
}

async fn calibrate(
    case: &Case,
    seed: u64,
) -> Result<(Report, WheelParams), Box<dyn std::error::Error>> {
    let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
    let mut cfg = MockConfig::with_ratios(nominal, 0.976, 0.992)?;
    cfg.noise.compass_sigma_rad = 0.2f64.to_radians();
    cfg.heading_model = case.model;
    cfg.seed = seed;
    let device = Arc::new(Mutex::new(MockDevice::new(cfg)?));
    // A different starting azimuth per seed: a deviation's effect depends on it.
    let psi0 = -3.0 + 1.7 * seed as f64 % 6.0;
    lock(&device).sim_mut().place(Pose::new(0.0, 0.0, psi0));
    let (stream, _task) = spawn_duplex(device.clone(), TimeMode::Virtual, case.faults);
    let (client, _) = Client::connect(stream, LinkConfig::default()).await?;
    let mut routine = RoutineConfig {
        settle_s: 0.0,
        write_back: WritePolicy::Yes,
        confirm_motion: false,
        backup_dir: Some(
            std::env::temp_dir().join(format!("odocal-sensors-{}", std::process::id())),
        ),
        ..RoutineConfig::default()
    };
    (case.tweak)(&mut routine);
    let truth = MockTruth(device.clone());
    let report = run(
        &Base::single(client),
        &routine,
        Some(&truth),
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await?;
    let t = *lock(&device).sim().truth();
    Ok((report, t))
}

#[tokio::main(flavor = "current_thread", start_paused = true)]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let seeds: u64 = std::env::args().nth(1).map_or(Ok(4), |a| a.parse())?;
    let lossy = FaultConfig {
        corrupt_byte_rate: 0.01,
        drop_frame_rate: 0.05,
        ..FaultConfig::default()
    };
    let cases = [
        Case {
            name: "ideal compass",
            model: HeadingModel::default(),
            faults: FaultConfig::default(),
            tweak: |_| {},
        },
        Case {
            name: "deviation 2.2°/0.7°, default",
            model: deviating(),
            faults: FaultConfig::default(),
            tweak: |_| {},
        },
        Case {
            name: "deviation, no swing",
            model: deviating(),
            faults: FaultConfig::default(),
            tweak: |c| c.swing = false,
        },
        Case {
            name: "deviation, --method legs",
            model: deviating(),
            faults: FaultConfig::default(),
            tweak: |c| {
                c.swing = false;
                c.method = Some(Method::Legs);
            },
        },
        Case {
            name: "deviation, --method exact",
            model: deviating(),
            faults: FaultConfig::default(),
            tweak: |c| {
                c.swing = false;
                c.method = Some(Method::Exact);
            },
        },
        Case {
            name: "motor interference 1.5°",
            model: HeadingModel {
                motor_offset_rad: 1.5f64.to_radians(),
                ..HeadingModel::default()
            },
            faults: FaultConfig::default(),
            tweak: |_| {},
        },
        Case {
            name: "gyro 1 % fast, no reference",
            model: gyro(),
            faults: FaultConfig::default(),
            tweak: |_| {},
        },
        Case {
            name: "gyro 1 % fast, --gyro-scale-error",
            model: gyro(),
            faults: FaultConfig::default(),
            tweak: |c| c.gyro_scale_error = Some(0.01),
        },
        Case {
            name: "link: 5 % lost, 1 % corrupt",
            model: HeadingModel::default(),
            faults: lossy,
            tweak: |_| {},
        },
    ];
    println!(
        "{seeds} seed(s) each; worst |error| of the written combinations against the truth, the \
         written method(s), the verification squares' worst |heading error|"
    );
    println!(
        "{:<36} {:>12} {:>12} {:>10}  methods",
        "heading sensor", "D_R/D_L %", "b/D̄ %", "verify °"
    );
    for case in &cases {
        let (mut worst_d, mut worst_b, mut worst_v) = (0.0f64, 0.0f64, 0.0f64);
        let mut methods = Vec::new();
        for seed in 0..seeds {
            let (report, truth) = calibrate(case, seed).await?;
            let (d, b) = combination_errors(&report.final_params, &truth);
            worst_d = worst_d.max(d.abs());
            worst_b = worst_b.max(b.abs());
            for v in &report.verification {
                worst_v = worst_v.max(v.heading_error_deg.abs());
            }
            for r in report.rounds.iter().filter(|r| r.written) {
                let m = r.chosen.method.to_string();
                if !methods.contains(&m) {
                    methods.push(m);
                }
            }
        }
        println!(
            "{:<36} {:>12.3} {:>12.3} {:>10.2}  {}",
            case.name,
            100.0 * worst_d,
            100.0 * worst_b,
            worst_v,
            methods.join(", ")
        );
    }
    Ok(())
}
