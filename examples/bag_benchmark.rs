//! Bag throughput: `odocal bag`'s reading (MCAP, CDR decoding of JointState and Imu) and
//! analysis on a simulated bag of about a million messages, on one core.
//!
//! `cargo run --release --example bag_benchmark` (target: ≥ 1 million messages per second)

use odocal::kinematics::{SplitConvention, WheelParams};
use odocal::ros::bag::writer::{write_simulated_bag, SimulatedBag};
use odocal::ros::bag::{analyse, infer_geometry, read_bag, BagOptions, GeometrySource, RosTopics};
use odocal::ros::yaml::RAD_PER_REV;
use odocal::sim::{NoiseModel, Simulator};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::temp_dir().join(format!("odocal-bag-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let path = dir.join("bench.mcap");
    let configured = WheelParams::nominal(0.15, 0.39, RAD_PER_REV);
    let truth = WheelParams::from_ratios(&configured, 0.976, 0.992, &SplitConvention::LeftNominal)?;
    let noise = NoiseModel {
        compass_sigma_rad: 0.2f64.to_radians(),
        ..NoiseModel::default()
    };
    let mut sim = Simulator::new(truth, configured, noise, 1)?;
    let cfg = SimulatedBag {
        side_m: 4.0,
        runs: 20,
        imu_hz: 200.0,
        joint_hz: 100.0,
        ..SimulatedBag::default()
    };
    let written = write_simulated_bag(&path, &mut sim, &cfg, &RosTopics::default())?;
    let bytes = std::fs::metadata(&path)?.len();
    let opts = BagOptions::default();
    let mut times = Vec::new();
    let mut messages = 0;
    for _ in 0..5 {
        let t = Instant::now();
        let data = read_bag(&path, &opts)?;
        let g = infer_geometry(&data)?;
        let report = analyse(
            &path,
            &data,
            g.params(),
            GeometrySource::Inferred(g),
            (0.075, 0.39),
            &opts,
        )?;
        times.push(t.elapsed().as_secs_f64());
        messages = data.messages;
        assert_eq!(report.runs.len(), 40);
    }
    times.sort_by(f64::total_cmp);
    let median = times[2];
    println!(
        "bag of {written} messages ({:.1} MiB; JointState + Imu + Odometry, CDR in MCAP): read \
         and analysed in {median:.3} s median of 5 → {:.2} million messages/s",
        bytes as f64 / (1 << 20) as f64,
        messages as f64 / median / 1e6
    );
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}
