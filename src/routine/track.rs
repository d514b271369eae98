//! Live tracking on any base: the online filter fed from the seam's travel and heading streams
//! while the robot drives — by whatever else drives it, or along a path this session drives
//! itself ([`DrivePath`]). Every sample goes to a sink in the order it arrived (a log of it
//! replays through [`Tracker::feed_recording`] to the same numbers: the filter sees the merged
//! time order, which depends only on the stamps).
//!
//! Safety: a path is driven only when asked for, within the routine's hard speed limits, one
//! guarded motion at a time ([`MotionGuard`]): an error, a cancellation or the end of the
//! session stops the base.

use super::config::{ConfigError, HARD_RATE_LIMIT_RAD_S, HARD_SPEED_LIMIT_M_S};
use super::RoutineError;
use crate::base::write::{
    write_once, Bounds, Commit, Question, WriteError, WritePolicy, WriteRequest, WriteUi,
};
use crate::base::{
    Base, Clocks, HeadingSample, MotionGuard, PoseSource, ReferencePose, SampleStream, TravelSample,
};
use crate::calibration::online::OnlineEstimate;
use crate::calibration::recording::{Event, Recording};
use crate::calibration::tracker::Tracker;
use crate::kinematics::WheelParams;
use crate::offline::log::{LogError, LogHeader, LogWriter};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{FRAC_PI_2, PI};
use std::path::Path;
use std::path::PathBuf;
use std::str::FromStr;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

/// A path the session drives while it tracks. Both excite both parameters: straight stretches
/// observe `E_d`, turns both ways observe `E_b`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DrivePath {
    /// Squares of this side (m), alternately clockwise and counter-clockwise.
    Squares {
        /// Side (m).
        side_m: f64,
    },
    /// Random straight stretches and turns (30–180° either way) that keep the robot inside a
    /// square of this side (m) centred on where it started.
    Wander {
        /// Side of the square the robot stays in (m).
        area_m: f64,
    },
}

impl std::fmt::Display for DrivePath {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DrivePath::Squares { side_m } => write!(
                f,
                "squares of {side_m} m side (alternately clockwise and counter-clockwise)"
            ),
            DrivePath::Wander { area_m } => write!(
                f,
                "straight stretches and turns inside a square of {area_m} m side"
            ),
        }
    }
}

impl FromStr for DrivePath {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let (kind, size) = s
            .split_once(':')
            .ok_or_else(|| format!("{s:?}: expected squares:SIDE_M or wander:AREA_M"))?;
        let size: f64 = size
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite() && (0.5..=50.0).contains(v))
            .ok_or_else(|| format!("{s:?}: the size must be in [0.5, 50] m"))?;
        match kind {
            "squares" => Ok(DrivePath::Squares { side_m: size }),
            "wander" => Ok(DrivePath::Wander { area_m: size }),
            other => Err(format!("{s:?}: {other} is not a path (squares, wander)")),
        }
    }
}

/// One motion of a path.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Step {
    Straight(f64),
    Turn(f64),
}

/// The motions of a path, as many as asked for.
fn steps(path: DrivePath, motions: usize, seed: u64) -> Vec<Step> {
    let mut out = Vec::with_capacity(motions);
    match path {
        DrivePath::Squares { side_m } => {
            let mut sign = -1.0;
            while out.len() < motions {
                for _ in 0..4 {
                    out.push(Step::Straight(side_m));
                    out.push(Step::Turn(sign * FRAC_PI_2));
                }
                sign = -sign;
            }
        }
        DrivePath::Wander { area_m } => {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let half = 0.5 * area_m;
            let (mut x, mut y, mut th) = (0.0f64, 0.0f64, 0.0f64);
            while out.len() < motions {
                let turn =
                    rng.random_range(PI / 6.0..=PI) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                th += turn;
                out.push(Step::Turn(turn));
                // As far as the box allows along the new heading (the commanded pose).
                let (c, s) = (th.cos(), th.sin());
                let room = |p: f64, d: f64| {
                    if d > 1e-9 {
                        (half - p) / d
                    } else if d < -1e-9 {
                        (-half - p) / d
                    } else {
                        f64::INFINITY
                    }
                };
                let reach = room(x, c).min(room(y, s)).max(0.0);
                let want = rng.random_range(0.3 * area_m..=area_m);
                let length = want.min(reach);
                if length >= 0.1 * area_m {
                    out.push(Step::Straight(length));
                    x += length * c;
                    y += length * s;
                }
            }
        }
    }
    out.truncate(motions);
    out
}

/// How a live session runs.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackOptions {
    /// Requested period of both streams.
    pub period: Duration,
    /// Stop after this long (wall clock); `None`: until the path is driven, or cancelled.
    pub duration: Option<Duration>,
    /// **Moves the robot**: a path to drive while tracking; `None` tracks whatever drives it.
    pub path: Option<DrivePath>,
    /// Motions of the path.
    pub motions: usize,
    /// Straight-leg speed limit (m/s).
    pub max_speed_m_s: f64,
    /// Turn-rate limit (rad/s).
    pub max_rate_rad_s: f64,
    /// Seed of a wandering path.
    pub seed: u64,
}

impl Default for TrackOptions {
    fn default() -> Self {
        TrackOptions {
            period: Duration::from_millis(20),
            duration: None,
            path: None,
            motions: 40,
            max_speed_m_s: 0.2,
            max_rate_rad_s: 0.5,
            seed: 1,
        }
    }
}

/// A path to drive while tracking (with the `cli` feature, `odocal track`'s and `record`'s
/// flags, their doc comments the help).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct PathOptions {
    /// MOVES THE ROBOT: drive this path while tracking: squares:SIDE_M (alternating
    /// clockwise and counter-clockwise) or wander:AREA_M (random stretches and turns both
    /// ways inside a square of that side). Asks first unless --yes.
    #[cfg_attr(feature = "cli", arg(long))]
    pub drive: Option<DrivePath>,
    /// Motions of the path.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 40))]
    pub motions: usize,
    /// Straight speed limit of the path (m/s, at most 1.0).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.2))]
    pub max_speed_m_s: f64,
    /// Turn-rate limit of the path (rad/s, at most 3.0).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.5))]
    pub max_rate_rad_s: f64,
    /// Seed of a wandering path.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1))]
    pub seed: u64,
}

/// Where `odocal track` gets its samples — a log, a data set, a wheels and poses pair, or
/// the live robot (against a pose topic if given) — and what it does with a live estimate
/// (with the `cli` feature, `odocal track`'s flags).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct TrackSettings {
    /// A log written by `odocal record` or `track --record`.
    #[cfg_attr(feature = "cli", arg(long))]
    pub log: Option<PathBuf>,
    /// A recorded OptiOdom set (ground-truth heading plays the compass).
    #[cfg_attr(feature = "cli", arg(long))]
    pub dataset: Option<PathBuf>,
    /// Live on a ROS robot (--base rosbridge://…): calibrate against this pose topic
    /// (PoseStamped, PoseWithCovarianceStamped such as /amcl_pose, or Odometry) instead of
    /// the heading: both diameters and the wheelbase in metres, and where the reference frame
    /// sits on the robot.
    #[cfg_attr(feature = "cli", arg(long, conflicts_with_all = ["log", "dataset", "poses"]))]
    pub reference: Option<String>,
    /// A pose reference from a file (t_s,x_m,y_m,yaw_rad; `odocal fit`'s format), with
    /// --wheels, replayed through the online filter.
    #[cfg_attr(feature = "cli", arg(long, requires = "wheels"))]
    pub poses: Option<PathBuf>,
    /// The wheels of --poses (t_s,left_rad,right_rad).
    #[cfg_attr(feature = "cli", arg(long, requires = "poses"))]
    pub wheels: Option<PathBuf>,
    /// With --poses: the configured wheel diameter (m).
    #[cfg_attr(feature = "cli", arg(long, requires = "poses"))]
    pub wheel_diameter_m: Option<f64>,
    /// With --poses: the configured wheelbase (m).
    #[cfg_attr(feature = "cli", arg(long, requires = "poses"))]
    pub wheelbase_m: Option<f64>,
    /// Live: also write every sample to this log (it replays to the same numbers).
    #[cfg_attr(feature = "cli", arg(long))]
    pub record: Option<PathBuf>,
    /// Live: requested sample period (ms).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 20))]
    pub period_ms: u64,
    /// Live: stop after this long [default: until Ctrl-C, or the end of the --drive path].
    #[cfg_attr(feature = "cli", arg(long))]
    pub duration_s: Option<f64>,
    /// Live: write the estimate back when both standard deviations are below --max-std.
    #[cfg_attr(feature = "cli", arg(long))]
    pub write_back: bool,
    /// Largest standard deviation of E_b and E_d that justifies a write-back.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.002))]
    pub max_std: f64,
    /// Where the parameter backup goes before a write-back.
    #[cfg_attr(feature = "cli", arg(long, default_value = "."))]
    pub backup_dir: PathBuf,
}

impl TrackSettings {
    /// A pose reference is the session's reference (a topic, or a poses file).
    pub fn with_poses(&self) -> bool {
        self.reference.is_some() || self.poses.is_some()
    }

    /// Refuses a write-back from a recording: it writes to a live robot only.
    pub fn check(&self) -> Result<(), ConfigError> {
        let replay = self.log.is_some() || self.dataset.is_some() || self.poses.is_some();
        if self.write_back && replay {
            let why = "--write-back writes to a live robot: give --port or --base";
            return Err(ConfigError::new(why));
        }
        Ok(())
    }
}

impl TrackOptions {
    /// A session sampled every `period_ms` (at least 1), for `duration_s` if given (a
    /// negative one ends it at once), driving `path` if it names one.
    pub fn new(period_ms: u64, duration_s: Option<f64>, path: &PathOptions) -> Self {
        TrackOptions {
            period: Duration::from_millis(period_ms.max(1)),
            duration: duration_s.map(|s| Duration::from_secs_f64(s.max(0.0))),
            path: path.drive,
            motions: path.motions,
            max_speed_m_s: path.max_speed_m_s,
            max_rate_rad_s: path.max_rate_rad_s,
            seed: path.seed,
        }
    }

    /// The question to ask before the path is driven, when there is one.
    pub fn question(&self) -> Option<String> {
        self.path.map(|p| {
            format!(
                "The robot will drive {} motions of {p} at up to {} m/s and {} rad/s. Is the \
                 area clear and may it move?",
                self.motions, self.max_speed_m_s, self.max_rate_rad_s
            )
        })
    }
}

/// Samples of each stream a session keeps for the clock-offset check at its end (an hour at
/// 50 Hz); beyond it the oldest go, so a session of any length holds bounded memory.
pub const LIVE_SAMPLES_KEPT: usize = 180_000;

/// Drops the oldest samples beyond [`LIVE_SAMPLES_KEPT`] (in batches, so it costs nothing per
/// sample).
fn bound<T>(v: &mut Vec<T>) {
    if v.len() >= 2 * LIVE_SAMPLES_KEPT {
        v.drain(..v.len() - LIVE_SAMPLES_KEPT);
    }
}

/// What a session saw.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TrackOutcome {
    /// The samples, as they arrived (the newest [`LIVE_SAMPLES_KEPT`] to
    /// 2·[`LIVE_SAMPLES_KEPT`] of each stream; the sink had them all).
    pub recording: Recording,
    /// Motions of the path driven.
    pub motions_driven: usize,
    /// Whether `cancel` ended it (Ctrl-C: the usual way to end tracking without a path or a
    /// duration); what arrived until then is kept.
    pub cancelled: bool,
}

/// Why a logged session ([`track_logged`]) failed.
#[derive(Debug, thiserror::Error)]
pub enum LoggedError {
    /// The session failed.
    #[error(transparent)]
    Routine(#[from] RoutineError),
    /// Writing the log failed (what was written until then is kept).
    #[error(transparent)]
    Log(#[from] LogError),
}

/// The header of a log of a live session on `base`, whose travel is converted with `params`.
pub fn log_header(base: &Base, params: WheelParams, period_ms: u64) -> LogHeader {
    LogHeader {
        odocal_version: env!("CARGO_PKG_VERSION").into(),
        device: None,
        params,
        period_ms,
        base: Some(base.info()),
        clocks: base.clocks(),
    }
}

/// [`track_live`] with every sample written to `log` when given, in the order it arrived (the
/// log replays to the same numbers). A write that fails ends the logging; the session runs
/// on, and the failure is returned once it ends (the log is not flushed here).
pub async fn track_logged(
    (base, poses): (&Base, Option<&dyn PoseSource>),
    tracker: &mut Tracker,
    opts: &TrackOptions,
    mut log: Option<&mut LogWriter>,
    on_checkpoint: &mut dyn FnMut(&OnlineEstimate),
    cancel: &CancellationToken,
) -> Result<TrackOutcome, LoggedError> {
    let mut error = None;
    let mut sink = |e: &Event| {
        if let (Some(w), None) = (log.as_deref_mut(), &error) {
            if let Err(e) = w.event(e) {
                error = Some(e);
            }
        }
    };
    let outcome = track_live(base, poses, tracker, opts, &mut sink, on_checkpoint, cancel).await;
    if let Some(e) = error {
        return Err(e.into());
    }
    Ok(outcome?)
}

impl TrackOutcome {
    /// Refuses a recording that holds no wheel travel, saying why that happens (what was
    /// written to `out` was its header only); `duration_s` is the session's limit, if any.
    pub fn check_recorded(&self, duration_s: Option<f64>, out: &Path) -> Result<(), String> {
        if !self.recording.travel.is_empty() {
            return Ok(());
        }
        Err(format!(
            "no telemetry arrived {} ({} written with its header only). The robot answers but \
             sends no wheel travel: a controller may stream only while the robot moves (drive \
             it while recording, or give --drive), and `odocal mock-device` in virtual time \
             (the default) never advances while idle: start it with --time-scale 1 to record \
             from it",
            match (self.cancelled, duration_s) {
                (false, Some(s)) => format!("in {s:.1} s"),
                _ => "before it was stopped".to_string(),
            },
            out.display()
        ))
    }
}

/// **Moves the robot when `opts.path` is given**: tracks `base` live with `tracker` (the poses of
/// `poses` as the reference in place of the heading source, when given) until the
/// path is driven, `opts.duration` passes or `cancel` fires (not an error: the outcome says
/// [`TrackOutcome::cancelled`]; a base driving a path is stopped either way); hands every sample to `sink` and
/// every checkpoint to `on_checkpoint`. At the end the streams' clock offset is checked (and
/// reported in the tracker, not corrected: live samples cannot be re-read).
pub async fn track_live(
    base: &Base,
    poses: Option<&dyn PoseSource>,
    tracker: &mut Tracker,
    opts: &TrackOptions,
    sink: &mut dyn FnMut(&Event),
    on_checkpoint: &mut dyn FnMut(&OnlineEstimate),
    cancel: &CancellationToken,
) -> Result<TrackOutcome, RoutineError> {
    check_path_limits(opts)?;
    let (mut travel, mut headings, mut pose_stream, clocks) =
        open_streams(base, poses, opts).await?;
    for e in tracker.start_stream(clocks) {
        on_checkpoint(&e);
    }
    let mut outcome = TrackOutcome {
        recording: Recording {
            clocks,
            ..Recording::default()
        },
        motions_driven: 0,
        cancelled: false,
    };
    let plan = opts
        .path
        .map(|p| steps(p, opts.motions, opts.seed))
        .unwrap_or_default();
    let driving = drive_plan(base, &plan, opts);
    tokio::pin!(driving);
    let deadline = sleep_for(opts.duration);
    tokio::pin!(deadline);
    let passive = opts.path.is_none();
    let mut take = |e: Event, outcome: &mut TrackOutcome, tracker: &mut Tracker| {
        take_sample(e, outcome, tracker, sink, on_checkpoint);
    };
    let (mut travel_open, mut headings_open) = (true, poses.is_none());
    let mut poses_open = poses.is_some();
    let result = loop {
        if !(travel_open || headings_open || poses_open) {
            break Err(RoutineError::Preflight(
                "both streams ended: the drive and the reference went away".into(),
            ));
        }
        tokio::select! {
            t = travel.recv(), if travel_open => match t {
                Some(t) => take(Event::Travel(t), &mut outcome, tracker),
                None => travel_open = false,
            },
            h = headings.recv(), if headings_open => match h {
                Some(h) => take(Event::Heading(h), &mut outcome, tracker),
                None => headings_open = false,
            },
            p = pose_stream.recv(), if poses_open => match p {
                Some(p) => take(Event::Pose(p), &mut outcome, tracker),
                None => poses_open = false,
            },
            r = &mut driving, if !passive => {
                match r {
                    Ok(n) => {
                        outcome.motions_driven = n;
                        break Ok(());
                    }
                    Err(e) => break Err(e),
                }
            }
            () = &mut deadline => break Ok(()),
            () = cancel.cancelled() => {
                outcome.cancelled = true;
                break Ok(());
            }
        }
    };
    if opts.path.is_some() {
        // However it ended, the base stops (a motion cut short has its guard's stop already).
        let _ = tokio::time::timeout(Duration::from_secs(2), base.drive.stop()).await;
    }
    result?;
    let rest = |e: Event| take(e, &mut outcome, tracker);
    take_remaining(&mut travel, &mut headings, &mut pose_stream, rest).await;
    for e in tracker.finish_stream() {
        on_checkpoint(&e);
    }
    tracker.check_time_offset("live", &outcome.recording);
    Ok(outcome)
}

/// Refuses a path to drive whose speed or turn-rate limit is beyond the hard limits.
fn check_path_limits(opts: &TrackOptions) -> Result<(), RoutineError> {
    if opts.path.is_some()
        && !(opts.max_speed_m_s > 0.0
            && opts.max_speed_m_s <= HARD_SPEED_LIMIT_M_S
            && opts.max_rate_rad_s > 0.0
            && opts.max_rate_rad_s <= HARD_RATE_LIMIT_RAD_S)
    {
        return Err(RoutineError::Config(super::config::ConfigError::new(
            format!(
                "speed limits must be in (0, {HARD_SPEED_LIMIT_M_S}] m/s and (0, \
             {HARD_RATE_LIMIT_RAD_S}] rad/s"
            ),
        )));
    }
    Ok(())
}

/// Opens the travel stream and the reference (headings or poses), with the session's clocks.
async fn open_streams(
    base: &Base,
    poses: Option<&dyn PoseSource>,
    opts: &TrackOptions,
) -> Result<
    (
        SampleStream<TravelSample>,
        SampleStream<HeadingSample>,
        SampleStream<ReferencePose>,
        Clocks,
    ),
    RoutineError,
> {
    let travel = base.drive.travel(opts.period).await?.ok_or_else(|| {
        RoutineError::Preflight("the drive cannot stream its wheel travel".into())
    })?;
    // One reference stream: the pose source's when there is one, else the heading source's
    // (a channel that never yields stands in for the one not read).
    let (headings, pose_stream, clocks) = match poses {
        Some(source) => (
            tokio::sync::mpsc::channel(1).1,
            source.stream().await?,
            base.clocks_with(source),
        ),
        None => (
            base.heading.stream(opts.period).await?.ok_or_else(|| {
                RoutineError::Preflight("the heading source cannot stream its readings".into())
            })?,
            tokio::sync::mpsc::channel(1).1,
            base.clocks(),
        ),
    };
    Ok((travel, headings, pose_stream, clocks))
}

/// Drives the path's motions, one guarded motion at a time; returns how many were driven.
async fn drive_plan(
    base: &Base,
    plan: &[Step],
    opts: &TrackOptions,
) -> Result<usize, RoutineError> {
    for step in plan {
        let guard = MotionGuard::new(&base.drive);
        match *step {
            Step::Straight(d) => base.drive.move_straight(d, opts.max_speed_m_s).await?,
            Step::Turn(a) => base.drive.turn_in_place(a, opts.max_rate_rad_s).await?,
        };
        guard.disarm();
    }
    Ok(plan.len())
}

/// Waits out the session's duration; without one, never ends (until the path or a cancel).
async fn sleep_for(duration: Option<Duration>) {
    match duration {
        Some(d) => tokio::time::sleep(d).await,
        // Until the path is driven, or cancelled.
        None => std::future::pending::<()>().await,
    }
}

/// Hands a sample to the sink, keeps it in the (bounded) recording and feeds the tracker.
fn take_sample(
    e: Event,
    outcome: &mut TrackOutcome,
    tracker: &mut Tracker,
    sink: &mut dyn FnMut(&Event),
    on_checkpoint: &mut dyn FnMut(&OnlineEstimate),
) {
    sink(&e);
    let passed = match &e {
        Event::Travel(t) => {
            bound(&mut outcome.recording.travel);
            outcome.recording.travel.push(*t);
            tracker.push_travel(*t)
        }
        Event::Heading(h) => {
            bound(&mut outcome.recording.headings);
            outcome.recording.headings.push(h.clone());
            tracker.push_heading(h.clone())
        }
        Event::Pose(p) => {
            bound(&mut outcome.recording.poses);
            outcome.recording.poses.push(*p);
            tracker.push_pose(*p)
        }
    };
    for c in passed {
        on_checkpoint(&c);
    }
}

/// Takes what the streams still hold once the session ended, travel first.
async fn take_remaining(
    travel: &mut SampleStream<TravelSample>,
    headings: &mut SampleStream<HeadingSample>,
    pose_stream: &mut SampleStream<ReferencePose>,
    mut take: impl FnMut(Event),
) {
    // Streams are forwarded by tasks of their own: what they hold still counts.
    for _ in 0..8 {
        tokio::task::yield_now().await;
    }
    while let Ok(t) = travel.try_recv() {
        take(Event::Travel(t));
    }
    while let Ok(h) = headings.try_recv() {
        take(Event::Heading(h));
    }
    while let Ok(p) = pose_stream.try_recv() {
        take(Event::Pose(p));
    }
}

/// What `track --write-back` did with the session's last estimate.
#[derive(Debug, Clone, PartialEq)]
pub enum WriteBack {
    /// Written and committed: the parameters as the store holds them.
    Written(crate::kinematics::WheelParams),
    /// Not written: the estimate is not yet precise enough (why, and what to do).
    TooUncertain(String),
}

/// Writes the parameters `last` says the robot has (its correction applied to `configured`,
/// the parameters in use) through the write service, when both of E_b's and E_d's standard
/// deviations are below `max_std`: within ±10 % of what the store holds, asked under
/// `policy`, backed up into `backup_dir` first.
pub async fn write_back(
    base: &Base,
    last: &OnlineEstimate,
    configured: &crate::kinematics::WheelParams,
    max_std: f64,
    policy: WritePolicy,
    backup_dir: &std::path::Path,
    ui: &mut dyn WriteUi,
) -> Result<WriteBack, WriteError> {
    if !(last.e_b_std < max_std && last.e_d_std < max_std) {
        return Ok(WriteBack::TooUncertain(format!(
            "uncertainty (E_b ± {:.5}, E_d ± {:.5}) above --max-std {max_std}; drive more",
            last.e_b_std, last.e_d_std
        )));
    }
    let request = WriteRequest {
        new: last.correction.apply(configured)?,
        bounds: Bounds::MaxChange {
            fraction: 0.1,
            wider: None,
        },
        policy,
        commit: Commit::Both,
        backup_dir,
        question: Question::OldToNew("Write these parameters and commit them?".into()),
    };
    let done = write_once(base.store.clone(), base.reconnect.clone(), request, ui).await?;
    Ok(WriteBack::Written(done.applied))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_turn_both_ways_and_wandering_stays_in_its_box() {
        let s = steps(DrivePath::Squares { side_m: 1.0 }, 16, 1);
        let turns: Vec<f64> = s
            .iter()
            .filter_map(|s| match s {
                Step::Turn(a) => Some(*a),
                Step::Straight(_) => None,
            })
            .collect();
        assert_eq!(turns.iter().sum::<f64>(), 0.0);
        let w = steps(DrivePath::Wander { area_m: 2.0 }, 200, 7);
        assert_eq!(w.len(), 200);
        let (mut x, mut y, mut th): (f64, f64, f64) = (0.0, 0.0, 0.0);
        let (mut left, mut right) = (0, 0);
        for s in w {
            match s {
                Step::Turn(a) => {
                    th += a;
                    if a > 0.0 {
                        left += 1
                    } else {
                        right += 1
                    }
                }
                Step::Straight(d) => {
                    x += d * th.cos();
                    y += d * th.sin();
                    assert!(x.abs() <= 1.0 + 1e-9 && y.abs() <= 1.0 + 1e-9, "{x}, {y}");
                }
            }
        }
        assert!(left > 20 && right > 20, "{left} left, {right} right");
        assert!("wander:0.1".parse::<DrivePath>().is_err());
        assert_eq!(
            "squares:2".parse::<DrivePath>(),
            Ok(DrivePath::Squares { side_m: 2.0 })
        );
    }
}

#[cfg(test)]
mod outcome_tests {
    use super::*;

    #[test]
    fn a_recording_without_travel_is_refused_saying_why() {
        let mut outcome = TrackOutcome {
            recording: Recording::default(),
            motions_driven: 0,
            cancelled: false,
        };
        let out = Path::new("session.jsonl");
        let e = outcome.check_recorded(Some(2.0), out).unwrap_err();
        assert!(
            e.starts_with("no telemetry arrived in 2.0 s (session.jsonl written"),
            "{e}"
        );
        assert!(e.contains("--time-scale 1"), "{e}");
        outcome.cancelled = true;
        let e = outcome.check_recorded(Some(2.0), out).unwrap_err();
        assert!(e.contains("before it was stopped"), "{e}");
    }
}

#[cfg(test)]
mod settings_tests {
    use super::*;

    fn live() -> TrackSettings {
        TrackSettings {
            log: None,
            dataset: None,
            reference: None,
            poses: None,
            wheels: None,
            wheel_diameter_m: None,
            wheelbase_m: None,
            record: None,
            period_ms: 20,
            duration_s: None,
            write_back: true,
            max_std: 0.002,
            backup_dir: PathBuf::from("."),
        }
    }

    #[test]
    fn a_path_is_asked_about_and_a_session_without_one_is_not() {
        let path = PathOptions {
            drive: Some("squares:2".parse().unwrap()),
            motions: 8,
            max_speed_m_s: 0.2,
            max_rate_rad_s: 0.5,
            seed: 1,
        };
        let opts = TrackOptions::new(0, Some(-1.0), &path);
        assert_eq!(opts.period, Duration::from_millis(1));
        assert_eq!(opts.duration, Some(Duration::ZERO));
        let q = opts.question().unwrap();
        assert!(
            q.starts_with("The robot will drive 8 motions of squares"),
            "{q}"
        );
        let still = PathOptions {
            drive: None,
            ..path
        };
        assert_eq!(TrackOptions::new(20, None, &still).question(), None);
    }

    #[test]
    fn a_write_back_goes_to_a_live_robot_only() {
        live().check().unwrap();
        assert!(!live().with_poses());
        let replay = TrackSettings {
            log: Some(PathBuf::from("session.jsonl")),
            ..live()
        };
        let e = replay.check().unwrap_err();
        assert!(
            e.to_string()
                .contains("--write-back writes to a live robot"),
            "{e}"
        );
        let against_poses = TrackSettings {
            reference: Some("/amcl_pose".into()),
            ..live()
        };
        assert!(against_poses.with_poses());
        against_poses.check().unwrap();
    }
}
