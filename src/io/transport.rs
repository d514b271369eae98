//! The byte stream under every serial protocol client, the one way odocal waits on it, and
//! the one way a link is shared.
//!
//! **The seam.** A client (the HAL's link, the RoboClaw, the NMEA compass, conformance's wire)
//! takes any [`Transport`]: a serial port from [`super::serial::open`], a pseudo-terminal, or
//! one end of the in-memory [`pair`] its tests use. Rosbridge's WebSocket runs over one as
//! well (`RosbridgeClient::connect_stream`).
//!
//! **Deadlines.** No serial client (the HAL, the RoboClaw, the NMEA compass, conformance)
//! reads or writes but through these helpers, and none waits without a [`Deadline`] except
//! the compass's reader, which waits on nothing else (a compass talks when it will):
//! [`read_some_by`],
//! [`read_exact_by`] and [`write_all_by`] tell a deadline that passed ([`Read::Late`], or an
//! error of kind `TimedOut` for a write) from a stream that ended ([`Read::Closed`]) and from
//! an I/O error, so a client decides what each means for its protocol (ask again, give up,
//! report the device gone) instead of each wrapping its own `tokio::time::timeout`. A write
//! has a deadline too: a USB adapter whose device vanished can block a write for good.
//! (Rosbridge's bytes are the WebSocket library's: its client waits on messages, and its
//! handshake has one timeout, in `ros::rosbridge`.)
//!
//! **One concurrency model.** A link's transport belongs to the task(s) its client spawns,
//! never to a lock its callers share: the HAL's link task and the RoboClaw's transaction task
//! (each caller's request goes through an unbounded channel with a `oneshot` for its answer),
//! the NMEA compass's reader task and rosbridge's reader and writer tasks (what arrives unasked
//! is published through `watch`/`broadcast` channels, [`crate::base::latest`]). So a caller
//! whose future is dropped mid-request (a timeout around `stop()`, Ctrl-C) never cuts an
//! exchange in half: the task finishes the exchange under way and drops the answer. The
//! channels are
//! unbounded because each caller awaits its own answer (the queue holds at most one request
//! per caller) and because a stop sent from `Drop`, which cannot wait, must never be refused
//! for a full queue.

use std::io;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

/// A byte stream a protocol client runs on: a serial port, a pseudo-terminal, a TCP stream, an
/// in-memory [`pair`].
pub trait Transport: AsyncRead + AsyncWrite + Unpin + Send + 'static {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send + 'static> Transport for T {}

/// A transport whose type a client does not name.
pub type BoxTransport = Box<dyn Transport>;

/// The instant by which a read or write must be done; [`Deadline::never`] for none (a task
/// that waits on something else beside it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Deadline(Option<Instant>);

impl Deadline {
    /// `wait` from now.
    pub fn after(wait: Duration) -> Self {
        Deadline(Some(Instant::now() + wait))
    }

    /// At `when`.
    pub fn at(when: Instant) -> Self {
        Deadline(Some(when))
    }

    /// No deadline.
    pub fn never() -> Self {
        Deadline(None)
    }

    /// At `when`, or never when there is none.
    pub fn at_or_never(when: Option<Instant>) -> Self {
        Deadline(when)
    }

    /// The instant, unless there is none.
    pub fn instant(self) -> Option<Instant> {
        self.0
    }

    /// Whether it has passed.
    pub fn passed(self) -> bool {
        self.0.is_some_and(|t| Instant::now() >= t)
    }

    /// The time left (zero once passed; `None` for no deadline).
    pub fn remaining(self) -> Option<Duration> {
        self.0.map(|t| t.saturating_duration_since(Instant::now()))
    }

    /// Whichever comes first.
    pub fn min(self, other: Deadline) -> Deadline {
        match (self.0, other.0) {
            (Some(a), Some(b)) => Deadline(Some(a.min(b))),
            (a, b) => Deadline(a.or(b)),
        }
    }

    /// Waits until it passes (forever for no deadline).
    pub async fn sleep(self) {
        match self.0 {
            Some(t) => tokio::time::sleep_until(t).await,
            None => std::future::pending().await,
        }
    }
}

/// What a read brought.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Read {
    /// This many bytes (at least one; for [`read_exact_by`], the whole buffer).
    Got(usize),
    /// The stream ended: the device was unplugged or the peer closed it.
    Closed,
    /// The deadline passed first (for [`read_exact_by`], whatever part arrived is lost).
    Late,
}

/// Reads what arrives, at least one byte, by `by`. Cancel-safe: in a `select!`, a read that
/// loses takes nothing.
pub async fn read_some_by<R>(r: &mut R, buf: &mut [u8], by: Deadline) -> io::Result<Read>
where
    R: AsyncRead + Unpin + ?Sized,
{
    let read = r.read(buf);
    let n = match by.0 {
        None => read.await?,
        Some(t) => match tokio::time::timeout_at(t, read).await {
            Err(_) => return Ok(Read::Late),
            Ok(n) => n?,
        },
    };
    Ok(if n == 0 { Read::Closed } else { Read::Got(n) })
}

/// Reads exactly `buf.len()` bytes by `by`. Not cancel-safe, and a late read loses the part
/// that came: for answers whose tail the next exchange discards anyway.
pub async fn read_exact_by<R>(r: &mut R, buf: &mut [u8], by: Deadline) -> io::Result<Read>
where
    R: AsyncRead + Unpin + ?Sized,
{
    let read = r.read_exact(buf);
    let done = match by.0 {
        None => read.await,
        Some(t) => match tokio::time::timeout_at(t, read).await {
            Err(_) => return Ok(Read::Late),
            Ok(done) => done,
        },
    };
    match done {
        Ok(n) => Ok(Read::Got(n)),
        Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => Ok(Read::Closed),
        Err(e) => Err(e),
    }
}

/// Takes what is already waiting, without waiting: [`Read::Late`] when nothing is.
pub fn read_waiting<R>(r: &mut R, buf: &mut [u8]) -> io::Result<Read>
where
    R: AsyncRead + Unpin + ?Sized,
{
    use futures_util::FutureExt;
    match r.read(buf).now_or_never() {
        None => Ok(Read::Late),
        Some(Ok(0)) => Ok(Read::Closed),
        Some(Ok(n)) => Ok(Read::Got(n)),
        Some(Err(e)) => Err(e),
    }
}

/// Writes all of `bytes` and flushes them by `by`; past it, an error of kind `TimedOut` that
/// says how many bytes were waiting (the port took none, or not all, in time).
pub async fn write_all_by<W>(w: &mut W, bytes: &[u8], by: Deadline) -> io::Result<()>
where
    W: AsyncWrite + Unpin + ?Sized,
{
    let write = async {
        w.write_all(bytes).await?;
        w.flush().await
    };
    match by.0 {
        None => write.await,
        Some(t) => match tokio::time::timeout_at(t, write).await {
            Ok(done) => done,
            Err(_) => Err(io::Error::new(
                io::ErrorKind::TimedOut,
                format!(
                    "the port did not take {} byte(s) in time: is the adapter still there?",
                    bytes.len()
                ),
            )),
        },
    }
}

/// The slack a write gets beyond its transmission time: a USB adapter's buffer and a host late
/// by a scheduling slice take far less; a port that takes nothing for this long is gone.
pub const WRITE_SLACK: Duration = Duration::from_secs(1);

/// The deadline of a write of `bytes` bytes at `baud`: their transmission and [`WRITE_SLACK`].
pub fn write_deadline(bytes: usize, baud: u32) -> Deadline {
    Deadline::after(super::serial::transmission(bytes, baud) + WRITE_SLACK)
}

/// Discards bytes that arrive within `quiet` of each other, for at most `at_most` (a stream
/// that never pauses is not waited out); returns how many. Ends at the first error or when the
/// stream ends: the exchange that follows meets it.
pub async fn drain<R>(r: &mut R, quiet: Duration, at_most: Duration) -> usize
where
    R: AsyncRead + Unpin + ?Sized,
{
    let mut junk = [0u8; 64];
    let until = Deadline::after(at_most);
    let mut dropped = 0;
    while let Ok(Read::Got(n)) = read_some_by(r, &mut junk, Deadline::after(quiet)).await {
        dropped += n;
        if until.passed() {
            break;
        }
    }
    dropped
}

/// Two transports joined in memory, each buffering up to `capacity` bytes the other has not
/// read: a client on one end, a mock device on the other, no pseudo-terminal.
pub fn pair(capacity: usize) -> (tokio::io::DuplexStream, tokio::io::DuplexStream) {
    tokio::io::duplex(capacity)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn a_read_tells_bytes_a_late_peer_and_an_ended_one_apart() {
        let (mut a, mut b) = pair(64);
        let mut buf = [0u8; 8];
        let late = read_some_by(&mut a, &mut buf, Deadline::after(Duration::from_millis(5)));
        assert_eq!(late.await.unwrap(), Read::Late);
        write_all_by(&mut b, b"abc", Deadline::never())
            .await
            .unwrap();
        let got = read_some_by(&mut a, &mut buf, Deadline::after(Duration::from_millis(5)));
        assert_eq!(got.await.unwrap(), Read::Got(3));
        assert_eq!(&buf[..3], b"abc");
        assert_eq!(read_waiting(&mut a, &mut buf).unwrap(), Read::Late);
        drop(b);
        let closed = read_some_by(&mut a, &mut buf, Deadline::after(Duration::from_millis(5)));
        assert_eq!(closed.await.unwrap(), Read::Closed);
        assert_eq!(read_waiting(&mut a, &mut buf).unwrap(), Read::Closed);
    }

    #[tokio::test(start_paused = true)]
    async fn an_exact_read_waits_for_the_whole_answer_or_says_late_or_closed() {
        let (mut a, mut b) = pair(64);
        let mut buf = [0u8; 4];
        write_all_by(&mut b, b"ab", Deadline::never())
            .await
            .unwrap();
        let short = read_exact_by(&mut a, &mut buf, Deadline::after(Duration::from_millis(5)));
        assert_eq!(short.await.unwrap(), Read::Late);
        write_all_by(&mut b, b"wxyz", Deadline::never())
            .await
            .unwrap();
        let whole = read_exact_by(&mut a, &mut buf, Deadline::after(Duration::from_millis(5)));
        assert_eq!(whole.await.unwrap(), Read::Got(4));
        assert_eq!(&buf, b"wxyz");
        write_all_by(&mut b, b"z", Deadline::never()).await.unwrap();
        drop(b);
        assert_eq!(
            read_exact_by(&mut a, &mut buf, Deadline::never())
                .await
                .unwrap(),
            Read::Closed
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_write_the_peer_never_takes_fails_by_its_deadline() {
        let (mut a, _b) = pair(4);
        let by = Deadline::after(Duration::from_millis(50));
        let err = write_all_by(&mut a, b"more than four", by)
            .await
            .unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::TimedOut);
        assert!(err.to_string().contains("14 byte(s)"), "{err}");
        assert!(by.passed());
    }

    #[tokio::test(start_paused = true)]
    async fn drain_drops_a_burst_and_stops_at_a_pause_or_its_limit() {
        let (mut a, mut b) = pair(256);
        write_all_by(&mut b, &[7u8; 100], Deadline::never())
            .await
            .unwrap();
        assert_eq!(
            drain(&mut a, Duration::from_millis(2), Duration::from_secs(1)).await,
            100
        );
        // A peer that never pauses: drained for at most the limit.
        let talker = tokio::spawn(async move {
            loop {
                if write_all_by(&mut b, &[1u8; 8], Deadline::never())
                    .await
                    .is_err()
                {
                    return;
                }
                tokio::time::sleep(Duration::from_millis(1)).await;
            }
        });
        let started = Instant::now();
        let dropped = drain(&mut a, Duration::from_millis(5), Duration::from_millis(100)).await;
        assert!(dropped > 0);
        let took = started.elapsed();
        assert!(
            took >= Duration::from_millis(100) && took < Duration::from_millis(120),
            "{took:?}"
        );
        talker.abort();
    }

    #[test]
    fn deadlines_order_and_tell_when_they_have_passed() {
        let soon = Deadline::at(Instant::now() + Duration::from_secs(1));
        let later = Deadline::at(Instant::now() + Duration::from_secs(5));
        assert_eq!(soon.min(later), soon);
        assert_eq!(Deadline::never().min(later), later);
        assert!(!Deadline::never().passed());
        assert_eq!(Deadline::never().remaining(), None);
        assert!(Deadline::at(Instant::now()).passed());
        assert!(Deadline::at_or_never(None) == Deadline::never());
    }
}
