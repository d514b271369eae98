//! A tracking session of the online filter ([`super::online`]): samples in, estimates out at
//! checkpoints every so many metres, from live streams or from recordings.
//!
//! Live samples arrive as two streams ([`Tracker::push_travel`], [`Tracker::push_heading`]) and
//! are merged into time order ([`super::recording::Merger`]); a recording is fed the same way
//! after its clocks are aligned ([`Tracker::feed_recording`]), a significant clock offset
//! removed first and noted in [`Tracker::time_offsets`]. Live streams cannot be re-read: a live
//! session checks its samples for an offset at the end and only reports it
//! ([`Tracker::check_time_offset`]). Because the merged order depends only on the stamps, the
//! replay of a live session's samples gives the same numbers as the session did (unless the
//! replay removes an offset the live session could only report).

use super::independence::{compare, Independence, ReferenceSource};
use super::observability::{judge, survey, DriveSurvey};
use super::online::{OnlineConfig, OnlineEstimate, OnlineEstimator, ScaleSource};
use super::plausibility::{check_units_and_signs, check_wheel_jumps, survey_scale};
use super::pose_fit::{fit_poses, FitConfig, Param, PoseFit};
use super::pose_reference::{Geometry, Pose2, PoseRecording, ReferenceKind, ReferencePose};
use super::recording::{
    wheel_angles, Clocks, Event, Feeder, HeadingSample, Merger, Recording, TravelSample,
};
use super::time_offset::TimeOffset;
use super::CalibrationError;
use crate::kinematics::{SplitConvention, WheelParams};
use serde::Serialize;

/// Least driving (m) before the online filter reports an estimate.
pub const MIN_DISTANCE_M: f64 = 0.5;

/// Where a session with a pose reference stands before its filter starts.
#[derive(Debug, Clone)]
enum PoseStart {
    /// Keeping the drive (wheel angles under the configured diameters, the poses) until it
    /// observes enough for a batch fit, tried again once this many poses are kept.
    Waiting(PoseRecording, usize),
    /// Started (or a heading session).
    Started,
    /// The reference is not one the filter can take, and why.
    Refused(String),
}

/// Wheel samples the start of a pose session keeps at most (an hour at 50 Hz; the oldest half
/// goes beyond it).
const START_SAMPLES_KEPT: usize = 180_000;
/// Poses before the first attempt to start; after an attempt that fails, the next waits for
/// half as many poses again as were kept (at least [`START_EVERY_POSES`] more), so that the
/// batch fits, which run on the live loop, cost a bounded multiple of the last.
const START_MIN_POSES: usize = 100;
const START_EVERY_POSES: usize = 50;

/// What `odocal fit` refuses by name before its fit, the filter must not take either: units and
/// signs, conventions, a reference made from the wheels.
fn start_refusal(
    drive: &PoseRecording,
    nominal: Geometry,
    drive_survey: &DriveSurvey,
) -> Option<CalibrationError> {
    check_wheel_jumps(drive)
        .and_then(|()| check_units_and_signs(&survey_scale(drive, nominal), drive_survey))
        .and_then(|()| drive_survey.diagnose())
        .err()
        .or_else(|| wheel_made(compare(drive, nominal, Pose2::default(), 0.0)))
}

/// Why a reference made from the wheels cannot start the filter, or `None` when it measures
/// the robot by itself (a heading of its own beside the wheels' positions included: the filter
/// would take its positions).
fn wheel_made(independence: Independence) -> Option<CalibrationError> {
    (independence.source != ReferenceSource::Independent).then(|| {
        CalibrationError::ReferenceFromWheels(format!(
            "{}; the online filter takes only a reference independent of the wheels",
            independence.explanation()
        ))
    })
}

/// A time offset found in one run of input.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunTimeOffset {
    /// The run (file name, "log", "live").
    pub run: String,
    /// What was found.
    pub offset: TimeOffset,
    /// Whether the heading was re-read at the shifted time before it was fed.
    pub corrected: bool,
}

/// The online filter's settings a session chooses (with the `cli` feature, `odocal track`'s
/// flags, their doc comments the help).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct TrackerSettings {
    /// Diameter split for E_b.
    #[cfg_attr(feature = "cli", arg(long, default_value = "left-nominal"))]
    pub convention: SplitConvention,
    /// Relative wheel slip per step assumed by the filter.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.01))]
    pub slip_fraction: f64,
    /// Heading noise per reading assumed by the filter (deg).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.37))]
    pub heading_sigma_deg: f64,
    /// Print an estimate every this many metres driven.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1.0))]
    pub every_m: f64,
    /// How late the reference's stamps are (s): the pose stamped t is the robot's at t − this
    /// (`odocal fit` measures it).
    #[cfg_attr(
        feature = "cli",
        arg(long, default_value_t = 0.0, allow_hyphen_values = true)
    )]
    pub reference_delay_s: f64,
}

impl Default for TrackerSettings {
    fn default() -> Self {
        TrackerSettings {
            convention: SplitConvention::LeftNominal,
            slip_fraction: 0.01,
            heading_sigma_deg: 0.37,
            every_m: 1.0,
            reference_delay_s: 0.0,
        }
    }
}

impl TrackerSettings {
    /// Where the wheels' absolute scale comes from: a pose reference observes it (the
    /// filter's own), headings alone do not (the convention's).
    pub fn scale(&self, with_poses: bool) -> ScaleSource {
        if with_poses {
            ScaleSource::Filter
        } else {
            ScaleSource::Convention(self.convention)
        }
    }

    /// A tracker for a session whose parameters in use are `configured`, its pose delay set.
    pub fn tracker(
        &self,
        configured: WheelParams,
        scale: ScaleSource,
    ) -> Result<Tracker, CalibrationError> {
        let mut c = OnlineConfig::new(configured);
        c.slip_fraction = self.slip_fraction;
        c.heading_sigma_rad = self.heading_sigma_deg.to_radians();
        let mut t = Tracker::new(c, scale, self.every_m)?;
        t.set_pose_delay(self.reference_delay_s);
        Ok(t)
    }
}

/// The online estimator with checkpoints every `every_m` metres driven.
pub struct Tracker {
    filter: OnlineEstimator,
    scale: ScaleSource,
    merger: Merger,
    feeder: Feeder,
    every_m: f64,
    next_m: f64,
    pose_delay_s: f64,
    pose_start: PoseStart,
    /// The batch fit the filter's parameters and mounting started from, in a session with a
    /// pose reference ([`OnlineEstimator::start_from_fit`]).
    pub started_from: Option<PoseFit>,
    /// Estimates taken at each checkpoint.
    pub checkpoints: Vec<OnlineEstimate>,
    /// Clock offsets found between the travel and heading streams, per run checked.
    pub time_offsets: Vec<RunTimeOffset>,
}

impl Tracker {
    /// A tracker over a fresh filter; live samples are taken to share one clock until
    /// [`Tracker::start_stream`] says otherwise.
    pub fn new(
        cfg: OnlineConfig,
        scale: ScaleSource,
        every_m: f64,
    ) -> Result<Self, CalibrationError> {
        let every_m = if every_m.is_finite() {
            every_m.max(0.01)
        } else {
            1.0
        };
        Ok(Tracker {
            filter: OnlineEstimator::new(cfg)?,
            scale,
            merger: Merger::new(Clocks::Shared),
            feeder: Feeder::new(),
            every_m,
            next_m: every_m,
            pose_delay_s: 0.0,
            pose_start: PoseStart::Waiting(PoseRecording::default(), START_MIN_POSES),
            started_from: None,
            checkpoints: Vec::new(),
            time_offsets: Vec::new(),
        })
    }

    /// Where the wheels' absolute scale comes from in this session (the excitation is judged
    /// on it).
    pub fn scale_source(&self) -> ScaleSource {
        self.scale
    }

    /// The filter.
    pub fn filter(&self) -> &OnlineEstimator {
        &self.filter
    }

    /// The current estimate.
    ///
    /// Input with no driving or no heading readings has nothing to estimate from: that is
    /// [`CalibrationError::TooLittleData`], not the prior dressed up as a result.
    pub fn estimate(&self) -> Result<OnlineEstimate, CalibrationError> {
        if let PoseStart::Refused(why) = &self.pose_start {
            return Err(CalibrationError::Unsupported(why.clone()));
        }
        let (_, headings) = self.filter.nis_mean();
        let (_, poses) = self.filter.nis_pose_mean();
        let heading_updates = headings + poses;
        let distance_m = self.filter.distance_m();
        if heading_updates < 2 || distance_m < MIN_DISTANCE_M {
            return Err(CalibrationError::TooLittleData {
                distance_m,
                heading_updates,
            });
        }
        self.filter.estimate(self.scale)
    }

    fn maybe_checkpoint(&mut self) -> Option<OnlineEstimate> {
        if self.filter.distance_m() >= self.next_m {
            // The next multiple of `every_m` past the distance, in one step: a loop adding
            // `every_m` would run for ever once the distance is beyond float resolution.
            let d = self.filter.distance_m();
            self.next_m = ((d / self.every_m).floor() + 1.0) * self.every_m;
            if self.next_m.partial_cmp(&d) != Some(std::cmp::Ordering::Greater) {
                self.next_m = f64::INFINITY;
            }
            if let Ok(e) = self.estimate() {
                self.checkpoints.push(e);
                return Some(e);
            }
        }
        None
    }

    fn feed(&mut self, events: Vec<Event>) -> Vec<OnlineEstimate> {
        let mut out = Vec::new();
        for e in &events {
            if self.hold(e) {
                continue;
            }
            self.feeder.feed(&mut self.filter, e);
            out.extend(self.maybe_checkpoint());
        }
        out
    }

    /// Until a session with a pose reference has observed enough for a batch fit, its poses
    /// are held (and its travel kept beside the filter's prediction); then the fit starts the
    /// filter, and the pose that completed it is its first fix. Returns whether `e` is held.
    fn hold(&mut self, e: &Event) -> bool {
        let PoseStart::Waiting(drive, next_try) = &mut self.pose_start else {
            // Started: everything goes on; refused: the poses are held for good.
            return matches!(self.pose_start, PoseStart::Refused(_)) && matches!(e, Event::Pose(_));
        };
        match e {
            Event::Heading(_) => {
                // A heading session: nothing to hold.
                self.pose_start = PoseStart::Started;
                false
            }
            Event::Travel(t) => {
                let configured = Geometry::from(&self.filter.config().configured);
                let next = wheel_angles(drive.wheels.last(), t, configured);
                if drive.wheels.len() >= START_SAMPLES_KEPT {
                    drive.wheels.drain(..START_SAMPLES_KEPT / 2);
                }
                drive.wheels.push(next);
                false
            }
            Event::Pose(p) => {
                if p.yaw_rad.is_none() {
                    self.pose_start = PoseStart::Refused(
                        "a position-only reference (no yaw, as GNSS): the online filter needs a \
                         yaw to anchor on; fit the recording with odocal fit"
                            .into(),
                    );
                    return true;
                }
                if drive.poses.len() >= START_SAMPLES_KEPT / 5 {
                    drive.poses.drain(..START_SAMPLES_KEPT / 10);
                    let first = drive.poses[0].time_s;
                    drive.wheels.retain(|w| w.time_s >= first - 1.0);
                    *next_try = (*next_try).min(drive.poses.len() + START_EVERY_POSES);
                }
                drive.poses.push(*p);
                let n = drive.poses.len();
                if n < *next_try {
                    return true;
                }
                let nominal = Geometry::from(&self.filter.config().configured);
                let drive_survey = survey(drive, nominal);
                if drive_survey.require().is_err() {
                    *next_try = n + START_EVERY_POSES;
                    return true;
                }
                if let Some(why) = start_refusal(drive, nominal, &drive_survey) {
                    self.pose_start = PoseStart::Refused(why.to_string());
                    return true;
                }
                // The kind from the data (a chained reference is not for this filter) and the
                // delay as `odocal fit` measures it: a localization is 50–100 ms late, and a
                // filter that took it as on time would reject good fixes and bias the wheelbase.
                let fit = match fit_poses(drive, &FitConfig::full(nominal)) {
                    Ok(fit) if judge(&fit).require_geometry().is_ok() => fit,
                    Err(CalibrationError::DelayBeyondSearch { delay_s, .. }) => {
                        self.pose_start = PoseStart::Refused(format!(
                            "the reference's turns follow the wheels' {delay_s:.2} s late, more \
                             than the start fit searches: give --reference-delay-s {:.2} (what \
                             is given is taken off before the fit) and track again",
                            self.pose_delay_s + delay_s
                        ));
                        return true;
                    }
                    _ => {
                        *next_try = n + (n / 2).max(START_EVERY_POSES);
                        return true;
                    }
                };
                if fit.kind.kind == ReferenceKind::Relative {
                    self.pose_start = PoseStart::Refused(format!(
                        "the reference accumulates error ({}): the online filter takes an \
                         absolute reference (motion capture, a map's localization); fit the \
                         recording with odocal fit",
                        fit.kind.reason
                    ));
                    return true;
                }
                let mount = Pose2 {
                    x: fit.value(Param::SensorX),
                    y: fit.value(Param::SensorY),
                    theta: fit.value(Param::SensorYaw),
                };
                let late = fit.value(Param::TimeOffset);
                if let Some(why) = wheel_made(compare(drive, nominal, mount, late)) {
                    self.pose_start = PoseStart::Refused(why.to_string());
                    return true;
                }
                // The poses held had the given delay taken off; the fit measured what is left.
                self.pose_delay_s += late;
                self.filter.start_from_fit(&fit);
                self.started_from = Some(fit);
                self.pose_start = PoseStart::Started;
                // The pose goes on to the filter as its first fix (anchoring the pose).
                false
            }
        }
    }

    /// Starts a new stretch of driving whose streams' clocks relate as `clocks`: the pose
    /// starts again at the origin (the parameters carry over).
    pub fn start_stream(&mut self, clocks: Clocks) -> Vec<OnlineEstimate> {
        let out = self.finish_stream();
        self.filter.restart_pose();
        self.merger = Merger::new(clocks);
        self.feeder = Feeder::new();
        out
    }

    /// Takes a live travel sample; returns the checkpoints passed.
    pub fn push_travel(&mut self, s: TravelSample) -> Vec<OnlineEstimate> {
        self.merger.push_travel(s);
        let ready = self.merger.ready();
        self.feed(ready)
    }

    /// The delay of a pose reference's stamps (s, positive: late; the pose stamped `t` is
    /// the robot's at `t − delay_s`), taken off every pose fed from now on. The filter does
    /// not estimate it: the batch fit does ([`super::pose_fit`]).
    pub fn set_pose_delay(&mut self, delay_s: f64) {
        self.pose_delay_s = if delay_s.is_finite() { delay_s } else { 0.0 };
    }

    /// The delay taken off every pose (s): the one given, plus what the start fit measured.
    pub fn pose_delay_s(&self) -> f64 {
        self.pose_delay_s
    }

    /// Takes a live reference pose (in place of heading samples: one reference stream per
    /// session); returns the checkpoints passed.
    pub fn push_pose(&mut self, p: ReferencePose) -> Vec<OnlineEstimate> {
        self.merger.push_pose(ReferencePose {
            time_s: p.time_s - self.pose_delay_s,
            ..p
        });
        let ready = self.merger.ready();
        self.feed(ready)
    }

    /// Takes a live heading sample; returns the checkpoints passed.
    pub fn push_heading(&mut self, s: HeadingSample) -> Vec<OnlineEstimate> {
        self.merger.push_heading(s);
        let ready = self.merger.ready();
        self.feed(ready)
    }

    /// Feeds what the streams left waiting (they ended); returns the checkpoints passed.
    pub fn finish_stream(&mut self) -> Vec<OnlineEstimate> {
        let rest = self.merger.finish();
        let out = self.feed(rest);
        self.feeder.finish(&mut self.filter);
        out
    }

    /// Feeds a whole recording as a run of its own (the pose starts at the origin): checked
    /// for a clock offset first and corrected if it is significant; returns the checkpoints
    /// passed.
    pub fn feed_recording(&mut self, run: &str, recording: &Recording) -> Vec<OnlineEstimate> {
        let wheelbase = self.filter.config().configured.wheelbase_m;
        let (aligned, alignment) = recording.aligned(wheelbase);
        if let Some(offset) = alignment.offset {
            self.time_offsets.push(RunTimeOffset {
                run: run.into(),
                offset,
                corrected: alignment.corrected,
            });
        }
        let mut out = self.start_stream(Clocks::Shared);
        // The poses' delay comes off before they are merged, as live (`push_pose`).
        let mut aligned = aligned;
        for p in &mut aligned.poses {
            p.time_s -= self.pose_delay_s;
        }
        let events = aligned.events();
        out.extend(self.feed(events));
        self.feeder.finish(&mut self.filter);
        out
    }

    /// Checks samples already fed live for a clock offset and records it uncorrected; returns
    /// it when one could be estimated.
    pub fn check_time_offset(&mut self, run: &str, recording: &Recording) -> Option<TimeOffset> {
        let wheelbase = self.filter.config().configured.wheelbase_m;
        let offset = recording.time_offset(wheelbase)?;
        self.time_offsets.push(RunTimeOffset {
            run: run.into(),
            offset,
            corrected: false,
        });
        Some(offset)
    }
}
