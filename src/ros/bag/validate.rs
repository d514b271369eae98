//! Every stream of a bag checked the way `track --log` checks a log, before anything is
//! estimated from it:
//! - samples are finite and physical: a wheel angle within ±[`MAX_JOINT_RAD`], odometry
//!   within ±[`MAX_POSITION_M`] of its origin;
//! - time goes forward on each topic, in the order the container hands the messages out (a
//!   sample stamped at or before the one kept before it is dropped); a topic where more than
//!   one sample and more than [`MAX_BACKWARD_SHARE`] of them go back is a reordered or
//!   repeated recording (split files listed out of order or twice, stamps reversed) and is
//!   refused with where;
//! - one wild sample — a spike that jumps further than any wheel turns
//!   ([`MAX_WHEEL_RATE_RAD_S`]), any robot yaws ([`MAX_YAW_RATE_RAD_S`]) or drives
//!   ([`crate::kinematics::MAX_WHEEL_SPEED_M_S`]) in the time between, and comes back at the
//!   next sample — is dropped: one sample must not move a result.
//!
//! Every drop is counted in a note naming the topic, the reason and the first message
//! (0-based, per topic). A jump that does not come back (a driver that reset its counts) is
//! kept, and a note says where: what follows it is the recording as it is.
//!
//! A live topic gets the same rules one message at a time ([`LiveJoints`], [`Forward`]): it
//! cannot look ahead, so a jump is held back one message, dropped when the next comes back
//! and taken as a new start (its step not counted as travel) when the next stays.

use super::BagError;
use crate::kinematics::MAX_WHEEL_SPEED_M_S;
use crate::ros::msg::angle_step;

/// Largest wheel angle taken as physical (rad): a 0.1 m wheel's angle after 1000 km, which a
/// driver that never resets its count could report after weeks of driving.
pub const MAX_JOINT_RAD: f64 = 1e7;

/// Fastest a wheel of a robot this tool calibrates turns (rad/s): 955 rpm, 3 m/s on a 30 mm
/// wheel.
pub const MAX_WHEEL_RATE_RAD_S: f64 = 100.0;

/// Fastest a robot yaws (rad/s): 2000 °/s, the widest range of common gyros.
pub const MAX_YAW_RATE_RAD_S: f64 = 35.0;

/// Farthest odometry may put the robot from its origin (m).
pub const MAX_POSITION_M: f64 = 1e6;

/// Largest share of a topic's samples that may go back in time and be dropped; more is a
/// recording in the wrong order, refused.
pub const MAX_BACKWARD_SHARE: f64 = 0.01;

/// What a jump must exceed beyond the rate bound, for stamps that jitter: a wheel angle (rad),
/// a yaw (rad), a position (m).
const JOINT_SLACK_RAD: f64 = 0.2;
const YAW_SLACK_RAD: f64 = 0.1;
const POSITION_SLACK_M: f64 = 0.2;

/// One message's sample as read: its 0-based index on its topic, its time (s) and its value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample<T> {
    /// 0-based message index on the topic.
    pub index: usize,
    /// Time (s, the bag's clock).
    pub t: f64,
    /// What it says.
    pub value: T,
}

/// Wheel joint angles as read (rad, possibly wrapped by the driver).
pub type Joints = (f64, f64);

/// Odometry as read: x (m), y (m), yaw (rad).
pub type Pose = (f64, f64, f64);

/// The drops of one check on one topic, for its note.
fn note(notes: &mut Vec<String>, topic: &str, total: usize, dropped: &[usize], why: &str) {
    if let Some(first) = dropped.first() {
        notes.push(format!(
            "{topic}: {} of {total} message(s) dropped: {why} (the first: message {first})",
            dropped.len()
        ));
    }
}

/// Drops the samples `ok` refuses.
fn physical<T>(
    samples: Vec<Sample<T>>,
    ok: impl Fn(&T) -> bool,
    topic: &str,
    why: &str,
    notes: &mut Vec<String>,
) -> Vec<Sample<T>> {
    let total = samples.len();
    let mut dropped = Vec::new();
    let kept = samples
        .into_iter()
        .filter(|s| {
            let keep = s.t.is_finite() && ok(&s.value);
            if !keep {
                dropped.push(s.index);
            }
            keep
        })
        .collect();
    note(notes, topic, total, &dropped, why);
    kept
}

/// Keeps the samples whose time is after the one kept before; refuses a topic that goes back
/// more than rarely.
fn forward<T>(
    samples: Vec<Sample<T>>,
    topic: &str,
    notes: &mut Vec<String>,
) -> Result<Vec<Sample<T>>, BagError> {
    let total = samples.len();
    let mut dropped = Vec::new();
    let mut first_back = None;
    let mut kept: Vec<Sample<T>> = Vec::with_capacity(total);
    for s in samples {
        match kept.last() {
            Some(last) if s.t <= last.t => {
                first_back.get_or_insert((s.index, s.t, last.index, last.t));
                dropped.push(s.index);
            }
            _ => kept.push(s),
        }
    }
    if dropped.len() > 1 && dropped.len() as f64 > MAX_BACKWARD_SHARE * total as f64 {
        if let Some((index, t_s, before, before_s)) = first_back {
            return Err(BagError::TimeBackwards {
                topic: topic.to_string(),
                index,
                t_s,
                before,
                before_s,
                count: dropped.len(),
                total,
            });
        }
    }
    note(
        notes,
        topic,
        total,
        &dropped,
        "stamped at or before the message before it",
    );
    Ok(kept)
}

/// Drops isolated spikes: a sample that `jumps` from the sample before and to the sample
/// after, where those two do not jump from each other. At the ends, a sample that jumps from
/// its neighbour where the next two agree.
fn despike<T>(
    samples: Vec<Sample<T>>,
    jumps: impl Fn(&Sample<T>, &Sample<T>) -> bool,
    topic: &str,
    why: &str,
    notes: &mut Vec<String>,
) -> Vec<Sample<T>> {
    let n = samples.len();
    if n < 3 {
        return samples;
    }
    let s = &samples;
    let spike: Vec<bool> = (0..n)
        .map(|i| match i {
            0 => jumps(&s[0], &s[1]) && !jumps(&s[1], &s[2]),
            _ if i == n - 1 => jumps(&s[i - 1], &s[i]) && !jumps(&s[i - 2], &s[i - 1]),
            _ => jumps(&s[i - 1], &s[i]) && jumps(&s[i], &s[i + 1]) && !jumps(&s[i - 1], &s[i + 1]),
        })
        .collect();
    // A jump that stays is not a spike; say where it is.
    let stays: Vec<usize> = (1..n)
        .filter(|&i| !spike[i] && !spike[i - 1] && jumps(&s[i - 1], &s[i]))
        .map(|i| s[i].index)
        .collect();
    if let Some(first) = stays.first() {
        notes.push(format!(
            "{topic}: {} jump(s) that stay ({why}; the first at message {first}): what \
             follows is taken as recorded, check the driver",
            stays.len()
        ));
    }
    let dropped: Vec<usize> = (0..n).filter(|&i| spike[i]).map(|i| s[i].index).collect();
    note(notes, topic, n, &dropped, &format!("a spike ({why})"));
    samples
        .into_iter()
        .zip(spike)
        .filter_map(|(s, spike)| (!spike).then_some(s))
        .collect()
}

/// One topic's three checks in order: the samples `ok` refuses dropped (as `ok_why`), time
/// forward, then isolated spikes where `jumps` (as `jump_why`).
fn checked<T>(
    samples: Vec<Sample<T>>,
    topic: &str,
    notes: &mut Vec<String>,
    (ok, ok_why): (impl Fn(&T) -> bool, &str),
    (jumps, jump_why): (impl Fn(&Sample<T>, &Sample<T>) -> bool, &str),
) -> Result<Vec<Sample<T>>, BagError> {
    let samples = physical(samples, ok, topic, ok_why, notes);
    let samples = forward(samples, topic, notes)?;
    Ok(despike(samples, jumps, topic, jump_why, notes))
}

/// The wheel angles checked, with spikes dropped, then unwrapped. A topic whose angles stay
/// within (−π, π] (but for at most [`MAX_BACKWARD_SHARE`] of them) is a driver that wraps its
/// continuous joints: an angle outside that range is then not physical, and steps are taken
/// modulo a turn. Any other topic's angles are taken as they are.
pub fn joints(
    samples: Vec<Sample<Joints>>,
    topic: &str,
    notes: &mut Vec<String>,
) -> Result<Vec<Sample<Joints>>, BagError> {
    use std::f64::consts::PI;
    let samples = physical(
        samples,
        |&(l, r)| l.abs() <= MAX_JOINT_RAD && r.abs() <= MAX_JOINT_RAD,
        topic,
        &format!("a wheel angle that is not a number within ±{MAX_JOINT_RAD:e} rad"),
        notes,
    );
    let within_turn = |&(l, r): &Joints| l.abs() <= PI + 1e-9 && r.abs() <= PI + 1e-9;
    let outside = samples.iter().filter(|s| !within_turn(&s.value)).count();
    let wraps = (outside as f64) <= MAX_BACKWARD_SHARE * samples.len() as f64;
    let step = |from: f64, to: f64| {
        if wraps {
            angle_step(from, to)
        } else {
            to - from
        }
    };
    let jumps = |a: &Sample<Joints>, b: &Sample<Joints>| {
        let limit = MAX_WHEEL_RATE_RAD_S * (b.t - a.t) + JOINT_SLACK_RAD;
        step(a.value.0, b.value.0).abs() > limit || step(a.value.1, b.value.1).abs() > limit
    };
    let samples = checked(
        samples,
        topic,
        notes,
        (
            |v: &Joints| !wraps || within_turn(v),
            "a wheel angle outside (−π, π] where the driver wraps its angles",
        ),
        (
            jumps,
            &format!("a wheel faster than {MAX_WHEEL_RATE_RAD_S} rad/s"),
        ),
    )?;
    // Unwrapped after the spikes are gone: a spike's wrap would stay in every later angle.
    let mut out: Vec<Sample<Joints>> = Vec::with_capacity(samples.len());
    let mut raw = None;
    for s in samples {
        let value = match (out.last(), raw) {
            (Some(p), Some((l, r))) => (
                p.value.0 + step(l, s.value.0),
                p.value.1 + step(r, s.value.1),
            ),
            _ => s.value,
        };
        raw = Some(s.value);
        out.push(Sample { value, ..s });
    }
    Ok(out)
}

/// The IMU's yaw checked (a message without a usable orientation is kept as `None`), with
/// spikes dropped.
pub fn yaw(
    samples: Vec<Sample<Option<f64>>>,
    topic: &str,
    notes: &mut Vec<String>,
) -> Result<Vec<Sample<Option<f64>>>, BagError> {
    let jumps = |a: &Sample<Option<f64>>, b: &Sample<Option<f64>>| match (a.value, b.value) {
        (Some(ya), Some(yb)) => {
            angle_step(ya, yb).abs() > MAX_YAW_RATE_RAD_S * (b.t - a.t) + YAW_SLACK_RAD
        }
        _ => false,
    };
    checked(
        samples,
        topic,
        notes,
        (
            |y: &Option<f64>| y.is_none_or(f64::is_finite),
            "a yaw that is not a number",
        ),
        (
            jumps,
            &format!("a yaw rate beyond {MAX_YAW_RATE_RAD_S} rad/s"),
        ),
    )
}

/// The controller's odometry checked, with spikes dropped.
pub fn odometry(
    samples: Vec<Sample<Pose>>,
    topic: &str,
    notes: &mut Vec<String>,
) -> Result<Vec<Sample<Pose>>, BagError> {
    let jumps = |a: &Sample<Pose>, b: &Sample<Pose>| {
        let dt = b.t - a.t;
        (b.value.0 - a.value.0).hypot(b.value.1 - a.value.1)
            > MAX_WHEEL_SPEED_M_S * dt + POSITION_SLACK_M
            || angle_step(a.value.2, b.value.2).abs() > MAX_YAW_RATE_RAD_S * dt + YAW_SLACK_RAD
    };
    checked(
        samples,
        topic,
        notes,
        (
            |&(x, y, yaw): &Pose| {
                x.abs() <= MAX_POSITION_M && y.abs() <= MAX_POSITION_M && yaw.is_finite()
            },
            &format!("a pose that is not a number within ±{MAX_POSITION_M:e} m"),
        ),
        (
            jumps,
            &format!("faster than {MAX_WHEEL_SPEED_M_S} m/s or {MAX_YAW_RATE_RAD_S} rad/s"),
        ),
    )
}

/// What a live check makes of one message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Use it: its step from the message used before is travel.
    Keep,
    /// Use it as a new start: the wheels jumped and stayed (a driver that reset its counts),
    /// so the step to it is not travel.
    Restart,
    /// Not yet: a jump, settled by the next message (as a spike, or as a new start).
    Hold,
    /// Drop it, for this reason.
    Drop(&'static str),
}

/// Time going forward on one live topic: a message stamped before the one kept before it is
/// dropped. (One stamped the same is kept: a driver that leaves its stamps at zero, or stamps
/// with a coarse clock, still drives; the rate checks then have no time to judge by.)
#[derive(Debug, Default, Clone)]
pub struct Forward {
    last_s: Option<f64>,
}

/// Why [`Forward`] drops a message.
pub const STAMPED_BACK: &str = "stamped before the message before it";

impl Forward {
    /// The verdict on a message stamped `t` (s).
    pub fn check(&mut self, t: f64) -> Verdict {
        match self.last_s {
            _ if !t.is_finite() => Verdict::Drop(STAMPED_BACK),
            Some(last) if t < last => Verdict::Drop(STAMPED_BACK),
            _ => {
                self.last_s = Some(t);
                Verdict::Keep
            }
        }
    }
}

/// A live wheel-joint topic checked as [`joints`] checks a bag's, one message at a time:
/// angles finite and within ±[`MAX_JOINT_RAD`], time forward, and a jump faster than any
/// wheel turns ([`MAX_WHEEL_RATE_RAD_S`]) held back one message: dropped as a spike when the
/// next message comes back, a new start when it stays. A step between two angles within
/// (−π, π] is taken modulo a turn (a driver that wraps its angles steps across ±π).
#[derive(Debug, Default, Clone)]
pub struct LiveJoints {
    forward: Forward,
    /// The message used last: time (s), angles (rad).
    kept: Option<(f64, Joints)>,
    /// A jump held back: time (s), angles (rad).
    held: Option<(f64, Joints)>,
}

/// Why [`LiveJoints`] drops a message that is not physical.
pub const NOT_PHYSICAL: &str = "a wheel angle that is not a number within ±1e7 rad";
/// Why [`LiveJoints`] drops a spike.
pub const SPIKE: &str = "a spike (a wheel faster than 100 rad/s, and back)";

impl LiveJoints {
    fn jumps((t0, a): (f64, Joints), (t1, b): (f64, Joints)) -> bool {
        // Modulo a turn between two angles a wrapping driver could send; as they are
        // otherwise (a modulo step hides any jump past half a turn).
        let step = |from: f64, to: f64| {
            let turn = std::f64::consts::PI + 1e-9;
            if from.abs() <= turn && to.abs() <= turn {
                angle_step(from, to)
            } else {
                to - from
            }
        };
        if t1 <= t0 {
            return false;
        }
        let limit = MAX_WHEEL_RATE_RAD_S * (t1 - t0) + JOINT_SLACK_RAD;
        step(a.0, b.0).abs() > limit || step(a.1, b.1).abs() > limit
    }

    /// The verdict on a message stamped `t` (s) with angles `value` (rad): `(held, this)`,
    /// where `held` settles the message held back before it, if any, as a spike
    /// ([`Verdict::Drop`]) or a new start ([`Verdict::Restart`], when this one stays where it
    /// jumped to: this one is then a [`Verdict::Restart`] too, the step between the two not
    /// counted).
    pub fn check(&mut self, t: f64, value: Joints) -> (Option<Verdict>, Verdict) {
        if !(value.0.abs() <= MAX_JOINT_RAD && value.1.abs() <= MAX_JOINT_RAD) {
            return (None, Verdict::Drop(NOT_PHYSICAL));
        }
        if let v @ Verdict::Drop(_) = self.forward.check(t) {
            return (None, v);
        }
        let this = (t, value);
        let back = |kept: Option<(f64, Joints)>| kept.is_some_and(|k| !Self::jumps(k, this));
        let settled = match self.held.take() {
            // Back where the wheels were: the held one was a spike.
            Some(_) if back(self.kept) => Some(Verdict::Drop(SPIKE)),
            // Where the held one jumped to: a new start.
            Some(held) if !Self::jumps(held, this) => {
                self.kept = Some(this);
                return (Some(Verdict::Restart), Verdict::Restart);
            }
            // Neither: the held one goes, this one is judged on its own.
            Some(_) => Some(Verdict::Drop(SPIKE)),
            None => None,
        };
        match self.kept {
            Some(k) if Self::jumps(k, this) => {
                self.held = Some(this);
                (settled, Verdict::Hold)
            }
            _ => {
                self.kept = Some(this);
                (settled, Verdict::Keep)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_live_topic_drops_spikes_and_reversed_stamps_and_restarts_after_a_jump_that_stays() {
        use super::{LiveJoints, Verdict, NOT_PHYSICAL, SPIKE, STAMPED_BACK};
        let mut j = LiveJoints::default();
        let mut at = |t: f64, angle: f64| j.check(t, (angle, angle));
        assert_eq!(at(0.00, 0.0), (None, Verdict::Keep));
        assert_eq!(at(0.02, 0.1), (None, Verdict::Keep));
        // A spike of 3 rad in 20 ms, and back: held, then dropped; the next is kept.
        assert_eq!(at(0.04, 3.1), (None, Verdict::Hold));
        assert_eq!(at(0.06, 0.2), (Some(Verdict::Drop(SPIKE)), Verdict::Keep));
        // Back only after a message stamped back (dropped) and 40 ms, near enough to the
        // spike too by then: still a spike, judged against where the wheels were first.
        let mut g = LiveJoints::default();
        assert_eq!(g.check(1.00, (10.0, 10.0)), (None, Verdict::Keep));
        assert_eq!(g.check(1.02, (13.0, 10.0)), (None, Verdict::Hold));
        assert_eq!(
            g.check(0.92, (10.1, 10.1)),
            (None, Verdict::Drop(STAMPED_BACK))
        );
        assert_eq!(
            g.check(1.06, (10.2, 10.2)),
            (Some(Verdict::Drop(SPIKE)), Verdict::Keep)
        );
        // Not a number, or 1e308: dropped, nothing held.
        assert_eq!(at(0.08, f64::NAN), (None, Verdict::Drop(NOT_PHYSICAL)));
        assert_eq!(at(0.10, 1e308), (None, Verdict::Drop(NOT_PHYSICAL)));
        // Stamped back: dropped. Stamped the same (a driver's stamps left at zero): kept, and
        // no rate to judge.
        assert_eq!(at(0.01, 0.2), (None, Verdict::Drop(STAMPED_BACK)));
        assert_eq!(at(0.06, 0.25), (None, Verdict::Keep));
        // A jump that stays (a driver that reset its counts): a new start.
        assert_eq!(at(0.12, 50.0), (None, Verdict::Hold));
        assert_eq!(at(0.14, 50.1), (Some(Verdict::Restart), Verdict::Restart));
        assert_eq!(at(0.16, 50.2), (None, Verdict::Keep));
        // A wrapped angle steps across ±π: no jump.
        let mut w = LiveJoints::default();
        assert_eq!(w.check(1.0, (3.1, 3.1)), (None, Verdict::Keep));
        assert_eq!(w.check(1.02, (-3.1, -3.1)), (None, Verdict::Keep));
        // A long pause allows a long step: 1 s at 100 rad/s.
        assert_eq!(w.check(2.02, (40.0, 40.0)), (None, Verdict::Keep));
        // The reasons quote the bounds the checks use.
        assert!(NOT_PHYSICAL.contains(&format!("±{:e} rad", super::MAX_JOINT_RAD)));
        assert!(SPIKE.contains(&format!("{} rad/s", super::MAX_WHEEL_RATE_RAD_S)));
    }

    use super::*;

    /// A wheel turning at 2 rad/s, sampled at 50 Hz, as a driver that wraps reports it.
    fn wheel(n: usize) -> Vec<Sample<Joints>> {
        turning(n, true)
    }

    /// The same wheel, wrapped or continuous.
    fn turning(n: usize, wrapped: bool) -> Vec<Sample<Joints>> {
        (0..n)
            .map(|i| {
                let t = i as f64 * 0.02;
                let a = if wrapped {
                    crate::kinematics::wrap_angle(2.0 * t)
                } else {
                    2.0 * t
                };
                Sample {
                    index: i,
                    t: 100.0 + t,
                    value: (a, -a),
                }
            })
            .collect()
    }

    #[test]
    fn good_wheels_pass_unwrapped_and_unnoted() {
        let mut notes = Vec::new();
        let out = joints(wheel(500), "/js", &mut notes).unwrap();
        assert!(notes.is_empty(), "{notes:?}");
        assert_eq!(out.len(), 500);
        let last = out.last().unwrap();
        assert!((last.value.0 - 2.0 * 499.0 * 0.02).abs() < 1e-9);
        assert!((last.value.1 + 2.0 * 499.0 * 0.02).abs() < 1e-9);
    }

    #[test]
    fn a_huge_value_and_a_spike_are_dropped_and_counted() {
        let cases = [
            (true, 0, 1e308),
            (true, 250, 1e308),
            (true, 499, f64::NAN),
            (true, 250, 1e6),
            (true, 250, 2.8),
            (false, 250, 1e6),
            (false, 0, -30.0),
            (false, 250, 2.8),
        ];
        for (wrapped, at, bad) in cases {
            let mut samples = turning(500, wrapped);
            let clean = joints(samples.clone(), "/js", &mut Vec::new()).unwrap();
            samples[at].value.0 += bad;
            let mut notes = Vec::new();
            let out = joints(samples, "/js", &mut notes).unwrap();
            assert_eq!(out.len(), 499, "{bad} at {at}: {notes:?}");
            assert_eq!(notes.len(), 1, "{notes:?}");
            assert!(
                notes[0].contains("1 of 500 message(s) dropped"),
                "{notes:?}"
            );
            assert!(notes[0].contains(&format!("message {at}")), "{notes:?}");
            // Every other angle exactly as without it: no wrap left behind.
            let kept: Vec<_> = clean.iter().filter(|s| s.index != at).collect();
            for (a, b) in out.iter().zip(kept) {
                assert!((a.value.0 - b.value.0).abs() < 1e-9, "{bad} at {at}");
            }
        }
    }

    #[test]
    fn time_going_back_drops_a_sample_and_refuses_a_reordered_stream() {
        let mut one = wheel(500);
        one[100].t = one[98].t;
        let mut notes = Vec::new();
        assert_eq!(joints(one, "/js", &mut notes).unwrap().len(), 499);
        assert!(notes[0].contains("stamped at or before"), "{notes:?}");
        // Reversed, or the same split twice: refused, naming the first.
        let reversed: Vec<_> = wheel(500).into_iter().rev().collect();
        let err = joints(reversed, "/js", &mut Vec::new()).unwrap_err();
        assert!(
            matches!(
                err,
                BagError::TimeBackwards {
                    count: 499,
                    total: 500,
                    ..
                }
            ),
            "{err}"
        );
        let twice: Vec<_> = wheel(300).into_iter().chain(wheel(300)).collect();
        let err = joints(twice, "/js", &mut Vec::new())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("`/js` goes back in time at message 0"),
            "{err}"
        );
    }

    #[test]
    fn a_jump_that_stays_is_kept_and_named() {
        let mut samples = turning(500, false);
        for s in &mut samples[300..] {
            s.value.0 -= 50.0;
        }
        let mut notes = Vec::new();
        let out = joints(samples, "/js", &mut notes).unwrap();
        assert_eq!(out.len(), 500);
        assert!(notes[0].contains("jump(s) that stay"), "{notes:?}");
        assert!(notes[0].contains("message 300"), "{notes:?}");
    }

    #[test]
    fn yaw_and_odometry_spikes_are_dropped() {
        let yaw_samples: Vec<_> = (0..100)
            .map(|i| Sample {
                index: i,
                t: i as f64 * 0.01,
                value: Some(if i == 40 { 3.0 } else { 0.001 * i as f64 }),
            })
            .collect();
        let mut notes = Vec::new();
        assert_eq!(yaw(yaw_samples, "/imu", &mut notes).unwrap().len(), 99);
        assert!(notes[0].contains("message 40"), "{notes:?}");
        let poses: Vec<_> = (0..100)
            .map(|i| Sample {
                index: i,
                t: i as f64 * 0.02,
                value: if i == 7 {
                    (1e300, 0.0, 0.0)
                } else if i == 60 {
                    (5.0, 0.0, 0.0)
                } else {
                    (0.01 * i as f64, 0.0, 0.0)
                },
            })
            .collect();
        let mut notes = Vec::new();
        assert_eq!(odometry(poses, "/odom", &mut notes).unwrap().len(), 98);
        assert_eq!(notes.len(), 2, "{notes:?}");
    }
}
