//! `odocal swing` and `odocal spin`: the heading sensor's own tests, each a few turns in place.
//! The swing fits a compass's deviation curve; the spin measures a gyro's scale error against
//! a mark on the floor. Both print the flag that gives the result to `calibrate`.

use crate::robot::RobotArgs;
use odocal::calibration::gyro::scale_from_spin;
use odocal::routine::spin::run_spin;
use odocal::routine::swing::{run_swing, SwingCommand};
use odocal::spec::RobotSection;
use serde_json::json;
use std::io::{BufRead, Write};
use std::time::Duration;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Arguments of `odocal swing`.
#[derive(Debug, clap::Args)]
pub struct SwingArgs {
    #[command(flatten)]
    robot: RobotArgs,
    /// Full turns each way.
    #[arg(long, default_value_t = 2)]
    turns: u32,
    /// Turn-rate limit (rad/s): slow, so that a compass that filters keeps up.
    #[arg(long, default_value_t = 0.5)]
    rate_rad_s: f64,
    /// Turn without asking first.
    #[arg(long)]
    yes: bool,
    /// Print the fit as one JSON object.
    #[arg(long)]
    json: bool,
}

/// Arguments of `odocal spin`.
#[derive(Debug, clap::Args)]
pub struct SpinArgs {
    #[command(flatten)]
    robot: RobotArgs,
    /// Full turns (negative: clockwise). More turns, a finer scale: 0.5° at the mark over 5
    /// turns is 0.03 %.
    #[arg(long, default_value_t = 5)]
    turns: i32,
    /// Turn-rate limit (rad/s).
    #[arg(long, default_value_t = 0.5)]
    rate_rad_s: f64,
    /// Readings averaged at rest before and after.
    #[arg(long, default_value_t = 10)]
    heading_samples: usize,
    /// How far past the start mark the robot stopped (deg, in the direction it turned;
    /// negative when short of it). Asked for when not given.
    #[arg(long, allow_hyphen_values = true)]
    past_mark_deg: Option<f64>,
    /// Turn without asking first.
    #[arg(long)]
    yes: bool,
    /// Print the result as one JSON object.
    #[arg(long)]
    json: bool,
}

fn ask(question: &str) -> Result<String, Box<dyn std::error::Error>> {
    eprint!("{question} ");
    std::io::stderr().flush()?;
    let mut line = String::new();
    std::io::stdin().lock().read_line(&mut line)?;
    Ok(line.trim().to_string())
}

pub fn confirm(yes: bool, what: &str) -> CliResult {
    if yes
        || matches!(
            ask(&format!("{what} Is the area clear? [y/N]"))?.as_str(),
            "y" | "yes"
        )
    {
        Ok(())
    } else {
        Err("the robot may not move".into())
    }
}

/// Runs `odocal swing`: **moves the robot** (turns in place).
pub async fn swing(args: SwingArgs) -> CliResult {
    if !(args.rate_rad_s.is_finite() && args.rate_rad_s > 0.0 && args.rate_rad_s <= 3.0) {
        return Err(format!("--rate-rad-s {}: must be in (0, 3]", args.rate_rad_s).into());
    }
    if !(1..=10).contains(&args.turns) {
        return Err(format!("--turns {}: must be 1..=10", args.turns).into());
    }
    let base = args.robot.spec(RobotSection::default())?.open().await?;
    confirm(
        args.yes,
        &format!(
            "The robot will turn in place {} full turn(s) each way at up to {} rad/s.",
            args.turns, args.rate_rad_s
        ),
    )?;
    let params = base.store.read().await?;
    let cmd = SwingCommand {
        turns_per_direction: args.turns,
        rate_rad_s: args.rate_rad_s,
        wheelbase_m: params.wheelbase_m,
        stream_period: Duration::from_millis(20),
    };
    let fit = tokio::select! {
        r = run_swing(&base, &cmd) => r?,
        _ = tokio::signal::ctrl_c() => {
            let _ = base.drive.stop().await;
            return Err("interrupted: the robot was stopped".into());
        }
    }
    .map_err(|why| format!("no swing: {why}"))?;
    let flag = fit
        .deviation
        .0
        .map(|c| format!("{:.3}", c.to_degrees()))
        .join(",");
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({
                "fit": fit,
                "compass_deviation_deg": flag,
                "advice": fit.advice(),
            }))?
        );
        return Ok(());
    }
    let se = fit.deviation_std_err_rad.map(f64::to_degrees);
    let [a1, b1, a2, b2] = fit.deviation.0.map(f64::to_degrees);
    println!(
        "compass deviation d(ψ) = A1·sin ψ + B1·cos ψ + A2·sin 2ψ + B2·cos 2ψ\n  \
         A1 {a1:+.3}° ± {:.3}°  B1 {b1:+.3}° ± {:.3}°  A2 {a2:+.3}° ± {:.3}°  B2 {b2:+.3}° ± {:.3}°\n  \
         up to {:.2}° with the heading; {:.2}° left after the fit (noise and what four harmonics \
         do not describe); {} readings",
        se[0],
        se[1],
        se[2],
        se[3],
        fit.amplitude_rad.to_degrees(),
        fit.residual_rms_rad.to_degrees(),
        fit.points
    );
    if let Some(advice) = fit.advice() {
        println!("advice: {advice}");
    }
    println!(
        "to remove it from every reading: --compass-deviation-deg {flag} (calibrate also \
         swings by itself unless --no-swing)"
    );
    Ok(())
}

/// Runs `odocal spin`: **moves the robot** (turns in place), then asks where it stopped.
pub async fn spin(args: SpinArgs) -> CliResult {
    if !(args.rate_rad_s.is_finite() && args.rate_rad_s > 0.0 && args.rate_rad_s <= 3.0) {
        return Err(format!("--rate-rad-s {}: must be in (0, 3]", args.rate_rad_s).into());
    }
    if !(1..=20).contains(&args.turns.unsigned_abs()) {
        return Err(format!("--turns {}: must be 1..=20 either way", args.turns).into());
    }
    if !(1..=100).contains(&args.heading_samples) {
        return Err(format!(
            "--heading-samples {}: must be 1..=100",
            args.heading_samples
        )
        .into());
    }
    let base = args.robot.spec(RobotSection::default())?.open().await?;
    confirm(
        args.yes,
        &format!(
            "Mark the robot's heading on the floor (a line along its side). It will turn in \
             place {} full turn(s) {} at up to {} rad/s.",
            args.turns.unsigned_abs(),
            if args.turns > 0 {
                "counter-clockwise"
            } else {
                "clockwise"
            },
            args.rate_rad_s
        ),
    )?;
    let record = tokio::select! {
        r = run_spin(&base, args.turns, args.rate_rad_s, args.heading_samples) => r?,
        _ = tokio::signal::ctrl_c() => {
            let _ = base.drive.stop().await;
            return Err("interrupted: the robot was stopped".into());
        }
    };
    let past_deg = match args.past_mark_deg {
        Some(d) => d,
        None => ask(
            "How far past the mark did it stop, in degrees, in the direction it turned \
             (negative if short of it)?",
        )?
        .parse::<f64>()
        .map_err(|e| format!("not a number of degrees: {e}"))?,
    };
    let s = scale_from_spin(
        record.heading_before_rad,
        record.heading_after_rad,
        f64::from(args.turns),
        past_deg.to_radians(),
    )?;
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({
                "spin": record,
                "past_mark_deg": past_deg,
                "gyro_scale_error": s,
            }))?
        );
        return Ok(());
    }
    println!(
        "gyro scale error {:+.3} % (it reads {:.5} times every turn)\n\
         to remove it: calibrate --gyro-scale-error {s:.5}",
        100.0 * s,
        1.0 + s
    );
    Ok(())
}
