//! [`Adjusted`]: a heading source as the user knows it better than its backend does — its kind
//! declared, and each reading corrected for a measured compass deviation (the curve a compass
//! swing fits, [`crate::calibration::swing`]), which depends on the reading alone.
//!
//! A gyro's scale error is not removed here: it scales heading *changes*, and a change between
//! two readings at rest a full turn apart cannot be unwrapped from the readings alone. The
//! routine removes it from each run against the odometry's turn
//! ([`crate::calibration::gyro::unscaled_error`]).

use super::{
    BaseError, ComponentInfo, HeadingKind, HeadingSample, HeadingSource, SampleStream,
    STREAM_CAPACITY,
};
use crate::kinematics::Deviation;
use async_trait::async_trait;
use std::sync::{Arc, RwLock};
use std::time::Duration;
use tokio::sync::mpsc;

/// A heading source with a declared kind and a deviation removed from its readings.
pub struct Adjusted {
    inner: Arc<dyn HeadingSource>,
    kind: Option<HeadingKind>,
    deviation: Arc<RwLock<Deviation>>,
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
        }
    }

    /// `inner` declared of `kind` and corrected for `deviation`, or `inner` itself when
    /// neither is given.
    pub fn wrap(
        inner: Arc<dyn HeadingSource>,
        kind: Option<HeadingKind>,
        deviation: Deviation,
    ) -> Arc<dyn HeadingSource> {
        if kind.is_none() && deviation.is_zero() {
            inner
        } else {
            Arc::new(Adjusted::new(inner, kind, deviation))
        }
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
        }
        info
    }

    async fn read(&self) -> Result<HeadingSample, BaseError> {
        let mut s = self.inner.read().await?;
        correct(&mut s, &self.deviation);
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
        let deviation = self.deviation.clone();
        tokio::spawn(async move {
            while let Some(mut s) = rx.recv().await {
                correct(&mut s, &deviation);
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
