//! Holes in a drive's streams: a stretch with no wheel sample or no reference pose, found from
//! each stream's own rate and named with its length and position, so that a fit over a dropped
//! bag chunk, a stalled driver or a lost localization says where its data are missing.
//!
//! A hole is an interval longer than [`HOLE_FACTOR`] times the stream's median interval and
//! longer than [`HOLE_MIN_S`]: a 1 Hz scan matcher's second is no hole, a 50 Hz encoder's is.

use super::pool::upper_median;
use super::pose_reference::PoseRecording;

/// Times a stream's median interval a gap must exceed to be a hole.
pub const HOLE_FACTOR: f64 = 10.0;
/// Shortest hole named (s).
pub const HOLE_MIN_S: f64 = 0.5;
/// Holes listed by position at most (the rest are counted).
const LISTED: usize = 3;

/// One hole in a stream.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hole {
    /// Its start, from the stream's first sample (s).
    pub at_s: f64,
    /// Its length (s).
    pub length_s: f64,
}

/// The holes in a stream of increasing stamps, with its median interval.
pub fn holes(stamps: &[f64]) -> (Vec<Hole>, f64) {
    let Some(&first) = stamps.first() else {
        return (Vec::new(), f64::NAN);
    };
    let gaps: Vec<f64> = stamps.windows(2).map(|w| w[1] - w[0]).collect();
    let Some(median) = upper_median(gaps.clone()) else {
        return (Vec::new(), f64::NAN);
    };
    let least = (HOLE_FACTOR * median).max(HOLE_MIN_S);
    let found = stamps
        .windows(2)
        .filter(|w| w[1] - w[0] > least)
        .map(|w| Hole {
            at_s: w[0] - first,
            length_s: w[1] - w[0],
        })
        .collect();
    (found, median)
}

/// A warning per stream of `recording` that has holes: how many, the longest listed with
/// their length and position.
pub fn hole_warnings(recording: &PoseRecording) -> Vec<String> {
    let wheels: Vec<f64> = recording.wheels.iter().map(|w| w.time_s).collect();
    let poses: Vec<f64> = recording.poses.iter().map(|p| p.time_s).collect();
    [("wheel", wheels), ("reference", poses)]
        .into_iter()
        .filter_map(|(name, stamps)| {
            let (mut found, median) = holes(&stamps);
            if found.is_empty() {
                return None;
            }
            let total: f64 = found.iter().map(|h| h.length_s).sum();
            let count = found.len();
            found.sort_by(|a, b| b.length_s.total_cmp(&a.length_s));
            let listed = found
                .iter()
                .take(LISTED)
                .map(|h| format!("{:.2} s at {:.1} s", h.length_s, h.at_s))
                .collect::<Vec<_>>()
                .join(", ");
            let more = if count > LISTED {
                format!(" and {} more", count - LISTED)
            } else {
                String::new()
            };
            Some(format!(
                "the {name} stream has {count} hole(s), {total:.1} s in all ({listed}{more}; \
                 from its first sample; it otherwise has a sample every {median:.3} s): the \
                 fit bridges them, but a dropped recording chunk or a stalled driver there \
                 loses what the robot did; check the recording"
            ))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hole_is_named_with_its_length_and_position_and_a_slow_stream_has_none() {
        let mut stamps: Vec<f64> = (0..500).map(|i| i as f64 * 0.02).collect();
        stamps.extend((0..500).map(|i| 13.0 + i as f64 * 0.02));
        let (found, median) = holes(&stamps);
        assert_eq!(found.len(), 1);
        assert!((found[0].at_s - 9.98).abs() < 1e-9, "{found:?}");
        assert!((found[0].length_s - 3.02).abs() < 1e-9, "{found:?}");
        assert!((median - 0.02).abs() < 1e-12);
        // A 1 Hz stream with a 13 s gap: a hole; its seconds are not.
        let slow: Vec<f64> = (0..100).map(f64::from).chain([112.0, 113.0]).collect();
        let (found, _) = holes(&slow);
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(holes(&(0..100).map(f64::from).collect::<Vec<_>>())
            .0
            .is_empty());
    }
}
