//! [`Adjusted`]: a heading source as the user knows it better than its backend does — its kind
//! declared, each reading corrected for a measured compass deviation (the curve a compass
//! swing fits, [`crate::calibration::swing`]) and for a gyro's measured scale error
//! ([`crate::calibration::gyro`]). The deviation depends on the reading alone; the scale
//! divides the heading's change since the first reading, which is unwrapped across every
//! reading (at rest and streamed alike; consecutive readings are far less than half a turn
//! apart).

use super::{
    BaseError, ComponentInfo, HeadingKind, HeadingSample, HeadingSource, SampleStream,
    STREAM_CAPACITY,
};
use crate::kinematics::{wrap_angle, Deviation};
use async_trait::async_trait;
use std::sync::{Arc, Mutex, RwLock};
use std::time::Duration;
use tokio::sync::mpsc;

/// A heading source with a declared kind, and a deviation and a gyro scale error removed
/// from its readings.
pub struct Adjusted {
    inner: Arc<dyn HeadingSource>,
    kind: Option<HeadingKind>,
    deviation: Arc<RwLock<Deviation>>,
    scale: Arc<Scale>,
}

/// A gyro's scale error and the unwrapped heading it divides.
#[derive(Default)]
struct Scale {
    error: f64,
    /// The first reading and the last, unwrapped from it (rad).
    unwrapped: Mutex<Option<(f64, f64)>>,
}

impl Scale {
    fn correct(&self, s: &mut HeadingSample) {
        if self.error == 0.0 || !s.validity.is_valid() {
            return;
        }
        let mut u = self.unwrapped.lock().unwrap_or_else(|p| p.into_inner());
        let (first, last) = match *u {
            None => (s.heading_rad, s.heading_rad),
            Some((first, last)) => (first, last + wrap_angle(s.heading_rad - last)),
        };
        *u = Some((first, last));
        s.heading_rad = wrap_angle(first + (last - first) / (1.0 + self.error));
    }
}

impl Adjusted {
    /// `inner`, declared to be of `kind` (when given), its readings corrected for `deviation`.
    pub fn new(
        inner: Arc<dyn HeadingSource>,
        kind: Option<HeadingKind>,
        deviation: Deviation,
    ) -> Self {
        Adjusted {
            inner,
            kind,
            deviation: Arc::new(RwLock::new(deviation)),
            scale: Arc::default(),
        }
    }

    /// The same with a gyro's scale error `s` removed (a gyro that reads `1 + s` times every
    /// turn).
    pub fn with_gyro_scale_error(mut self, s: f64) -> Self {
        self.scale = Arc::new(Scale {
            error: s,
            unwrapped: Mutex::new(None),
        });
        self
    }

    /// The deviation removed from every reading, shared: a swing that measures a new one sets
    /// it here and every reading from then on (streams already open included) is corrected by
    /// it.
    pub fn deviation(&self) -> Arc<RwLock<Deviation>> {
        self.deviation.clone()
    }
}

fn correct(s: &mut HeadingSample, deviation: &RwLock<Deviation>) {
    let d = *deviation.read().unwrap_or_else(|p| p.into_inner());
    if s.validity.is_valid() && !d.is_zero() {
        s.heading_rad = d.remove(s.heading_rad);
    }
}

#[async_trait]
impl HeadingSource for Adjusted {
    fn info(&self) -> ComponentInfo {
        let mut info = self.inner.info();
        let d = *self.deviation.read().unwrap_or_else(|p| p.into_inner());
        if !info.details.is_object() {
            info.details = serde_json::json!({ "backend": info.details });
        }
        if let Some(map) = info.details.as_object_mut() {
            map.insert(
                "deviation_removed_deg".into(),
                serde_json::json!(d.0.map(f64::to_degrees)),
            );
            map.insert(
                "gyro_scale_error_removed".into(),
                serde_json::json!(self.scale.error),
            );
        }
        info
    }

    async fn read(&self) -> Result<HeadingSample, BaseError> {
        let mut s = self.inner.read().await?;
        correct(&mut s, &self.deviation);
        self.scale.correct(&mut s);
        Ok(s)
    }

    async fn stream(
        &self,
        period: Duration,
    ) -> Result<Option<SampleStream<HeadingSample>>, BaseError> {
        let Some(mut rx) = self.inner.stream(period).await? else {
            return Ok(None);
        };
        let (tx, out) = mpsc::channel(STREAM_CAPACITY);
        let (deviation, scale) = (self.deviation.clone(), self.scale.clone());
        tokio::spawn(async move {
            while let Some(mut s) = rx.recv().await {
                correct(&mut s, &deviation);
                scale.correct(&mut s);
                if tx.send(s).await.is_err() {
                    return;
                }
            }
        });
        Ok(Some(out))
    }

    fn kind(&self) -> HeadingKind {
        self.kind.unwrap_or_else(|| self.inner.kind())
    }

    fn clock(&self) -> Option<String> {
        self.inner.clock()
    }
}
