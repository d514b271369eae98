//! A ROS robot's pose reference over rosbridge, live: a `geometry_msgs/PoseStamped`,
//! `PoseWithCovarianceStamped` (AMCL's `/amcl_pose`) or `nav_msgs/Odometry` topic (motion
//! capture, GNSS, visual odometry) as a [`PoseSource`] for `odocal track --reference`. It
//! opens a rosbridge connection of its own (rosbridge serves any number), asks rosapi for the
//! topic's type, and forwards each usable message as a [`ReferencePose`] stamped by its header
//! — the robot's clock, as its joint states are. Messages stamped back in time, without a
//! rotation or not decodable are dropped and counted ([`RosPoseSource::dropped`]).

use super::bag::reference::{stated_std, REFERENCE_TYPES};
use super::live::{decode, next_message, robot_clock, stamp_of, RosBaseError};
use super::msg::{
    types, yaw_of, Covariance36, Odometry, Pose, PoseStamped, PoseWithCovarianceStamped,
};
use super::rosbridge::RosbridgeClient;
use crate::base::{BaseError, ComponentInfo, Fanout, PoseSource, ReferencePose, SampleStream};
use async_trait::async_trait;
use serde_json::{json, Value};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// A pose topic read live.
pub struct RosPoseSource {
    url: String,
    topic: String,
    type_name: String,
    poses: Fanout<ReferencePose>,
    dropped: Arc<AtomicU64>,
    // Kept so that the connection lives as long as the source.
    _client: RosbridgeClient,
}

impl RosPoseSource {
    /// Connects to the rosbridge server at `url` and subscribes to `topic`, whose type rosapi
    /// must report as one of the three pose types.
    pub async fn connect(url: &str, topic: &str, timeout: Duration) -> Result<Self, RosBaseError> {
        let client = RosbridgeClient::connect(url, timeout).await?;
        let answer = client
            .call_service(
                "/rosapi/topic_type",
                "rosapi_msgs/srv/TopicType",
                json!({ "topic": topic }),
                timeout,
            )
            .await?;
        let type_name = answer
            .get("type")
            .and_then(Value::as_str)
            .unwrap_or_default()
            .to_string();
        if type_name.is_empty() {
            return Err(RosBaseError::Config(format!(
                "{topic} is not a topic of the robot (rosapi knows no type for it): is the \
                 localization running, and the name right (--reference)?"
            )));
        }
        if !REFERENCE_TYPES.iter().any(|t| types::is(&type_name, t)) {
            return Err(RosBaseError::Config(format!(
                "{topic} carries {type_name}; a pose reference is a geometry_msgs/PoseStamped, \
                 geometry_msgs/PoseWithCovarianceStamped or nav_msgs/Odometry topic"
            )));
        }
        let rx = client.subscribe(topic, &type_name)?;
        let poses: Fanout<ReferencePose> = Fanout::default();
        let dropped = Arc::new(AtomicU64::new(0));
        tokio::spawn(follow(
            rx,
            type_name.clone(),
            poses.clone(),
            dropped.clone(),
        ));
        Ok(RosPoseSource {
            url: url.to_string(),
            topic: topic.to_string(),
            type_name,
            poses,
            dropped,
            _client: client,
        })
    }

    /// Messages dropped so far (stamped back in time, no rotation, not decodable).
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

/// The pose and stated covariance of one message of `type_name`.
fn pose_of(type_name: &str, v: &Value) -> Result<(Pose, Option<Covariance36>), String> {
    if types::is(type_name, types::POSE_STAMPED) {
        decode::<PoseStamped>(v).map(|p| (p.pose, None))
    } else if types::is(type_name, types::POSE_WITH_COVARIANCE_STAMPED) {
        decode::<PoseWithCovarianceStamped>(v).map(|p| (p.pose.pose, Some(p.pose.covariance)))
    } else {
        decode::<Odometry>(v).map(|o| (o.pose.pose, Some(o.pose.covariance)))
    }
}

async fn follow(
    mut rx: tokio::sync::broadcast::Receiver<Value>,
    type_name: String,
    out: Fanout<ReferencePose>,
    dropped: Arc<AtomicU64>,
) {
    let mut last: Option<f64> = None;
    while let Some(v) = next_message(&mut rx).await {
        let usable = stamp_of(&v)
            .filter(|t| t.is_finite() && last.is_none_or(|l| *t > l))
            .zip(pose_of(&type_name, &v).ok())
            .and_then(|(t, (pose, cov))| {
                let yaw = yaw_of(&pose.orientation).ok()?;
                (pose.position.x.is_finite() && pose.position.y.is_finite()).then(|| {
                    ReferencePose {
                        time_s: t,
                        x_m: pose.position.x,
                        y_m: pose.position.y,
                        yaw_rad: Some(yaw),
                        stated_std: cov.as_ref().and_then(stated_std),
                    }
                })
            });
        match usable {
            Some(p) => {
                last = Some(p.time_s);
                out.send(&p);
            }
            None => {
                dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

#[async_trait]
impl PoseSource for RosPoseSource {
    fn info(&self) -> ComponentInfo {
        ComponentInfo {
            kind: "rosbridge pose topic".into(),
            id: format!("{} {}", self.url, self.topic),
            details: json!({ "type": self.type_name }),
        }
    }

    async fn stream(&self) -> Result<SampleStream<ReferencePose>, BaseError> {
        Ok(self.poses.subscribe())
    }

    fn clock(&self) -> Option<String> {
        Some(robot_clock(&self.url))
    }
}
