//! `odocal swing` and `odocal spin`: the heading sensor's own tests, each a few turns in place.
//! The swing fits a compass's deviation curve; the spin measures a gyro's scale error against
//! a mark on the floor. Both print the flag that gives the result to `calibrate`.

use odocal::base::HeadingKind;
use odocal::calibration::gyro::scale_from_spin;
use odocal::kinematics::wrap_angle;
use odocal::roboclaw::profile::{save_heading, HeadingSection};
use odocal::routine::heading::mean_heading;
use odocal::routine::spin::{run_spin, SpinOutcome};
use odocal::routine::swing::{run_swing, SwingCommand, SwingOutcome};
use odocal::spec::flags::RobotFlags;
use odocal::spec::{HeadingSpec, RobotSection, StoreSpec};
use std::time::Duration;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Arguments of `odocal swing`.
#[derive(Debug, clap::Args)]
pub struct SwingArgs {
    #[command(flatten)]
    robot: RobotFlags,
    /// Full turns each way.
    #[arg(long, default_value_t = 2)]
    turns: u32,
    /// Turn-rate limit (rad/s): slow, so that a compass that filters keeps up.
    #[arg(long = "max-rate-rad-s", alias = "rate-rad-s", default_value_t = 0.5)]
    rate_rad_s: f64,
    /// Save the curve in the robot profile's [heading] table (a profile store only; backed up
    /// beside it first, for `odocal restore`): every later command with this profile removes
    /// it.
    #[arg(long)]
    save: bool,
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
    robot: RobotFlags,
    /// Full turns (negative: clockwise). More turns, a finer scale: 0.5° at the mark over 5
    /// turns is 0.03 %.
    #[arg(long, default_value_t = 5)]
    turns: i32,
    /// Turn-rate limit (rad/s).
    #[arg(long = "max-rate-rad-s", alias = "rate-rad-s", default_value_t = 0.5)]
    rate_rad_s: f64,
    /// Readings averaged at rest before and after.
    #[arg(long, default_value_t = 10)]
    heading_samples: usize,
    /// How far past the start mark the robot stopped (deg, in the direction it turned;
    /// negative when short of it). Asked for when not given and there is no --reference.
    #[arg(long, allow_hyphen_values = true)]
    past_mark_deg: Option<f64>,
    /// A compass that sees the same turn (a heading spec, e.g. nmea:PORT): it tells where the
    /// robot stopped instead of a floor mark. Over whole turns its deviation is the same at
    /// both ends.
    #[arg(long, conflicts_with = "past_mark_deg")]
    reference: Option<String>,
    /// Turn without asking first.
    #[arg(long)]
    yes: bool,
    /// Print the result as one JSON object.
    #[arg(long)]
    json: bool,
}

pub fn confirm(yes: bool, what: &str) -> CliResult {
    if yes || crate::prompt::yes(&format!("{what} Is the area clear?")) {
        Ok(())
    } else {
        Err("the robot may not move".into())
    }
}

/// Why `--save` needs a profile.
const SAVE_NEEDS_PROFILE: &str = "--save keeps the curve in a robot profile: give --profile \
     (for other robots, pass the printed --compass-deviation-deg)";

/// A turn-rate limit a robot may be given (rad/s).
fn check_rate(rate_rad_s: f64) -> CliResult {
    if rate_rad_s.is_finite() && rate_rad_s > 0.0 && rate_rad_s <= 3.0 {
        return Ok(());
    }
    Err(format!("--max-rate-rad-s {rate_rad_s}: must be in (0, 3]").into())
}

/// `fut`, the robot's motion, unless a signal comes first: then the robot is stopped.
async fn or_stopped<T>(
    base: &odocal::base::Base,
    fut: impl std::future::Future<Output = T>,
) -> Result<T, Box<dyn std::error::Error>> {
    tokio::select! {
        r = fut => Ok(r),
        name = crate::prompt::signal() => {
            let _ = base.drive.stop().await;
            let name = name.unwrap_or("a signal");
            Err(format!("interrupted ({name}): the robot was stopped").into())
        }
    }
}

/// Keeps the curve (what was already removed and what the swing found) in the profile at
/// `path`, through the write service (backed up first); returns the outcome with where.
async fn save_curve(
    base: &odocal::base::Base,
    path: &std::path::Path,
    mut outcome: SwingOutcome,
) -> Result<SwingOutcome, Box<dyn std::error::Error>> {
    let kind = base.heading.kind();
    let section = HeadingSection {
        kind: (kind == HeadingKind::Magnetic).then_some(kind),
        compass_deviation_deg: Some(outcome.total_deg()),
    };
    let backup = save_heading(path, &section).await?;
    outcome.saved = Some((path.to_path_buf(), backup));
    Ok(outcome)
}

/// Runs `odocal swing`: **moves the robot** (turns in place).
pub async fn swing(args: SwingArgs) -> CliResult {
    check_rate(args.rate_rad_s)?;
    if !(1..=10).contains(&args.turns) {
        return Err(format!("--turns {}: must be 1..=10", args.turns).into());
    }
    let spec = args.robot.spec(RobotSection::default())?;
    let save_to = match (&spec.store, args.save) {
        (StoreSpec::Profile(path), true) => Some(path.clone()),
        (_, true) => return Err(SAVE_NEEDS_PROFILE.into()),
        _ => None,
    };
    // What is already removed from the readings (a flag, or the profile's saved curve): the
    // swing measures what is left, and the curve to keep is both.
    let (_, applied) = spec.heading_correction()?;
    let base = spec.open().await?;
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
        // Not measured here: the residual is judged against a fixed allowance.
        noise_std_rad: None,
    };
    let fit = or_stopped(&base, run_swing(&base, &cmd))
        .await??
        .map_err(|why| match why {
            odocal::routine::swing::NoSwing::Refused(why) => {
                format!("the swing's fit was refused, nothing was saved: {why}")
            }
            why => format!("no swing: {why}"),
        })?;
    let mut outcome = SwingOutcome {
        fit,
        applied,
        saved: None,
    };
    if let Some(path) = &save_to {
        outcome = save_curve(&base, path, outcome).await?;
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&outcome.json())?);
    } else {
        print!("{outcome}");
    }
    Ok(())
}

/// How far past its mark the robot stopped, in the direction it turned (deg): given, read off
/// a reference compass (its deviation the same after whole turns), or asked.
async fn past_mark_deg(
    args: &SpinArgs,
    reference: Option<&dyn odocal::base::HeadingSource>,
    before: Option<f64>,
) -> Result<f64, Box<dyn std::error::Error>> {
    let sign = f64::from(args.turns.signum());
    Ok(match (args.past_mark_deg, reference, before) {
        (Some(d), _, _) => d,
        (None, Some(r), Some(before)) => {
            let after = mean_heading(r, args.heading_samples).await?;
            sign * wrap_angle(after - before).to_degrees()
        }
        _ => crate::prompt::answer(
            "How far past the mark did it stop, in degrees, in the direction it turned \
             (negative if short of it)?",
        )?
        .parse::<f64>()
        .map_err(|e| format!("not a number of degrees: {e}"))?,
    })
}

/// `spin`'s flags, checked before anything is opened.
fn check_spin(args: &SpinArgs) -> CliResult {
    check_rate(args.rate_rad_s)?;
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
    Ok(())
}

/// `spin --reference`, opened, and its heading before the turn.
async fn open_reference(
    args: &SpinArgs,
) -> Result<
    Option<(std::sync::Arc<dyn odocal::base::HeadingSource>, f64)>,
    Box<dyn std::error::Error>,
> {
    let Some(text) = &args.reference else {
        return Ok(None);
    };
    let r = text
        .parse::<HeadingSpec>()?
        .open()
        .await?
        .ok_or("--reference: give a heading source of its own (nmea:PORT…), not drive")?;
    let before = mean_heading(r.as_ref(), args.heading_samples).await?;
    Ok(Some((r, before)))
}

/// Runs `odocal spin`: **moves the robot** (turns in place), then asks where it stopped.
pub async fn spin(args: SpinArgs) -> CliResult {
    check_spin(&args)?;
    let base = args.robot.spec(RobotSection::default())?.open().await?;
    let reference = open_reference(&args).await?;
    let reference_before = reference.as_ref().map(|r| r.1);
    let reference = reference.map(|r| r.0);
    confirm(
        args.yes,
        &format!(
            "{}It will turn in place {} full turn(s) {} at up to {} rad/s.",
            if reference.is_some() {
                ""
            } else {
                "Mark the robot's heading on the floor (a line along its side). "
            },
            args.turns.unsigned_abs(),
            if args.turns > 0 {
                "counter-clockwise"
            } else {
                "clockwise"
            },
            args.rate_rad_s
        ),
    )?;
    let spin = run_spin(&base, args.turns, args.rate_rad_s, args.heading_samples);
    let record = or_stopped(&base, spin).await??;
    let past_deg = past_mark_deg(&args, reference.as_deref(), reference_before).await?;
    let s = scale_from_spin(
        record.heading_before_rad,
        record.heading_after_rad,
        f64::from(args.turns),
        past_deg.to_radians(),
    )?;
    let outcome = SpinOutcome {
        spin: record,
        past_mark_deg: past_deg,
        past_mark_from: if reference.is_some() {
            "reference"
        } else {
            "mark"
        },
        gyro_scale_error: s,
    };
    if args.json {
        // Through a `Value`: its keys in the order every command's JSON has (sorted).
        let value = serde_json::to_value(outcome)?;
        println!("{}", serde_json::to_string_pretty(&value)?);
    } else {
        print!("{outcome}");
    }
    Ok(())
}
