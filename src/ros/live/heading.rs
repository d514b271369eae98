//! The IMU's orientation as the heading source: followed in the background, its yaw read as a
//! fresh sample per request.

use super::*;

pub(super) async fn follow_imu(
    mut rx: tokio::sync::broadcast::Receiver<Value>,
    (topic, rejects): (String, Rejects),
    tx: Publisher,
    streams: Fanout<HeadingSample>,
) {
    let mut forward = Forward::default();
    loop {
        let Some(v) = next_message(&mut rx).await else {
            return;
        };
        let stamp = stamp_of(&v).unwrap_or(0.0);
        if let Verdict::Drop(why) = forward.check(stamp) {
            rejects.note(&topic, why.into(), &v);
            continue;
        }
        let sample = match decode::<Imu>(&v) {
            Err(e) => {
                rejects.note(&topic, e.clone(), &v);
                HeadingSample {
                    time_s: stamp,
                    heading_rad: 0.0,
                    validity: Validity::Invalid(format!("undecodable IMU message: {e}")),
                }
            }
            Ok(imu) if imu.orientation_covariance[0] == -1.0 => HeadingSample {
                time_s: stamp,
                heading_rad: 0.0,
                validity: Validity::Invalid(
                    "the IMU publishes no orientation (orientation_covariance[0] = -1)".into(),
                ),
            },
            Ok(imu) => match yaw_of(&imu.orientation) {
                Ok(yaw) => HeadingSample {
                    time_s: stamp,
                    heading_rad: yaw,
                    validity: Validity::Valid,
                },
                Err(why) => HeadingSample {
                    time_s: stamp,
                    heading_rad: 0.0,
                    validity: Validity::Invalid(why.into()),
                },
            },
        };
        streams.send(&sample);
        tx.publish(Instant::now(), sample);
    }
}

#[async_trait]
impl HeadingSource for RosHeading {
    fn info(&self) -> ComponentInfo {
        ComponentInfo {
            kind: "rosbridge-imu".into(),
            id: format!("{}{}", self.url, self.topic),
            details: Value::Null,
        }
    }

    async fn read(&self) -> Result<HeadingSample, BaseError> {
        // Robot time of the newest wheel data: the reading must be at least as new, so that a
        // heading "at rest" is never one taken before the wheels stopped (messages of the two
        // topics can be processed at different paces).
        // And it must arrive after this call: the newest cached message returned to every read
        // would make ten readings at rest one reading ten times (a noise of zero, an average of
        // one sample).
        let newest = self.wheels.borrow().stamp_s;
        let asked = Instant::now();
        let fresh = self
            .latest
            .read_after(asked, self.stale, |s| s.time_s >= newest);
        match fresh.await {
            Fresh::Got(sample) => Ok(sample),
            Fresh::Closed => Err(BaseError::HeadingInvalid {
                reason: format!("{} ended", self.topic),
            }),
            Fresh::Stale(last) => Ok(HeadingSample {
                time_s: last.as_ref().map_or(0.0, |s| s.time_s),
                heading_rad: last.as_ref().map_or(0.0, |s| s.heading_rad),
                validity: Validity::Invalid(format!(
                    "stale: no new {} message as new as the wheel data ({newest:.3} s) within {}",
                    self.topic,
                    crate::io::seconds(&self.stale)
                )),
            }),
        }
    }

    async fn stream(
        &self,
        _period: Duration,
    ) -> Result<Option<SampleStream<HeadingSample>>, BaseError> {
        Ok(Some(self.streams.subscribe()))
    }

    fn clock(&self) -> Option<String> {
        Some(robot_clock(&self.url))
    }
}
