//! Serving a [`MockDevice`] over a byte stream: an in-memory duplex or a real pseudo-terminal,
//! in virtual or scaled real time, with seeded fault injection.

use super::device::MockDevice;
use super::pty::{spawn_on_pty, PtyServer};
use crate::protocol::{Frame, FrameCodec, FrameKind};
use bytes::BytesMut;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

/// SPEC.md §2.1's inter-byte gap after which a partial frame is discarded.
pub const INTER_BYTE_GAP: Duration = Duration::from_millis(20);

/// A device shared between its server task and observers (tests, the CLI).
pub type SharedDevice = Arc<Mutex<MockDevice>>;

/// A second sensor on the device's robot (the `--nmea` compass beside its own): the true
/// heading, to which the compass adds only its own noise. It shares none of the device's own
/// sensor's errors, so a gyro can be measured against it.
pub fn separate_compass(device: &SharedDevice) -> super::nmea::HeadingFn {
    let device = device.clone();
    Arc::new(move || Some(lock(&device).sim().pose().heading_rad))
}

/// Locks a shared device; a panic elsewhere while holding the lock does not make the device's
/// state unusable for observers, so poisoning is ignored.
pub fn lock(device: &SharedDevice) -> MutexGuard<'_, MockDevice> {
    device.lock().unwrap_or_else(|e| e.into_inner())
}

/// How device time passes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum TimeMode {
    /// A motion completes the moment it is accepted (telemetry is generated in device time).
    Virtual,
    /// Device time follows the wall clock, multiplied by `scale` (1 = real time).
    RealTime {
        /// Device seconds per wall-clock second.
        scale: f64,
    },
}

/// Seeded misbehaviour of the link and the device.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct FaultConfig {
    /// Probability that any byte, in either direction, has one bit flipped.
    pub corrupt_byte_rate: f64,
    /// Probability that a whole frame, in either direction, is lost.
    pub drop_frame_rate: f64,
    /// Delay before each answer.
    pub latency: Duration,
    /// The device vanishes (stops reading and writing) after receiving this many frames.
    pub disconnect_after_frames: Option<u64>,
    /// Every n-th request is answered NACK BUSY without being executed.
    pub busy_every: Option<u64>,
    /// The device vanishes right after executing the first request with this message id,
    /// its answer unsent: a device killed at the worst moment (a SAVE_PARAMS that landed but
    /// was never acknowledged).
    #[serde(default)]
    pub vanish_after_executing: Option<u8>,
    /// Seed of the fault draws (independent of the simulator's).
    pub seed: u64,
}

impl std::str::FromStr for FaultConfig {
    type Err = super::MockError;

    /// Parses `corrupt=0.01,drop=0.05,latency-ms=5,disconnect-after=200,busy-every=7,seed=3`
    /// (any subset, any order): probabilities in [0, 1], a latency in [0, 10 000] ms, counts
    /// as whole numbers. Anything else is refused with the key it concerns.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        parse_faults(s).map_err(super::MockError::Faults)
    }
}

fn parse_faults(s: &str) -> Result<FaultConfig, String> {
    let mut f = FaultConfig::default();
    for item in s.split(',').filter(|i| !i.trim().is_empty()) {
        let (k, v) = item
            .split_once('=')
            .ok_or_else(|| format!("{item:?} is not key=value"))?;
        let num = |v: &str| v.trim().parse::<f64>().map_err(|e| format!("{k}: {e}"));
        let int = |v: &str| v.trim().parse::<u64>().map_err(|e| format!("{k}: {e}"));
        match k.trim() {
            "corrupt" => f.corrupt_byte_rate = num(v)?,
            "drop" => f.drop_frame_rate = num(v)?,
            "latency-ms" => {
                let ms = num(v)?;
                // A device answers within 50 ms (SPEC.md §3); a mock may be slower, but not
                // negative, not NaN and not for ever.
                if !(0.0..=10_000.0).contains(&ms) {
                    return Err(format!("latency-ms must be in [0, 10000], got {v}"));
                }
                f.latency = Duration::from_secs_f64(ms / 1e3);
            }
            "disconnect-after" => f.disconnect_after_frames = Some(int(v)?),
            "busy-every" => f.busy_every = Some(int(v)?),
            "seed" => f.seed = int(v)?,
            other => return Err(format!("unknown fault {other:?}")),
        }
    }
    for (name, p) in [
        ("corrupt", f.corrupt_byte_rate),
        ("drop", f.drop_frame_rate),
    ] {
        if !(0.0..=1.0).contains(&p) {
            return Err(format!("{name} must be a probability in [0, 1], got {p}"));
        }
    }
    Ok(f)
}

/// Why a server stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ServeEnd {
    /// The host closed the stream.
    HostClosed,
    /// The device vanished as `disconnect_after_frames` asked.
    Disconnected,
}

struct Faults {
    cfg: FaultConfig,
    rng: ChaCha8Rng,
    frames_in: u64,
    requests: u64,
}

impl Faults {
    fn corrupt(&mut self, bytes: &mut [u8]) {
        if self.cfg.corrupt_byte_rate <= 0.0 {
            return;
        }
        for b in bytes {
            if self.rng.random_bool(self.cfg.corrupt_byte_rate.min(1.0)) {
                *b ^= 1 << self.rng.random_range(0..8);
            }
        }
    }

    fn lose(&mut self) -> bool {
        self.cfg.drop_frame_rate > 0.0 && self.rng.random_bool(self.cfg.drop_frame_rate.min(1.0))
    }
}

async fn send<W: AsyncWrite + Unpin>(
    w: &mut W,
    frames: Vec<Frame>,
    faults: &mut Faults,
) -> std::io::Result<()> {
    for f in frames {
        if faults.lose() {
            continue;
        }
        let mut bytes = f.to_bytes();
        faults.corrupt(&mut bytes);
        w.write_all(&bytes).await?;
    }
    w.flush().await
}

/// Serves `device` over `stream` until the host closes it or a fault makes the device vanish.
pub async fn serve<S>(
    device: SharedDevice,
    stream: S,
    time: TimeMode,
    faults: FaultConfig,
) -> std::io::Result<ServeEnd>
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    let (mut rd, mut wr) = tokio::io::split(stream);
    if let TimeMode::RealTime { scale } = time {
        lock(&device).set_host_time_scale(scale);
    }
    let mut faults = Faults {
        cfg: faults,
        rng: ChaCha8Rng::seed_from_u64(faults.seed),
        frames_in: 0,
        requests: 0,
    };
    let mut codec = FrameCodec::new();
    let mut buf = BytesMut::new();
    let mut chunk = [0u8; 1024];
    let tick = Duration::from_millis(2);
    let mut last = tokio::time::Instant::now();
    let mut last_byte = last;
    loop {
        let n = match time {
            TimeMode::Virtual => rd.read(&mut chunk).await?,
            TimeMode::RealTime { scale } => {
                tokio::select! {
                    r = rd.read(&mut chunk) => r?,
                    () = tokio::time::sleep(tick) => {
                        let now = tokio::time::Instant::now();
                        let dt = (now - last).as_secs_f64() * scale;
                        last = now;
                        let events = lock(&device).advance(dt);
                        send(&mut wr, events, &mut faults).await?;
                        continue;
                    }
                }
            }
        };
        if n == 0 {
            return Ok(ServeEnd::HostClosed);
        }
        // SPEC.md §2.1: a partial frame older than the inter-byte gap is discarded (the host
        // may have restarted mid-frame).
        let now = tokio::time::Instant::now();
        if !buf.is_empty() && now - last_byte > INTER_BYTE_GAP {
            buf.clear();
        }
        last_byte = now;
        let bytes = &mut chunk[..n];
        faults.corrupt(bytes);
        for frame in codec.feed(&mut buf, bytes) {
            faults.frames_in += 1;
            if faults
                .cfg
                .disconnect_after_frames
                .is_some_and(|n| faults.frames_in > n)
            {
                run_on_until_idle(&device, time, tick, last).await;
                return Ok(ServeEnd::Disconnected);
            }
            if faults.lose() {
                continue;
            }
            let Some(out) = answer(&device, &frame, time, &mut faults, &mut last) else {
                return Ok(ServeEnd::Disconnected);
            };
            if !faults.cfg.latency.is_zero() {
                tokio::time::sleep(faults.cfg.latency).await;
            }
            send(&mut wr, out, &mut faults).await?;
        }
    }
}

/// After the link is gone the firmware lives on: in real time it keeps executing (and its
/// watchdog keeps watching) until the base is idle; device time was last advanced at `last`.
async fn run_on_until_idle(
    device: &SharedDevice,
    time: TimeMode,
    tick: Duration,
    mut last: tokio::time::Instant,
) {
    if let TimeMode::RealTime { scale } = time {
        while lock(device).is_moving() {
            tokio::time::sleep(tick).await;
            let now = tokio::time::Instant::now();
            lock(device).advance((now - last).as_secs_f64() * scale);
            last = now;
        }
    }
}

/// The frames the device sends in answer to `frame` (a BUSY or a refusal injected, device time
/// brought up to now from `last`), or `None` when it vanishes right after executing it.
fn answer(
    device: &SharedDevice,
    frame: &Frame,
    time: TimeMode,
    faults: &mut Faults,
    last: &mut tokio::time::Instant,
) -> Option<Vec<Frame>> {
    let mut out = Vec::new();
    if frame.kind == FrameKind::Request {
        faults.requests += 1;
    }
    let busy = frame.kind == FrameKind::Request
        && faults
            .cfg
            .busy_every
            .is_some_and(|k| k > 0 && faults.requests.is_multiple_of(k));
    if busy {
        out.extend(MockDevice::busy(frame));
    } else if time == TimeMode::Virtual && is_open_ended_wheel_speed(frame) {
        // Virtual time cannot run "until the next command": refuse, naming the field.
        out.push(
            crate::protocol::Packet::nack(
                frame.seq,
                frame.msg,
                crate::protocol::Nack {
                    code: crate::protocol::NackCode::OutOfRange,
                    detail: 2,
                },
            )
            .to_frame(),
        );
    } else {
        let mut d = lock(device);
        if let TimeMode::RealTime { scale } = time {
            // Bring device time up to now before the request is executed.
            let now = tokio::time::Instant::now();
            out.extend(d.advance((now - *last).as_secs_f64() * scale));
            *last = now;
        }
        out.extend(d.handle(frame));
        if frame.kind == FrameKind::Request && faults.cfg.vanish_after_executing == Some(frame.msg)
        {
            return None;
        }
        if time == TimeMode::Virtual {
            out.extend(d.run_until_idle());
        }
    }
    Some(out)
}

fn is_open_ended_wheel_speed(frame: &Frame) -> bool {
    matches!(
        crate::protocol::Packet::from_frame(frame),
        Ok(crate::protocol::Packet {
            body: crate::protocol::Body::Request {
                request: crate::protocol::Request::WheelSpeed(
                    crate::protocol::message::WheelSpeedRequest { duration_ms: 0, .. }
                )
            },
            ..
        })
    )
}

/// An in-process link: the host's end of a `tokio::io::duplex` whose other end is served.
pub fn spawn_duplex(
    device: SharedDevice,
    time: TimeMode,
    faults: FaultConfig,
) -> (
    tokio::io::DuplexStream,
    tokio::task::JoinHandle<std::io::Result<ServeEnd>>,
) {
    let (host, dev) = tokio::io::duplex(64 * 1024);
    let task = tokio::spawn(serve(device, dev, time, faults));
    (host, task)
}

/// Creates a pseudo-terminal and serves `device` on it.
pub fn spawn_pty(
    device: SharedDevice,
    time: TimeMode,
    faults: FaultConfig,
) -> std::io::Result<PtyServer<ServeEnd>> {
    spawn_on_pty(Box::new(move |master| {
        Box::pin(serve(device.clone(), master, time, faults))
    }))
}
