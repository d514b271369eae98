//! Monte-Carlo accuracy of every estimator under compass noise, beside the Cramér–Rao bound.
//!
//! `cargo run --release --example accuracy_study [-- TRIALS]` simulates the paper's robot
//! (E_b 0.976, E_d 0.992, D 0.15 m, b 0.39 m, 4 m square; Lee on 2 m) with a compass of
//! σ = 0.37° (the paper's STARGAZER figure), read once at rest before and after each run, for
//! n = 1, 5 and 20 runs per direction, and prints each method's bias and standard deviation of
//! E_b and E_d next to the bound. Position-based methods see noise-free positions here, so
//! their spread is zero and only their bias shows.

use odocal::calibration::Method;
use odocal::offline::study::{accuracy_study, StudyConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let trials: usize = std::env::args()
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(2000);
    let mut cfg = StudyConfig::paper(0.976, 0.992);
    cfg.noise.compass_sigma_rad = 0.37f64.to_radians();
    println!(
        "compass σ 0.37°, {trials} trials per row, truth E_b {} E_d {}",
        cfg.true_e_b, cfg.true_e_d
    );
    println!(
        "{:>3} {:<13} {:>11} {:>10} {:>10} {:>11} {:>10} {:>10} {:>12}",
        "n",
        "method",
        "E_b bias",
        "E_b std",
        "CRB std",
        "E_d bias",
        "E_d std",
        "CRB std",
        "std/CRB b,d"
    );
    for runs in [1, 5, 20] {
        cfg.runs = runs;
        let start = std::time::Instant::now();
        for row in accuracy_study(&cfg, trials, 1)? {
            let ratio = if matches!(row.method, Method::Umbmark | Method::Lee) {
                "-".to_string()
            } else {
                format!(
                    "{:.3},{:.3}",
                    row.e_b_std / row.e_b_crb_std,
                    row.e_d_std / row.e_d_crb_std
                )
            };
            println!(
                "{:>3} {:<13} {:>11.2e} {:>10.2e} {:>10.2e} {:>11.2e} {:>10.2e} {:>10.2e} {:>12}",
                runs,
                row.method.name(),
                row.e_b_bias,
                row.e_b_std,
                row.e_b_crb_std,
                row.e_d_bias,
                row.e_d_std,
                row.e_d_crb_std,
                ratio
            );
        }
        eprintln!("(n = {runs}: {:.2} s)", start.elapsed().as_secs_f64());
    }
    Ok(())
}
