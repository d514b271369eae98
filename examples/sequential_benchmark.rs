//! `calibrate --target-eb-std` against today's fixed plan, on the in-process simulated robot
//! in virtual time: the robot time each needs for the same stated precision, and how often the
//! stated standard errors cover the truth at 2σ.
//!
//! `cargo run --release --example sequential_benchmark [-- SEEDS]` (default 200). The robot is
//! the demo's (E_b 0.976, E_d 0.992, D 0.15 m, b 0.39 m, compass σ 0.37°, 50 Hz); the routine
//! the default one (4 m squares, compass swing, matched-legs), settles left out. The fixed plan
//! drives 5 + 5 squares a round, a second round to confirm, and 3 + 3 to verify. Its median
//! stated standard error of `E_b` (of the estimate written last) becomes the target of the
//! sequential run. Issue 24's bar: the sequential run within 70 % of the fixed plan's robot
//! time, and both errors covering the truth at 2σ in 90–99 % of the seeds.

use odocal::base::{Base, GroundTruth};
use odocal::calibration::plan::duration_text;
use odocal::calibration::HeadingKind;
use odocal::kinematics::{SplitConvention, WheelParams};
use odocal::mock::SimBase;
use odocal::routine::config::{RoutineConfig, WritePolicy};
use odocal::routine::planning::{plan_of, Setting, DEFAULT_FOOTPRINT_M};
use odocal::routine::report::Phase;
use odocal::routine::{run, Unattended};
use odocal::sim::{NoiseModel, Simulator};
use tokio_util::sync::CancellationToken;

const SIGMA_DEG: f64 = 0.37;

/// What one calibration cost and stated.
struct Outcome {
    robot_time_s: f64,
    squares: usize,
    /// Stated standard errors of the estimate written last.
    stated: [f64; 2],
    /// Whether the truth is within two of them.
    covered: [bool; 2],
}

fn settings(target_e_b_std: Option<f64>) -> RoutineConfig {
    RoutineConfig {
        target_e_b_std,
        write_back: WritePolicy::Yes,
        confirm_motion: false,
        settle_s: 0.0,
        backup_dir: Some(std::env::temp_dir().join("odocal-sequential-bench")),
        ..RoutineConfig::default()
    }
}

async fn calibrate(
    seed: u64,
    target_e_b_std: Option<f64>,
) -> Result<Outcome, Box<dyn std::error::Error>> {
    let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
    let truth = WheelParams::from_ratios(&nominal, 0.976, 0.992, &SplitConvention::LeftNominal)?;
    let noise = NoiseModel {
        compass_sigma_rad: SIGMA_DEG.to_radians(),
        ..NoiseModel::default()
    };
    let sim = SimBase::new(Simulator::new(truth, nominal, noise, seed)?);
    let report = run(
        &Base::single(sim.clone()),
        &settings(target_e_b_std),
        Some(&sim),
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await?;
    let last = report
        .rounds
        .iter()
        .rfind(|r| r.written)
        .ok_or("nothing was written")?;
    let e = &last.chosen;
    // The truth relative to the parameters that round was driven with.
    let before = last.params_before;
    let true_b = sim.true_params().wheelbase_m / before.wheelbase_m;
    let true_d = sim.true_params().e_d() / before.e_d();
    let stated = [
        e.e_b_std_err.ok_or("no standard error")?,
        e.e_d_std_err.ok_or("no standard error")?,
    ];
    let separate_verification = report
        .verification
        .iter()
        .filter(|r| r.phase == Phase::Verification)
        .count();
    Ok(Outcome {
        robot_time_s: sim.time_s(),
        squares: report.rounds.iter().map(|r| r.runs.len()).sum::<usize>() + separate_verification,
        stated,
        covered: [
            (e.e_b - true_b).abs() <= 2.0 * stated[0],
            (e.e_d - true_d).abs() <= 2.0 * stated[1],
        ],
    })
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// One line of the table; returns the mean robot time (s).
fn row(name: &str, outcomes: &[Outcome]) -> f64 {
    let n = outcomes.len() as f64;
    let mean = |f: &dyn Fn(&Outcome) -> f64| outcomes.iter().map(f).sum::<f64>() / n;
    let time = mean(&|o| o.robot_time_s);
    let cover = |k: usize| 100.0 * mean(&|o| f64::from(u8::from(o.covered[k])));
    println!(
        "{name:<26} {:>12} {:>8.1} {:>13.3e} {:>13.3e} {:>8.1} % {:>6.1} %",
        duration_text(time),
        mean(&|o| o.squares as f64),
        median(outcomes.iter().map(|o| o.stated[0]).collect()),
        median(outcomes.iter().map(|o| o.stated[1]).collect()),
        cover(0),
        cover(1),
    );
    time
}

#[tokio::main(flavor = "current_thread")]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let seeds: u64 = std::env::args()
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(200);
    let started = std::time::Instant::now();
    let mut fixed = Vec::new();
    for seed in 1..=seeds {
        fixed.push(calibrate(seed, None).await?);
    }
    let target = median(fixed.iter().map(|o| o.stated[0]).collect());
    let mut sequential = Vec::new();
    for seed in 1..=seeds {
        sequential.push(calibrate(seed, Some(target)).await?);
    }
    let setting = Setting {
        space: None,
        footprint_m: DEFAULT_FOOTPRINT_M,
        wheelbase_m: 0.39,
        heading_sigma_rad: SIGMA_DEG.to_radians(),
        heading_kind: HeadingKind::Magnetic,
        readings_per_s: None,
        run_scatter_rad: 0.0,
        m_per_count: 0.0,
    };
    let planned = |t| plan_of(&settings(t), &setting);
    let (plan_fixed, plan_target) = (planned(None)?, planned(Some(target))?);
    println!(
        "odocal sequential benchmark: {seeds} seeds of the simulated robot (E_b 0.976, E_d \
         0.992, compass σ {SIGMA_DEG}°), default routine ({} m squares, {}), {:.0} s of wall \
         time",
        plan_fixed.side_m,
        plan_fixed.method,
        started.elapsed().as_secs_f64()
    );
    println!(
        "{:<26} {:>12} {:>8} {:>13} {:>13} {:>10} {:>8}",
        "", "robot time", "squares", "stated σ(E_b)", "stated σ(E_d)", "cover E_b", "E_d"
    );
    let t_fixed = row("fixed (5 per direction)", &fixed);
    let t_seq = row(&format!("--target-eb-std {target:.2e}"), &sequential);
    let reached = sequential.iter().filter(|o| o.stated[0] <= target).count();
    println!(
        "(medians of the stated errors, of the estimate written last; cover: truth within 2 of \
         them)"
    );
    println!(
        "sequential robot time: {:.0} % of the fixed plan's (issue 24: at most 70 %); target \
         reached in {reached} of {seeds} runs",
        100.0 * t_seq / t_fixed
    );
    println!(
        "the plan predicted: fixed {} ({} squares), sequential {} ({} squares, {} per \
         direction in round 1)",
        duration_text(plan_fixed.robot_time_s),
        plan_fixed.squares,
        duration_text(plan_target.robot_time_s),
        plan_target.squares,
        plan_target.runs_per_direction
    );
    Ok(())
}
