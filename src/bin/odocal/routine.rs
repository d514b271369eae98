//! `odocal demo`, `calibrate`, `run` and `export`: the recalibration routine's commands.

use crate::print_json;
use indicatif::{ProgressBar, ProgressStyle};
use odocal::base::Base;
use odocal::calibration::Method;
use odocal::demo::{run_demo, DemoOptions};
use odocal::hal::open_port;
use odocal::kinematics::SplitConvention;
use odocal::routine::config::{RoutineConfig, WritePolicy};
use odocal::routine::report::Report;
use odocal::routine::{run, RoutineEvent, RoutineUi};
use serde_json::json;
use std::io::{BufRead, IsTerminal, Write};
use std::path::PathBuf;
use tokio_util::sync::CancellationToken;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Progress bar and questions on the terminal (stderr), answers from stdin.
struct TerminalUi {
    bar: Option<ProgressBar>,
    quiet: bool,
    assume_yes: bool,
}

impl TerminalUi {
    fn new(quiet: bool, assume_yes: bool) -> Self {
        TerminalUi {
            bar: None,
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
        let ask = || {
            eprint!("{question} [y/N] ");
            let _ = std::io::stderr().flush();
            let mut line = String::new();
            let ok = std::io::stdin().lock().read_line(&mut line).is_ok();
            ok && matches!(line.trim(), "y" | "Y" | "yes" | "YES")
        };
        match &self.bar {
            Some(b) => b.suspend(|| tokio::task::block_in_place(ask)),
            None => tokio::task::block_in_place(ask),
        }
    }

    fn event(&mut self, event: &RoutineEvent) {
        match event {
            RoutineEvent::Stage(s) => self.say(&format!("· {s}")),
            RoutineEvent::Warning(w) => self.say(&format!("warning: {w}")),
            RoutineEvent::Plan { motions } => {
                if let Some(b) = self.bar.take() {
                    b.finish_and_clear();
                }
                if !self.quiet && std::io::stderr().is_terminal() {
                    let bar = ProgressBar::new(*motions);
                    bar.set_style(
                        ProgressStyle::with_template(
                            "{bar:30} {pos}/{len} motions · {msg} · ETA {eta}",
                        )
                        .unwrap_or_else(|_| ProgressStyle::default_bar()),
                    );
                    self.bar = Some(bar);
                }
            }
            RoutineEvent::Motion {
                phase,
                run,
                of,
                direction,
                motion,
            } => {
                if let Some(b) = &self.bar {
                    let what = if motion % 2 == 1 { "leg" } else { "turn" };
                    b.set_message(format!(
                        "{phase}: run {run}/{of} {direction}, {what} {}/4",
                        motion.div_ceil(2)
                    ));
                    b.inc(1);
                }
            }
            RoutineEvent::RunDone { heading_error_deg } => {
                if self.bar.is_none() {
                    self.say(&format!(
                        "  run done: heading error {heading_error_deg:+.3}°"
                    ));
                }
            }
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
fn ctrl_c_token() -> CancellationToken {
    let token = CancellationToken::new();
    let t = token.clone();
    tokio::spawn(async move {
        if tokio::signal::ctrl_c().await.is_ok() {
            eprintln!("\nCtrl-C: stopping the robot and restoring the parameters…");
            t.cancel();
        }
    });
    token
}

fn print_outcome(report: &Report, json_out: bool, files: &[PathBuf]) -> CliResult {
    if json_out {
        let mut v = serde_json::to_value(report)?;
        // The paths (hundreds of points per run, most of the report's size) stay in the report
        // directory's report.json; stdout gets everything else.
        let strip = |runs: Option<&mut serde_json::Value>| {
            for run in runs.and_then(|r| r.as_array_mut()).into_iter().flatten() {
                if let Some(obj) = run.as_object_mut() {
                    obj.remove("odometry_path");
                    obj.remove("true_path");
                }
            }
        };
        if let Some(rounds) = v.get_mut("rounds").and_then(|r| r.as_array_mut()) {
            for round in rounds {
                strip(round.get_mut("runs"));
            }
        }
        strip(v.get_mut("verification"));
        if let Some(obj) = v.as_object_mut() {
            obj.insert("report_files".into(), json!(files));
            obj.insert(
                "paths".into(),
                json!("odometry_path and true_path of each run are in report.json"),
            );
        }
        return print_json(&v);
    }
    if let Some(r) = report.rounds.last() {
        println!("estimates (round {}):", r.round);
        println!(
            "{:<13} {:>9} {:>9} {:>9} {:>9}",
            "method", "E_b", "±", "E_d", "±"
        );
        for e in &r.estimates {
            let f = |v: Option<f64>| v.map_or("–".into(), |v| format!("{v:.5}"));
            println!(
                "{:<13} {:>9.6} {:>9} {:>9.6} {:>9}{}",
                e.method.name(),
                e.e_b,
                f(e.e_b_std_err),
                e.e_d,
                f(e.e_d_std_err),
                if e.method == r.chosen.method {
                    "  ← chosen"
                } else {
                    ""
                }
            );
        }
        println!();
    }
    println!(
        "{} round(s), {}, {}",
        report.rounds.len(),
        if report.converged {
            "converged"
        } else {
            "not converged"
        },
        if report.written {
            "parameters written and committed"
        } else {
            "nothing written"
        }
    );
    print!("{}", odocal::report::summary_table(report));
    println!(
        "backup of the original parameters: {}",
        report.backup_path.display()
    );
    for f in files {
        println!("wrote {}", f.display());
    }
    for w in &report.warnings {
        println!("warning: {w}");
    }
    Ok(())
}

fn finish(report: &Report, report_dir: Option<&PathBuf>, json_out: bool) -> CliResult {
    let files = match report_dir {
        Some(d) => odocal::report::write_dir(report, d)?,
        None => Vec::new(),
    };
    print_outcome(report, json_out, &files)
}

/// Arguments of `odocal demo`.
#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// True E_b of the simulated robot.
    #[arg(long, default_value_t = 0.976)]
    true_eb: f64,
    /// True E_d of the simulated robot.
    #[arg(long, default_value_t = 0.992)]
    true_ed: f64,
    /// Compass noise per reading (deg).
    #[arg(long, default_value_t = 0.37)]
    compass_sigma_deg: f64,
    /// Seed of the simulated robot.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Link faults, as for `mock-device` (e.g. "corrupt=0.01,drop=0.05").
    #[arg(long)]
    faults: Option<String>,
    /// Where to write report.json, report.md and the plots.
    #[arg(long, default_value = "odocal-demo-report")]
    report_dir: PathBuf,
    /// Print the whole report as one JSON object.
    #[arg(long)]
    json: bool,
    /// Allow parameter changes of up to 100 % (a simulated skid-steer robot, --true-eb 1.5).
    #[arg(long)]
    allow_large_change: bool,
}

/// Runs `odocal demo`.
pub async fn demo(args: DemoArgs) -> CliResult {
    let mut opts = DemoOptions {
        true_e_b: args.true_eb,
        true_e_d: args.true_ed,
        compass_sigma_deg: args.compass_sigma_deg,
        seed: args.seed,
        ..DemoOptions::default()
    };
    if let Some(f) = &args.faults {
        opts.faults = f.parse::<odocal::mock::FaultConfig>()?;
    }
    opts.faults.seed = args.seed;
    opts.routine.backup_dir = args.report_dir.clone();
    opts.routine.report_dir = Some(args.report_dir.clone());
    if args.allow_large_change {
        opts.routine.allow_large_change = true;
        opts.routine.max_change = 1.0;
    }
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
    let mut ui = TerminalUi::new(args.json, true);
    let token = ctrl_c_token();
    let (report, _device) = run_demo(&opts, &mut ui, &token).await?;
    drop(ui);
    finish(&report, Some(&args.report_dir), args.json)
}

/// Routine settings that can be given as flags (they override a routine file).
#[derive(Debug, Clone, clap::Args)]
pub struct RoutineFlags {
    /// Square side (m).
    #[arg(long)]
    side_m: Option<f64>,
    /// Squares per direction per round.
    #[arg(long)]
    runs: Option<usize>,
    /// Straight-leg speed limit (m/s, at most 1.0).
    #[arg(long)]
    max_speed_m_s: Option<f64>,
    /// Turn-rate limit (rad/s, at most 3.0).
    #[arg(long)]
    max_rate_rad_s: Option<f64>,
    /// Pause before each heading reading for the base to settle (s).
    #[arg(long)]
    settle_s: Option<f64>,
    /// Heading readings averaged at rest before and after each square.
    #[arg(long)]
    heading_samples: Option<usize>,
    /// Estimator to write: umbmark, lee, heading-only, jung-chung, exact or legs. Default:
    /// legs when the heading along the legs was streamed in every run, else exact.
    #[arg(long)]
    method: Option<String>,
    /// Diameter split for estimation and write-back: left-nominal, mean-preserving or
    /// measured-scale:COMMANDED_M,MEASURED_M.
    #[arg(long)]
    convention: Option<SplitConvention>,
    /// Straight-line check: commanded distance (m); with --straight-measured-m.
    #[arg(long, requires = "straight_measured_m")]
    straight_commanded_m: Option<f64>,
    /// Straight-line check: measured distance (m).
    #[arg(long, requires = "straight_commanded_m")]
    straight_measured_m: Option<f64>,
    /// Verification squares per direction.
    #[arg(long)]
    verification_runs: Option<usize>,
    /// Convergence tolerance on |E_b − 1| and |E_d − 1|.
    #[arg(long)]
    tolerance: Option<f64>,
    /// Most calibration rounds.
    #[arg(long)]
    max_rounds: Option<usize>,
    /// Estimate and report only; write nothing (with --yes: move without asking, still write
    /// nothing).
    #[arg(long)]
    dry_run: bool,
    /// Answer yes to every question: move, and write unless --dry-run.
    #[arg(long)]
    yes: bool,
    /// Refuse to write any parameter changed by more than this fraction (default 0.1; at most
    /// 0.25 unless --allow-large-change).
    #[arg(long)]
    max_change: Option<f64>,
    /// Keep the written parameters even when verification does not show them clearly better
    /// (by default they are restored and odocal exits non-zero).
    #[arg(long)]
    keep_worse: bool,
    /// Allow changes of up to 100 % (skid-steer robots need wheelbase multipliers of 1.5–1.9);
    /// asks you to type LARGE unless --yes. Default --max-change then 1.0.
    #[arg(long)]
    allow_large_change: bool,
    /// Where to write the backup (default: the report directory, or here).
    #[arg(long)]
    backup_dir: Option<PathBuf>,
    /// Where to write report.json, report.md and the plots.
    #[arg(long)]
    report_dir: Option<PathBuf>,
    /// Print the whole report as one JSON object.
    #[arg(long)]
    json: bool,
}

impl RoutineFlags {
    fn apply(&self, cfg: &mut RoutineConfig) -> Result<(), Box<dyn std::error::Error>> {
        macro_rules! set {
            ($($f:ident => $t:ident),*) => { $(if let Some(v) = self.$f.clone() { cfg.$t = v; })* };
        }
        set!(side_m => side_m, runs => runs_per_direction, max_speed_m_s => max_speed_m_s,
             max_rate_rad_s => max_rate_rad_s, verification_runs => verification_runs,
             tolerance => tolerance, max_rounds => max_rounds, settle_s => settle_s,
             heading_samples => heading_samples);
        if let Some(m) = &self.method {
            cfg.method = Some(m.parse::<Method>()?);
        }
        cfg.keep_worse |= self.keep_worse;
        if self.allow_large_change {
            cfg.allow_large_change = true;
            cfg.max_change = self.max_change.unwrap_or(1.0);
            if !self.yes {
                eprint!(
                    "--allow-large-change lets odocal write parameters up to {:.0} % away from \
                     what the robot holds now. Type LARGE to allow it: ",
                    100.0 * cfg.max_change
                );
                let mut line = String::new();
                std::io::stdin().read_line(&mut line)?;
                if line.trim() != "LARGE" {
                    return Err("large changes not confirmed (type LARGE, or give --yes)".into());
                }
            }
        } else if let Some(m) = self.max_change {
            cfg.max_change = m;
        }
        if let Some(c) = self.convention {
            cfg.convention = c;
        }
        if let (Some(commanded_m), Some(measured_m)) =
            (self.straight_commanded_m, self.straight_measured_m)
        {
            cfg.convention = SplitConvention::MeasuredScale {
                commanded_m,
                measured_m,
            };
        }
        if self.dry_run {
            cfg.write_back = WritePolicy::DryRun;
        } else if self.yes {
            cfg.write_back = WritePolicy::Yes;
        }
        if let Some(d) = &self.report_dir {
            cfg.report_dir = Some(d.clone());
            cfg.backup_dir = d.clone();
        }
        if let Some(d) = &self.backup_dir {
            cfg.backup_dir = d.clone();
        }
        cfg.validate()?;
        Ok(())
    }
}

/// Arguments of `odocal calibrate`.
#[derive(Debug, clap::Args)]
pub struct CalibrateArgs {
    /// Serial port of a motor controller that speaks odocal's protocol.
    #[arg(long, conflicts_with = "base")]
    port: Option<String>,
    /// A ROS robot: rosbridge://HOST:PORT (needs --ros-yaml); or a RoboClaw:
    /// roboclaw:PORT[?address=128&baud=38400] (needs --heading and --profile).
    #[arg(long)]
    base: Option<String>,
    /// The heading source of a RoboClaw base: nmea:PORT[?baud=4800].
    #[arg(long)]
    heading: Option<String>,
    /// The robot profile of a RoboClaw base (geometry, wiring, limits; written back).
    #[arg(long)]
    profile: Option<PathBuf>,
    #[command(flatten)]
    ros: RosLiveArgs,
    /// Baud rate.
    #[arg(long, default_value_t = 115_200)]
    baud: u32,
    /// A routine file to start from (flags override it).
    #[arg(long)]
    config: Option<PathBuf>,
    #[command(flatten)]
    flags: RoutineFlags,
}

fn read_config(path: &std::path::Path) -> Result<RoutineConfig, Box<dyn std::error::Error>> {
    let text = odocal::base::files::read_bounded(path, odocal::base::files::MAX_TEXT_FILE)
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    RoutineConfig::from_toml(&text).map_err(|e| format!("{}: {e}", path.display()).into())
}

/// ROS settings of `calibrate --base rosbridge://…` (a routine file's `[ros]` table holds the
/// same keys).
#[derive(Debug, Clone, clap::Args)]
pub struct RosLiveArgs {
    /// The controller's ros2_control YAML: the geometry is read from it and the calibrated
    /// multipliers are written into it (backed up beside it first).
    #[arg(long)]
    ros_yaml: Option<PathBuf>,
    /// The diff_drive_controller's name.
    #[arg(long)]
    controller: Option<String>,
    /// Velocity topic (default /cmd_vel; newer setups use /diff_drive_controller/cmd_vel).
    #[arg(long)]
    cmd_vel: Option<String>,
    /// Publish geometry_msgs/TwistStamped instead of Twist.
    #[arg(long)]
    twist_stamped: bool,
    /// Where the drive's odometry comes from: joint-states (default) or odom.
    #[arg(long)]
    wheel_source: Option<String>,
    /// Joint states topic.
    #[arg(long)]
    joint_states_topic: Option<String>,
    /// IMU topic.
    #[arg(long)]
    imu_topic: Option<String>,
    /// Odometry topic.
    #[arg(long)]
    odom_topic: Option<String>,
    /// Also set the written multipliers on the running controller (set_parameters).
    #[arg(long)]
    ros_set_live: bool,
}

impl RosLiveArgs {
    /// The base settings: the routine file's `[ros]` table, then these flags.
    fn config(
        &self,
        url: &str,
        file: Option<&toml::Table>,
    ) -> Result<odocal::ros::base::RosBaseConfig, Box<dyn std::error::Error>> {
        let mut c: odocal::ros::base::RosBaseConfig = match file {
            Some(t) => t
                .clone()
                .try_into()
                .map_err(|e| format!("[ros] table: {e}"))?,
            None => Default::default(),
        };
        c.url = url.to_string();
        if let Some(y) = &self.ros_yaml {
            c.yaml = y.clone();
        } else if file.is_none_or(|t| !t.contains_key("yaml")) {
            return Err("a ROS robot needs --ros-yaml (the controller's ros2_control YAML)".into());
        }
        if let Some(v) = &self.controller {
            c.controller = v.clone();
        }
        if let Some(v) = &self.cmd_vel {
            c.cmd_vel = v.clone();
        }
        c.twist_stamped |= self.twist_stamped;
        c.set_live |= self.ros_set_live;
        if let Some(v) = &self.wheel_source {
            c.wheel_source = match v.as_str() {
                "joint-states" => odocal::ros::base::WheelSource::JointStates,
                "odom" => odocal::ros::base::WheelSource::Odom,
                other => {
                    return Err(format!("--wheel-source {other}: use joint-states or odom").into())
                }
            };
        }
        if let Some(v) = &self.joint_states_topic {
            c.topics.joint_states = v.clone();
        }
        if let Some(v) = &self.imu_topic {
            c.topics.imu = v.clone();
        }
        if let Some(v) = &self.odom_topic {
            c.topics.odom = v.clone();
        }
        Ok(c)
    }
}

/// Where the routine runs: a serial port, a ROS robot, or a RoboClaw with a compass.
enum Target<'a> {
    Port {
        path: &'a str,
        baud: u32,
    },
    Ros(Box<odocal::ros::base::RosBaseConfig>),
    RoboClaw {
        drive: String,
        heading: Option<String>,
        profile: Option<PathBuf>,
    },
}

async fn run_on(mut cfg: RoutineConfig, target: Target<'_>, flags: &RoutineFlags) -> CliResult {
    // A real calibration always leaves its evidence behind.
    if cfg.report_dir.is_none() {
        cfg.report_dir = Some(PathBuf::from("odocal-report"));
    }
    let place = match &target {
        Target::Port { path, .. } => path.to_string(),
        Target::Ros(r) => r.url.clone(),
        Target::RoboClaw { drive, .. } => drive.clone(),
    };
    if !flags.json {
        eprintln!(
            "odocal calibrate: this MOVES THE ROBOT on {place}: {} squares of {} m per direction \
             per round at up to {} m/s. Ctrl-C stops it at any time.",
            cfg.runs_per_direction, cfg.side_m, cfg.max_speed_m_s
        );
    }
    let base = match target {
        Target::Port { path, baud } => {
            let (client, info) = open_port(path, baud).await?;
            if !flags.json {
                eprintln!(
                    "connected: {} (protocol {}.{}, serial {:#x})",
                    info.firmware_id, info.major, info.minor, info.serial_number
                );
            }
            // A device that resets or is re-plugged mid-run is reopened to restore the backup.
            let reconnect =
                odocal::hal::base::reconnect_port(client.clone(), path.to_string(), baud);
            Base::single(client).with_reconnect(reconnect)
        }
        Target::RoboClaw {
            drive,
            heading,
            profile,
        } => {
            let base =
                crate::serial_bases::roboclaw_base(&drive, heading.as_deref(), profile.as_deref())
                    .await?;
            if !flags.json {
                let info = base.info();
                eprintln!(
                    "connected: {} ({}), heading {}, profile {}",
                    info.drive.id, info.drive.details["firmware"], info.heading.id, info.store.id
                );
            }
            base
        }
        Target::Ros(r) => {
            let base = odocal::ros::base::connect(&r).await?;
            if !flags.json {
                eprintln!(
                    "connected: rosbridge at {}, geometry and write-back in {} ({})",
                    r.url,
                    r.yaml.display(),
                    r.controller
                );
            }
            base
        }
    };
    let mut ui = TerminalUi::new(flags.json, flags.yes);
    let token = ctrl_c_token();
    let report = run(&base, &cfg, None, &mut ui, &token).await?;
    drop(ui);
    finish(&report, cfg.report_dir.as_ref(), flags.json)
}

/// Runs `odocal calibrate`.
pub async fn calibrate(args: CalibrateArgs) -> CliResult {
    let mut cfg = match &args.config {
        Some(p) => read_config(p)?,
        None => RoutineConfig::default(),
    };
    args.flags.apply(&mut cfg)?;
    let target = match (&args.port, &args.base) {
        (Some(p), None) => Target::Port {
            path: p,
            baud: args.baud,
        },
        (None, Some(url)) if url.starts_with("rosbridge://") || url.starts_with("ws://") => {
            Target::Ros(Box::new(args.ros.config(url, cfg.ros.as_ref())?))
        }
        (None, Some(spec)) if spec.starts_with("roboclaw:") => Target::RoboClaw {
            drive: spec.clone(),
            heading: args.heading.clone().or_else(|| cfg.heading.clone()),
            profile: args.profile.clone().or_else(|| cfg.profile.clone()),
        },
        (None, Some(other)) => {
            return Err(format!(
                "--base {other}: use rosbridge://HOST:PORT or roboclaw:PORT (or --port for a \
                 controller that speaks odocal's protocol)"
            )
            .into())
        }
        _ => {
            return Err(
                "give --port PATH (odocal protocol), --base rosbridge://HOST:PORT or --base \
                 roboclaw:PORT"
                    .into(),
            )
        }
    };
    run_on(cfg, target, &args.flags).await
}

/// Arguments of `odocal run`.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// The routine file (TOML; see examples/*.toml). `port = "mock"` uses the simulated robot.
    routine: PathBuf,
    #[command(flatten)]
    flags: RoutineFlags,
}

/// Runs `odocal run`.
pub async fn run_file(args: RunArgs) -> CliResult {
    let mut cfg = read_config(&args.routine)?;
    args.flags.apply(&mut cfg)?;
    match cfg.port.clone().as_deref() {
        Some("mock") => {
            // The simulated robot moves nobody's hardware: no need to ask before it drives.
            cfg.confirm_motion = false;
            let opts = DemoOptions {
                routine: cfg.clone(),
                ..DemoOptions::default()
            };
            let mut ui = TerminalUi::new(args.flags.json, args.flags.yes);
            let token = ctrl_c_token();
            let (report, _) = run_demo(&opts, &mut ui, &token).await?;
            drop(ui);
            finish(&report, cfg.report_dir.as_ref(), args.flags.json)
        }
        Some(url) if url.starts_with("rosbridge://") || url.starts_with("ws://") => {
            let ros = RosLiveArgs {
                ros_yaml: None,
                controller: None,
                cmd_vel: None,
                twist_stamped: false,
                wheel_source: None,
                joint_states_topic: None,
                imu_topic: None,
                odom_topic: None,
                ros_set_live: false,
            }
            .config(url, cfg.ros.as_ref())?;
            run_on(cfg.clone(), Target::Ros(Box::new(ros)), &args.flags).await
        }
        Some(spec) if spec.starts_with("roboclaw:") => {
            let target = Target::RoboClaw {
                drive: spec.to_string(),
                heading: cfg.heading.clone(),
                profile: cfg.profile.clone(),
            };
            run_on(cfg.clone(), target, &args.flags).await
        }
        Some(port) => {
            let target = Target::Port {
                path: port,
                baud: cfg.baud,
            };
            run_on(cfg.clone(), target, &args.flags).await
        }
        None => Err(format!(
            "{}: no `port` (a serial port path, or \"mock\" for the simulated robot)",
            args.routine.display()
        )
        .into()),
    }
}

/// Arguments of `odocal export`.
#[derive(Debug, clap::Args)]
pub struct ExportArgs {
    /// Any odocal result as JSON: a report.json (demo, calibrate, run), or the --json output of
    /// estimate, track or bag.
    #[arg(long, alias = "report")]
    from: PathBuf,
    /// The ros2_control YAML: merged into if it exists (multipliers only, backup beside),
    /// created otherwise.
    #[arg(long)]
    ros2: PathBuf,
    /// The controller's name in the YAML.
    #[arg(
        long,
        alias = "controller-name",
        default_value = "diff_drive_controller"
    )]
    controller: String,
    /// Which estimate to export (default: the result's default method, else exact).
    #[arg(long)]
    method: Option<String>,
    /// Merge into an existing --ros2 file (its multipliers change; the original is kept beside
    /// it as a backup). Without it an existing file is left alone.
    #[arg(long)]
    force: bool,
}

/// Runs `odocal export`.
pub fn export(args: ExportArgs) -> CliResult {
    use odocal::report::ros2::{calibration_of, export, Exported};
    let len = std::fs::metadata(&args.from)
        .map_err(|e| format!("cannot read {}: {e}", args.from.display()))?
        .len();
    if len > 64 << 20 {
        return Err(format!(
            "{}: {len} bytes is not an odocal result",
            args.from.display()
        )
        .into());
    }
    let text = odocal::base::files::read_bounded(&args.from, odocal::base::files::MAX_TEXT_FILE)
        .map_err(|e| format!("cannot read {}: {e}", args.from.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| format!("{}: not JSON ({e})", args.from.display()))?;
    let cal = calibration_of(&v, args.method.as_deref())
        .map_err(|e| format!("{}: {e}", args.from.display()))?;
    if args.ros2.exists() && !args.force {
        return Err(format!(
            "{} exists: not changed. --force merges the {} calibration's multipliers into it \
             (everything else stays, the original is kept beside it as a backup)",
            args.ros2.display(),
            cal.method
        )
        .into());
    }
    match export(&args.ros2, &args.controller, &cal)? {
        Exported::Created => println!("wrote {} ({} calibration)", args.ros2.display(), cal.method),
        Exported::Merged { backup } => println!(
            "merged the {} calibration's multipliers into {} (the original is {})",
            cal.method,
            args.ros2.display(),
            backup.display()
        ),
    }
    Ok(())
}
