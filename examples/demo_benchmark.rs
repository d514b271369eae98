//! Wall time of the full demo routine (2 × 5 squares of 4 m, a second round, verification),
//! including the pseudo-terminal link: `cargo run --release --example demo_benchmark`.
//! Target (issue 5): under 3 s.

use odocal::demo::{run_demo, DemoOptions};
use odocal::routine::Unattended;
use std::time::Instant;
use tokio_util::sync::CancellationToken;

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut times = Vec::new();
    let mut motions = 0;
    let mut samples = 0;
    for seed in 1..=10 {
        let mut opts = DemoOptions {
            seed,
            ..DemoOptions::default()
        };
        opts.routine.backup_dir = Some(std::env::temp_dir().join("odocal-demo-bench"));
        let t = Instant::now();
        let (report, device) = run_demo(&opts, &mut Unattended, &CancellationToken::new()).await?;
        times.push(t.elapsed().as_secs_f64());
        motions = odocal::mock::lock(&device).counters().motions_completed;
        samples = report.diagnostics["telemetry_received"]
            .as_u64()
            .unwrap_or(0);
        assert!(report.written && report.converged);
    }
    times.sort_by(f64::total_cmp);
    println!(
        "odocal demo routine ({motions} motions, {samples} telemetry samples at 50 Hz device \
         time): median {:.3} s, max {:.3} s over 10 runs",
        times[5], times[9]
    );
    Ok(())
}
