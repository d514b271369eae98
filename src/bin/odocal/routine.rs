//! `odocal demo`, `calibrate` and `run`: the recalibration routine's commands.

use crate::out::print_json;
use indicatif::{ProgressBar, ProgressStyle};
#[cfg(all(feature = "mock", feature = "odocal-protocol"))]
use odocal::demo::{run_demo, DemoOptions};
use odocal::routine::config::RoutineConfig;
use odocal::routine::overrides::Overrides;
use odocal::routine::progress::{RobotClock, Shown};
use odocal::routine::report::Report;
use odocal::routine::{run, RoutineEvent, RoutineUi};
use odocal::spec::flags::RobotFlags;
use odocal::spec::{BaseSpec, RobotSection, RoutineFile};
use std::io::IsTerminal;
use std::path::PathBuf;
use tokio_util::sync::CancellationToken;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Progress bar and questions on the terminal (stderr), answers from stdin. The bar counts
/// robot time (tenths of a second of motion at the speed limits), so its ETA is the robot's.
struct TerminalUi {
    bar: Option<ProgressBar>,
    /// Robot time counted and planned, and what to show of each event.
    clock: RobotClock,
    /// Where a run that stopped left the robot and its parameters.
    ending: Option<odocal::routine::Ending>,
    quiet: bool,
    assume_yes: bool,
}

impl TerminalUi {
    /// `err` with, when the run stopped after it started, the two lines that say where the
    /// robot and its parameters are: the last lines the user reads.
    fn ended(&mut self, err: impl std::error::Error + 'static) -> Box<dyn std::error::Error> {
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
        match self.ending.take() {
            Some(ending) => format!("{err}\n{ending}").into(),
            None => err.into(),
        }
    }
}

/// Ticks of the progress bar per second of robot time.
const TICKS_PER_S: f64 = 10.0;

impl TerminalUi {
    fn new(quiet: bool, assume_yes: bool) -> Self {
        TerminalUi {
            bar: None,
            clock: RobotClock::default(),
            ending: None,
            quiet,
            assume_yes,
        }
    }

    fn say(&self, line: &str) {
        if self.quiet {
            return;
        }
        match &self.bar {
            Some(b) => b.println(line),
            None => eprintln!("{line}"),
        }
    }
}

impl RoutineUi for TerminalUi {
    fn confirm(&mut self, question: &str) -> bool {
        if self.assume_yes {
            self.say(&format!("{question} yes (--yes)"));
            return true;
        }
        let ask = || crate::prompt::yes(question);
        match &self.bar {
            Some(b) => b.suspend(|| tokio::task::block_in_place(ask)),
            None => tokio::task::block_in_place(ask),
        }
    }

    fn event(&mut self, event: &RoutineEvent) {
        let ticks = |s: f64| (s * TICKS_PER_S).round() as u64;
        match self.clock.update(event) {
            Shown::Line(line) => self.say(&line),
            Shown::Step(line) if self.bar.is_none() => self.say(&line),
            Shown::Step(_) | Shown::Nothing => {}
            Shown::Phase(robot_time_s) => {
                if let Some(b) = self.bar.take() {
                    b.finish_and_clear();
                }
                if !self.quiet && std::io::stderr().is_terminal() {
                    let bar = ProgressBar::new(ticks(robot_time_s));
                    bar.set_style(
                        ProgressStyle::with_template(
                            "{bar:30} {msg} · robot time {prefix} · ETA {eta}",
                        )
                        .unwrap_or_else(|_| ProgressStyle::default_bar()),
                    );
                    self.bar = Some(bar);
                }
            }
            Shown::Extend(robot_time_s) => {
                if let Some(b) = &self.bar {
                    b.inc_length(ticks(robot_time_s));
                }
            }
            Shown::Motion {
                message,
                prefix,
                position_s,
            } => {
                if let Some(b) = &self.bar {
                    b.set_message(message);
                    b.set_prefix(prefix);
                    b.set_position(ticks(position_s));
                }
            }
        }
        if let RoutineEvent::Ended(ending) = event {
            self.ending = Some(ending.clone());
        }
    }
}

impl Drop for TerminalUi {
    fn drop(&mut self) {
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
    }
}

/// A token cancelled by Ctrl-C.
fn print_outcome(report: &Report, json_out: bool, files: &[PathBuf]) -> CliResult {
    if json_out {
        return print_json(&odocal::report::text::outcome_json(report, files)?);
    }
    print!("{}", odocal::report::text::outcome(report, files));
    Ok(())
}

fn finish(report: &Report, report_dir: Option<&PathBuf>, json_out: bool) -> CliResult {
    // The directory the run claimed before it moved (its backup is there), else the one asked.
    let files = match report.report_dir.as_ref().or(report_dir) {
        Some(d) => odocal::report::write_dir(report, d)?,
        None => Vec::new(),
    };
    print_outcome(report, json_out, &files)
}

/// Arguments of `odocal demo`.
#[cfg(all(feature = "mock", feature = "odocal-protocol"))]
#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    #[command(flatten)]
    demo: odocal::demo::DemoSettings,
    /// Print the whole report as one JSON object.
    #[arg(long)]
    json: bool,
}

/// Runs `odocal demo`.
#[cfg(all(feature = "mock", feature = "odocal-protocol"))]
pub async fn demo(args: DemoArgs) -> CliResult {
    let opts = args.demo.options()?;
    if !args.json {
        eprintln!(
            "odocal demo: a simulated robot (E_b {}, E_d {}, D {} m, b {} m, compass σ {}°) on a \
             pseudo-terminal; full recalibration in virtual time",
            opts.true_e_b,
            opts.true_e_d,
            opts.nominal.left_wheel_diameter_m,
            opts.nominal.wheelbase_m,
            opts.compass_sigma_deg
        );
    }
    let go = async |ui: &mut TerminalUi, token: &CancellationToken| {
        run_demo(&opts, ui, token)
            .await
            .map(|(report, _device)| report)
    };
    reported((args.json, true), Some(&args.demo.report_dir), go).await
}

/// Routine settings that can be given as flags (they override a routine file).
#[derive(Debug, Clone, clap::Args)]
pub struct RoutineFlags {
    #[command(flatten)]
    set: Overrides,
    /// Print the whole report as one JSON object.
    #[arg(long)]
    json: bool,
}

impl RoutineFlags {
    /// Applies the flags, asking for LARGE first when --allow-large-change comes without --yes.
    fn apply(&self, cfg: &mut RoutineConfig) -> CliResult {
        self.set.apply(cfg)?;
        if let Some(question) = self.set.needs_large_confirmation(cfg) {
            if crate::prompt::answer(&question)? != "LARGE" {
                return Err("large changes not confirmed (type LARGE, or give --yes)".into());
            }
        }
        Ok(())
    }
}

/// Arguments of `odocal calibrate`.
#[derive(Debug, clap::Args)]
pub struct CalibrateArgs {
    #[command(flatten)]
    robot: RobotFlags,
    /// A routine file to start from (flags override it).
    #[arg(long)]
    config: Option<PathBuf>,
    #[command(flatten)]
    flags: RoutineFlags,
}

/// Runs the routine `go` with a terminal UI, then writes the report into its directory and
/// prints the outcome; a run that stopped ends with where the robot and its parameters are.
async fn reported<E: std::error::Error + 'static>(
    (json, yes): (bool, bool),
    report_dir: Option<&PathBuf>,
    go: impl AsyncFnOnce(&mut TerminalUi, &CancellationToken) -> Result<Report, E>,
) -> CliResult {
    let mut ui = TerminalUi::new(json, yes);
    let token =
        crate::prompt::ctrl_c_token(Some("stopping the robot and restoring the parameters…"));
    let report = match go(&mut ui, &token).await {
        Ok(report) => report,
        Err(e) => return Err(ui.ended(e)),
    };
    drop(ui);
    finish(&report, report_dir, json)
}

/// **Moves the robot**: the routine on the robot `spec` names.
async fn run_on(mut cfg: RoutineConfig, spec: BaseSpec, flags: &RoutineFlags) -> CliResult {
    // A real calibration always leaves its evidence behind.
    if cfg.report_dir.is_none() {
        cfg.report_dir = Some(PathBuf::from("odocal-report"));
    }
    // Connected first (nothing moves yet): a wrong port is named before anything says that
    // the robot will move.
    let base = spec.open().await?;
    if !flags.json {
        eprintln!("{}", cfg.motion_notice(&spec.place()));
        eprintln!("connected: {}", base.info());
    }
    let drive = base.drive.clone();
    crate::prompt::stop_on_forced_exit(move || drive.emergency_stop());
    let go = async |ui: &mut TerminalUi, token: &CancellationToken| {
        run(&base, &cfg, None, ui, token).await
    };
    reported((flags.json, flags.set.yes), cfg.report_dir.as_ref(), go).await
}

/// The built-in simulated robot with these settings (it moves nobody's hardware: no need to
/// ask before it drives).
#[cfg(all(feature = "mock", feature = "odocal-protocol"))]
async fn run_simulated(mut cfg: RoutineConfig, flags: &RoutineFlags) -> CliResult {
    cfg.confirm_motion = false;
    let opts = DemoOptions {
        routine: cfg.clone(),
        ..DemoOptions::default()
    };
    let go = async |ui: &mut TerminalUi, token: &CancellationToken| {
        run_demo(&opts, ui, token)
            .await
            .map(|(report, _device)| report)
    };
    reported((flags.json, flags.set.yes), cfg.report_dir.as_ref(), go).await
}

/// The routine on whatever the spec names.
async fn run_spec(cfg: RoutineConfig, spec: BaseSpec, flags: &RoutineFlags) -> CliResult {
    #[cfg(all(feature = "mock", feature = "odocal-protocol"))]
    if spec.drive.is(&odocal::spec::registry::SIMULATED) {
        return run_simulated(cfg, flags).await;
    }
    run_on(cfg, spec, flags).await
}

/// Runs `odocal calibrate`.
pub async fn calibrate(args: CalibrateArgs) -> CliResult {
    let (robot, mut cfg) = match &args.config {
        Some(p) => {
            let f = RoutineFile::load(p)?;
            (f.robot, f.routine)
        }
        None => (RobotSection::default(), RoutineConfig::default()),
    };
    args.flags.apply(&mut cfg)?;
    let spec = args.robot.spec(robot)?;
    run_spec(cfg, spec, &args.flags).await
}

/// Arguments of `odocal run`.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// The routine file (TOML; see examples/*.toml). `drive = "mock"` in its [robot] table
    /// uses the simulated robot.
    routine: PathBuf,
    #[command(flatten)]
    flags: RoutineFlags,
}

/// Runs `odocal run`.
pub async fn run_file(args: RunArgs) -> CliResult {
    let RoutineFile { robot, routine } = RoutineFile::load(&args.routine)?;
    let mut cfg = routine;
    args.flags.apply(&mut cfg)?;
    let spec = robot
        .spec()
        .map_err(|e| format!("{}: {e}", args.routine.display()))?;
    run_spec(cfg, spec, &args.flags).await
}
