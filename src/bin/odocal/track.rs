//! `odocal record` and `odocal track`: logs of a live session and the online estimator, on any
//! base (a controller of our protocol, a ROS robot, a RoboClaw with a compass).

use crate::out::print_json;
use crate::prompt::TerminalWriteUi;
use clap::ArgGroup;
use odocal::base::{Base, PoseSource};
use odocal::calibration::online::{OnlineConfig, OnlineEstimate, ScaleSource};
use odocal::calibration::tracker::{Tracker, TrackerSettings};
use odocal::kinematics::WheelParams;
use odocal::offline::log::LogWriter;
use odocal::offline::track_replay::{replay_dataset, replay_files, replay_log};
use odocal::report::track::{pose_session, TrackSummary};
use odocal::routine::config::WritePolicy;
use odocal::routine::track::{
    log_header, track_logged, write_back, PathOptions, TrackOptions, TrackOutcome, TrackSettings,
    WriteBack,
};
use odocal::spec::flags::RobotFlags;
use odocal::spec::RobotSection;
use std::path::PathBuf;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// How a live session drives, if it does.
#[derive(Debug, Clone, clap::Args)]
pub struct DriveArgs {
    #[command(flatten)]
    path: PathOptions,
    /// Answer yes: drive without asking (`track --write-back`: also write without asking).
    #[arg(long)]
    yes: bool,
}

/// Opens the robot and reads the parameters its travel is converted with.
async fn open(robot: &RobotFlags) -> Result<(Base, WheelParams), Box<dyn std::error::Error>> {
    let base = robot.spec(RobotSection::default())?.open().await?;
    let params = base.store.read().await?;
    Ok((base, params))
}

/// A live session (against the pose reference given beside the base, else its heading): asks
/// before a path is driven, writes every sample to `log` if given.
async fn live(
    (base, poses): (&Base, Option<&dyn PoseSource>),
    tracker: &mut Tracker,
    (period_ms, duration_s): (u64, Option<f64>),
    drive: &DriveArgs,
    log: Option<&mut LogWriter>,
    mut on_checkpoint: impl FnMut(&OnlineEstimate),
) -> Result<TrackOutcome, Box<dyn std::error::Error>> {
    let opts = TrackOptions::new(period_ms, duration_s, &drive.path);
    if let Some(question) = opts.question().filter(|_| !drive.yes) {
        if !tokio::task::block_in_place(|| crate::prompt::yes(&question)) {
            return Err("the robot may not move (not driven)".into());
        }
    }
    if opts.path.is_some() {
        let drive = base.drive.clone();
        crate::prompt::stop_on_forced_exit(move || drive.emergency_stop());
    }
    let token = crate::prompt::ctrl_c_token(None);
    let on = &mut on_checkpoint;
    Ok(track_logged((base, poses), tracker, &opts, log, on, &token).await?)
}

/// Arguments of `odocal record`.
#[derive(Debug, clap::Args)]
pub struct RecordArgs {
    #[command(flatten)]
    robot: RobotFlags,
    /// The log to write (JSON lines).
    #[arg(long)]
    out: PathBuf,
    /// Requested sample period (ms).
    #[arg(long, default_value_t = 20)]
    period_ms: u64,
    /// Stop after this long [default: until Ctrl-C, or the end of the --drive path].
    #[arg(long)]
    duration_s: Option<f64>,
    #[command(flatten)]
    drive: DriveArgs,
}

/// Runs `odocal record`.
pub async fn record(args: RecordArgs) -> CliResult {
    let (base, params) = open(&args.robot).await?;
    let mut log = LogWriter::create(&args.out, log_header(&base, params, args.period_ms))?;
    eprintln!(
        "recording wheel travel and headings to {} ({})",
        args.out.display(),
        match (args.drive.path.drive, args.duration_s) {
            (Some(_), _) => "while driving the path".to_string(),
            (None, Some(s)) => format!("for {s} s"),
            (None, None) => "Ctrl-C to stop".to_string(),
        }
    );
    let mut tracker = Tracker::new(
        OnlineConfig::new(params),
        ScaleSource::Filter,
        f64::INFINITY,
    )?;
    let outcome = live(
        (&base, None),
        &mut tracker,
        (args.period_ms, args.duration_s),
        &args.drive,
        Some(&mut log),
        |_| {},
    )
    .await?;
    log.flush()?;
    if outcome.cancelled {
        eprintln!("stopped by Ctrl-C (or SIGTERM, SIGHUP)");
    }
    outcome.check_recorded(args.duration_s, &args.out)?;
    let rec = &outcome.recording;
    println!(
        "recorded {} travel samples and {} headings to {}",
        rec.travel.len(),
        rec.headings.len(),
        args.out.display()
    );
    Ok(())
}

/// Arguments of `odocal track`.
#[derive(Debug, clap::Args)]
#[command(group(ArgGroup::new("source").required(true).args(["port", "base", "log", "dataset", "poses"])))]
pub struct TrackArgs {
    #[command(flatten)]
    robot: RobotFlags,
    #[command(flatten)]
    session: TrackSettings,
    #[command(flatten)]
    filter: TrackerSettings,
    #[command(flatten)]
    drive: DriveArgs,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

fn show(e: &OnlineEstimate, json_out: bool, label: &str) {
    if !json_out {
        println!(
            "{label:>9} {:>8.2} m   E_b {:.5} ± {:.5}   E_d {:.6} ± {:.6}",
            e.distance_m, e.e_b, e.e_b_std, e.e_d, e.e_d_std
        );
    }
}

/// A tracker fed, the parameters in use, and the live base when there was one.
type Session = (Tracker, WheelParams, Option<Base>);

/// Runs `odocal track`.
pub async fn track(args: TrackArgs) -> CliResult {
    let with_poses = args.session.with_poses();
    // A pose reference observes the absolute scale: the filter's own, not a convention's.
    let scale = args.filter.scale(with_poses);
    if !args.json {
        println!(
            "method online (the default with no squares to drive: an extended Kalman filter over \
             every wheel sample and heading reading or pose fix); ± is 1σ of the filter's \
             covariance"
        );
        println!("{:>9} {:>10}   estimate", "", "driven");
    }
    args.session.check()?;
    let shown = |e: &OnlineEstimate| show(e, args.json, "");
    let f = &args.filter;
    let replayed = match (
        &args.session.poses,
        &args.session.wheels,
        &args.session.dataset,
        &args.session.log,
    ) {
        (Some(p), Some(w), _, _) => {
            let geometry = (args.session.wheel_diameter_m, args.session.wheelbase_m);
            replay_files(f, (p, w), geometry, scale, shown)?
        }
        (_, _, Some(dir), _) => replay_dataset(f, dir, scale, shown)?,
        (_, _, None, Some(path)) => replay_log(f, path, scale, shown)?,
        _ => return finish(&args, live_session(&args, scale).await?, with_poses).await,
    };
    let session = (replayed.tracker, replayed.configured, None);
    finish(&args, session, with_poses).await
}

/// A live robot (`--port`, `--base`), perhaps driven, perhaps against a pose topic, perhaps
/// recorded.
async fn live_session(
    args: &TrackArgs,
    scale: ScaleSource,
) -> Result<Session, Box<dyn std::error::Error>> {
    let poses = match &args.session.reference {
        Some(topic) => Some(args.robot.pose_source(topic).await?),
        None => None,
    };
    let (b, configured) = open(&args.robot).await?;
    let mut t = args.filter.tracker(configured, scale)?;
    let mut log = match &args.session.record {
        Some(p) => Some(LogWriter::create(
            p,
            log_header(&b, configured, args.session.period_ms),
        )?),
        None => None,
    };
    let outcome = live(
        (&b, poses.as_deref()),
        &mut t,
        (args.session.period_ms, args.session.duration_s),
        &args.drive,
        log.as_mut(),
        |e| show(e, args.json, ""),
    )
    .await;
    // Flushed whatever happened: what was recorded until then is kept.
    let flushed = log.as_mut().map_or(Ok(()), |l| l.flush());
    let outcome = outcome.inspect_err(|_| {
        // An error: what was estimated until then is still worth seeing.
        if let (Ok(last), false) = (t.estimate(), args.json) {
            show(&last, false, "last");
            println!(
                "(the estimate when tracking stopped, ± 1σ of the online filter; nothing written)"
            );
        }
    })?;
    if outcome.cancelled && !args.json {
        println!(
            "stopped by Ctrl-C (or SIGTERM, SIGHUP){}",
            if args.drive.path.drive.is_some() {
                "; the robot is stopped"
            } else {
                ""
            }
        );
    }
    flushed?;
    Ok((t, configured, Some(b)))
}

/// The last estimate, the pose session's findings, the write-back, and the summary.
async fn finish(
    args: &TrackArgs,
    (tracker, configured, base): Session,
    with_poses: bool,
) -> CliResult {
    let last = tracker.estimate()?;
    show(&last, args.json, "final");
    let with_poses = with_poses || tracker.started_from.is_some();
    if with_poses && !args.json {
        print!("{}", pose_session(&tracker, &last, &configured));
    }
    // The scale the session was tracked on (a log of a pose session replays as one).
    let excitation = tracker.filter().excitation(tracker.scale_source())?;
    let mut written = None;
    if let (true, Some(base)) = (args.session.write_back, &base) {
        let (policy, mut ui) = (
            WritePolicy::of_flags(false, args.drive.yes),
            TerminalWriteUi,
        );
        let (dir, max_std) = (&args.session.backup_dir, args.session.max_std);
        match write_back(base, &last, &configured, max_std, policy, dir, &mut ui).await? {
            WriteBack::Written(p) => {
                eprintln!("written and committed");
                written = Some(p);
            }
            WriteBack::TooUncertain(why) => eprintln!("not written: {why}"),
        }
    }
    let summary = TrackSummary {
        tracker: &tracker,
        last: &last,
        configured: &configured,
        with_poses,
        excitation: &excitation,
        written,
    };
    if args.json {
        return print_json(&summary.json());
    }
    print!("{}", summary.text());
    Ok(())
}
