//! The telemetry schedule of SPEC.md §5 (0x50, 0x51): the period, when the next sample is
//! due, and the sample index, which counts every sample due whether or not it was sent.

/// When telemetry samples are due, and their index.
#[derive(Debug, Clone, Copy, Default)]
pub struct TelemetrySchedule {
    period_us: u64,
    next_us: u64,
    sample_index: u32,
}

impl TelemetrySchedule {
    /// Off (power-up).
    pub const fn new() -> Self {
        TelemetrySchedule {
            period_us: 0,
            next_us: 0,
            sample_index: 0,
        }
    }

    /// CONFIGURE_TELEMETRY: `period_us` 0 turns it off; otherwise the first sample is due now.
    pub fn configure(&mut self, period_us: u64, now_us: u64) {
        self.period_us = period_us;
        self.next_us = now_us;
    }

    /// When the next sample is due, if telemetry is on.
    pub fn next_due_us(&self) -> Option<u64> {
        (self.period_us > 0).then_some(self.next_us)
    }

    /// If a sample is due at `now_us`, its index; the schedule moves on by one period. Periods
    /// missed entirely (a device that polled late) use up their indices, so the host counts
    /// them as lost.
    pub fn take(&mut self, now_us: u64) -> Option<u32> {
        if self.period_us == 0 || now_us < self.next_us {
            return None;
        }
        let missed = (now_us - self.next_us) / self.period_us;
        // The index wraps modulo 2^32 like every counter on the wire.
        self.sample_index = self.sample_index.wrapping_add(missed as u32);
        self.next_us += (missed + 1) * self.period_us;
        let index = self.sample_index;
        self.sample_index = self.sample_index.wrapping_add(1);
        Some(index)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_are_due_each_period_and_missed_ones_use_up_their_index() {
        let mut t = TelemetrySchedule::new();
        assert_eq!(t.take(0), None, "off");
        t.configure(5_000, 1_000);
        assert_eq!(t.take(999), None);
        assert_eq!(t.take(1_000), Some(0));
        assert_eq!(t.take(5_999), None);
        assert_eq!(t.next_due_us(), Some(6_000));
        assert_eq!(t.take(6_000), Some(1));
        // Polled 12 ms late: the two samples due meanwhile are lost.
        assert_eq!(t.take(23_000), Some(4));
        assert_eq!(t.next_due_us(), Some(26_000));
        t.configure(0, 30_000);
        assert_eq!(t.take(100_000), None);
    }
}
