//! A constant clock offset between the encoder stream and the heading stream: detection and
//! correction.
//!
//! Encoders and a heading sensor are often stamped by different clocks (a motor controller and
//! an IMU, a robot and a motion-capture system) or the sensor filters with a delay. The online
//! filter then compares the odometry's heading with a heading from another moment, and every
//! turn looks like a wheel error: on a recorded free run a 0.3 s offset put the filter 4σ off.
//!
//! The offset is found from the turn rates, which do not depend on the parameters being
//! estimated (a wrong `E_b` scales the odometry's rate, it does not shift it): the normalised
//! cross-correlation of the odometry's per-sample turn and the sensor's per-sample turn is
//! computed for every lag within ±`max_offset_s`, and the peak is refined by a parabola through
//! it and its neighbours. The correlation is taken over rates, not headings, so a heading bias
//! and slow drift drop out.
//!
//! Sign convention (this is the one place it is defined): `offset_s > 0` means the heading
//! stream **lags**: the reading stamped `t` shows the robot as it was at `t − offset_s`.
//! [`shift_heading`] corrects it by reading the heading stream at `t + offset_s` for the
//! encoder sample stamped `t`.

use super::pose_reference::{Geometry, Odometry, PoseRecording};
use crate::kinematics::wrap_angle;
use serde::Serialize;

/// Largest offset searched for (s): every input uses this window.
pub const MAX_OFFSET_S: f64 = 1.0;

/// Offsets below this (s) are not worth a warning: below one telemetry period of most robots,
/// and a heading error of `ω·offset` ≤ 0.05 rad at 1 rad/s.
pub const WARN_ABOVE_S: f64 = 0.05;

/// The detected offset.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TimeOffset {
    /// The offset (s); positive when the heading stream lags (see the module).
    pub offset_s: f64,
    /// Normalised cross-correlation of the two turn rates at the offset (1: identical shape).
    pub correlation: f64,
    /// Correlation at zero offset, for comparison.
    pub correlation_at_zero: f64,
    /// The sample period the series was analysed at (s).
    pub period_s: f64,
}

impl TimeOffset {
    /// Whether the offset is large enough to warn about ([`WARN_ABOVE_S`]).
    pub fn significant(&self) -> bool {
        self.offset_s.abs() > WARN_ABOVE_S
    }
}

/// Per-sample rates of both streams on the encoder samples: odometry turn and sensor turn
/// (NaN where a reading is missing on either side of the interval).
fn rates(odo_turn_rad: &[f64], heading_rad: &[Option<f64>]) -> (Vec<f64>, Vec<f64>) {
    let n = odo_turn_rad.len().min(heading_rad.len());
    let mut o = Vec::with_capacity(n);
    let mut h = Vec::with_capacity(n);
    for i in 1..n {
        o.push(odo_turn_rad[i]);
        h.push(match (heading_rad[i - 1], heading_rad[i]) {
            (Some(a), Some(b)) if a.is_finite() && b.is_finite() => wrap_angle(b - a),
            _ => f64::NAN,
        });
    }
    (o, h)
}

fn correlation(o: &[f64], h: &[f64], lag: isize) -> Option<f64> {
    let (mut soh, mut soo, mut shh, mut n) = (0.0, 0.0, 0.0, 0usize);
    for (i, &oi) in o.iter().enumerate() {
        let j = i as isize + lag;
        if j < 0 || j as usize >= h.len() {
            continue;
        }
        let hj = h[j as usize];
        if !(oi.is_finite() && hj.is_finite()) {
            continue;
        }
        soh += oi * hj;
        soo += oi * oi;
        shh += hj * hj;
        n += 1;
    }
    (n > 10 && soo > 0.0 && shh > 0.0).then(|| soh / (soo * shh).sqrt())
}

/// Least total turn (rad, summed |rate|) both streams must show for an offset to be estimated.
const MIN_TURN_RAD: f64 = std::f64::consts::PI;

/// Estimates the offset from encoder samples at `times_s` (the odometry's turn over each
/// sample's interval, from the configured parameters) and the heading read at each sample.
/// `None` when the data cannot tell: fewer than two samples, too little turning (under half a
/// turn in total), or no correlation between the two rates at any lag.
pub fn estimate_time_offset(
    times_s: &[f64],
    odo_turn_rad: &[f64],
    heading_rad: &[Option<f64>],
    max_offset_s: f64,
) -> Option<TimeOffset> {
    if times_s.len() < 3 || odo_turn_rad.len() != times_s.len() {
        return None;
    }
    let mut dts: Vec<f64> = times_s
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| d.is_finite() && *d > 0.0)
        .collect();
    dts.sort_by(f64::total_cmp);
    let period_s = *dts.get(dts.len() / 2)?;
    let (o, h) = rates(odo_turn_rad, heading_rad);
    let turned = |v: &[f64]| {
        v.iter()
            .filter(|x| x.is_finite())
            .map(|x| x.abs())
            .sum::<f64>()
    };
    if turned(&o) < MIN_TURN_RAD || turned(&h) < MIN_TURN_RAD {
        return None;
    }
    let max_lag = (max_offset_s / period_s)
        .ceil()
        .clamp(1.0, o.len() as f64 / 4.0) as isize;
    let c: Vec<Option<f64>> = (-max_lag..=max_lag)
        .map(|l| correlation(&o, &h, l))
        .collect();
    let (best, peak) = c
        .iter()
        .enumerate()
        .filter_map(|(i, v)| v.map(|v| (i, v)))
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    if peak <= 0.3 {
        return None;
    }
    // Parabolic refinement through the peak and its neighbours (when both exist).
    let frac = match (
        best.checked_sub(1).and_then(|i| c[i]),
        c.get(best + 1).copied().flatten(),
    ) {
        (Some(a), Some(b)) => {
            let denom = a - 2.0 * peak + b;
            if denom < 0.0 {
                (0.5 * (a - b) / denom).clamp(-0.5, 0.5)
            } else {
                0.0
            }
        }
        _ => 0.0,
    };
    let lag = best as f64 - max_lag as f64 + frac;
    Some(TimeOffset {
        offset_s: lag * period_s,
        correlation: peak,
        correlation_at_zero: c[max_lag as usize].unwrap_or(f64::NAN),
        period_s,
    })
}

/// The delay of a pose reference's stamps against the wheels' (positive: late), from its yaw's
/// turn rate against the odometry's of the `nominal` geometry at the reference's stamps,
/// searched within ±`max_offset_s`; `None` without a yaw or when the data cannot tell.
pub fn reference_delay(
    recording: &PoseRecording,
    nominal: Geometry,
    max_offset_s: f64,
) -> Option<TimeOffset> {
    if !recording.has_yaw() {
        return None;
    }
    let odo = Odometry::integrate(&recording.wheels, nominal);
    let mut hint = 0;
    let (mut times, mut turns, mut yaws) = (Vec::new(), Vec::new(), Vec::new());
    let mut last: Option<f64> = None;
    for p in &recording.poses {
        let Some(o) = odo.at(p.time_s, &mut hint) else {
            continue;
        };
        times.push(p.time_s);
        turns.push(last.map_or(0.0, |l| o.theta - l));
        last = Some(o.theta);
        yaws.push(p.yaw_rad);
    }
    estimate_time_offset(&times, &turns, &yaws, max_offset_s)
}

/// The heading at each of the times `at`, read from readings `heading` taken at `times`
/// (sorted): linearly interpolated over the **unwrapped** heading (so interpolation across ±π
/// is right, and a turn of several revolutions stays continuous), starting from the first
/// reading's value. `None` before the first reading, after the last, or next to a missing one.
pub fn unwrapped_heading_at(
    times: &[f64],
    heading: &[Option<f64>],
    at: &[f64],
) -> Vec<Option<f64>> {
    let n = times.len().min(heading.len());
    let mut unwrapped: Vec<Option<f64>> = Vec::with_capacity(n);
    let mut prev: Option<(f64, f64)> = None; // (wrapped, unwrapped)
    for h in heading.iter().take(n) {
        let u = h.filter(|v| v.is_finite()).map(|v| match prev {
            Some((pw, pu)) => pu + wrap_angle(v - pw),
            None => v,
        });
        if let (Some(v), Some(u)) = (*h, u) {
            prev = Some((v, u));
        }
        unwrapped.push(u);
    }
    let times = &times[..n];
    at.iter()
        .map(|&t| {
            let i = times.partition_point(|&ts| ts <= t);
            if i == 0 {
                return None;
            }
            if i == n {
                // Exactly on the last reading, or beyond it.
                return (times[n - 1] == t).then(|| unwrapped[n - 1]).flatten();
            }
            let (t0, t1) = (times[i - 1], times[i]);
            let (a, b) = (unwrapped[i - 1]?, unwrapped[i]?);
            let f = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 };
            Some(a + f * (b - a))
        })
        .collect()
}

/// The heading stream corrected for `offset_s`: at each encoder time `t`, the heading read at
/// `t + offset_s` ([`unwrapped_heading_at`], wrapped again); `None` beyond the readings or
/// next to a missing one.
pub fn shift_heading(
    times_s: &[f64],
    heading_rad: &[Option<f64>],
    offset_s: f64,
) -> Vec<Option<f64>> {
    let at: Vec<f64> = times_s.iter().map(|t| t + offset_s).collect();
    unwrapped_heading_at(times_s, heading_rad, &at)
        .into_iter()
        .map(|h| h.map(wrap_angle))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A robot turning left and right in bursts, sampled at 50 Hz; the heading stream shows the
    /// heading `delay_s` late and 5 % larger turns (a wrong `E_b` must not matter).
    fn series(delay_s: f64) -> (Vec<f64>, Vec<f64>, Vec<Option<f64>>) {
        // The integral of a turn rate 0.8·sin(0.7t) + 0.4·sin(1.9t) rad/s.
        let heading =
            |t: f64| 0.8 / 0.7 * (1.0 - (0.7 * t).cos()) + 0.4 / 1.9 * (1.0 - (1.9 * t).cos());
        let dt = 0.02;
        let times: Vec<f64> = (0..3000).map(|i| f64::from(i) * dt).collect();
        let odo: Vec<f64> = times
            .iter()
            .map(|&t| {
                if t == 0.0 {
                    0.0
                } else {
                    heading(t) - heading(t - dt)
                }
            })
            .collect();
        let head = times
            .iter()
            .map(|&t| Some(wrap_angle(1.05 * heading((t - delay_s).max(0.0)) + 0.3)))
            .collect();
        (times, odo, head)
    }

    #[test]
    fn a_heading_stream_three_tenths_of_a_second_late_is_found_and_corrected() {
        let (t, odo, head) = series(0.3);
        let found = estimate_time_offset(&t, &odo, &head, 1.0).unwrap();
        assert!((found.offset_s - 0.3).abs() < 0.01, "{found:?}");
        assert!(found.significant());
        assert!(found.correlation > found.correlation_at_zero);
        let fixed = shift_heading(&t, &head, found.offset_s);
        let again = estimate_time_offset(&t, &odo, &fixed, 1.0).unwrap();
        assert!(again.offset_s.abs() < 0.01, "{again:?}");
        assert!(!again.significant());
        // The end of the corrected stream has no reading to take: none is invented.
        assert_eq!(fixed.last(), Some(&None));
    }

    #[test]
    fn aligned_streams_read_zero_and_a_stream_ahead_reads_negative() {
        let (t, odo, head) = series(0.0);
        let found = estimate_time_offset(&t, &odo, &head, 1.0).unwrap();
        assert!(found.offset_s.abs() < 0.005, "{found:?}");
        // The heading stream 0.2 s early: readings shifted back in time.
        let early = shift_heading(&t, &head, 0.2);
        let found = estimate_time_offset(&t, &odo, &early, 1.0).unwrap();
        assert!((found.offset_s + 0.2).abs() < 0.01, "{found:?}");
    }

    #[test]
    fn straight_driving_cannot_tell_an_offset() {
        let t: Vec<f64> = (0..500).map(|i| f64::from(i) * 0.02).collect();
        let odo = vec![0.0; 500];
        let head = vec![Some(0.1); 500];
        assert_eq!(estimate_time_offset(&t, &odo, &head, 1.0), None);
        assert_eq!(
            estimate_time_offset(&t[..2], &odo[..2], &head[..2], 1.0),
            None
        );
    }
}
