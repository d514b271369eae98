//! Errors of the calibration layer.

use super::Method;
use crate::kinematics::{Direction, KinematicsError};

/// Errors of the calibration layer: input no real test can produce, or an estimate that is not a
/// robot.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibrationError {
    /// A direction has no runs.
    #[error("no {0} runs: a square test needs at least one run in each direction")]
    NoRuns(Direction),
    /// A number is NaN or infinite.
    #[error("{what} of {direction} run {} is not finite", index + 1)]
    NonFinite {
        /// Which quantity.
        what: &'static str,
        /// Direction of the run.
        direction: Direction,
        /// 0-based run index.
        index: usize,
    },
    /// A heading error beyond 180° was not wrapped: a unit or sign mistake.
    #[error("{direction} run {}: heading error {degrees:.2}° is beyond ±180°; heading errors are wrapped: check the units (degrees vs radians)", index + 1)]
    HeadingTooLarge {
        /// Direction of the run.
        direction: Direction,
        /// 0-based run index.
        index: usize,
        /// The error in degrees.
        degrees: f64,
    },
    /// A final position farther from the start than the square's perimeter.
    #[error("{direction} run {}: its final position is {} m from the start, farther than the square's whole perimeter ({} m): not a square run; check the units (metres) and the signs", index + 1, if *distance_m < 1e6 { format!("{distance_m:.3}") } else { format!("{distance_m:.3e}") }, 4.0 * side_m)]
    FarEndPoint {
        /// Direction of the run.
        direction: Direction,
        /// Index within its direction (0-based).
        index: usize,
        /// Distance of the final position from the start (m).
        distance_m: f64,
        /// The square's side (m).
        side_m: f64,
    },
    /// Some runs give final positions and others do not.
    #[error(
        "final positions must be given for every run or for none ({with} of {total} have one)"
    )]
    InconsistentPositions {
        /// Runs that have a position.
        with: usize,
        /// All runs.
        total: usize,
    },
    /// The side or wheelbase is not a positive length.
    #[error("{name} must be finite and > 0, got {value}")]
    BadGeometry {
        /// Which length.
        name: &'static str,
        /// Its value.
        value: f64,
    },
    /// A position-based method was asked for without final positions.
    #[error("method {0} needs the final positions of every run")]
    MissingPositions(Method),
    /// The measurements imply an impossible robot (e.g. a non-positive wheel diameter).
    #[error("method {method}: {reason}")]
    NotPhysical {
        /// The method.
        method: Method,
        /// What went wrong.
        reason: String,
    },
    /// The leg-aware method was asked for without the heading along the legs.
    #[error("method legs needs the heading along the legs of every run (a heading stream during the runs)")]
    MissingLegHeadings,
    /// The online filter was given too little to estimate from.
    #[error("too little data: {distance_m:.2} m driven and {heading_updates} heading reading(s) or reference pose(s) used; drive at least half a metre, with turns both ways, while the reference is read")]
    TooLittleData {
        /// Distance driven (m).
        distance_m: f64,
        /// Heading readings and reference poses used.
        heading_updates: u64,
    },
    /// The estimate could not be turned into parameters.
    #[error(transparent)]
    Kinematics(#[from] KinematicsError),
    /// A drive with a pose reference that cannot be fitted as given: too short, streams that
    /// do not overlap, a reference in another convention. The text says what to do.
    #[error("{0}")]
    PoseInput(String),
    /// The drive did not observe parameters that would be written: what to drive instead.
    #[error("the drive did not observe {parameters}: {advice}")]
    NotObserved {
        /// The parameters, named as in the report.
        parameters: String,
        /// What to drive so that they are observed.
        advice: String,
    },
    /// A pose reference made from the wheels it is to calibrate (the controller's odometry, a
    /// filter fusing the wheels): it can give back only what the wheels were integrated with.
    /// The text names what it is, the figures that say so, and what to give instead.
    #[error("{0}")]
    ReferenceFromWheels(String),
    /// The reference's turns follow the wheels' by more than the time offset the fit searches.
    #[error(
        "the reference's turns follow the wheels' {:.2} s {} (turn-rate correlation \
         {correlation:.2} there, {correlation_at_zero:.2} at none), beyond the ±{searched_s:.2} s \
         the fit searches: give --max-time-offset-s {:.1} (or stamp both streams with one \
         clock) and fit again",
        delay_s.abs(),
        if *delay_s > 0.0 { "later" } else { "earlier" },
        (delay_s.abs() + 0.5).ceil()
    )]
    DelayBeyondSearch {
        /// The delay the turn rates show (s, positive: the reference is late).
        delay_s: f64,
        /// The turn rates' correlation at that delay.
        correlation: f64,
        /// Their correlation at no delay.
        correlation_at_zero: f64,
        /// The largest offset the fit searches (s).
        searched_s: f64,
    },
    /// A number given is outside what the computation can take (the flag or field is named).
    #[error("{0}")]
    OutOfRange(String),
    /// The request is valid but not supported by this computation.
    #[error("unsupported: {0}")]
    Unsupported(String),
}
