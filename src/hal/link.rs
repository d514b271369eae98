//! The task that owns the link: one request in flight, retries with the same sequence number,
//! responses matched by sequence number, events fanned out to subscribers.
//!
//! A request is retried until it has been tried `retries + 1` times **and** its budget has
//! passed since it was first sent: `retry_budget`, or the device's watchdog plus one deadline
//! if that is longer, so the host gives up only once the device has stopped by itself. Each
//! attempt waits for transmission, the device's answer time and twice the latency measured on
//! the link (the shortest answer seen beyond transmission). Budgets, not counts: on a link that
//! loses half the attempts (1 % of bytes corrupted and 5 % of frames lost both ways make most
//! frames of 30 bytes a coin toss), a fixed count of six fails one request in 64, and a
//! calibration sends hundreds. Retries reuse the sequence number, so the device answers a
//! repeated motion from its cache and never runs it twice.

use super::{HalError, LinkError, LinkStats, TelemetrySample};
use crate::io::transport::{self, Deadline, Read};
use crate::kinematics::wrap_angle;
use crate::protocol::message::{id, payload_len, Event, MotionDone, NackCode};
use crate::protocol::units;
use crate::protocol::{Body, FrameCodec, FrameKind, Packet, Request, Response};
use bytes::BytesMut;
use std::collections::VecDeque;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::{broadcast, mpsc, oneshot};
use tokio::time::Instant;

/// The fewest attempts a request's budget allows at its own deadline: on a line that loses
/// half the exchanges, twelve fail one request in four thousand (six: one in 64).
pub const MIN_ATTEMPTS: u32 = 12;

/// Link timing and retry policy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkConfig {
    /// Baud rate, for deadlines (10 bits per byte on an 8N1 line).
    pub baud: u32,
    /// Retries of a request that got no answer (same sequence number), at least.
    pub retries: u32,
    /// Keep retrying until this long after the first attempt, however many retries that takes.
    pub retry_budget: Duration,
    /// Added to each deadline beyond transmission time and device latency.
    pub margin: Duration,
    /// Retries (with a new sequence number) of a request answered NACK BUSY.
    pub busy_retries: u32,
    /// Wait before retrying after BUSY.
    pub busy_backoff: Duration,
    /// The device's answer time for ordinary requests (SPEC.md §3: 50 ms).
    pub response_time: Duration,
    /// The device's answer time for requests that write storage (SPEC.md §3: 500 ms).
    pub storage_time: Duration,
}

impl Default for LinkConfig {
    fn default() -> Self {
        LinkConfig {
            baud: super::DEFAULT_BAUD,
            retries: 5,
            retry_budget: Duration::from_secs(3),
            margin: Duration::from_millis(30),
            busy_retries: 5,
            busy_backoff: Duration::from_millis(5),
            response_time: Duration::from_millis(50),
            storage_time: Duration::from_millis(500),
        }
    }
}

impl LinkConfig {
    /// How long to wait for the answer to `request`: both frames' transmission time at the
    /// baud rate, plus the device's response time from SPEC.md §3, plus the margin.
    pub fn deadline(&self, request: &Request) -> Duration {
        let device = match request.msg() {
            id::SAVE_PARAMS | id::RESTORE_DEFAULTS => self.storage_time,
            _ => self.response_time,
        };
        self.wire_time(request) + device + self.margin
    }

    /// Both frames' transmission time at the baud rate.
    pub fn wire_time(&self, request: &Request) -> Duration {
        let msg = request.msg();
        let req = payload_len(FrameKind::Request, msg).unwrap_or(0) + 9;
        let resp = payload_len(FrameKind::Response, msg).unwrap_or(0) + 9;
        crate::io::serial::transmission(req + resp, self.baud)
    }

    /// The retry budget of a request while the device's watchdog is `watchdog` (zero: off):
    /// at least [`LinkConfig::retry_budget`]; at least [`MIN_ATTEMPTS`] deadlines, so that a
    /// request with a long answer time (SAVE_PARAMS: 500 ms) is tried as often on a lossy
    /// line as a quick one; and at least the watchdog plus one deadline, so that the host gives
    /// up on a silent link only once the device has stopped by itself.
    pub fn budget(&self, request: &Request, watchdog: Duration) -> Duration {
        let deadline = self.deadline(request);
        let budget = self.retry_budget.max(MIN_ATTEMPTS * deadline);
        if watchdog.is_zero() {
            budget
        } else {
            budget.max(watchdog + deadline)
        }
    }
}

/// What the client asks of the link task.
pub(super) enum Command {
    /// Send a request and report its answer.
    Request {
        request: Request,
        /// Retry budget for this request instead of the configured one.
        budget: Option<Duration>,
        reply: oneshot::Sender<Result<Response, HalError>>,
    },
    /// Abandon everything pending and send STOP at once (guards, Ctrl-C).
    EmergencyStop,
    /// Send STOP (if this host moved the base) and let go of the stream, so the port can be
    /// opened again: a reconnection after the device stopped answering.
    Close,
}

/// A request waiting its turn: the request, its retry budget override, where its answer goes.
type Queued = (
    Request,
    Option<Duration>,
    oneshot::Sender<Result<Response, HalError>>,
);

struct Pending {
    request: Request,
    seq: u8,
    bytes: Vec<u8>,
    deadline: Instant,
    first_sent: Instant,
    /// Whether a retried answer's time bounds the link's latency.
    measures_link: bool,
    budget: Duration,
    attempts: u32,
    busy_left: u32,
    /// Set after BUSY: at the deadline, resend with a new sequence number.
    resend_new_seq: bool,
    reply: Option<oneshot::Sender<Result<Response, HalError>>>,
}

/// Host-side unwrapping of the device's wrapping counters and clock.
#[derive(Default)]
struct Unwrap {
    last: Option<(u32, i32, i32, u32)>,
    left: i64,
    right: i64,
    time_us: u64,
}

/// What the link task keeps between turns of its loop.
struct State {
    /// The sequence number last used.
    seq: u8,
    /// Requests waiting their turn.
    queue: VecDeque<Queued>,
    /// The request in flight.
    pending: Option<Pending>,
    /// Why the link is gone, once it is.
    closed: Option<LinkError>,
    /// Whether this host sent a request that moves the base.
    moved: bool,
}

pub(super) struct Link {
    pub(super) config: LinkConfig,
    pub(super) stats: Arc<LinkStats>,
    pub(super) events: broadcast::Sender<TelemetrySample>,
    pub(super) motion_done: broadcast::Sender<MotionDone>,
}

impl Link {
    pub(super) async fn run<S>(self, stream: S, mut commands: mpsc::UnboundedReceiver<Command>)
    where
        S: AsyncRead + AsyncWrite + Unpin,
    {
        let (mut rd, mut wr) = tokio::io::split(stream);
        let mut codec = FrameCodec::new();
        let mut buf = BytesMut::new();
        let mut chunk = [0u8; 1024];
        let mut st = State {
            seq: 0,
            queue: VecDeque::new(),
            pending: None,
            closed: None,
            moved: false,
        };
        let mut unwrap = Unwrap::default();
        loop {
            if st.pending.is_none() && st.closed.is_none() {
                self.start_next(&mut wr, &mut st).await;
            }
            if let Some(err) = &st.closed {
                // The link is gone: fail everything now and anything asked later.
                if refuse_while_closed(err, &mut st.pending, &mut st.queue, &mut commands).await {
                    continue;
                }
                return;
            }
            let deadline = Deadline::at_or_never(st.pending.as_ref().map(|p| p.deadline));
            // In a fixed order (commands, then what arrived, then a deadline: a read by its
            // deadline takes bytes that are there before it says late): the same bytes give
            // the same exchanges, so a simulated link's losses repeat run after run.
            tokio::select! {
                biased;
                cmd = commands.recv() => {
                    if !self.on_command(cmd, &mut wr, &mut st).await {
                        return;
                    }
                }
                read = transport::read_some_by(&mut rd, &mut chunk, deadline) => match read {
                    Ok(Read::Closed) => st.closed = Some(LinkError::Closed),
                    Err(e) if gone(&e) => st.closed = Some(LinkError::Closed),
                    Err(e) => st.closed = Some(e.into()),
                    Ok(Read::Got(n)) => {
                        for frame in codec.feed(&mut buf, &chunk[..n]) {
                            self.stats.frames_received.fetch_add(1, Ordering::Relaxed);
                            self.dispatch(&frame, &mut st.pending, &mut unwrap);
                        }
                        self.stats.decoder_dropped_bytes.store(codec.stats().bytes_dropped, Ordering::Relaxed);
                    }
                    Ok(Read::Late) => self.on_deadline(&mut wr, &mut st).await,
                },
            }
        }
    }

    /// Sends the next queued request, if any, as the one in flight.
    async fn start_next<W: AsyncWrite + Unpin>(&self, wr: &mut W, st: &mut State) {
        if let Some((request, budget, reply)) = st.queue.pop_front() {
            st.moved |= request.moves_robot();
            st.seq = st.seq.wrapping_add(1);
            let busy_left = self.config.busy_retries;
            match self
                .start(wr, request, st.seq, busy_left, Some(reply))
                .await
            {
                Ok(mut p) => {
                    if let Some(b) = budget {
                        p.budget = b;
                        // A budget of its own (HELLO while a board boots): its answer
                        // time is the board's, not the link's.
                        p.measures_link = false;
                    }
                    st.pending = Some(p);
                }
                Err(e) => st.closed = Some(e),
            }
        }
    }

    /// Handles a client's command; false when the task is to end (Close, or no client left).
    async fn on_command<W: AsyncWrite + Unpin>(
        &self,
        cmd: Option<Command>,
        wr: &mut W,
        st: &mut State,
    ) -> bool {
        match cmd {
            Some(Command::Close) | None => {
                for (_, _, reply) in st.queue.drain(..) {
                    let _ = reply.send(Err(HalError::Link(LinkError::Closed)));
                }
                if let Some(p) = st.pending.take() {
                    fail(p.reply, LinkError::Closed);
                }
                // Every client handle is gone, or one asked to let go: if this host moved
                // the base, stop it before letting go (read-only sessions leave it alone).
                if st.moved {
                    let _ = self
                        .start(wr, Request::Stop, st.seq.wrapping_add(1), 0, None)
                        .await;
                }
                return false;
            }
            Some(Command::Request {
                request,
                budget,
                reply,
            }) => {
                st.queue.push_back((request, budget, reply));
            }
            Some(Command::EmergencyStop) => {
                if let Some(p) = st.pending.take() {
                    fail(p.reply, LinkError::Cancelled);
                }
                for (_, _, reply) in st.queue.drain(..) {
                    let _ = reply.send(Err(HalError::Link(LinkError::Cancelled)));
                }
                st.seq = st.seq.wrapping_add(1);
                match self.start(wr, Request::Stop, st.seq, 0, None).await {
                    Ok(p) => st.pending = Some(p),
                    Err(e) => st.closed = Some(e),
                }
            }
        }
        true
    }

    /// At the deadline: resends after BUSY, retries within the budget, or fails as timed out.
    async fn on_deadline<W: AsyncWrite + Unpin>(&self, wr: &mut W, st: &mut State) {
        if let Some(mut p) = st.pending.take() {
            if p.resend_new_seq {
                st.seq = st.seq.wrapping_add(1);
                let reply = p.reply.take();
                match self.start(wr, p.request, st.seq, p.busy_left, reply).await {
                    Ok(np) => st.pending = Some(np),
                    Err(e) => st.closed = Some(e),
                }
            } else if p.attempts <= self.config.retries || p.first_sent.elapsed() < p.budget {
                self.stats.retries.fetch_add(1, Ordering::Relaxed);
                p.attempts += 1;
                p.deadline = Instant::now() + self.deadline(&p.request);
                if let Err(e) = write(wr, &p.bytes, self.config.baud).await {
                    st.closed = Some(e);
                }
                st.pending = Some(p);
            } else {
                self.stats.timeouts.fetch_add(1, Ordering::Relaxed);
                let after = p.first_sent.elapsed();
                fail(
                    p.reply,
                    LinkError::Timeout {
                        msg: p.request.msg(),
                        attempts: p.attempts,
                        after,
                    },
                );
            }
        }
    }

    async fn start<W: AsyncWrite + Unpin>(
        &self,
        wr: &mut W,
        request: Request,
        seq: u8,
        busy_left: u32,
        reply: Option<oneshot::Sender<Result<Response, HalError>>>,
    ) -> Result<Pending, LinkError> {
        let bytes = Packet::request(seq, request).to_frame().to_bytes();
        if let Err(e) = write(wr, &bytes, self.config.baud).await {
            // The caller hears why (not just that the link closed after it).
            fail(reply, e.clone());
            return Err(e);
        }
        self.stats.requests.fetch_add(1, Ordering::Relaxed);
        let now = Instant::now();
        Ok(Pending {
            deadline: now + self.deadline(&request),
            first_sent: now,
            measures_link: true,
            budget: self.config.budget(
                &request,
                Duration::from_millis(self.stats.watchdog_ms.load(Ordering::Relaxed)),
            ),
            request,
            seq,
            bytes,
            attempts: 1,
            busy_left,
            resend_new_seq: false,
            reply,
        })
    }

    /// The deadline of one attempt: [`LinkConfig::deadline`] plus twice the latency measured
    /// on this link (a USB adapter adds 1–16 ms each way), so that a slow adapter is not
    /// taken for a lost frame.
    fn deadline(&self, request: &Request) -> Duration {
        let latency = self.stats.adapter_latency().unwrap_or_else(|| {
            Duration::from_micros(self.stats.latency_bound_us.load(Ordering::Relaxed))
        });
        self.config.deadline(request) + 2 * latency.min(Duration::from_secs(1))
    }

    /// What an answer tells of the link: the time beyond transmission, and the watchdog
    /// timeout the device acknowledged. The shortest time seen on a first attempt is the
    /// adapter's latency plus the device's quickest turnaround. A retried request's answer may
    /// be to any attempt: its time from the first is only an upper bound, used until a first
    /// attempt is answered (deadlines too long for a while rather than retries forever on a
    /// link slower than every deadline).
    fn measured(&self, p: &Pending, response: &Response) {
        let beyond = p
            .first_sent
            .elapsed()
            .saturating_sub(self.config.wire_time(&p.request));
        if p.attempts == 1 {
            self.stats.record_latency(beyond);
        } else if p.measures_link {
            let us = u64::try_from(beyond.as_micros()).unwrap_or(u64::MAX);
            self.stats.latency_bound_us.fetch_max(us, Ordering::Relaxed);
        }
        if let Response::ConfigureWatchdog(w) = response {
            self.stats
                .watchdog_ms
                .store(u64::from(w.timeout_ms), Ordering::Relaxed);
        }
    }

    fn dispatch(
        &self,
        frame: &crate::protocol::Frame,
        pending: &mut Option<Pending>,
        unwrap: &mut Unwrap,
    ) {
        let packet = match Packet::from_frame(frame) {
            Ok(p) => p,
            Err(e) => {
                self.stats.undecodable.fetch_add(1, Ordering::Relaxed);
                if let Some(p) =
                    pending.take_if(|p| p.seq == frame.seq && p.request.msg() == frame.msg)
                {
                    fail(p.reply, LinkError::Decode(e));
                }
                return;
            }
        };
        match packet.body {
            Body::Event { event } => self.event(event, unwrap),
            Body::Response { response } => {
                match pending.take_if(|p| p.seq == packet.seq && p.request.msg() == response.msg())
                {
                    Some(p) => {
                        self.measured(&p, &response);
                        if let Some(r) = p.reply {
                            let _ = r.send(Ok(response));
                        }
                    }
                    None => {
                        self.stats.stale_answers.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
            Body::Nack { msg, nack } => {
                let Some(p) = pending
                    .as_mut()
                    .filter(|p| p.seq == packet.seq && p.request.msg() == msg)
                else {
                    self.stats.stale_answers.fetch_add(1, Ordering::Relaxed);
                    return;
                };
                if nack.code == NackCode::Busy && p.busy_left > 0 {
                    self.stats.busy.fetch_add(1, Ordering::Relaxed);
                    p.busy_left -= 1;
                    p.resend_new_seq = true;
                    p.deadline = Instant::now() + self.config.busy_backoff;
                    return;
                }
                if let Some(p) = pending.take() {
                    if let Some(r) = p.reply {
                        let _ = r.send(Err(HalError::Nack { msg, nack }));
                    }
                }
            }
            Body::Request { .. } => {
                self.stats.stale_answers.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    fn event(&self, event: Event, u: &mut Unwrap) {
        let t = match event {
            Event::Telemetry(t) => t,
            Event::MotionDone(done) => {
                let _ = self.motion_done.send(done);
                return;
            }
        };
        let dropped = match u.last {
            Some((idx, l, r, ts)) => {
                u.left += i64::from(t.left_counts.wrapping_sub(l));
                u.right += i64::from(t.right_counts.wrapping_sub(r));
                u.time_us += u64::from(t.timestamp_us.wrapping_sub(ts));
                t.sample_index.wrapping_sub(idx).wrapping_sub(1)
            }
            None => {
                u.left = i64::from(t.left_counts);
                u.right = i64::from(t.right_counts);
                u.time_us = u64::from(t.timestamp_us);
                0
            }
        };
        u.last = Some((
            t.sample_index,
            t.left_counts,
            t.right_counts,
            t.timestamp_us,
        ));
        self.stats
            .telemetry_dropped
            .fetch_add(u64::from(dropped), Ordering::Relaxed);
        self.stats
            .telemetry_received
            .fetch_add(1, Ordering::Relaxed);
        let _ = self.events.send(TelemetrySample {
            sample_index: t.sample_index,
            device_time_s: units::us_to_s(u.time_us),
            left_counts: u.left,
            right_counts: u.right,
            heading_rad: wrap_angle(units::urad_to_rad(t.heading_urad)),
            heading_valid: t.heading_valid,
            motion_state: t.motion_state,
            queue_depth: t.queue_depth,
            dropped_before: dropped,
        });
    }
}

/// With the link gone: fails the pending request, the queued ones and the next command (the
/// loop calls it again for each); false when the task is to end.
async fn refuse_while_closed(
    err: &LinkError,
    pending: &mut Option<Pending>,
    queue: &mut VecDeque<Queued>,
    commands: &mut mpsc::UnboundedReceiver<Command>,
) -> bool {
    if let Some(p) = pending.take() {
        fail(p.reply, err.clone());
    }
    for (_, _, reply) in queue.drain(..) {
        let _ = reply.send(Err(HalError::Link(err.clone())));
    }
    match commands.recv().await {
        Some(Command::Request { reply, .. }) => {
            let _ = reply.send(Err(HalError::Link(err.clone())));
            true
        }
        Some(Command::EmergencyStop) => true,
        Some(Command::Close) | None => false,
    }
}

fn fail(reply: Option<oneshot::Sender<Result<Response, HalError>>>, err: LinkError) {
    if let Some(r) = reply {
        let _ = r.send(Err(HalError::Link(err)));
    }
}

/// Sends `bytes` by the time their transmission takes at `baud` and the slack of a write
/// ([`transport::write_deadline`]): a port that takes nothing for that long has gone.
async fn write<W: AsyncWrite + Unpin>(
    wr: &mut W,
    bytes: &[u8],
    baud: u32,
) -> Result<(), LinkError> {
    let by = transport::write_deadline(bytes.len(), baud);
    match transport::write_all_by(wr, bytes, by).await {
        Ok(()) => Ok(()),
        // The far end has gone, as a read that ends says: the link closed.
        Err(e) if gone(&e) => Err(LinkError::Closed),
        Err(e) => Err(e.into()),
    }
}

/// Whether a read or write failed because the other end has gone (unplugged, closed).
fn gone(e: &std::io::Error) -> bool {
    use std::io::ErrorKind::{BrokenPipe, ConnectionAborted, ConnectionReset};
    matches!(e.kind(), BrokenPipe | ConnectionReset | ConnectionAborted)
}
