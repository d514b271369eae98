//! A board of perfect motors, for tests, harnesses and examples: [`IdealWheels`] turn at the
//! commanded speed and stop exactly on their targets; [`IdealBoard`] adds a robot of exactly
//! the given geometry (its heading integrated from the wheels), a clock the caller moves
//! ([`SimulatedBoard`]) and no noise. Simulators with physics of their own reuse
//! [`IdealWheels`] and feed its wheel travel to their model.

use super::{Board, DriveCommand, HeadingReading, SimulatedBoard};
use crate::message::ParamsBlock;
use core::f64::consts::PI;

#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Wheel {
    speed_counts_s: f64,
    /// Where the wheel stops (exact counts, in the positions the caller passes); `None`: no
    /// target.
    target: Option<f64>,
}

/// Two wheels that do exactly what [`Board::drive`] asks: turn at the commanded speed and stop
/// on the encoder target, to the fraction of a count.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct IdealWheels {
    wheels: [Wheel; 2],
}

/// The encoder reading (wrapping `i32`) of an exact wheel position in counts.
pub fn encoder_reading(position_counts: f64) -> i32 {
    // Cumulative counters wrap modulo 2^32 on the wire (SPEC.md §4).
    libm::round(position_counts) as i64 as i32
}

impl IdealWheels {
    /// Takes `command`, the wheels being at `position` (exact counts, left and right; the
    /// encoders read their rounding, [`encoder_reading`]).
    pub fn command(&mut self, command: &DriveCommand, position: [f64; 2]) {
        for (w, (drive, pos)) in self
            .wheels
            .iter_mut()
            .zip([command.left, command.right].iter().zip(position))
        {
            w.speed_counts_s = drive.speed_counts_s;
            w.target = drive.stop_at.map(|target| {
                libm::round(pos) + f64::from(target.wrapping_sub(encoder_reading(pos)))
            });
        }
    }

    /// Stops both wheels at once (and forgets their targets: call it when the positions are
    /// reset too).
    pub fn stop(&mut self) {
        self.wheels = [Wheel::default(); 2];
    }

    /// Whether both wheels stand still at `position`.
    pub fn at_rest(&self, position: [f64; 2]) -> bool {
        self.wheels
            .iter()
            .zip(position)
            .all(|(w, p)| w.speed_counts_s == 0.0 || w.target == Some(p))
    }

    /// The wheels' positions after turning for `dt_s` seconds from `position`: a wheel that
    /// reaches its target stops exactly on it.
    pub fn step(&self, dt_s: f64, position: [f64; 2]) -> [f64; 2] {
        let mut out = position;
        for (w, p) in self.wheels.iter().zip(out.iter_mut()) {
            let moved = *p + w.speed_counts_s * dt_s.max(0.0);
            *p = match w.target {
                // Never past the target, never away from it.
                Some(t) if (t - *p) * w.speed_counts_s <= 0.0 => *p,
                Some(t) if (moved - t) * w.speed_counts_s >= 0.0 => t,
                _ => moved,
            };
        }
        out
    }
}

/// A perfect robot of exactly the geometry it is given, its clock moved by the caller.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IdealBoard {
    now_us: u64,
    wheels: IdealWheels,
    position: [f64; 2],
    heading_rad: f64,
    m_per_count: [f64; 2],
    wheelbase_m: f64,
    /// Device seconds per second of the host's clock (see [`IdealBoard::with_host_time_scale`]).
    host_time_scale: f64,
}

impl IdealBoard {
    /// A robot whose true wheels and wheelbase are `robot`'s, at rest, heading 0, clock 0.
    pub fn new(robot: &ParamsBlock) -> Self {
        let si = robot.to_si();
        IdealBoard {
            now_us: 0,
            wheels: IdealWheels::default(),
            position: [0.0; 2],
            heading_rad: 0.0,
            m_per_count: [
                PI * si.left_wheel_diameter_m / si.counts_per_wheel_rev,
                PI * si.right_wheel_diameter_m / si.counts_per_wheel_rev,
            ],
            wheelbase_m: si.wheelbase_m,
            host_time_scale: 1.0,
        }
    }

    /// The same board for a host whose clock runs `scale` times slower than this board's (a
    /// simulation in sped-up time): watchdog timeouts, which measure host silence, stretch by
    /// it. Ignored unless finite and positive.
    pub fn with_host_time_scale(mut self, scale: f64) -> Self {
        if scale.is_finite() && scale > 0.0 {
            self.host_time_scale = scale;
        }
        self
    }

    /// The board's clock (µs).
    pub fn now(&self) -> u64 {
        self.now_us
    }

    /// Each wheel's exact position (counts since the last encoder reset).
    pub fn position_counts(&self) -> [f64; 2] {
        self.position
    }

    /// The robot's heading (rad, counter-clockwise positive, not wrapped).
    pub fn heading_rad(&self) -> f64 {
        self.heading_rad
    }
}

/// `angle` wrapped to (−π, π].
fn wrap(angle: f64) -> f64 {
    let r = libm::remainder(angle, 2.0 * PI);
    if r <= -PI {
        r + 2.0 * PI
    } else {
        r
    }
}

impl Board for IdealBoard {
    fn now_us(&mut self) -> u64 {
        self.now_us
    }

    fn drive(&mut self, command: &DriveCommand) {
        self.wheels.command(command, self.position);
    }

    fn stop(&mut self) {
        self.wheels.stop();
    }

    fn at_rest(&mut self) -> bool {
        self.wheels.at_rest(self.position)
    }

    fn encoders(&mut self) -> (i32, i32) {
        (
            encoder_reading(self.position[0]),
            encoder_reading(self.position[1]),
        )
    }

    fn reset_encoders(&mut self) {
        // Only while idle (SPEC.md §7.10): targets held in the old positions are dropped.
        self.wheels.stop();
        self.position = [0.0; 2];
    }

    fn heading(&mut self) -> HeadingReading {
        HeadingReading {
            heading_urad: libm::round(wrap(self.heading_rad) * 1e6) as i32,
            valid: true,
            sensor_status: 1,
        }
    }

    fn watchdog_timeout_us(&self, timeout_ms: u16) -> u64 {
        libm::round(f64::from(timeout_ms) * 1000.0 * self.host_time_scale) as u64
    }
}

impl SimulatedBoard for IdealBoard {
    fn advance_to(&mut self, now_us: u64) {
        let dt_s = now_us.saturating_sub(self.now_us) as f64 * 1e-6;
        let before = self.position;
        self.position = self.wheels.step(dt_s, before);
        let arcs = [
            (self.position[0] - before[0]) * self.m_per_count[0],
            (self.position[1] - before[1]) * self.m_per_count[1],
        ];
        // The turn of a differential drive: the wheels' arc difference over the wheelbase.
        self.heading_rad += (arcs[1] - arcs[0]) / self.wheelbase_m;
        self.now_us = self.now_us.max(now_us);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::WheelDrive;

    #[test]
    fn ideal_wheels_stop_exactly_on_their_targets_whatever_the_steps() {
        let mut w = IdealWheels::default();
        let drive = |speed, stop_at| WheelDrive {
            speed_counts_s: speed,
            stop_at,
        };
        w.command(
            &DriveCommand {
                motion_id: 1,
                left: drive(100.0, Some(681)),
                right: drive(-50.0, Some(-300)),
            },
            [0.4, 0.0],
        );
        let mut pos = [0.4, 0.0];
        for _ in 0..1000 {
            pos = w.step(0.0137, pos);
        }
        assert_eq!(pos, [681.0, -300.0]);
        assert!(w.at_rest(pos));
        assert_eq!(encoder_reading(pos[0]), 681);
    }
}
