//! [`Fanout`]: one source, any number of sample streams, for backends whose samples arrive
//! once and go to every subscriber (travel, headings).

use super::{SampleStream, STREAM_CAPACITY};
use std::sync::{Arc, Mutex};
use tokio::sync::mpsc;

/// The subscribers of one source; cheap to clone, all clones share them.
#[derive(Debug)]
pub struct Fanout<T> {
    subs: Arc<Mutex<Vec<mpsc::Sender<T>>>>,
}

impl<T> Clone for Fanout<T> {
    fn clone(&self) -> Self {
        Fanout {
            subs: self.subs.clone(),
        }
    }
}

impl<T> Default for Fanout<T> {
    fn default() -> Self {
        Fanout {
            subs: Arc::default(),
        }
    }
}

impl<T: Clone> Fanout<T> {
    /// A new stream of every sample from now on.
    pub fn subscribe(&self) -> SampleStream<T> {
        let (tx, rx) = mpsc::channel(STREAM_CAPACITY);
        self.subs.lock().unwrap_or_else(|p| p.into_inner()).push(tx);
        rx
    }

    /// Hands `v` to every live stream; a stream whose reader is gone is dropped, and one whose
    /// reader lags [`STREAM_CAPACITY`] samples behind misses this one rather than growing.
    pub fn send(&self, v: &T) {
        let mut subs = self.subs.lock().unwrap_or_else(|p| p.into_inner());
        subs.retain(|tx| !tx.is_closed());
        for tx in subs.iter() {
            let _ = tx.try_send(v.clone());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_live_stream_gets_every_sample_and_dropped_ones_are_forgotten() {
        let f = Fanout::<u32>::default();
        let mut a = f.subscribe();
        let b = f.subscribe();
        f.send(&1);
        drop(b);
        f.send(&2);
        assert_eq!((a.try_recv(), a.try_recv()), (Ok(1), Ok(2)));
        assert_eq!(f.subs.lock().unwrap().len(), 1);
    }
}
