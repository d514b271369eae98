//! What a user is shown of a run's progress: the robot time counted against the time planned
//! (at the speed limits, so an ETA is the robot's), and the words for each [`RoutineEvent`].
//! A front end keeps a [`RobotClock`] and draws what [`RobotClock::update`] returns: a line, or
//! a progress bar's new length, message and position (the bar itself is the front end's).

use super::RoutineEvent;
use crate::calibration::plan::duration_text;

/// Robot time of the phase under way: counted so far, and planned (extensions included).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RobotClock {
    /// Robot time of the motions finished in this phase (s).
    pub counted_s: f64,
    /// Robot time this phase plans at the speed limits (s).
    pub planned_s: f64,
    /// The same to the tenth of a second per plan and extension, as a bar counts it (s): the
    /// total a bar shows.
    pub bar_s: f64,
}

/// What to show for one event.
#[derive(Debug, Clone, PartialEq)]
pub enum Shown {
    /// A line, always.
    Line(String),
    /// A line when no progress bar shows the same (a square done, a realignment).
    Step(String),
    /// A new phase of this much robot time (s): a new bar.
    Phase(f64),
    /// The phase grows by this much robot time (s).
    Extend(f64),
    /// A motion finished: the bar's message, its prefix (robot time so far of planned), and
    /// its position (s of robot time).
    Motion {
        /// What is being driven.
        message: String,
        /// Robot time counted of planned.
        prefix: String,
        /// Robot time counted (s).
        position_s: f64,
    },
    /// Nothing to show (the run's ending is said with its error, last).
    Nothing,
}

/// `s` to the tenth of a second, as a bar counts it: the total shown is the bar's.
fn tenths(s: f64) -> f64 {
    (s * 10.0).round() / 10.0
}

impl RobotClock {
    /// Counts `event` and says what to show for it.
    pub fn update(&mut self, event: &RoutineEvent) -> Shown {
        match event {
            RoutineEvent::Stage(s) => Shown::Line(format!("· {s}")),
            RoutineEvent::Warning(w) => Shown::Line(format!("warning: {w}")),
            RoutineEvent::Plan { robot_time_s, .. } => {
                *self = RobotClock {
                    counted_s: 0.0,
                    planned_s: *robot_time_s,
                    bar_s: tenths(*robot_time_s),
                };
                Shown::Phase(*robot_time_s)
            }
            RoutineEvent::Extend { robot_time_s, .. } => {
                self.planned_s += robot_time_s;
                self.bar_s += tenths(*robot_time_s);
                Shown::Extend(*robot_time_s)
            }
            RoutineEvent::Motion {
                phase,
                run,
                of,
                direction,
                motion,
                duration_s,
            } => {
                self.counted_s += duration_s;
                let what = if motion % 2 == 1 { "leg" } else { "turn" };
                Shown::Motion {
                    message: format!(
                        "{phase}: run {run}/{of} {direction}, {what} {}/4",
                        motion.div_ceil(2)
                    ),
                    prefix: format!(
                        "{} of {}",
                        duration_text(self.counted_s),
                        duration_text(self.bar_s)
                    ),
                    position_s: self.counted_s,
                }
            }
            RoutineEvent::Realigned {
                turn_rad, left_rad, ..
            } => Shown::Step(format!(
                "  turned {:+.2}° back to the first square's heading ({:.2}° off now)",
                turn_rad.to_degrees(),
                left_rad.abs().to_degrees()
            )),
            RoutineEvent::RunDone {
                phase,
                run,
                of,
                direction,
                heading_error_deg,
            } => Shown::Step(format!(
                "  {phase}: square {run} of {of} ({direction}) done, heading error \
                 {heading_error_deg:+.3}° · robot time {} so far, about {} left in this phase",
                duration_text(self.counted_s),
                duration_text((self.planned_s - self.counted_s).max(0.0))
            )),
            RoutineEvent::Ended(_) => Shown::Nothing,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::Direction;
    use crate::routine::report::Phase;

    #[test]
    fn robot_time_is_counted_against_the_plan_and_its_extensions() {
        let mut clock = RobotClock::default();
        let plan = RoutineEvent::Plan {
            motions: 8,
            robot_time_s: 100.0,
        };
        assert_eq!(clock.update(&plan), Shown::Phase(100.0));
        let motion = RoutineEvent::Motion {
            phase: Phase::Calibration { round: 1 },
            run: 1,
            of: 2,
            direction: Direction::Cw,
            motion: 3,
            duration_s: 30.0,
        };
        match clock.update(&motion) {
            Shown::Motion {
                message,
                prefix,
                position_s,
            } => {
                assert_eq!(message, "round 1: run 1/2 clockwise, leg 2/4");
                assert_eq!(prefix, "30 s of 1 min 40 s");
                assert_eq!(position_s, 30.0);
            }
            other => panic!("{other:?}"),
        }
        let more = RoutineEvent::Extend {
            motions: 8,
            robot_time_s: 50.0,
        };
        assert_eq!(clock.update(&more), Shown::Extend(50.0));
        let done = RoutineEvent::RunDone {
            phase: Phase::Calibration { round: 1 },
            run: 1,
            of: 2,
            direction: Direction::Cw,
            heading_error_deg: -1.25,
        };
        match clock.update(&done) {
            Shown::Step(line) => assert!(
                line.contains("heading error -1.250°") && line.contains("about 2 min left"),
                "{line}"
            ),
            other => panic!("{other:?}"),
        }
        // A new phase starts its count again.
        clock.update(&plan);
        assert_eq!(clock.counted_s, 0.0);
    }
}
