//! The watchdog of SPEC.md §5 (0x60) and §7.7: armed with a timeout, fed by every request
//! frame that passes the CRC, tripped when the host is silent for the timeout while the base
//! moves, and acknowledged by HEARTBEAT or CONFIGURE_WATCHDOG.

use crate::message::WatchdogState;

/// The watchdog's state and clock.
#[derive(Debug, Clone, Copy)]
pub struct Watchdog {
    state: WatchdogState,
    timeout_us: u64,
    last_feed_us: u64,
}

impl Default for Watchdog {
    fn default() -> Self {
        Self::new()
    }
}

impl Watchdog {
    /// Disabled (power-up).
    pub const fn new() -> Self {
        Watchdog {
            state: WatchdogState::Disabled,
            timeout_us: 0,
            last_feed_us: 0,
        }
    }

    /// Disabled, armed or tripped.
    pub fn state(&self) -> WatchdogState {
        self.state
    }

    /// Notes that the host spoke at `now_us` (a request frame passed the CRC).
    pub fn feed(&mut self, now_us: u64) {
        self.last_feed_us = now_us;
    }

    /// CONFIGURE_WATCHDOG: arms with `timeout_us` (0 disarms) and acknowledges a trip.
    pub fn configure(&mut self, timeout_us: u64, now_us: u64) {
        self.timeout_us = timeout_us;
        self.last_feed_us = now_us;
        self.state = if timeout_us == 0 {
            WatchdogState::Disabled
        } else {
            WatchdogState::Armed
        };
    }

    /// HEARTBEAT: acknowledges a trip (the watchdog is armed again).
    pub fn acknowledge(&mut self) {
        if self.state == WatchdogState::Tripped {
            self.state = WatchdogState::Armed;
        }
    }

    /// When the watchdog trips if the host stays silent and the base keeps `moving`.
    pub fn deadline_us(&self, moving: bool) -> Option<u64> {
        (self.state == WatchdogState::Armed && moving)
            .then(|| self.last_feed_us.saturating_add(self.timeout_us))
    }

    /// Trips the watchdog if its deadline has passed at `now_us`; returns whether it did (the
    /// caller then stops the base).
    pub fn check(&mut self, now_us: u64, moving: bool) -> bool {
        let expired = self.deadline_us(moving).is_some_and(|d| now_us >= d);
        if expired {
            self.state = WatchdogState::Tripped;
        }
        expired
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn it_trips_only_when_armed_moving_and_unfed_for_the_timeout() {
        let mut w = Watchdog::new();
        assert!(!w.check(1_000_000, true), "disabled");
        w.configure(100_000, 0);
        assert_eq!(w.state(), WatchdogState::Armed);
        assert!(!w.check(500_000, false), "idle: nothing to stop");
        assert!(!w.check(99_999, true));
        w.feed(90_000);
        assert!(!w.check(189_999, true), "fed at 90 ms");
        assert_eq!(w.deadline_us(true), Some(190_000));
        assert!(w.check(190_000, true));
        assert_eq!(w.state(), WatchdogState::Tripped);
        // Tripped: it does not trip again, and a heartbeat re-arms it.
        assert!(!w.check(10_000_000, true));
        w.acknowledge();
        assert_eq!(w.state(), WatchdogState::Armed);
        // CONFIGURE_WATCHDOG 0 acknowledges and disarms.
        w.check(u64::MAX, true);
        w.configure(0, 0);
        assert_eq!(w.state(), WatchdogState::Disabled);
        assert_eq!(w.deadline_us(true), None);
    }
}
