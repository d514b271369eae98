//! A client of the rosbridge v2 protocol: JSON operations over a WebSocket, as
//! `rosbridge_server` serves them on ROS 1 and ROS 2 robots (`subscribe`, `advertise`,
//! `publish`, `call_service`, and the server's `publish`, `service_response` and `status`).
//!
//! One task reads the socket and fans messages out per topic; one writes. The connection
//! state is shared: once the server goes away every call fails with [`RosbridgeError::Closed`]
//! and every subscription ends.

use super::fragment::Defragmenter;
use futures_util::{SinkExt, StreamExt};
use serde_json::{json, Value};
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::{broadcast, mpsc, oneshot, watch};
use tokio_tungstenite::tungstenite::Message;

/// Errors talking to rosbridge.
#[derive(Debug, Clone, thiserror::Error)]
pub enum RosbridgeError {
    /// The URL is not `ws://HOST:PORT` or `rosbridge://HOST:PORT`.
    #[error("bad rosbridge URL {url:?}: {reason}")]
    Url {
        /// The URL.
        url: String,
        /// What is wrong.
        reason: String,
    },
    /// Nothing answered, or not with a WebSocket.
    #[error("cannot open a WebSocket to {url}: {reason}")]
    Connect {
        /// The URL.
        url: String,
        /// Why (refused, not a WebSocket server, …).
        reason: String,
    },
    /// The server answered, but not in the rosbridge protocol.
    #[error("{url} is not a rosbridge server: {reason}")]
    NotRosbridge {
        /// The URL.
        url: String,
        /// What it sent instead.
        reason: String,
    },
    /// The connection ended.
    #[error("the rosbridge connection closed: {0}")]
    Closed(String),
    /// Something expected did not arrive in time.
    #[error("{0}")]
    Timeout(String),
    /// A service call failed.
    #[error("service {service} failed: {reason}")]
    Service {
        /// The service.
        service: String,
        /// The server's message.
        reason: String,
    },
}

type Pending = Arc<Mutex<HashMap<String, oneshot::Sender<Result<Value, String>>>>>;
type Topics = Arc<Mutex<HashMap<String, broadcast::Sender<Value>>>>;

/// A connection to a rosbridge server; cheap to clone, all clones share it.
#[derive(Clone)]
pub struct RosbridgeClient {
    url: String,
    out: mpsc::UnboundedSender<Message>,
    topics: Topics,
    pending: Pending,
    closed: watch::Receiver<Option<String>>,
    next_id: Arc<AtomicU64>,
    /// Messages that were not rosbridge operations, with the first of them.
    foreign: Arc<Mutex<(u64, Option<String>)>>,
}

/// Turns `rosbridge://h:p` or `ws://h:p` into the WebSocket URL.
pub fn websocket_url(url: &str) -> Result<String, RosbridgeError> {
    let bad = |reason: &str| RosbridgeError::Url {
        url: url.into(),
        reason: reason.into(),
    };
    let rest = url
        .strip_prefix("rosbridge://")
        .or_else(|| url.strip_prefix("ws://"))
        .ok_or_else(|| bad("use rosbridge://HOST:PORT or ws://HOST:PORT"))?;
    if rest.is_empty() || rest.starts_with('/') {
        return Err(bad("no host"));
    }
    Ok(format!("ws://{rest}"))
}

/// Nothing answered `url` within `timeout`.
fn no_answer(url: &str, timeout: Duration) -> RosbridgeError {
    RosbridgeError::Connect {
        url: url.into(),
        reason: format!("no answer within {}", crate::io::seconds(&timeout)),
    }
}

/// Why the WebSocket to `url` did not open, in words that tell "not reached" from "not a
/// rosbridge server".
fn not_connected(url: &str, e: tokio_tungstenite::tungstenite::Error) -> RosbridgeError {
    use tokio_tungstenite::tungstenite::Error;
    let reason = match e {
        // Nothing listening, or the network: the server was not reached.
        Error::Io(io) => io.to_string(),
        Error::Http(r) => format!(
            "the server answered HTTP {} instead of upgrading to a WebSocket: not a rosbridge \
             server",
            r.status()
        ),
        // Reached, but the handshake failed (an old HTTP, not HTTP at all, …).
        other => {
            format!("the server did not accept a WebSocket ({other}): not a rosbridge server")
        }
    };
    RosbridgeError::Connect {
        url: url.into(),
        reason,
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl RosbridgeClient {
    /// Opens the WebSocket (within `timeout`) and starts the connection's tasks.
    pub async fn connect(url: &str, timeout: Duration) -> Result<Self, RosbridgeError> {
        let ws_url = websocket_url(url)?;
        let connect = tokio_tungstenite::connect_async(ws_url.as_str());
        let (stream, _) = tokio::time::timeout(timeout, connect)
            .await
            .map_err(|_| no_answer(url, timeout))?
            .map_err(|e| not_connected(url, e))?;
        Ok(Self::start(stream, url))
    }

    /// The same over any byte stream (an in-memory peer, a tunnel): the WebSocket handshake
    /// within `timeout`, then the connection's tasks; `label` names it where a URL would.
    pub async fn connect_stream<S>(
        stream: S,
        label: &str,
        timeout: Duration,
    ) -> Result<Self, RosbridgeError>
    where
        S: crate::io::transport::Transport,
    {
        let handshake = tokio_tungstenite::client_async("ws://localhost/", stream);
        let (stream, _) = tokio::time::timeout(timeout, handshake)
            .await
            .map_err(|_| no_answer(label, timeout))?
            .map_err(|e| not_connected(label, e))?;
        Ok(Self::start(stream, label))
    }

    /// Starts the connection's tasks on an open WebSocket: one writes, one reads and fans out.
    fn start<S>(stream: tokio_tungstenite::WebSocketStream<S>, url: &str) -> Self
    where
        S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send + 'static,
    {
        let (mut sink, mut source) = stream.split();
        let (out, mut out_rx) = mpsc::unbounded_channel::<Message>();
        let (closed_tx, closed) = watch::channel(None);
        let topics: Topics = Arc::default();
        let pending: Pending = Arc::default();
        let foreign: Arc<Mutex<(u64, Option<String>)>> = Arc::default();
        let closed_w = closed_tx.clone();
        tokio::spawn(async move {
            while let Some(m) = out_rx.recv().await {
                if let Err(e) = sink.send(m).await {
                    let _ = closed_w.send(Some(e.to_string()));
                    return;
                }
            }
            // Every handle is gone: close politely.
            let _ = sink.send(Message::Close(None)).await;
        });
        let (t, p, f) = (topics.clone(), pending.clone(), foreign.clone());
        tokio::spawn(async move {
            let mut fragments = Defragmenter::default();
            let reason = loop {
                match source.next().await {
                    None => break "the server closed the connection".to_string(),
                    Some(Err(e)) => break e.to_string(),
                    Some(Ok(Message::Close(frame))) => {
                        break frame.map_or("the server closed the connection".into(), |f| {
                            format!("the server closed the connection: {}", f.reason)
                        })
                    }
                    Some(Ok(Message::Text(text))) => {
                        dispatch(text.as_str(), &t, &p, &f, Some(&mut fragments))
                    }
                    Some(Ok(Message::Binary(b))) => {
                        note_foreign(&f, format!("{} binary bytes", b.len()))
                    }
                    Some(Ok(_)) => {}
                }
            };
            lock(&t).clear();
            for (_, reply) in lock(&p).drain() {
                let _ = reply.send(Err(reason.clone()));
            }
            let _ = closed_tx.send(Some(reason));
        });
        RosbridgeClient {
            url: url.into(),
            out,
            topics,
            pending,
            closed,
            next_id: Arc::new(AtomicU64::new(1)),
            foreign,
        }
    }

    /// The URL it was opened with.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// Why the connection ended, if it has.
    pub fn closed(&self) -> Option<String> {
        self.closed.borrow().clone()
    }

    /// A receiver that changes when the connection ends.
    pub fn closed_watch(&self) -> watch::Receiver<Option<String>> {
        self.closed.clone()
    }

    /// Messages received that were not rosbridge operations, and the first of them.
    pub fn foreign(&self) -> (u64, Option<String>) {
        lock(&self.foreign).clone()
    }

    fn send(&self, op: Value) -> Result<(), RosbridgeError> {
        if let Some(r) = self.closed() {
            return Err(RosbridgeError::Closed(r));
        }
        self.out
            .send(Message::text(op.to_string()))
            .map_err(|_| RosbridgeError::Closed("the connection's writer ended".into()))
    }

    fn id(&self, what: &str) -> String {
        format!(
            "odocal-{what}-{}",
            self.next_id.fetch_add(1, Ordering::Relaxed)
        )
    }

    /// Subscribes to `topic` of `type_name`; every message's `msg` object arrives on the receiver.
    pub fn subscribe(
        &self,
        topic: &str,
        type_name: &str,
    ) -> Result<broadcast::Receiver<Value>, RosbridgeError> {
        self.subscribe_throttled(topic, type_name, Duration::ZERO)
    }

    /// [`Self::subscribe`], the server sending at most one message per `throttle` (rosbridge's
    /// `throttle_rate`; zero: every message). A topic already subscribed keeps its first
    /// subscription's rate.
    pub fn subscribe_throttled(
        &self,
        topic: &str,
        type_name: &str,
        throttle: Duration,
    ) -> Result<broadcast::Receiver<Value>, RosbridgeError> {
        let rx = {
            let mut topics = lock(&self.topics);
            match topics.get(topic) {
                Some(tx) => return Ok(tx.subscribe()),
                None => {
                    let (tx, rx) = broadcast::channel(4096);
                    topics.insert(topic.to_string(), tx);
                    rx
                }
            }
        };
        self.send(json!({
            "op": "subscribe",
            "id": self.id("sub"),
            "topic": topic,
            "type": type_name,
            "queue_length": 0,
            "throttle_rate": u64::try_from(throttle.as_millis()).unwrap_or(u64::MAX),
        }))?;
        Ok(rx)
    }

    /// Announces that this client publishes `topic` of `type_name`.
    pub fn advertise(&self, topic: &str, type_name: &str) -> Result<(), RosbridgeError> {
        self.send(
            json!({"op": "advertise", "id": self.id("adv"), "topic": topic, "type": type_name}),
        )
    }

    /// Publishes `msg` on `topic` (advertised first). Never waits: safe from `Drop`.
    pub fn publish(&self, topic: &str, msg: Value) -> Result<(), RosbridgeError> {
        self.send(json!({"op": "publish", "topic": topic, "msg": msg}))
    }

    /// Calls a service and waits up to `timeout` for its `values`.
    pub async fn call_service(
        &self,
        service: &str,
        type_name: &str,
        args: Value,
        timeout: Duration,
    ) -> Result<Value, RosbridgeError> {
        let id = self.id("call");
        let (tx, rx) = oneshot::channel();
        lock(&self.pending).insert(id.clone(), tx);
        self.send(json!({
            "op": "call_service",
            "id": id,
            "service": service,
            "type": type_name,
            "args": args,
        }))?;
        let answer = tokio::time::timeout(timeout, rx).await;
        lock(&self.pending).remove(&id);
        match answer {
            Err(_) => Err(RosbridgeError::Timeout(format!(
                "service {service} did not answer within {}",
                crate::io::seconds(&timeout)
            ))),
            Ok(Err(_)) => Err(RosbridgeError::Closed("the connection ended".into())),
            Ok(Ok(Err(reason))) => Err(RosbridgeError::Service {
                service: service.into(),
                reason,
            }),
            Ok(Ok(Ok(values))) => Ok(values),
        }
    }
}

fn note_foreign(f: &Mutex<(u64, Option<String>)>, what: String) {
    let mut f = lock(f);
    f.0 += 1;
    if f.1.is_none() {
        f.1 = Some(what.chars().take(120).collect());
    }
}

fn dispatch(
    text: &str,
    topics: &Topics,
    pending: &Pending,
    foreign: &Mutex<(u64, Option<String>)>,
    fragments: Option<&mut Defragmenter>,
) {
    // rosbridge writes NaN and infinities inside fixed-size float arrays as bare tokens
    // (rosbridge_suite #916): not JSON, but a message all the same.
    let Ok(v) = serde_json::from_str::<Value>(&super::msg::lenient::json(text)) else {
        note_foreign(foreign, format!("non-JSON text {text:?}"));
        return;
    };
    match v.get("op").and_then(Value::as_str) {
        Some("publish") => {
            let (Some(topic), Some(msg)) = (v.get("topic").and_then(Value::as_str), v.get("msg"))
            else {
                return;
            };
            if let Some(tx) = lock(topics).get(topic) {
                let _ = tx.send(msg.clone());
            }
        }
        Some("service_response") => {
            let Some(id) = v.get("id").and_then(Value::as_str) else {
                return;
            };
            if let Some(reply) = lock(pending).remove(id) {
                let ok = v.get("result").and_then(Value::as_bool).unwrap_or(true);
                let values = v.get("values").cloned().unwrap_or(Value::Null);
                let _ = reply.send(if ok {
                    Ok(values)
                } else {
                    Err(values
                        .as_str()
                        .map_or_else(|| values.to_string(), String::from))
                });
            }
        }
        // A server may fragment what it sends (its own fragment_size): the whole message is
        // dispatched once its last piece is in.
        // (A fragment inside a fragmented message is refused: `fragments` is then `None`.)
        Some("fragment") => match fragments.map(|d| d.feed(&v)) {
            Some(Ok(Some(whole))) => dispatch(&whole, topics, pending, foreign, None),
            Some(Ok(None)) => {}
            Some(Err(e)) => note_foreign(foreign, e.to_string()),
            None => note_foreign(foreign, "a fragment inside a fragmented message".into()),
        },
        Some(_) => {}
        None => note_foreign(foreign, format!("JSON without an \"op\": {text}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A server's publish in fragments (ids and totals as rosbridge_suite writes them, the
    /// pieces out of order) reaches the topic's subscribers once its last piece is in; a
    /// fragment inside a fragmented message is counted as foreign, not followed.
    #[tokio::test]
    async fn fragments_from_the_server_make_one_message() {
        let topics: Topics = Arc::default();
        let pending: Pending = Arc::default();
        let foreign = Mutex::new((0, None));
        let (tx, mut rx) = broadcast::channel(4);
        lock(&topics).insert("/imu".into(), tx);
        let text = json!({"op": "publish", "topic": "/imu", "msg": {"x": 1.5}}).to_string();
        let mut pieces = super::super::fragment::split(&text, 10, "7");
        pieces.swap(0, 1);
        let mut d = Defragmenter::default();
        for p in &pieces {
            assert!(rx.try_recv().is_err());
            dispatch(&p.to_string(), &topics, &pending, &foreign, Some(&mut d));
        }
        assert_eq!(rx.try_recv().unwrap(), json!({"x": 1.5}));
        assert_eq!(lock(&foreign).0, 0);
        let nested = super::super::fragment::split(&pieces[0].to_string(), 1000, "8");
        dispatch(
            &nested[0].to_string(),
            &topics,
            &pending,
            &foreign,
            Some(&mut d),
        );
        assert_eq!(lock(&foreign).0, 1);
    }

    /// What answers a byte stream instead of a WebSocket server is named: a web server
    /// (HTTP 200, no upgrade), a device that talks something else (an NMEA compass on the
    /// port), and a peer that says nothing (within the timeout).
    #[tokio::test]
    async fn a_stream_that_is_not_a_websocket_is_refused_by_name() {
        use crate::io::transport::{self, Deadline};
        async fn answered(with: &'static [u8]) -> RosbridgeError {
            let (client, mut server) = transport::pair(4096);
            let peer = tokio::spawn(async move {
                // Waits for the request to end, then answers and hangs up.
                let mut request = Vec::new();
                let mut chunk = [0u8; 512];
                while !request.ends_with(b"\r\n\r\n") {
                    let by = Deadline::after(Duration::from_secs(5));
                    match transport::read_some_by(&mut server, &mut chunk, by).await {
                        Ok(transport::Read::Got(n)) => request.extend_from_slice(&chunk[..n]),
                        _ => break,
                    }
                }
                let _ = transport::write_all_by(&mut server, with, Deadline::never()).await;
                request
            });
            let err = RosbridgeClient::connect_stream(client, "test", Duration::from_secs(5))
                .await
                .err()
                .expect("connected to a peer that is not a WebSocket server");
            let request = peer.await.unwrap();
            assert!(request.starts_with(b"GET / HTTP/1.1\r\n"), "{request:?}");
            err
        }
        let web = answered(b"HTTP/1.1 200 OK\r\nContent-Length: 0\r\n\r\n").await;
        let text = web.to_string();
        assert!(matches!(web, RosbridgeError::Connect { .. }), "{text}");
        assert!(text.contains("HTTP 200 OK instead of upgrading"), "{text}");
        assert!(text.contains("not a rosbridge server"), "{text}");
        let compass = answered(b"$HEHDT,123.4,T*2D\r\n$HEHDT,123.5,T*2C\r\n").await;
        let text = compass.to_string();
        assert!(text.contains("did not accept a WebSocket"), "{text}");
        assert!(text.contains("not a rosbridge server"), "{text}");
        let (client, _silent) = transport::pair(4096);
        let timeout = Duration::from_millis(200);
        let silent = RosbridgeClient::connect_stream(client, "test", timeout).await;
        let text = silent.err().expect("a silent peer").to_string();
        assert!(text.contains("no answer within"), "{text}");
    }
}
