//! Why a robot did not move: a motion that leaves the odometry still for [`STILL_LIMIT`] is
//! stopped, and a diagnosis asks what else could tell (the joint states, the odometry, the
//! controller's services) so the error names the likely cause.

use super::*;

/// A robot whose odometry has not changed this long after a motion's first command is not
/// obeying: stopped and diagnosed ([`NotMoving`]).
pub const STILL_LIMIT: Duration = Duration::from_secs(1);

/// Odometry changes below these (m, rad) are not motion.
pub(super) const STILL_M: f64 = 1e-4;

pub(super) const STILL_RAD: f64 = 1e-4;

/// The robot did not move on a motion's command: what the other wheel source and the robot's
/// graph say about why.
#[derive(Debug, thiserror::Error)]
#[error(
    "the robot did not move within {} of the first command on {topic} ({kind}): its \
     odometry ({odometry}) did not change; {other}; {diagnosis}; stopped",
    crate::io::seconds(.after)
)]
pub struct NotMoving {
    /// The velocity topic commanded.
    pub topic: String,
    /// The message type published there.
    pub kind: String,
    /// How long it waited.
    pub after: Duration,
    /// The odometry source watched.
    pub odometry: String,
    /// What the other wheel source (the controller's odometry, or the joint states) showed
    /// meanwhile.
    pub other: String,
    /// What rosapi tells: the topic's type, its subscribers, the velocity topics that exist.
    pub diagnosis: String,
}

/// How long each rosapi question of the still-robot diagnosis may take; they are asked at
/// once, so that the diagnosis ends within a second of [`STILL_LIMIT`].
pub const DIAGNOSIS_CALL_TIMEOUT: Duration = Duration::from_millis(400);

/// A change of the other wheel source beyond this (m, rad) is motion.
pub(super) const WITNESS_MOVED: f64 = 1e-3;

/// The wheel source motions do not close on, followed (ten messages a second) for the
/// still-robot diagnosis: when the watched source shows no motion, this one tells a robot that
/// does not move from a source that does not show it.
#[derive(Clone)]
pub(super) struct Witness {
    pub(super) topic: String,
    pub(super) what: &'static str,
    /// Its latest reading: x, y (m) and yaw (rad) of the odometry, or the wheel angles (rad).
    pub(super) latest: watch::Receiver<Option<Vec<f64>>>,
}

impl Witness {
    /// Subscribes to the source `cfg` does not close on; `wheels` are the joint names given.
    pub(super) fn follow(
        client: &RosbridgeClient,
        cfg: &RosBaseConfig,
        wheels: (Option<String>, Option<String>),
    ) -> Result<Self, RosbridgeError> {
        let odom = cfg.wheel_source == WheelSource::JointStates;
        let (topic, kind, what) = if odom {
            (
                &cfg.topics.odom,
                types::ODOMETRY,
                "the controller's odometry",
            )
        } else {
            (
                &cfg.topics.joint_states,
                types::JOINT_STATE,
                "the joint states",
            )
        };
        let mut rx = client.subscribe_throttled(topic, kind, Duration::from_millis(100))?;
        let (tx, latest) = watch::channel(None);
        tokio::spawn(async move {
            while let Some(v) = next_message(&mut rx).await {
                let reading = if odom {
                    decode::<Odometry>(&v).ok().map(|o| {
                        let p = o.pose.pose;
                        let yaw = yaw_of(&p.orientation).unwrap_or(f64::NAN);
                        vec![p.position.x, p.position.y, yaw]
                    })
                } else {
                    decode::<JointState>(&v).ok().map(|js| {
                        match js.wheel_indices(&wheels.0, &wheels.1) {
                            Some((l, r)) => [l, r]
                                .iter()
                                .filter_map(|&i| js.position.get(i).copied())
                                .collect(),
                            None => js.position,
                        }
                    })
                };
                if reading.is_some() && tx.send(reading).is_err() {
                    return;
                }
            }
        });
        Ok(Witness {
            topic: topic.clone(),
            what,
            latest,
        })
    }

    /// Its latest reading.
    pub(super) fn now(&self) -> Option<Vec<f64>> {
        self.latest.borrow().clone()
    }

    /// What it showed between `before` and now, for a robot whose `watched` source did not
    /// change.
    pub(super) fn says(&self, before: &Option<Vec<f64>>, watched: &str) -> String {
        let (topic, what) = (&self.topic, self.what);
        match (before, self.now()) {
            (_, None) => format!("{topic} ({what}) sent nothing to compare with"),
            (None, Some(_)) => format!("{topic} ({what}) began only during the motion"),
            (Some(a), Some(b)) => {
                let change = a
                    .iter()
                    .zip(&b)
                    .map(|(x, y)| super::super::msg::angle_step(*x, *y).abs())
                    .fold(0.0, f64::max);
                if a.len() != b.len() || change > WITNESS_MOVED {
                    let hint = if what == "the joint states" {
                        format!(
                            " (is {watched} the controller's odometry, and is the controller \
                             running?)"
                        )
                    } else {
                        " (are the wheel joints named as the YAML or --left-joint/--right-joint \
                         say, and does the hardware report their positions?)"
                            .into()
                    };
                    format!(
                        "{topic} ({what}) did change: the robot moves, but {watched} does not \
                         show it{hint}"
                    )
                } else {
                    format!("{topic} ({what}) did not change either")
                }
            }
        }
    }
}

impl RosDrive {
    /// Why nothing moves: what the other wheel source showed since the first command
    /// (`witnessed` then), and rosapi's answers, asked at once, each within
    /// [`DIAGNOSIS_CALL_TIMEOUT`]: the velocity topic's type and subscribers, and the robot's
    /// topics of a velocity type.
    pub(super) async fn diagnose_still(&self, witnessed: &Option<Vec<f64>>) -> NotMoving {
        let client = &self.commander.client;
        let ask = |service: &'static str, kind: &'static str, args: Value| async move {
            client
                .call_service(service, kind, args, DIAGNOSIS_CALL_TIMEOUT)
                .await
                .ok()
        };
        let topic = self.cfg.cmd_vel.clone();
        let kind = if self.cfg.twist_stamped {
            types::TWIST_STAMPED
        } else {
            types::TWIST
        };
        let (listed, subscribers, all) = tokio::join!(
            ask(
                "/rosapi/topic_type",
                "rosapi_msgs/srv/TopicType",
                json!({ "topic": topic })
            ),
            ask(
                "/rosapi/subscribers",
                "rosapi_msgs/srv/Subscribers",
                json!({ "topic": topic })
            ),
            ask("/rosapi/topics", "rosapi_msgs/srv/Topics", json!({})),
        );
        let mut notes = Vec::new();
        match listed
            .as_ref()
            .and_then(|v| v.get("type"))
            .and_then(Value::as_str)
        {
            Some(t) if !t.is_empty() && !types::is(t, kind) && !types::is(kind, t) => notes.push(
                format!("{topic} carries {t}, not the {kind} published (--twist-stamped)"),
            ),
            _ => {}
        }
        let subscribers = subscribers
            .and_then(|v| v.get("subscribers").cloned())
            .and_then(|v| serde_json::from_value::<Vec<String>>(v).ok());
        match subscribers {
            Some(s) if s.is_empty() => notes.push(format!("nothing subscribes to {topic}")),
            Some(s) => notes.push(format!("{topic} is subscribed by {}", s.join(", "))),
            None => notes.push("rosapi did not say who subscribes".into()),
        }
        let pairs: Vec<(String, String)> = all
            .as_ref()
            .and_then(|v| {
                let t: Vec<String> = serde_json::from_value(v.get("topics")?.clone()).ok()?;
                let k: Vec<String> = serde_json::from_value(v.get("types")?.clone()).ok()?;
                Some(t.into_iter().zip(k).collect())
            })
            .unwrap_or_default();
        let velocity: Vec<String> = pairs
            .iter()
            .filter(|(t, k)| {
                *t != topic && (types::is(k, types::TWIST) || types::is(k, types::TWIST_STAMPED))
            })
            .map(|(t, k)| format!("{t} ({k})"))
            .collect();
        if !velocity.is_empty() {
            notes.push(format!(
                "velocity topics on this robot: {} (give the controller's with --cmd-vel, and \
                 --twist-stamped for TwistStamped)",
                velocity.join(", ")
            ));
        }
        let odometry = self.cfg.wheel_topic().to_string();
        NotMoving {
            topic,
            kind: kind.into(),
            after: STILL_LIMIT,
            other: self.witness.says(witnessed, &odometry),
            odometry,
            diagnosis: notes.join("; "),
        }
    }
}
