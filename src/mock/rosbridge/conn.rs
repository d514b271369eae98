//! One client connection in the rosbridge v2 protocol (ROSBRIDGE_PROTOCOL.md): subscriptions
//! kept per subscription id, with `throttle_rate` and `queue_length` applied as
//! `rosbridge_server` applies them (the fastest throttle and the shortest queue of a topic's
//! subscriptions; a throttled message is dropped, a queue drops its oldest), advertisements,
//! publications, service calls, and `status` messages for what it refuses, at the level the
//! client set with `set_level` (`error` until then). As in rosbridge_suite, the
//! `fragment_size` of any operation becomes the connection's: everything it sends that is
//! longer goes out as `fragment` operations; fragments from the client are put together
//! ([`crate::ros::fragment`]).
//!
//! Each message of a topic goes to a connection once, whatever its number of subscriptions,
//! without a subscription id (the client fans it out), as the real server does.

use super::services::{call_service, topic_types};
use super::{lock, MockRosConfig, MockRosState, Outgoing};
use crate::io::transport::BoxTransport;
use crate::ros::fragment::{self, Defragmenter};
use crate::ros::msg::{types, Twist, TwistStamped};
use futures_util::stream::SplitSink;
use futures_util::{SinkExt, StreamExt};
use serde_json::{json, Value};
use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::broadcast;
use tokio::time::Instant;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::WebSocketStream;

/// A client's WebSocket, over the bytes it is served on: a TCP socket, or one end of an
/// in-memory [`crate::io::transport::pair`] ([`super::MockRosbridge::connect_in_memory`]).
type Sink = SplitSink<WebSocketStream<BoxTransport>, Message>;

/// Status levels, most severe first: a client hears those at or above its level.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Level {
    Error,
    Warning,
    Info,
}

impl Level {
    fn name(self) -> &'static str {
        match self {
            Level::Error => "error",
            Level::Warning => "warning",
            Level::Info => "info",
        }
    }
}

/// One `subscribe` of a topic.
#[derive(Debug, Clone)]
struct Subscription {
    id: Option<Value>,
    throttle: Duration,
    queue_length: usize,
}

/// A topic this connection subscribes to, with its subscriptions and delivery state.
#[derive(Debug, Default)]
struct Subscribed {
    subscriptions: Vec<Subscription>,
    last_sent: Option<Instant>,
    queue: VecDeque<Value>,
}

impl Subscribed {
    fn throttle(&self) -> Duration {
        self.subscriptions
            .iter()
            .map(|s| s.throttle)
            .min()
            .unwrap_or_default()
    }

    fn queue_length(&self) -> usize {
        self.subscriptions
            .iter()
            .map(|s| s.queue_length)
            .min()
            .unwrap_or_default()
    }

    fn window_open(&self, now: Instant) -> bool {
        self.last_sent
            .is_none_or(|last| now.duration_since(last) >= self.throttle())
    }

    /// What to send of `msg` now: it alone, or what the queue lets go.
    fn offer(&mut self, msg: Value, now: Instant) -> Vec<Value> {
        if self.queue_length() == 0 {
            if self.window_open(now) {
                self.last_sent = Some(now);
                return vec![msg];
            }
            return Vec::new();
        }
        self.queue.push_back(msg);
        while self.queue.len() > self.queue_length() {
            self.queue.pop_front();
        }
        self.release(now)
    }

    /// What the queue lets go now.
    fn release(&mut self, now: Instant) -> Vec<Value> {
        let mut out = Vec::new();
        while !self.queue.is_empty() && self.window_open(now) {
            out.extend(self.queue.pop_front());
            self.last_sent = Some(now);
            if self.throttle().is_zero() {
                continue;
            }
            break;
        }
        out
    }
}

/// The state of one connection.
struct Connection {
    cfg: MockRosConfig,
    state: Arc<Mutex<MockRosState>>,
    sink: Sink,
    subscribed: BTreeMap<String, Subscribed>,
    level: Option<Level>,
    fragments: Defragmenter,
    /// The `fragment_size` the client last gave in any operation: what the connection sends
    /// longer than it goes in fragments.
    fragment_size: Option<usize>,
    /// Ids given to fragmented messages.
    fragmented: u64,
}

/// `pkg/msg/Type` for `pkg/Type` or `pkg/msg/Type`.
pub(super) fn canonical_type(t: &str) -> String {
    let mut parts = t.split('/');
    match (parts.next(), parts.next(), parts.next()) {
        (Some(pkg), Some(name), None) => format!("{pkg}/msg/{name}"),
        _ => t.to_string(),
    }
}

/// Serves one client until it closes or the server vanishes.
pub(super) async fn serve(
    wire: BoxTransport,
    cfg: MockRosConfig,
    state: Arc<Mutex<MockRosState>>,
    mut topics: broadcast::Receiver<Outgoing>,
) {
    let Ok(ws) = tokio_tungstenite::accept_async(wire).await else {
        return;
    };
    lock(&state).counters.connections += 1;
    let (sink, mut source) = ws.split();
    let mut c = Connection {
        cfg,
        state,
        sink,
        subscribed: BTreeMap::new(),
        level: Some(Level::Error),
        fragments: Defragmenter::default(),
        fragment_size: None,
        fragmented: 0,
    };
    let mut tick = tokio::time::interval(Duration::from_millis(10));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        let alive = tokio::select! {
            m = topics.recv() => match m {
                Ok((topic, msg, at)) => c.deliver(&topic, msg, at).await,
                Err(broadcast::error::RecvError::Lagged(_)) => true,
                Err(_) => false,
            },
            _ = tick.tick() => c.release_queues().await,
            m = source.next() => match m {
                Some(Ok(Message::Text(t))) => c.handle(t.as_str()).await,
                Some(Ok(Message::Close(_))) | None | Some(Err(_)) => false,
                Some(Ok(_)) => true,
            },
        };
        if !alive {
            return;
        }
    }
}

impl Connection {
    async fn send(&mut self, v: Value) -> bool {
        self.send_text(v.to_string()).await
    }

    /// Sends `text`, in `fragment` operations when it is longer than the connection's
    /// `fragment_size` (rosbridge's `Protocol.send`).
    async fn send_text(&mut self, text: String) -> bool {
        match self.fragment_size {
            Some(size) if text.chars().count() > size => {
                self.fragmented += 1;
                let id = format!("fragmented-{}", self.fragmented);
                for piece in fragment::split(&text, size, &id) {
                    if self
                        .sink
                        .send(Message::text(piece.to_string()))
                        .await
                        .is_err()
                    {
                        return false;
                    }
                }
                true
            }
            _ => self.sink.send(Message::text(text)).await.is_ok(),
        }
    }

    /// A published message, as this connection's subscriptions let it through.
    async fn deliver(&mut self, topic: &str, msg: Value, at: Instant) -> bool {
        let Some(sub) = self.subscribed.get_mut(topic) else {
            return true;
        };
        // Transport latency: no message leaves earlier than this after it was made.
        tokio::time::sleep_until(at + self.cfg.latency).await;
        let out = sub.offer(msg, Instant::now());
        for m in out {
            let text = self.publish_text(topic, m);
            if !self.send_text(text).await {
                return false;
            }
        }
        true
    }

    async fn release_queues(&mut self) -> bool {
        let now = Instant::now();
        let mut out = Vec::new();
        for (topic, sub) in &mut self.subscribed {
            for m in sub.release(now) {
                out.push((topic.clone(), m));
            }
        }
        for (topic, m) in out {
            let text = self.publish_text(&topic, m);
            if !self.send_text(text).await {
                return false;
            }
        }
        true
    }

    /// The `publish` operation's text; NaN written the way this robot's rosbridge writes it.
    fn publish_text(&self, topic: &str, msg: Value) -> String {
        let text = json!({"op": "publish", "topic": topic, "msg": msg}).to_string();
        if self.cfg.effort == super::EffortStyle::BareNan {
            // serde_json writes a NaN as null; rosbridge_suite #916 writes the token.
            text.replace("\"effort\":[null,null]", "\"effort\":[NaN,NaN]")
                .replace(
                    "\"angular_velocity_covariance\":[null,null,null,null,null,null,null,null,null]",
                    "\"angular_velocity_covariance\":[NaN,NaN,NaN,NaN,NaN,NaN,NaN,NaN,NaN]",
                )
        } else {
            text
        }
    }

    /// A `status` message, when the client's level lets it through.
    async fn status(&mut self, level: Level, msg: String, id: Option<&Value>) -> bool {
        lock(&self.state).counters.bad_requests += u64::from(level == Level::Error);
        if self.level.is_none_or(|l| level > l) {
            return true;
        }
        lock(&self.state).counters.status_sent += 1;
        let mut v = json!({"op": "status", "level": level.name(), "msg": msg});
        if let Some(id) = id {
            v["id"] = id.clone();
        }
        self.send(v).await
    }

    async fn refuse(&mut self, msg: String, op: &Value) -> bool {
        let id = op.get("id").cloned();
        self.status(Level::Error, msg, id.as_ref()).await
    }

    /// One operation from the client.
    async fn handle(&mut self, text: &str) -> bool {
        match parse(text) {
            Ok(op) => self.operation(op, false).await,
            Err(msg) => self.status(Level::Error, msg, None).await,
        }
    }

    /// One parsed operation; `reassembled` when it came in fragments (a fragment inside one
    /// is refused).
    async fn operation(&mut self, op: Value, reassembled: bool) -> bool {
        let Some(name) = op.get("op").and_then(Value::as_str) else {
            return self
                .status(Level::Error, "a message without \"op\"".into(), None)
                .await;
        };
        // As rosbridge does: any operation's fragment_size becomes the connection's.
        if let Some(size) = op.get("fragment_size").and_then(Value::as_u64) {
            self.fragment_size = usize::try_from(size).ok().filter(|&n| n > 0);
        }
        let topic = op.get("topic").and_then(Value::as_str).map(String::from);
        match (name, topic) {
            ("subscribe", Some(topic)) => self.subscribe(&op, topic).await,
            ("unsubscribe", Some(topic)) => {
                let id = op.get("id");
                if let Some(sub) = self.subscribed.get_mut(&topic) {
                    match id {
                        Some(id) => sub.subscriptions.retain(|s| s.id.as_ref() != Some(id)),
                        None => sub.subscriptions.clear(),
                    }
                    if sub.subscriptions.is_empty() {
                        self.subscribed.remove(&topic);
                    }
                }
                true
            }
            ("advertise", Some(topic)) => self.advertise(&op, topic).await,
            ("unadvertise", Some(_)) => true,
            ("publish", Some(topic)) => self.publish(&op, topic).await,
            ("subscribe" | "unsubscribe" | "advertise" | "unadvertise" | "publish", None) => {
                self.refuse(
                    format!("{name}: the required field \"topic\" is missing"),
                    &op,
                )
                .await
            }
            ("call_service", _) => {
                let reply = call_service(&op, &self.cfg, &self.state);
                self.send(reply).await
            }
            ("fragment", _) if reassembled => {
                let msg = "fragment: a fragment inside a fragmented message".into();
                self.refuse(msg, &op).await
            }
            // The whole operation, once its last piece is in.
            ("fragment", _) => match self.fragments.feed(&op).map(|w| w.map(|w| parse(&w))) {
                Ok(Some(Ok(inner))) => Box::pin(self.operation(inner, true)).await,
                Ok(Some(Err(msg))) => self.refuse(format!("fragment: {msg}"), &op).await,
                Ok(None) => true,
                Err(e) => self.refuse(format!("fragment: {e}"), &op).await,
            },
            ("set_level", _) => {
                match op.get("level").and_then(Value::as_str) {
                    Some("error") => self.level = Some(Level::Error),
                    Some("warning") => self.level = Some(Level::Warning),
                    Some("info") => self.level = Some(Level::Info),
                    Some("none") => self.level = None,
                    other => {
                        let msg = format!(
                            "set_level: {other:?} is not a level (error, warning, info, none)"
                        );
                        return self.refuse(msg, &op).await;
                    }
                }
                true
            }
            (other, _) => {
                let msg = format!(
                    "{other}: not an operation this server offers (subscribe, unsubscribe, \
                     advertise, unadvertise, publish, call_service, set_level, fragment)"
                );
                self.refuse(msg, &op).await
            }
        }
    }

    async fn subscribe(&mut self, op: &Value, topic: String) -> bool {
        let known = topic_types(&self.cfg, &self.state).remove(&topic);
        let asked = op.get("type").and_then(Value::as_str).map(canonical_type);
        match (&known, &asked) {
            (Some(k), Some(a)) if k != a => {
                let msg = format!(
                    "subscribe: tried to register topic {topic} with type {a} but it is already \
                     established with type {k}"
                );
                return self.refuse(msg, op).await;
            }
            (None, None) => {
                let msg = format!(
                    "subscribe: cannot infer topic type for topic {topic} as it is not yet \
                     advertised"
                );
                return self.refuse(msg, op).await;
            }
            _ => {}
        }
        let ms = |key: &str| op.get(key).and_then(Value::as_u64).unwrap_or(0);
        let sub = Subscription {
            id: op.get("id").cloned(),
            throttle: Duration::from_millis(ms("throttle_rate")),
            queue_length: usize::try_from(ms("queue_length")).unwrap_or(usize::MAX),
        };
        let entry = self.subscribed.entry(topic).or_default();
        match entry
            .subscriptions
            .iter_mut()
            // Keyed by id as rosbridge keys them: subscriptions without one share the key None.
            .find(|s| s.id == sub.id)
        {
            Some(same) => *same = sub,
            None => entry.subscriptions.push(sub),
        }
        true
    }

    async fn advertise(&mut self, op: &Value, topic: String) -> bool {
        let Some(asked) = op.get("type").and_then(Value::as_str).map(canonical_type) else {
            return self
                .refuse(
                    "advertise: the required field \"type\" is missing".into(),
                    op,
                )
                .await;
        };
        if let Some(known) = topic_types(&self.cfg, &self.state).remove(&topic) {
            if known != asked {
                let msg = format!(
                    "advertise: tried to register topic {topic} with type {asked} but it is \
                     already established with type {known}"
                );
                return self.refuse(msg, op).await;
            }
        }
        lock(&self.state).advertised.insert(topic, asked);
        true
    }

    async fn publish(&mut self, op: &Value, topic: String) -> bool {
        let Some(kind) = topic_types(&self.cfg, &self.state).remove(&topic) else {
            let msg = format!(
                "publish: cannot infer topic type for topic {topic} as it is not yet advertised"
            );
            return self.refuse(msg, op).await;
        };
        if topic != self.cfg.cmd_vel {
            // Into the graph, where nothing of the robot listens.
            return true;
        }
        let msg = op.get("msg").cloned().unwrap_or(json!({}));
        let twist = if kind == types::TWIST_STAMPED {
            strict::<TwistStamped>(&msg).map(|t| t.twist)
        } else {
            strict::<Twist>(&msg)
        };
        let tw = match twist {
            Ok(tw) => tw,
            Err(e) => {
                let msg = format!("publish: {topic} carries {kind}: {e}");
                return self.refuse(msg, op).await;
            }
        };
        let mut s = lock(&self.state);
        s.cmd = (tw.linear.x, tw.angular.z);
        s.last_cmd_s = s.time_s;
        s.counters.commands += 1;
        s.counters.last_command = s.cmd;
        if tw.is_zero() {
            s.counters.zero_commands += 1;
        }
        true
    }
}

/// A message read as rosbridge reads it into a ROS type: a field the type does not have is an
/// error (missing ones keep their defaults).
/// An operation's JSON, or why it is none.
fn parse(text: &str) -> Result<Value, String> {
    serde_json::from_str(text).map_err(|_| {
        format!(
            "cannot parse {:?} as JSON",
            text.chars().take(80).collect::<String>()
        )
    })
}

fn strict<T: serde::de::DeserializeOwned + Default + serde::Serialize>(
    msg: &Value,
) -> Result<T, String> {
    let fields = serde_json::to_value(T::default()).map_err(|e| e.to_string())?;
    if let (Some(have), Some(want)) = (msg.as_object(), fields.as_object()) {
        if let Some(extra) = have.keys().find(|k| !want.contains_key(*k)) {
            return Err(format!("the message type does not have a field {extra}"));
        }
    }
    let mut full = fields;
    merge(&mut full, msg);
    serde_json::from_value(full).map_err(|e| e.to_string())
}

/// `over` laid over `base`, field by field.
fn merge(base: &mut Value, over: &Value) {
    match (base, over) {
        (Value::Object(b), Value::Object(o)) => {
            for (k, v) in o {
                match b.get_mut(k) {
                    Some(slot) => merge(slot, v),
                    None => {
                        b.insert(k.clone(), v.clone());
                    }
                }
            }
        }
        (slot, v) => *slot = v.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sub(throttle_ms: u64, queue_length: usize) -> Subscription {
        Subscription {
            id: None,
            throttle: Duration::from_millis(throttle_ms),
            queue_length,
        }
    }

    #[tokio::test(start_paused = true)]
    async fn throttle_drops_and_queues_keep_the_newest() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        // Throttled, no queue: what falls inside the window is dropped.
        let mut s = Subscribed {
            subscriptions: vec![sub(100, 0)],
            ..Subscribed::default()
        };
        let sent: Vec<_> = (0..10)
            .flat_map(|i| s.offer(json!(i), at(i * 30)))
            .collect();
        assert_eq!(sent, vec![json!(0), json!(4), json!(8)]);
        // The fastest of two subscriptions sets the rate.
        s.subscriptions.push(sub(0, 0));
        assert_eq!(s.offer(json!(10), at(271)), vec![json!(10)]);
        assert_eq!(s.offer(json!(11), at(272)), vec![json!(11)]);
        // A queue of two behind a throttle keeps the newest two and lets one go per window.
        let mut q = Subscribed {
            subscriptions: vec![sub(100, 2)],
            ..Subscribed::default()
        };
        assert_eq!(q.offer(json!(0), at(0)), vec![json!(0)]);
        assert!(q.offer(json!(1), at(10)).is_empty());
        assert!(q.offer(json!(2), at(20)).is_empty());
        assert!(q.offer(json!(3), at(30)).is_empty());
        assert_eq!(q.release(at(100)), vec![json!(2)]);
        assert!(q.release(at(150)).is_empty());
        assert_eq!(q.release(at(200)), vec![json!(3)]);
    }

    #[test]
    fn strict_reading_refuses_fields_the_type_does_not_have() {
        let twist = json!({"linear": {"x": 0.5}, "angular": {"z": 0.1}});
        assert_eq!(strict::<Twist>(&twist).unwrap().linear.x, 0.5);
        let err = strict::<TwistStamped>(&twist).unwrap_err();
        assert!(err.contains("does not have a field"), "{err}");
        let stamped = json!({"header": {"frame_id": "base_link"}, "twist": twist});
        assert_eq!(
            strict::<TwistStamped>(&stamped).unwrap().twist.angular.z,
            0.1
        );
        assert_eq!(canonical_type("geometry_msgs/Twist"), types::TWIST);
        assert_eq!(canonical_type(types::TWIST), types::TWIST);
    }
}
