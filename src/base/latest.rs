//! The newest reading of a heading sensor that streams on its own (a compass's sentences, a ROS
//! IMU topic), and the one rule for reading it: a reading is *fresh* when it arrived after the
//! read was asked for, so a heading "at rest" is never one taken before the robot stopped, and
//! ten reads at rest are ten readings, not one cached reading ten times.
//!
//! A backend's reader task holds the [`Publisher`] and stamps each reading with its arrival;
//! the backend's [`super::HeadingSource::read`] asks [`Latest::read_after`] and says, in its
//! own words, why a stale or closed stream gave nothing.

use super::HeadingSample;
use std::time::Duration;
use tokio::sync::watch;
use tokio::time::Instant;

/// The newest reading and when it arrived (`None` before the first).
pub type Stamped = Option<(Instant, HeadingSample)>;

/// What a reader task publishes into.
#[derive(Debug)]
pub struct Publisher(watch::Sender<Stamped>);

/// The newest reading, as the heading source reads it.
#[derive(Debug, Clone)]
pub struct Latest(watch::Receiver<Stamped>);

/// A publisher and its reader, with no reading yet.
pub fn channel() -> (Publisher, Latest) {
    let (tx, rx) = watch::channel(None);
    (Publisher(tx), Latest(rx))
}

/// What [`Latest::read_after`] found.
#[derive(Debug, Clone, PartialEq)]
pub enum Fresh {
    /// A reading that arrived after the call and passed the caller's test.
    Got(HeadingSample),
    /// The reader task ended (the port closed, the connection dropped).
    Closed,
    /// None arrived in time; the newest there was, if any.
    Stale(Option<HeadingSample>),
}

impl Publisher {
    /// Publishes `sample`, which arrived `at`; `false` when no one reads any more.
    pub fn publish(&self, at: Instant, sample: HeadingSample) -> bool {
        self.0.send(Some((at, sample))).is_ok()
    }
}

impl Latest {
    /// The first reading that arrived strictly after `asked` and passes `also`, waiting at
    /// most `wait`. Strictly after: under a clock that does not move between two calls (a
    /// paused test clock, a coarse timer) one reading must not be read twice.
    pub async fn read_after(
        &self,
        asked: Instant,
        wait: Duration,
        also: impl Fn(&HeadingSample) -> bool,
    ) -> Fresh {
        let mut rx = self.0.clone();
        let waited = tokio::time::timeout(
            wait,
            rx.wait_for(|h| h.as_ref().is_some_and(|(at, s)| *at > asked && also(s))),
        )
        .await;
        // The `Ref` a wait returns holds the channel's lock: take the sample out at once.
        match waited {
            Ok(Ok(h)) => match h.as_ref() {
                Some((_, s)) => Fresh::Got(s.clone()),
                None => Fresh::Stale(None),
            },
            Ok(Err(_)) => Fresh::Closed,
            Err(_) => Fresh::Stale(self.last()),
        }
    }

    /// The newest reading, fresh or not.
    pub fn last(&self) -> Option<HeadingSample> {
        self.0.borrow().as_ref().map(|(_, s)| s.clone())
    }

    /// The channel, for a caller that waits for the first reading of all.
    pub fn receiver(&self) -> &watch::Receiver<Stamped> {
        &self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::Validity;

    fn sample(time_s: f64) -> HeadingSample {
        HeadingSample {
            time_s,
            heading_rad: 0.25,
            validity: Validity::Valid,
        }
    }

    #[tokio::test(start_paused = true)]
    async fn only_a_reading_after_the_call_is_fresh() {
        let (tx, latest) = channel();
        let wait = Duration::from_millis(100);
        // Nothing yet: stale, with nothing to show.
        let asked = Instant::now();
        assert_eq!(
            latest.read_after(asked, wait, |_| true).await,
            Fresh::Stale(None)
        );
        // A reading from before the call is not fresh, but is the newest there was.
        assert!(tx.publish(Instant::now(), sample(1.0)));
        let asked = Instant::now();
        assert_eq!(
            latest.read_after(asked, wait, |_| true).await,
            Fresh::Stale(Some(sample(1.0)))
        );
        // One that arrives while waiting is; the caller's test applies too.
        let asked = Instant::now();
        let publisher = async {
            tokio::time::sleep(Duration::from_millis(10)).await;
            tx.publish(Instant::now(), sample(2.0));
            tokio::time::sleep(Duration::from_millis(10)).await;
            tx.publish(Instant::now(), sample(3.0));
            tx
        };
        let (got, tx) = tokio::join!(
            latest.read_after(asked, wait, |s| s.time_s >= 3.0),
            publisher
        );
        assert_eq!(got, Fresh::Got(sample(3.0)));
        // The reader task gone: closed.
        drop(tx);
        assert_eq!(
            latest.read_after(Instant::now(), wait, |_| true).await,
            Fresh::Closed
        );
    }
}
