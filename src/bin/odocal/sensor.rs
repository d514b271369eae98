//! `odocal swing` and `odocal spin`: the heading sensor's own tests, each a few turns in place.
//! The swing fits a compass's deviation curve; the spin measures a gyro's scale error against
//! a mark on the floor. Both print the flag that gives the result to `calibrate`. And
//! `odocal heading` and `status`, which read a robot's sensor or controller without moving it.

use odocal::kinematics::wrap_angle;
use odocal::routine::heading::mean_heading;
use odocal::routine::spin::{run_spin, SpinOutcome, SpinSettings};
use odocal::routine::swing::{run_swing, SwingOutcome, SwingSettings};
use odocal::spec::flags::RobotFlags;
use odocal::spec::{DriveSpec, HeadingSpec, RobotSection, SpecError};

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Arguments of `odocal swing`.
#[derive(Debug, clap::Args)]
pub struct SwingArgs {
    #[command(flatten)]
    robot: RobotFlags,
    #[command(flatten)]
    swing: SwingSettings,
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
    #[command(flatten)]
    spin: SpinSettings,
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

/// Runs `odocal swing`: **moves the robot** (turns in place).
pub async fn swing(args: SwingArgs) -> CliResult {
    args.swing.check()?;
    let spec = args.robot.spec(RobotSection::default())?;
    if args.save {
        spec.profile_for_curve()?;
    }
    // What is already removed from the readings (a flag, or the profile's saved curve): the
    // swing measures what is left, and the curve to keep is both.
    let (_, applied) = spec.heading_correction()?;
    let base = spec.open().await?;
    confirm(args.yes, &args.swing.question())?;
    let cmd = args.swing.command(base.store.read().await?.wheelbase_m);
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
    if args.save {
        outcome = spec.save_curve(base.heading.kind(), outcome).await?;
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
    let sign = f64::from(args.spin.turns.signum());
    Ok(match (args.past_mark_deg, reference, before) {
        (Some(d), _, _) => d,
        (None, Some(r), Some(before)) => {
            let after = mean_heading(r, args.spin.heading_samples).await?;
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
    let before = mean_heading(r.as_ref(), args.spin.heading_samples).await?;
    Ok(Some((r, before)))
}

/// Runs `odocal spin`: **moves the robot** (turns in place), then asks where it stopped.
pub async fn spin(args: SpinArgs) -> CliResult {
    args.spin.check()?;
    let base = args.robot.spec(RobotSection::default())?.open().await?;
    let reference = open_reference(&args).await?;
    let reference_before = reference.as_ref().map(|r| r.1);
    let reference = reference.map(|r| r.0);
    confirm(args.yes, &args.spin.question(reference.is_some()))?;
    let SpinSettings {
        turns,
        rate_rad_s,
        heading_samples,
    } = args.spin;
    let record = or_stopped(&base, run_spin(&base, turns, rate_rad_s, heading_samples)).await??;
    let past_deg = past_mark_deg(&args, reference.as_deref(), reference_before).await?;
    let outcome = SpinOutcome::of(record, past_deg, reference.is_some())?;
    if args.json {
        // Through a `Value`: its keys in the order every command's JSON has (sorted).
        let value = serde_json::to_value(outcome)?;
        println!("{}", serde_json::to_string_pretty(&value)?);
    } else {
        print!("{outcome}");
    }
    Ok(())
}

/// Port flags shared by `status` and the `params` commands.
#[derive(Debug, Clone, clap::Args)]
pub struct PortArgs {
    /// Serial port path (e.g. /dev/ttyUSB0, or the path `odocal mock-device` printed);
    /// `roboclaw:PORT?address=128&baud=38400` for `status` of a RoboClaw, `nmea:PORT?baud=4800`
    /// for `heading` of an NMEA compass.
    #[arg(long)]
    pub port: String,
    /// Baud rate [default: 115200; a RoboClaw's: its spec's, else 38400].
    #[arg(long)]
    pub baud: Option<u32>,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

impl PortArgs {
    /// The drive `--port` names, `--baud` laid under its own options.
    pub fn drive(&self) -> Result<DriveSpec, SpecError> {
        let mut drive: DriveSpec = self.port.parse()?;
        if let Some(baud) = self.baud {
            drive.with_baud(baud, &self.port)?;
        }
        Ok(drive)
    }
}

/// Runs `odocal status`.
pub async fn status(port: PortArgs) -> CliResult {
    let status = port.drive()?.status().await?;
    if port.json {
        return crate::out::print_json(&status.json);
    }
    print!("{}", status.text);
    Ok(())
}

/// Arguments of `odocal heading`: a heading sensor alone (`--port nmea:PORT`, `--heading
/// nmea:PORT`, or an odocal-protocol controller's `--port`), or any robot's own (`--base
/// rosbridge://HOST:PORT --ros-yaml …` reads its IMU).
#[derive(Debug, clap::Args)]
pub struct HeadingArgs {
    #[command(flatten)]
    robot: odocal::spec::flags::RobotFlags,
    /// Readings to average (circular mean); with two or more, their σ is printed too (the
    /// noise per reading `odocal plan` needs: hold the robot still).
    #[arg(long = "heading-samples", alias = "samples", default_value_t = 1)]
    samples: usize,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

/// Runs `odocal heading`.
pub async fn heading(args: HeadingArgs) -> CliResult {
    use odocal::routine::heading::HeadingReading;
    let (source, _robot) = args.robot.open_heading().await?;
    let reading = HeadingReading::read(source.as_ref(), args.samples).await?;
    if args.json {
        return crate::out::print_json(&reading.json());
    }
    println!("{reading}");
    Ok(())
}
