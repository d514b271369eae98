//! Motions on the device: a request's travel checked and turned into encoder counts, queued,
//! started on the board, watched until the wheels reach their targets, and the telemetry sent
//! meanwhile.

use super::*;

impl<B: Board, S: ParamStorage> Device<B, S> {
    /// Starts the front motion if it has not started, completes it once its time is over and
    /// both wheels read their targets, and so on down the queue.
    pub(super) fn run_queue(&mut self, now: u64, sink: &mut impl Sink) {
        // Each pass starts or completes one motion: a bounded number of passes.
        for _ in 0..=2 * QUEUE_CAPACITY {
            let Some(front) = self.queue.front().copied() else {
                self.running = None;
                return;
            };
            match self.running {
                Some(run) if run.id == front.id => {
                    if !self.finished(&run, now) {
                        return;
                    }
                    self.queue.pop_front();
                    self.running = None;
                    self.completed_motions = self.completed_motions.wrapping_add(1);
                    self.stats.motions_completed += 1;
                    let done = MotionDone {
                        motion_id: run.id,
                        completed_motions: self.completed_motions,
                    };
                    let seq = self.next_event_seq();
                    sink.send(&Packet::event(seq, Event::MotionDone(done)).to_frame());
                }
                _ => self.start(&front, now),
            }
        }
    }

    pub(super) fn start(&mut self, motion: &Planned, now: u64) {
        let (l, r) = self.board.encoders();
        let (left, right, run) = match motion.travel {
            Travel::Counts {
                left,
                right,
                duration_us,
            } => {
                let secs = duration_us.max(1) as f64 * 1e-6;
                let target = [l.wrapping_add(left), r.wrapping_add(right)];
                let wheel = |travel: i32, target: i32| WheelDrive {
                    speed_counts_s: f64::from(travel) / secs,
                    stop_at: Some(target),
                };
                (
                    wheel(left, target[0]),
                    wheel(right, target[1]),
                    Running {
                        id: motion.id,
                        end_us: Some(now.saturating_add(duration_us)),
                        travel: [left, right],
                        target,
                    },
                )
            }
            Travel::OpenEnded {
                left_counts_s,
                right_counts_s,
            } => {
                let wheel = |speed| WheelDrive {
                    speed_counts_s: speed,
                    stop_at: None,
                };
                (
                    wheel(left_counts_s),
                    wheel(right_counts_s),
                    Running {
                        id: motion.id,
                        end_us: None,
                        travel: [0, 0],
                        target: [l, r],
                    },
                )
            }
        };
        self.board.drive(&DriveCommand {
            motion_id: motion.id,
            left,
            right,
        });
        self.stopping = false;
        self.running = Some(run);
    }

    pub(super) fn finished(&mut self, run: &Running, now: u64) -> bool {
        let Some(end) = run.end_us else {
            return false;
        };
        if now < end {
            return false;
        }
        let (l, r) = self.board.encoders();
        reached(l, run.target[0], run.travel[0]) && reached(r, run.target[1], run.travel[1])
    }

    pub(super) fn send_telemetry(&mut self, sample_index: u32, now: u64, sink: &mut impl Sink) {
        if !sink.has_room() {
            self.stats.telemetry_unsent += 1;
            return;
        }
        let (left_counts, right_counts) = self.board.encoders();
        let status = self.status();
        let heading = self.board.heading();
        let sample = Telemetry {
            sample_index,
            timestamp_us: now as u32,
            left_counts,
            right_counts,
            heading_urad: heading.heading_urad,
            heading_valid: heading.valid,
            motion_state: status.motion_state,
            queue_depth: status.queue_depth,
        };
        let seq = self.next_event_seq();
        if sink.send(&Packet::event(seq, Event::Telemetry(sample)).to_frame()) {
            self.stats.telemetry_sent += 1;
        } else {
            self.stats.telemetry_unsent += 1;
        }
    }

    /// Refuses a parameter or odometry change unless the base is idle (SPEC.md §7.10).
    pub(super) fn require_idle(&mut self) -> Result<(), Nack> {
        if self.motion_state() == MotionState::Idle {
            Ok(())
        } else {
            refuse(NackCode::InvalidState, 0xFF)
        }
    }

    /// Each wheel's target (whole counts, halves away from zero) for these arcs (m) by the
    /// active parameters; `None` if one does not fit a signed 32-bit count.
    pub(super) fn counts(&self, arcs_m: [f64; 2]) -> Option<[i32; 2]> {
        let p = self.active.to_si();
        let per_count = [
            PI * p.left_wheel_diameter_m / p.counts_per_wheel_rev,
            PI * p.right_wheel_diameter_m / p.counts_per_wheel_rev,
        ];
        let mut out = [0i32; 2];
        for ((o, arc), m) in out.iter_mut().zip(arcs_m).zip(per_count) {
            let c = libm::round(arc / m);
            if !(c.is_finite() && libm::fabs(c) < 2_147_483_647.0) {
                return None;
            }
            *o = c as i32;
        }
        Some(out)
    }

    /// Queues (or, with `Replace`, runs at once) a motion whose fields passed their checks.
    pub(super) fn accept(
        &mut self,
        travel: Travel,
        mode: MotionMode,
    ) -> Result<MotionAccepted, Nack> {
        if self.watchdog.state() == WatchdogState::Tripped
            || self.fault_flags() & BLOCKING_FAULTS != 0
        {
            return refuse(NackCode::InvalidState, 0xFF);
        }
        if mode == MotionMode::Replace {
            self.queue.clear();
            self.running = None;
        }
        let planned = self
            .queue
            .push(travel)
            .or_else(|_| refuse(NackCode::Busy, 0xFF))?;
        self.stats.motions_accepted += 1;
        Ok(MotionAccepted {
            queue_depth: self.queue.len() as u8,
            motion_id: planned.id,
        })
    }

    /// Accepts a MOVE_STRAIGHT or TURN_IN_PLACE whose fields passed: wheel arcs (m), and its
    /// size (µm or µrad) at `rate` (mm/s or mrad/s), which gives its time.
    pub(super) fn accept_counts(
        &mut self,
        arcs_m: [f64; 2],
        size: u32,
        rate: u16,
        mode: MotionMode,
    ) -> Result<MotionAccepted, Nack> {
        let [left, right] = self.counts(arcs_m).ok_or(Nack {
            code: NackCode::OutOfRange,
            detail: 0,
        })?;
        let duration_us = (u64::from(size) * 1000).div_ceil(u64::from(rate.max(1)));
        let travel = Travel::Counts {
            left,
            right,
            duration_us,
        };
        self.accept(travel, mode)
    }
}

/// The executing motion, once started.
#[derive(Debug, Clone, Copy)]
pub(super) struct Running {
    pub(super) id: u16,
    /// When its commanded time is over (µs); `None`: open-ended.
    pub(super) end_us: Option<u64>,
    /// Each wheel's travel (counts) and target reading.
    pub(super) travel: [i32; 2],
    pub(super) target: [i32; 2],
}

/// The field checks of MOVE_STRAIGHT and TURN_IN_PLACE: the size (field 0) non-zero and at
/// most `max`, the speed or rate (field 1) non-zero and within the device's `limit`.
pub(super) fn motion_fields(size: u32, max: u32, rate: u16, limit: u16) -> Result<(), Nack> {
    if size == 0 || size > max {
        return refuse(NackCode::OutOfRange, 0);
    }
    if rate == 0 || rate > limit {
        return refuse(NackCode::OutOfRange, 1);
    }
    Ok(())
}

/// Whether a wheel that was to travel `travel` counts to `target` has reached it.
pub(super) fn reached(reading: i32, target: i32, travel: i32) -> bool {
    let past = reading.wrapping_sub(target);
    match travel {
        0 => true,
        t if t > 0 => past >= 0,
        _ => past <= 0,
    }
}
