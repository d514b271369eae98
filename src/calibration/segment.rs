//! Square runs found in a long recording (a bag, a log): from the odometry, not from timing.
//!
//! Each travel interval of a [`Track`] is at rest, straight or a turn in place
//! ([`super::legs::classify`], by the robot's own odometry with the configured geometry). A run
//! is a stretch of motion between two rests of at least `min_rest_s` whose odometry turns about
//! ±360° in four ±90° turns between four legs. Its heading error is the heading's change
//! (circular means over up to [`REST_WINDOW_S`] of rest before and after) minus the odometry's
//! turn over the run — a real run does not turn exactly ±360°, so this removes the
//! controller's execution error, as the live routine does with the drive's reported turn.

use super::legs::{classify, pieces, LegMeasurement, Phase};
use super::recording::Track;
use crate::kinematics::{wrap_angle, Direction, Displacement};
use serde::Serialize;
use std::f64::consts::FRAC_PI_4;

/// Longest stretch of rest before and after a run whose readings are averaged (s).
pub const REST_WINDOW_S: f64 = 1.0;

/// How to find runs.
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentOptions {
    /// Shortest rest that separates runs (s).
    pub min_rest_s: f64,
    /// Explicit runs as (start, end) on the track's clock; empty: find them.
    pub ranges: Vec<(f64, f64)>,
    /// Keep runs without four legs and four turns (the side is known from elsewhere).
    pub keep_irregular: bool,
}

impl Default for SegmentOptions {
    fn default() -> Self {
        SegmentOptions {
            min_rest_s: 0.5,
            ranges: Vec::new(),
            keep_irregular: false,
        }
    }
}

/// A range that holds no usable run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("time range {0}")]
pub struct RangeError(pub String);

/// A square run found in (or assigned to) a track, measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunSegment {
    /// Direction (from the odometry's turn).
    pub direction: Direction,
    /// Start (s, the track's clock).
    pub start_s: f64,
    /// End (s).
    pub end_s: f64,
    /// Legs' mean length by odometry (m), when four legs were found.
    pub mean_leg_m: Option<f64>,
    /// Odometry turn over the run (rad, unwrapped).
    pub odometry_turn_rad: f64,
    /// The odometry's turn and distance over the run.
    pub odometry: Displacement,
    /// The heading's change over the run (rad; at-rest means before and after).
    pub heading_turn_rad: f64,
    /// Heading error: heading turn minus odometry turn (rad, wrapped).
    pub heading_error_rad: f64,
    /// Heading readings averaged at rest (before, after).
    pub rest_readings: [usize; 2],
    /// Heading error from the middle of the first leg to the middle of the last (rad), when
    /// four legs were found ([`super::legs`]).
    pub leg_heading_error_rad: Option<f64>,
    /// The heading along the legs, leg by leg.
    pub legs: Option<LegMeasurement>,
}

/// One travel interval: start, end and the point (index) that ends it.
#[derive(Clone, Copy)]
struct Interval {
    from_s: f64,
    to_s: f64,
    ds: f64,
    dth: f64,
    point: usize,
}

fn intervals(track: &Track) -> Vec<Interval> {
    track
        .points
        .windows(2)
        .enumerate()
        .map(|(i, w)| Interval {
            from_s: w[0].time_s,
            to_s: w[1].time_s,
            ds: w[1].step.distance_m,
            dth: w[1].step.turn_rad,
            point: i + 1,
        })
        .collect()
}

/// Stretches of motion ([start, end) interval indices) between rests of at least
/// `min_rest_s`, and a note for motion that runs to the end of the track.
fn episodes(
    inc: &[Interval],
    wheelbase_m: f64,
    min_rest_s: f64,
) -> (Vec<(usize, usize)>, Vec<String>) {
    let phases: Vec<Phase> = inc
        .iter()
        .map(|x| classify(x.ds, x.dth, x.to_s - x.from_s, wheelbase_m))
        .collect();
    let (mut out, mut notes) = (Vec::new(), Vec::new());
    let mut i = 0;
    let mut start: Option<usize> = None;
    while i < inc.len() {
        if phases[i] == Phase::Rest {
            let j = (i..inc.len())
                .find(|&k| phases[k] != Phase::Rest)
                .unwrap_or(inc.len());
            let rest_s = inc[j - 1].to_s - inc[i].from_s;
            if rest_s >= min_rest_s || j == inc.len() {
                if let Some(s) = start.take() {
                    out.push((s, i));
                }
            }
            i = j;
        } else {
            start.get_or_insert(i);
            i += 1;
        }
    }
    if let Some(s) = start {
        notes.push(format!(
            "motion from {:.1} s to the end: no rest after it",
            inc[s].from_s
        ));
    }
    (out, notes)
}

/// Legs (m) and corners (rad) of a run ([`pieces`]).
fn legs_and_turns(inc: &[Interval], wheelbase_m: f64) -> (Vec<f64>, Vec<f64>) {
    let (mut legs, mut turns) = (Vec::new(), Vec::new());
    for p in pieces(
        inc.iter().map(|x| (x.ds, x.dth, x.to_s - x.from_s)),
        wheelbase_m,
    ) {
        if p.phase == Phase::Turn {
            turns.push(p.amount);
        } else {
            legs.push(p.amount);
        }
    }
    (legs, turns)
}

/// Finds the square runs of `track` (or takes `opts.ranges`) and measures each; returns them
/// and, for every stretch of motion not used, why.
pub fn find_squares(
    track: &Track,
    wheelbase_m: f64,
    opts: &SegmentOptions,
) -> Result<(Vec<RunSegment>, Vec<String>), RangeError> {
    let inc = intervals(track);
    let (episodes, mut skipped) = if opts.ranges.is_empty() {
        episodes(&inc, wheelbase_m, opts.min_rest_s)
    } else {
        let mut out = Vec::new();
        for &(a, b) in &opts.ranges {
            if !(a.is_finite() && b.is_finite() && b > a) {
                return Err(RangeError(format!("{a}..{b} is empty or not finite")));
            }
            let s = inc.partition_point(|x| x.from_s < a);
            let e = inc.partition_point(|x| x.to_s <= b);
            if e <= s {
                return Err(RangeError(format!("{a}..{b} s holds no wheel data")));
            }
            out.push((s, e));
        }
        (out, Vec::new())
    };
    let mut runs = Vec::new();
    for (s, e) in episodes {
        let (t_start, t_end) = (inc[s].from_s, inc[e - 1].to_s);
        let turn: f64 = inc[s..e].iter().map(|x| x.dth).sum();
        let Some(direction) = Direction::of_square_turn(turn, FRAC_PI_4) else {
            skipped.push(format!(
                "{t_start:.1}–{t_end:.1} s: turns {:.0}°, not a square (±360°)",
                turn.to_degrees()
            ));
            continue;
        };
        let (legs, turns) = legs_and_turns(&inc[s..e], wheelbase_m);
        let mean_leg_m = (legs.len() == 4 && turns.len() == 4)
            .then(|| legs.iter().map(|l| l.abs()).sum::<f64>() / 4.0);
        if mean_leg_m.is_none() && !opts.keep_irregular {
            skipped.push(format!(
                "{t_start:.1}–{t_end:.1} s: {} legs and {} turns, not four of each (give the \
                 side to use it anyway)",
                legs.len(),
                turns.len()
            ));
            continue;
        }
        let (before, nb) = track.mean_heading(t_start - REST_WINDOW_S, t_start);
        let (after, na) = track.mean_heading(t_end, t_end + REST_WINDOW_S);
        let (Some(before), Some(after)) = (before, after) else {
            skipped.push(format!(
                "{t_start:.1}–{t_end:.1} s: no valid heading at rest before or after"
            ));
            continue;
        };
        // The odometry over the same windows as the heading: a turn's slow tail after the
        // run's end (below the rest threshold) is in the heading after, so it must be in the
        // odometry's turn too.
        let turn = match (
            track.mean_odometry_turn(t_start - REST_WINDOW_S, t_start),
            track.mean_odometry_turn(t_end, t_end + REST_WINDOW_S),
        ) {
            (Some(a), Some(b)) => b - a,
            _ => turn,
        };
        let heading_turn = wrap_angle(after - before - turn) + turn;
        // The run's points: the one at its start (the rest before) to the one ending it.
        let points = inc[s].point - 1..inc[e - 1].point + 1;
        let legs = track.leg_measurement_in(points, wheelbase_m);
        let distance = inc[s..e].iter().map(|x| x.ds).sum();
        runs.push(RunSegment {
            direction,
            start_s: t_start,
            end_s: t_end,
            mean_leg_m,
            odometry_turn_rad: turn,
            odometry: Displacement {
                distance_m: distance,
                turn_rad: turn,
            },
            heading_turn_rad: heading_turn,
            heading_error_rad: wrap_angle(heading_turn - turn),
            rest_readings: [nb, na],
            leg_heading_error_rad: legs.map(|l| l.heading_error_rad()),
            legs,
        });
    }
    Ok((runs, skipped))
}
