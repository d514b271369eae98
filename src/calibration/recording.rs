//! One recording pipeline for every source: time-stamped wheel travel and headings, put on one
//! clock, turned into odometry, and handed to the estimators.
//!
//! Every input odocal calibrates from — the live routine's squares, live tracking on any base,
//! ROS bags of any container, recorded data sets, telemetry logs — converts into a
//! [`Recording`]: the wheel travel the drive believed (configured metres per interval) and the
//! heading readings, each on its stream's clock. Everything after that happens here, once:
//!
//! 1. **Clocks** ([`Recording::aligned`]): streams of one clock compare directly; streams of
//!    two clocks that started together are first aligned on their first samples. Then the
//!    turn-rate correlation of [`super::time_offset`] looks for a remaining offset within
//!    [`super::time_offset::MAX_OFFSET_S`], and a significant one is removed.
//! 2. **Odometry and heading per interval** ([`Recording::track`]): each travel sample's
//!    [`Displacement`] (the turn written once, in [`crate::kinematics`]) and the heading
//!    interpolated at its time over the unwrapped readings.
//! 3. **Measurements**: the heading along the legs ([`Track::leg_measurement`],
//!    [`super::legs`]), whole-run turns ([`Track::turns`]), circular means at rest
//!    ([`Track::mean_heading`]); square runs found in a long recording are
//!    [`super::segment`]'s.
//! 4. **The online filter** ([`Merger`], [`Feeder`]): both streams merged into one time order
//!    (as they arrive, for live input; all at once, for recorded input — the same order either
//!    way), each heading reading applied at its own time inside the travel interval that holds
//!    it.
//!
//! The sample types are [`crate::samples`]' (below both this layer and the seam, whose
//! backends produce them); they are re-exported here under their old paths.

use super::legs::{leg_measurement, LegMeasurement, LegSample};
use super::online::OnlineEstimator;
use super::pose_reference::{ReferencePose, WheelAngles};
use super::time_offset::{estimate_time_offset, unwrapped_heading_at, TimeOffset, MAX_OFFSET_S};
use crate::kinematics::{wrap_angle, Displacement};
use serde::{Deserialize, Serialize};

pub use crate::samples::{Clocks, HeadingSample, TravelSample, Validity};
use std::collections::VecDeque;

/// Wheel travel and headings of one stretch of driving, each on its stream's clock.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Recording {
    /// Wheel travel, in time order.
    pub travel: Vec<TravelSample>,
    /// Heading readings (valid or not), in time order.
    pub headings: Vec<HeadingSample>,
    /// How the two streams' clocks relate.
    pub clocks: Clocks,
    /// Poses of an absolute reference (in place of headings; on the travel clock, its delay
    /// removed), in time order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub poses: Vec<ReferencePose>,
}

/// How completely a stream that should never pause covered its span.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Coverage {
    /// Time from its first sample to its last (s).
    pub span_s: f64,
    /// Time inside gaps longer than three of its median intervals (s): samples lost or late.
    pub missing_s: f64,
    /// The share of the span not missing (0–1).
    pub fraction: f64,
}

/// The coverage of sample times `times` (in order), or `None` with fewer than three samples.
/// A gap counts as missing beyond one median interval, once it is longer than three: a
/// stream that lost or delayed samples (a busy host, a lossy link) says by how much.
pub fn coverage(times: &[f64]) -> Option<Coverage> {
    if times.len() < 3 {
        return None;
    }
    let mut gaps: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    let span_s = times[times.len() - 1] - times[0];
    let mut sorted = gaps.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    if !(span_s > 0.0 && median.is_finite()) {
        return None;
    }
    gaps.retain(|g| *g > 3.0 * median);
    let missing_s: f64 = gaps.iter().map(|g| g - median).sum();
    Some(Coverage {
        span_s,
        missing_s,
        fraction: (1.0 - missing_s / span_s).clamp(0.0, 1.0),
    })
}

/// How a recording's heading stream was put on its travel clock.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Alignment {
    /// Added to every heading time (s): the coarse step between separate clocks plus the
    /// removed offset (0 for one clock and no significant offset).
    pub shift_s: f64,
    /// The offset the turn rates show after the coarse step, when they can tell (sign
    /// convention of [`super::time_offset`]: positive when the heading lags).
    pub offset: Option<TimeOffset>,
    /// Whether that offset was removed (it is when [`TimeOffset::significant`]).
    pub corrected: bool,
    /// Whether the two clocks can be compared at all: separate clocks whose streams span
    /// times that differ by more than a fifth (and a second) do not run at one rate (a
    /// simulation's clock beside this host's), and no heading is read at any travel time.
    pub comparable: bool,
}

/// One travel interval: it ends at `time_s` and began at the previous point's time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackPoint {
    /// End of the interval on the travel clock (s).
    pub time_s: f64,
    /// The odometry's displacement over the interval (configured geometry).
    pub step: Displacement,
    /// The odometry's turn from the start of the recording to `time_s` (rad, not wrapped).
    pub odometry_turn_rad: f64,
    /// The heading at `time_s` (rad, unwrapped from the first reading), or `None` outside the
    /// readings or next to an invalid one.
    pub heading_rad: Option<f64>,
}

/// A recording as odometry and heading on one clock ([`Recording::track`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Track {
    /// One point per travel sample.
    pub points: Vec<TrackPoint>,
    /// The valid readings on the travel clock: (time s, heading rad wrapped).
    pub readings: Vec<(f64, f64)>,
    /// How the clocks were aligned.
    pub alignment: Alignment,
}

/// The turns over a whole track.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Turns {
    /// The odometry's turn (rad, not wrapped).
    pub odometry_rad: f64,
    /// The heading sensor's turn from the first reading to the last (rad, unwrapped).
    pub heading_rad: Option<f64>,
}

impl Recording {
    /// The coarse step (s) that puts heading times on the travel clock before any correlation.
    fn coarse_shift(&self) -> f64 {
        match (self.clocks, self.travel.first(), self.headings.first()) {
            (Clocks::StartedTogether, Some(d), Some(h)) => d.time_s - h.time_s,
            _ => 0.0,
        }
    }

    /// Times, odometry turns and headings at every travel sample, with heading times moved by
    /// `shift_s`.
    fn series(&self, wheelbase_m: f64, shift_s: f64) -> (Vec<f64>, Vec<f64>, Vec<Option<f64>>) {
        let times: Vec<f64> = self.travel.iter().map(|t| t.time_s).collect();
        let turns = self
            .travel
            .iter()
            .map(|t| Displacement::of_wheels(t.left_m, t.right_m, wheelbase_m).turn_rad)
            .collect();
        let (h_times, h_values): (Vec<f64>, Vec<Option<f64>>) = self
            .headings
            .iter()
            .map(|h| (h.time_s + shift_s, h.usable()))
            .unzip();
        let heading = unwrapped_heading_at(&h_times, &h_values, &times);
        (times, turns, heading)
    }

    /// Whether the streams' clocks can be compared (see [`Alignment::comparable`]).
    fn comparable(&self) -> bool {
        let span = |first: Option<f64>, last: Option<f64>| match (first, last) {
            (Some(a), Some(b)) => b - a,
            _ => 0.0,
        };
        let d = span(
            self.travel.first().map(|t| t.time_s),
            self.travel.last().map(|t| t.time_s),
        );
        let h = span(
            self.headings.first().map(|t| t.time_s),
            self.headings.last().map(|t| t.time_s),
        );
        self.clocks == Clocks::Shared || (d - h).abs() <= 0.2 * d.max(h) + 1.0
    }

    /// The same recording with its heading stream on the travel clock (coarse step for
    /// separate clocks, then a significant offset removed), and how that was done.
    pub fn aligned(&self, wheelbase_m: f64) -> (Recording, Alignment) {
        if !self.poses.is_empty() {
            // A pose reference's delay is the batch fit's to find (`pose_fit`), not the turn
            // rates' correlation: its poses go on as they are.
            return (
                self.clone(),
                Alignment {
                    comparable: true,
                    ..Alignment::default()
                },
            );
        }
        let comparable = self.comparable();
        if !comparable {
            return (
                Recording {
                    travel: self.travel.clone(),
                    headings: Vec::new(),
                    clocks: Clocks::Shared,
                    poses: Vec::new(),
                },
                Alignment {
                    comparable,
                    ..Alignment::default()
                },
            );
        }
        let coarse = self.coarse_shift();
        let (times, turns, heading) = self.series(wheelbase_m, coarse);
        let offset = estimate_time_offset(&times, &turns, &heading, MAX_OFFSET_S);
        let corrected = offset.is_some_and(|o| o.significant());
        // A reading stamped τ that lags by `offset` shows the robot at τ − offset.
        let shift_s = coarse - offset.filter(|_| corrected).map_or(0.0, |o| o.offset_s);
        let aligned = Recording {
            travel: self.travel.clone(),
            headings: self
                .headings
                .iter()
                .map(|h| HeadingSample {
                    time_s: h.time_s + shift_s,
                    ..h.clone()
                })
                .collect(),
            clocks: Clocks::Shared,
            poses: Vec::new(),
        };
        (
            aligned,
            Alignment {
                shift_s,
                offset,
                corrected,
                comparable,
            },
        )
    }

    /// The offset the turn rates show, without changing anything (for live input, which
    /// cannot be re-read).
    pub fn time_offset(&self, wheelbase_m: f64) -> Option<TimeOffset> {
        if !self.comparable() {
            return None;
        }
        let (times, turns, heading) = self.series(wheelbase_m, self.coarse_shift());
        estimate_time_offset(&times, &turns, &heading, MAX_OFFSET_S)
    }

    /// Odometry and heading per travel interval, after [`Recording::aligned`].
    pub fn track(&self, wheelbase_m: f64) -> Track {
        let (aligned, alignment) = self.aligned(wheelbase_m);
        let (times, _, heading) = aligned.series(wheelbase_m, 0.0);
        let mut turn = 0.0;
        let points = aligned
            .travel
            .iter()
            .zip(times)
            .zip(heading)
            .map(|((t, time_s), heading_rad)| {
                let step = Displacement::of_wheels(t.left_m, t.right_m, wheelbase_m);
                turn += step.turn_rad;
                TrackPoint {
                    time_s,
                    step,
                    odometry_turn_rad: turn,
                    heading_rad,
                }
            })
            .collect();
        let readings = aligned
            .headings
            .iter()
            .filter_map(|h| h.usable().map(|v| (h.time_s, v)))
            .collect();
        Track {
            points,
            readings,
            alignment,
        }
    }

    /// A drive against a pose reference as the online filter takes it: each wheel interval's
    /// rotation as travel under the `configured` diameters (what a controller with them would
    /// count), the poses as they are; one clock.
    pub fn of_pose_recording(
        drive: &super::pose_reference::PoseRecording,
        configured: super::pose_reference::Geometry,
    ) -> Recording {
        let travel = drive
            .wheels
            .first()
            .map(|w| TravelSample {
                time_s: w.time_s,
                left_m: 0.0,
                right_m: 0.0,
            })
            .into_iter()
            .chain(drive.wheels.windows(2).map(|w| TravelSample {
                time_s: w[1].time_s,
                left_m: (w[1].left_rad - w[0].left_rad) * 0.5 * configured.left_diameter_m,
                right_m: (w[1].right_rad - w[0].right_rad) * 0.5 * configured.right_diameter_m,
            }))
            .collect();
        Recording {
            travel,
            headings: Vec::new(),
            clocks: Clocks::Shared,
            poses: drive.poses.clone(),
        }
    }

    /// The inverse of [`Recording::of_pose_recording`]: the travel summed into cumulative wheel
    /// angles under the `configured` diameters, and the poses (for `fit` on a live session's
    /// samples).
    pub fn pose_recording(
        &self,
        configured: super::pose_reference::Geometry,
    ) -> super::pose_reference::PoseRecording {
        let mut wheels: Vec<WheelAngles> = Vec::with_capacity(self.travel.len());
        for t in &self.travel {
            let next = wheel_angles(wheels.last(), t, configured);
            wheels.push(next);
        }
        super::pose_reference::PoseRecording {
            wheels,
            poses: self.poses.clone(),
        }
    }

    /// Every sample as one event stream in time order, on the travel clock ([`Merger`]).
    pub fn events(&self) -> Vec<Event> {
        let mut m = Merger::new(self.clocks);
        for t in &self.travel {
            m.push_travel(*t);
        }
        if self.poses.is_empty() {
            for h in &self.headings {
                m.push_heading(h.clone());
            }
        } else {
            // A recording with a pose reference merges its poses (headings beside them are
            // not a second reference stream: one merger holds one).
            for p in &self.poses {
                m.push_pose(*p);
            }
        }
        m.finish()
    }
}

impl Track {
    /// The heading along the legs ([`super::legs`]) of the points in `range`: heading minus
    /// odometry turn at each point with a heading, the travel of points without one carried to
    /// the next (a lost reading loses no wheel travel); `None` without four legs.
    pub fn leg_measurement_in(
        &self,
        range: std::ops::Range<usize>,
        wheelbase_m: f64,
    ) -> Option<LegMeasurement> {
        let points = self.points.get(range)?;
        let mut samples = Vec::with_capacity(points.len());
        let mut carried = Displacement::default();
        for p in points {
            carried = carried.plus(&p.step);
            let Some(h) = p.heading_rad else { continue };
            samples.push(LegSample {
                t: p.time_s,
                ds: carried.distance_m,
                dth: carried.turn_rad,
                error_rad: h - p.odometry_turn_rad,
            });
            carried = Displacement::default();
        }
        leg_measurement(&samples, wheelbase_m)
    }

    /// [`Track::leg_measurement_in`] over the whole track.
    pub fn leg_measurement(&self, wheelbase_m: f64) -> Option<LegMeasurement> {
        self.leg_measurement_in(0..self.points.len(), wheelbase_m)
    }

    /// The odometry's turn and distance over the points in `range`.
    pub fn odometry_in(&self, range: std::ops::Range<usize>) -> Displacement {
        self.points
            .get(range)
            .unwrap_or_default()
            .iter()
            .fold(Displacement::default(), |a, p| a.plus(&p.step))
    }

    /// The odometry's turn over every interval and the heading's from the first valid reading
    /// to the last.
    pub fn turns(&self) -> Turns {
        let heading_rad = match (self.readings.first(), self.readings.len()) {
            (Some(_), n) if n >= 2 => Some(
                self.readings
                    .windows(2)
                    .map(|w| wrap_angle(w[1].1 - w[0].1))
                    .sum(),
            ),
            _ => None,
        };
        Turns {
            odometry_rad: self.points.iter().map(|p| p.step.turn_rad).sum(),
            heading_rad,
        }
    }

    /// The mean of the odometry's turn (from the start, rad) over the points with times in
    /// `[from_s, to_s]`, or `None` without one: the odometry's counterpart of
    /// [`Track::mean_heading`] over the same window, so that a robot still creeping at the
    /// start or the end of a rest counts alike in both.
    pub fn mean_odometry_turn(&self, from_s: f64, to_s: f64) -> Option<f64> {
        let lo = self.points.partition_point(|p| p.time_s < from_s);
        let (sum, n) = self.points[lo..]
            .iter()
            .take_while(|p| p.time_s <= to_s)
            .fold((0.0, 0usize), |(s, n), p| (s + p.odometry_turn_rad, n + 1));
        (n > 0).then(|| sum / n as f64)
    }

    /// The circular mean of the valid readings with times in `[from_s, to_s]`, and how many.
    pub fn mean_heading(&self, from_s: f64, to_s: f64) -> (Option<f64>, usize) {
        let lo = self.readings.partition_point(|r| r.0 < from_s);
        let within = self.readings[lo..].iter().take_while(|r| r.0 <= to_s);
        let n = within.clone().count();
        (crate::kinematics::circular_mean(within.map(|r| r.1)), n)
    }
}

/// The cumulative wheel angles after travel `t` under the `configured` diameters, from
/// `prev` (zero at the start).
pub(crate) fn wheel_angles(
    prev: Option<&WheelAngles>,
    t: &TravelSample,
    configured: super::pose_reference::Geometry,
) -> WheelAngles {
    let (l, r) = prev.map_or((0.0, 0.0), |w| (w.left_rad, w.right_rad));
    WheelAngles {
        time_s: t.time_s,
        left_rad: l + t.left_m / (0.5 * configured.left_diameter_m),
        right_rad: r + t.right_m / (0.5 * configured.right_diameter_m),
    }
}

/// A travel sample, a heading reading or a reference pose in the merged time order of a
/// recording (reference times on the travel clock).
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// Wheel travel over the interval ending at its time.
    Travel(TravelSample),
    /// A heading reading.
    Heading(HeadingSample),
    /// A pose of an absolute reference ([`super::pose_reference`]'s conventions).
    Pose(ReferencePose),
}

impl Event {
    /// The time on the travel clock (s).
    pub fn time_s(&self) -> f64 {
        match self {
            Event::Travel(t) => t.time_s,
            Event::Heading(h) => h.time_s,
            Event::Pose(p) => p.time_s,
        }
    }

    /// The same event `shift_s` later (a reference sample brought to the travel clock).
    fn shifted(self, shift_s: f64) -> Event {
        match self {
            Event::Travel(t) => Event::Travel(TravelSample {
                time_s: t.time_s + shift_s,
                ..t
            }),
            Event::Heading(h) => Event::Heading(HeadingSample {
                time_s: h.time_s + shift_s,
                ..h
            }),
            Event::Pose(p) => Event::Pose(ReferencePose {
                time_s: p.time_s + shift_s,
                ..p
            }),
        }
    }
}

/// Most samples a [`Merger`] holds while waiting for the other stream; beyond it the oldest go
/// out unmatched rather than growing without bound (a stream silent for hours).
pub const MERGE_CAPACITY: usize = 1 << 20;

/// Merges a travel stream and a reference stream (heading readings, or the poses of a pose
/// reference) into one time order as their samples arrive.
///
/// An event goes out once both streams have shown a later stamp (each stream arrives in its
/// own time order, so nothing earlier can still come), ties with travel first; at the end
/// [`Merger::finish`] hands out the rest. The order depends only on the stamps, not on how the
/// two streams interleaved on arrival: a live session and the replay of its log feed the filter
/// identically. Streams of separate clocks ([`Clocks::StartedTogether`]) wait for both first
/// samples, which fix the step between the clocks.
#[derive(Debug, Clone)]
pub struct Merger {
    clocks: Clocks,
    firsts: (Option<f64>, Option<f64>),
    travel: VecDeque<TravelSample>,
    /// The reference stream's samples, as events on their own clock.
    headings: VecDeque<Event>,
    newest: (Option<f64>, Option<f64>),
}

impl Merger {
    /// An empty merger for streams whose clocks relate as `clocks`.
    pub fn new(clocks: Clocks) -> Self {
        Merger {
            clocks,
            firsts: (None, None),
            travel: VecDeque::new(),
            headings: VecDeque::new(),
            newest: (None, None),
        }
    }

    fn shift(&self) -> Option<f64> {
        match self.clocks {
            Clocks::Shared => Some(0.0),
            Clocks::StartedTogether => Some(self.firsts.0? - self.firsts.1?),
        }
    }

    /// Takes a travel sample.
    pub fn push_travel(&mut self, s: TravelSample) {
        self.firsts.0.get_or_insert(s.time_s);
        self.newest.0 = Some(self.newest.0.map_or(s.time_s, |t| t.max(s.time_s)));
        self.travel.push_back(s);
    }

    /// Takes a heading sample (on its own clock).
    pub fn push_heading(&mut self, s: HeadingSample) {
        self.push_reference(Event::Heading(s));
    }

    /// Takes a reference pose (on its own clock), in place of heading readings: one reference
    /// stream per merger, in its own time order.
    pub fn push_pose(&mut self, p: ReferencePose) {
        self.push_reference(Event::Pose(p));
    }

    fn push_reference(&mut self, e: Event) {
        let t = e.time_s();
        self.firsts.1.get_or_insert(t);
        self.newest.1 = Some(self.newest.1.map_or(t, |n| n.max(t)));
        self.headings.push_back(e);
    }

    fn pop(&mut self, shift: f64, before: f64) -> Option<Event> {
        let t = self.travel.front().map(|s| s.time_s);
        let h = self.headings.front().map(|s| s.time_s() + shift);
        let over = self.travel.len() + self.headings.len() > MERGE_CAPACITY;
        let take_travel = match (t, h) {
            (Some(t), Some(h)) => t <= h,
            (Some(_), None) => true,
            (None, Some(_)) => false,
            (None, None) => return None,
        };
        let time = if take_travel { t } else { h }?;
        if !(time < before || over) {
            return None;
        }
        if take_travel {
            self.travel.pop_front().map(Event::Travel)
        } else {
            self.headings.pop_front().map(|e| e.shifted(shift))
        }
    }

    /// The events no later arrival can precede, in time order.
    pub fn ready(&mut self) -> Vec<Event> {
        let (Some(shift), (Some(t), Some(h))) = (self.shift(), self.newest) else {
            return self.overflow();
        };
        let before = t.min(h + shift);
        let mut out = Vec::new();
        while let Some(e) = self.pop(shift, before) {
            out.push(e);
        }
        out
    }

    /// Beyond [`MERGE_CAPACITY`] with one stream silent: the oldest go out anyway.
    fn overflow(&mut self) -> Vec<Event> {
        let mut out = Vec::new();
        let shift = self.shift().unwrap_or(0.0);
        while self.travel.len() + self.headings.len() > MERGE_CAPACITY {
            match self.pop(shift, f64::NEG_INFINITY) {
                Some(e) => out.push(e),
                None => break,
            }
        }
        out
    }

    /// Every event left, in time order (the streams ended). With separate clocks and one
    /// stream empty, the other's samples go out on their own clock.
    pub fn finish(&mut self) -> Vec<Event> {
        let shift = self.shift().unwrap_or(0.0);
        let mut out = Vec::new();
        while let Some(e) = self.pop(shift, f64::INFINITY) {
            out.push(e);
        }
        out
    }
}

/// Feeds merged events to the online filter: travel predicts, a valid heading reading
/// updates at its own time — inside the travel interval that holds it, that interval's travel
/// is split in proportion to time (constant speed within an interval).
#[derive(Debug, Clone, Default)]
pub struct Feeder {
    last_s: Option<f64>,
    waiting: Vec<(f64, Fix)>,
}

/// A reference sample waiting for the travel interval that holds it.
#[derive(Debug, Clone, Copy)]
enum Fix {
    Heading(f64),
    Pose(ReferencePose),
}

impl Fix {
    fn apply(self, filter: &mut OnlineEstimator) {
        match self {
            Fix::Heading(v) => {
                filter.update_heading(v);
            }
            Fix::Pose(p) => {
                filter.update_pose(p.x_m, p.y_m, p.yaw_rad, p.stated_std);
            }
        }
    }
}

impl Feeder {
    /// A feeder at the start of a stretch of driving.
    pub fn new() -> Self {
        Feeder::default()
    }

    /// Feeds one event (events must come in time order, as a [`Merger`] gives them).
    pub fn feed(&mut self, filter: &mut OnlineEstimator, event: &Event) {
        let fix = match event {
            Event::Heading(h) => h.usable().map(|v| (h.time_s, Fix::Heading(v))),
            Event::Pose(p) => Some((p.time_s, Fix::Pose(*p))),
            Event::Travel(_) => None,
        };
        match event {
            Event::Heading(_) | Event::Pose(_) => {
                let Some((time_s, fix)) = fix else { return };
                if self.last_s.is_none_or(|t| time_s <= t) {
                    fix.apply(filter);
                } else {
                    self.waiting.push((time_s, fix));
                }
            }
            Event::Travel(s) => {
                let start = self.last_s.unwrap_or(s.time_s).min(s.time_s);
                let span = s.time_s - start;
                let mut done = 0.0;
                for (t, v) in std::mem::take(&mut self.waiting) {
                    let f = if span > 0.0 {
                        ((t - start) / span).clamp(0.0, 1.0)
                    } else {
                        1.0
                    };
                    if f > done {
                        filter.predict_travel((f - done) * s.left_m, (f - done) * s.right_m);
                        done = f;
                    }
                    v.apply(filter);
                }
                if done < 1.0 {
                    filter.predict_travel((1.0 - done) * s.left_m, (1.0 - done) * s.right_m);
                }
                self.last_s = Some(self.last_s.map_or(s.time_s, |t| t.max(s.time_s)));
            }
        }
    }

    /// Applies readings still waiting for a travel interval (the driving ended before them).
    pub fn finish(&mut self, filter: &mut OnlineEstimator) {
        for (_, v) in std::mem::take(&mut self.waiting) {
            v.apply(filter);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn travel(t: f64, l: f64, r: f64) -> TravelSample {
        TravelSample {
            time_s: t,
            left_m: l,
            right_m: r,
        }
    }

    fn heading(t: f64, h: f64) -> HeadingSample {
        HeadingSample {
            time_s: t,
            heading_rad: h,
            validity: Validity::Valid,
        }
    }

    #[test]
    fn the_merged_order_does_not_depend_on_how_the_streams_interleaved() {
        let travel: Vec<_> = (0..50)
            .map(|i| travel(0.02 * f64::from(i), 0.01, 0.012))
            .collect();
        let headings: Vec<_> = (0..17)
            .map(|i| heading(0.013 + 0.06 * f64::from(i), 0.001 * f64::from(i)))
            .collect();
        let all_at_once = Recording {
            travel: travel.clone(),
            headings: headings.clone(),
            clocks: Clocks::Shared,
            poses: Vec::new(),
        }
        .events();
        assert_eq!(all_at_once.len(), 67);
        assert!(all_at_once
            .windows(2)
            .all(|w| w[0].time_s() <= w[1].time_s()));
        // Headings arriving in bursts, late: the same order.
        let mut m = Merger::new(Clocks::Shared);
        let mut live = Vec::new();
        let mut hs = headings.iter();
        for (i, t) in travel.iter().enumerate() {
            m.push_travel(*t);
            if i % 7 == 6 {
                for h in hs.by_ref().take(3) {
                    m.push_heading(h.clone());
                }
            }
            live.extend(m.ready());
        }
        for h in hs {
            m.push_heading(h.clone());
            live.extend(m.ready());
        }
        live.extend(m.finish());
        assert_eq!(live, all_at_once);
    }

    #[test]
    fn separate_clocks_meet_at_their_first_samples() {
        let rec = Recording {
            travel: vec![travel(100.0, 0.0, 0.0), travel(100.1, 0.1, 0.1)],
            headings: vec![heading(5.0, 0.3), heading(5.05, 0.3)],
            clocks: Clocks::StartedTogether,
            poses: Vec::new(),
        };
        let times: Vec<f64> = rec.events().iter().map(Event::time_s).collect();
        assert_eq!(times, vec![100.0, 100.0, 100.05, 100.1]);
        let track = rec.track(0.4);
        assert_eq!(track.alignment.shift_s, 95.0);
        assert_eq!(track.points[0].heading_rad, Some(0.3));
        // The second travel sample lies beyond the last reading: no heading is invented.
        assert_eq!(track.points[1].heading_rad, None);
    }

    #[test]
    fn a_reading_inside_an_interval_splits_its_travel() {
        use crate::calibration::online::OnlineConfig;
        use crate::kinematics::WheelParams;
        let cfg = OnlineConfig::new(WheelParams::nominal(0.15, 0.39, 4096.0));
        // Straight at 1 m/s; a reading at 0.05 s into a 0.1 s interval, and one at its end.
        let events = [
            Event::Heading(heading(0.0, 0.0)),
            Event::Travel(travel(0.0, 0.0, 0.0)),
            Event::Heading(heading(0.05, 0.0)),
            Event::Travel(travel(0.1, 0.1, 0.1)),
            Event::Heading(heading(0.1, 0.0)),
        ];
        let mut split = OnlineEstimator::new(cfg).unwrap();
        let mut feeder = Feeder::new();
        for e in &events {
            feeder.feed(&mut split, e);
        }
        feeder.finish(&mut split);
        // By hand: 5 cm, update, 5 cm, update.
        let mut by_hand = OnlineEstimator::new(cfg).unwrap();
        by_hand.update_heading(0.0);
        by_hand.predict_travel(0.0, 0.0);
        by_hand.predict_travel(0.05, 0.05);
        by_hand.update_heading(0.0);
        by_hand.predict_travel(0.05, 0.05);
        by_hand.update_heading(0.0);
        assert_eq!(split.state(), by_hand.state());
        assert_eq!(split.covariance(), by_hand.covariance());
    }

    #[test]
    fn coverage_counts_the_gaps_of_a_stream() {
        let times: Vec<f64> = (0..100).map(|k| 0.1 * f64::from(k)).collect();
        let full = coverage(&times).unwrap();
        assert!(full.missing_s < 1e-9 && (full.fraction - 1.0).abs() < 1e-12);
        // Two seconds lost in the middle.
        let holed: Vec<f64> = times
            .iter()
            .copied()
            .filter(|t| !(4.0..6.0).contains(t))
            .collect();
        let c = coverage(&holed).unwrap();
        assert!((c.missing_s - 2.0).abs() < 1e-9, "{c:?}");
        assert!((c.fraction - (1.0 - 2.0 / 9.9)).abs() < 1e-9, "{c:?}");
        assert!(coverage(&[0.0, 1.0]).is_none());
    }
}
