//! One motor channel of the mock controller: its running command (a speed, a duty, a leg of a
//! buffered distance command), the queue of legs behind it, and each physics step's wheel speed
//! and duty under that command.

use super::*;

/// One buffered distance command of one motor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Leg {
    /// ±1.
    pub(super) direction: f64,
    /// Top speed (counts/s).
    pub(super) speed: f64,
    /// Acceleration and braking (counts/s²).
    pub(super) accel: f64,
    /// Counts to travel.
    pub(super) distance: f64,
}

impl Leg {
    pub(super) fn new(speed: i32, distance: u32, accel: f64) -> Self {
        Leg {
            direction: if speed < 0 { -1.0 } else { 1.0 },
            speed: f64::from(speed.unsigned_abs()),
            // A zero acceleration would never arrive; the slowest that does.
            accel: accel.max(1.0),
            distance: f64::from(distance),
        }
    }
}

/// What a motor is doing.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(super) enum Running {
    /// Nothing: the motor stands.
    #[default]
    Idle,
    /// A speed command: this signed speed (counts/s) until another command.
    Speed { target: f64, accel: f64 },
    /// A duty command: this signed fraction of full duty (open loop, QPPS at full duty).
    Duty { duty: f64 },
    /// A buffered distance command with the counts still to go.
    Leg { leg: Leg, remaining: f64 },
}

/// One motor channel.
#[derive(Debug, Clone, Default)]
pub(super) struct Motor {
    /// Encoder position; the controller's register is its low 32 bits.
    pub(super) counter: f64,
    /// Speed (counts/s, signed).
    pub(super) speed: f64,
    pub(super) running: Running,
    /// Buffered commands waiting behind the running one.
    pub(super) queue: VecDeque<Leg>,
    /// The register wrapped below zero since the status was last read.
    pub(super) underflow: bool,
    /// The register wrapped above 2³²−1 since the status was last read.
    pub(super) overflow: bool,
}

impl Motor {
    pub(super) fn register(&self) -> u32 {
        (self.counter.round() as i64) as u32
    }

    pub(super) fn moving(&self) -> bool {
        self.speed != 0.0
            || match self.running {
                Running::Idle => false,
                Running::Speed { target, .. } => target != 0.0,
                Running::Duty { duty } => duty != 0.0,
                Running::Leg { .. } => true,
            }
    }

    pub(super) fn stop(&mut self) {
        self.speed = 0.0;
        self.running = Running::Idle;
        self.queue.clear();
    }

    /// A command that is not buffered: it replaces whatever runs and empties the buffer.
    pub(super) fn command(&mut self, running: Running) {
        self.queue.clear();
        self.running = running;
    }

    pub(super) fn runs_leg(&self) -> bool {
        matches!(self.running, Running::Leg { .. })
    }

    /// Whether a buffered command would be taken now.
    pub(super) fn takes(&self, replace: bool) -> bool {
        replace || !self.runs_leg() || self.queue.len() < BUFFER_DEPTH
    }

    /// A buffered command: queued behind a running one (flag 0), or replacing it and the
    /// queue (flag 1); it starts at once when no buffered command runs.
    pub(super) fn buffer(&mut self, leg: Leg, replace: bool) {
        // A speed or duty command never finishes, so a leg queued behind one would never run:
        // the manual's "executes immediately if no other command … is executing" is read as
        // no *buffered* command, which is also what 47 reports (0x80) under a speed command.
        if replace || !self.runs_leg() {
            self.queue.clear();
            self.start(leg);
        } else {
            self.queue.push_back(leg);
        }
    }

    /// Starts `leg`, or, if it goes nowhere, the next one waiting.
    pub(super) fn start(&mut self, leg: Leg) {
        let mut next = Some(leg);
        while let Some(leg) = next {
            if leg.distance > 0.0 && leg.speed > 0.0 {
                self.running = Running::Leg {
                    leg,
                    remaining: leg.distance,
                };
                return;
            }
            next = self.queue.pop_front();
        }
        self.running = Running::Idle;
        self.speed = 0.0;
    }

    /// The buffer length as command 47 reports it: 0x80 when no buffered command runs, else
    /// how many wait behind the running one.
    pub(super) fn buffer_length(&self) -> u8 {
        if self.runs_leg() {
            self.queue.len().min(usize::from(u8::MAX)) as u8
        } else {
            BUFFER_IDLE
        }
    }

    /// The duty applied, ±1.
    pub(super) fn duty(&self, qpps: f64) -> f64 {
        match self.running {
            Running::Duty { duty } => duty,
            _ => self.speed / qpps.max(1.0),
        }
        .clamp(-1.0, 1.0)
    }

    /// Moves by `dt` seconds; returns the counts turned.
    pub(super) fn step(&mut self, dt: f64, qpps: f64) -> f64 {
        let before = self.counter;
        match self.running {
            Running::Idle => self.speed = 0.0,
            Running::Speed { target, accel } => {
                let v = self.speed;
                let v1 = v + (target - v).clamp(-accel * dt, accel * dt);
                self.counter += 0.5 * (v + v1) * dt;
                self.speed = v1;
            }
            Running::Duty { duty } => {
                self.speed = duty * qpps;
                self.counter += self.speed * dt;
            }
            Running::Leg { leg, remaining } => {
                // Trapezoid: accelerate to the top speed, brake to stop on the distance (a
                // queued leg starts from rest, where the controller may blend them); a motor
                // turning the other way is taken as standing.
                let v = (self.speed * leg.direction).max(0.0);
                let brake = (2.0 * leg.accel * remaining).sqrt();
                let v1 = (v + leg.accel * dt).min(leg.speed).min(brake).max(0.0);
                let step = (0.5 * (v + v1) * dt).min(remaining);
                let remaining = remaining - step;
                self.counter += leg.direction * step;
                self.speed = leg.direction * v1;
                if remaining <= 1e-9 {
                    self.speed = 0.0;
                    self.running = Running::Idle;
                    if let Some(next) = self.queue.pop_front() {
                        self.start(next);
                    }
                } else {
                    self.running = Running::Leg { leg, remaining };
                }
            }
        }
        let wraps = |c: f64| (c.round() as i64).div_euclid(1 << 32);
        match wraps(self.counter).cmp(&wraps(before)) {
            std::cmp::Ordering::Less => self.underflow = true,
            std::cmp::Ordering::Greater => self.overflow = true,
            std::cmp::Ordering::Equal => {}
        }
        self.counter - before
    }
}
