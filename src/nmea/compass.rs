//! An NMEA 0183 compass on a serial line as the seam's [`HeadingSource`].
//!
//! Compasses differ: 0.2 to 50 sentences a second, lines ended by CR LF, LF or CR alone, and a
//! port that holds whatever the compass sent before odocal opened it. So: what was queued
//! before the port was opened is dropped; any of the three line ends ends a sentence; and a
//! reading is stale only after about two and a half of the compass's own observed intervals
//! (never sooner than the configured minimum), so that a slow compass can be averaged.

use super::sentence::{azimuth_to_heading, parse, Kind, NmeaError, MAX_SENTENCE};
use crate::base::latest::{self, Fresh, Latest, Publisher};
use crate::base::{
    BaseError, ComponentInfo, Fanout, HeadingKind, HeadingSample, HeadingSource, SampleStream,
    Validity,
};
use crate::io::transport::{self, Deadline, Read};
use async_trait::async_trait;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::AsyncRead;
use tokio::time::Instant;

/// Counters of what the compass sent.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct NmeaStats {
    /// Heading sentences used.
    pub headings: u64,
    /// Sentences with a bad checksum.
    pub bad_checksums: u64,
    /// Malformed sentences or lines.
    pub malformed: u64,
    /// Other sentence types ignored.
    pub ignored: u64,
}

/// A compass on a serial line.
pub struct NmeaCompass {
    label: String,
    latest: Latest,
    stats: Arc<Mutex<(NmeaStats, Option<String>)>>,
    streams: Fanout<HeadingSample>,
    stale: Duration,
    arrivals: Arc<Mutex<VecDeque<Instant>>>,
}

/// The most bytes taken as one burst (about a hundred sentences).
const MAX_BURST: usize = 8192;
/// Arrivals kept to judge the compass's rate.
const RATE_WINDOW: usize = 9;
/// How long a first reading is awaited, before the compass's rate is known: a compass at
/// 0.2 Hz sends within 5 s.
pub const FIRST_WAIT: Duration = Duration::from_secs(6);
/// The longest a fresh reading is awaited, whatever the rate.
pub const MAX_WAIT: Duration = Duration::from_secs(15);

/// How long to await a fresh reading: 2.5 median intervals of `arrivals`, at least `min`,
/// at most [`MAX_WAIT`]; [`FIRST_WAIT`] (or `min`) before two sentences have arrived.
pub fn wait_for_fresh(arrivals: &VecDeque<Instant>, min: Duration) -> Duration {
    match interval(arrivals) {
        None => FIRST_WAIT.max(min),
        Some(median) => median.mul_f64(2.5).clamp(min, MAX_WAIT.max(min)),
    }
}

impl NmeaCompass {
    /// Reads sentences from `stream` (a serial port, PTY, anything); `label` names it.
    pub fn new<S>(stream: S, label: &str, stale: Duration) -> Self
    where
        S: AsyncRead + Unpin + Send + 'static,
    {
        let (tx, latest) = latest::channel();
        let stats: Arc<Mutex<(NmeaStats, Option<String>)>> = Arc::default();
        let streams: Fanout<HeadingSample> = Fanout::default();
        let arrivals: Arc<Mutex<VecDeque<Instant>>> = Arc::default();
        let out = Outputs {
            tx,
            stats: stats.clone(),
            streams: streams.clone(),
            arrivals: arrivals.clone(),
        };
        tokio::spawn(read_sentences(stream, out));
        NmeaCompass {
            label: label.into(),
            latest,
            stats,
            streams,
            stale,
            arrivals,
        }
    }

    /// Opens a serial port (4800–115200 baud).
    pub fn open(path: &str, baud: u32, stale: Duration) -> Result<Self, BaseError> {
        if !(4800..=115_200).contains(&baud) {
            return Err(BaseError::InvalidArgument {
                component: "heading (NMEA)".into(),
                reason: format!("baud {baud} is outside NMEA 0183's 4800–115200"),
            });
        }
        let port = crate::io::serial::open(path, baud)
            .map_err(|e| BaseError::backend(format!("heading (NMEA {path})"), e))?;
        // Sentences the compass sent before now would be taken for readings after the call.
        crate::io::serial::clear_input(&port)
            .map_err(|e| BaseError::backend(format!("heading (NMEA {path})"), e))?;
        Ok(Self::new(port, path, stale))
    }

    /// What has been received.
    pub fn stats(&self) -> NmeaStats {
        self.stats.lock().unwrap_or_else(|p| p.into_inner()).0
    }
}

/// Where the reader puts what it reads.
struct Outputs {
    tx: Publisher,
    stats: Arc<Mutex<(NmeaStats, Option<String>)>>,
    streams: Fanout<HeadingSample>,
    arrivals: Arc<Mutex<VecDeque<Instant>>>,
}

async fn read_sentences<S: AsyncRead + Unpin>(mut stream: S, out: Outputs) {
    let mut line: Vec<u8> = Vec::with_capacity(MAX_SENTENCE);
    let mut chunk = [0u8; 256];
    let mut chosen: Option<Kind> = None;
    let mut too_long = false;
    loop {
        // A compass talks on its own: no deadline, the readers' waits are on `Latest`.
        let n = match transport::read_some_by(&mut stream, &mut chunk, Deadline::never()).await {
            Ok(Read::Got(n)) => n,
            Ok(Read::Closed | Read::Late) | Err(_) => return,
        };
        // What is already waiting is read with it, so a backlog longer than one read is one
        // burst (and is stamped as one).
        let mut bytes = chunk[..n].to_vec();
        let mut ended = false;
        while bytes.len() < MAX_BURST {
            match transport::read_waiting(&mut stream, &mut chunk) {
                Ok(Read::Closed) | Err(_) => {
                    ended = true;
                    break;
                }
                Ok(Read::Got(m)) => bytes.extend_from_slice(&chunk[..m]),
                Ok(Read::Late) => break,
            }
        }
        let mut burst: Vec<f64> = Vec::new();
        for &b in &bytes {
            // CR LF, LF alone and CR alone all end a sentence; the empty line between CR and
            // LF is nothing.
            if b != b'\n' && b != b'\r' {
                if line.len() < MAX_SENTENCE {
                    line.push(b);
                } else {
                    too_long = true;
                }
                continue;
            }
            if line.is_empty() && !too_long {
                continue;
            }
            let text = String::from_utf8_lossy(&line).into_owned();
            line.clear();
            let mut st = out.stats.lock().unwrap_or_else(|p| p.into_inner());
            if std::mem::take(&mut too_long) {
                st.0.malformed += 1;
                st.1 = Some("a line longer than NMEA's 82 characters".into());
                continue;
            }
            match parse(&text) {
                Ok((kind, azimuth)) => {
                    // One sentence type throughout, the best heard so far.
                    if chosen.is_some_and(|c| kind > c) {
                        st.0.ignored += 1;
                        continue;
                    }
                    chosen = Some(kind);
                    st.0.headings += 1;
                    burst.push(azimuth_to_heading(azimuth));
                }
                Err(NmeaError::Other(_)) => st.0.ignored += 1,
                Err(e @ NmeaError::Checksum { .. }) => {
                    st.0.bad_checksums += 1;
                    st.1 = Some(e.to_string());
                }
                Err(e) => {
                    st.0.malformed += 1;
                    st.1 = Some(format!("{e} in {text:?}"));
                }
            }
        }
        publish(&out, &burst);
        if ended {
            return;
        }
    }
}

/// Publishes the headings of one read from the port. More than one at once is a backlog (the
/// host was stalled, the adapter held them): they were sent at the compass's own pace, so
/// each is stamped back from now at its observed interval (never before the previous one),
/// not all at one instant, which would read as a gap in the stream and a pile-up after it.
fn publish(out: &Outputs, headings: &[f64]) {
    let Some(last) = headings.len().checked_sub(1) else {
        return;
    };
    let now = Instant::now();
    let now_s = crate::base::host_time_s();
    let mut arrivals = out.arrivals.lock().unwrap_or_else(|p| p.into_inner());
    let interval = interval(&arrivals).unwrap_or_default();
    let previous = arrivals.back().copied();
    for (i, &heading_rad) in headings.iter().enumerate() {
        let back = interval * u32::try_from(last - i).unwrap_or(u32::MAX);
        let mut at = now.checked_sub(back).unwrap_or(now);
        if let Some(p) = previous {
            at = at.max(p);
        }
        let sample = HeadingSample {
            time_s: now_s - now.duration_since(at).as_secs_f64(),
            heading_rad,
            validity: Validity::Valid,
        };
        arrivals.push_back(at);
        while arrivals.len() > RATE_WINDOW {
            arrivals.pop_front();
        }
        out.streams.send(&sample);
        if i == last {
            out.tx.publish(at, sample);
        }
    }
}

/// The median interval between `arrivals`, if two have arrived.
fn interval(arrivals: &VecDeque<Instant>) -> Option<Duration> {
    let mut gaps: Vec<Duration> = arrivals
        .iter()
        .zip(arrivals.iter().skip(1))
        .map(|(a, b)| b.duration_since(*a))
        .collect();
    gaps.sort();
    gaps.get(gaps.len() / 2).copied()
}

#[async_trait]
impl HeadingSource for NmeaCompass {
    fn info(&self) -> ComponentInfo {
        ComponentInfo {
            kind: "nmea0183".into(),
            id: self.label.clone(),
            details: serde_json::to_value(self.stats()).unwrap_or_default(),
        }
    }

    async fn read(&self) -> Result<HeadingSample, BaseError> {
        // A reading taken after this call: never one from before the robot stopped.
        let asked = Instant::now();
        let wait = wait_for_fresh(
            &self.arrivals.lock().unwrap_or_else(|p| p.into_inner()),
            self.stale,
        );
        match self.latest.read_after(asked, wait, |_| true).await {
            Fresh::Got(sample) => Ok(sample),
            Fresh::Closed => Err(BaseError::HeadingInvalid {
                reason: format!("{} closed", self.label),
            }),
            Fresh::Stale(_) => {
                let (stats, last_error) =
                    self.stats.lock().unwrap_or_else(|p| p.into_inner()).clone();
                Ok(HeadingSample {
                    time_s: 0.0,
                    heading_rad: 0.0,
                    validity: Validity::Invalid(format!(
                        "stale: no valid heading sentence on {} within {} ({} used, {} bad checksums, {} malformed{})",
                        self.label,
                        crate::io::seconds(&wait),
                        stats.headings,
                        stats.bad_checksums,
                        stats.malformed,
                        last_error.map(|e| format!("; last: {e}")).unwrap_or_default()
                    )),
                })
            }
        }
    }

    async fn stream(
        &self,
        _period: Duration,
    ) -> Result<Option<SampleStream<HeadingSample>>, BaseError> {
        Ok(Some(self.streams.subscribe()))
    }

    fn kind(&self) -> HeadingKind {
        HeadingKind::Magnetic
    }

    fn clock(&self) -> Option<String> {
        // Stamped on arrival of each sentence.
        Some(crate::base::HOST_CLOCK.into())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nmea::sentence::sentence;

    /// Ten sentences at 10 Hz, then a stall of the host: the next five arrive in one read and
    /// are stamped 0.1 s apart, ending now, as the compass sent them.
    #[tokio::test(start_paused = true)]
    async fn a_backlog_read_at_once_keeps_the_compass_pace() {
        use tokio::io::AsyncWriteExt;
        let (mut tx, rx) = tokio::io::duplex(4096);
        let compass = NmeaCompass::new(rx, "test", Duration::from_millis(100));
        let mut stream = compass.stream(Duration::ZERO).await.unwrap().unwrap();
        let line = |deg: f64| sentence("HEHDT", &format!("{deg:.1},T"));
        for i in 0..10 {
            tx.write_all(line(f64::from(i)).as_bytes()).await.unwrap();
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        tokio::time::sleep(Duration::from_millis(400)).await;
        // Longer than one read of the port (256 bytes), padded as a talker may pad.
        let backlog: String = (10..15)
            .map(|i| {
                sentence(
                    "HEHDT",
                    &format!("{:.1},T,{}", f64::from(i), "0".repeat(40)),
                )
            })
            .collect();
        assert!(backlog.len() > 256);
        tx.write_all(backlog.as_bytes()).await.unwrap();
        tokio::time::sleep(Duration::from_millis(10)).await;
        let mut times = Vec::new();
        while let Ok(Some(h)) = tokio::time::timeout(Duration::from_millis(1), stream.recv()).await
        {
            times.push(h.time_s);
        }
        assert_eq!(times.len(), 15, "{times:?}");
        for w in times[10..].windows(2) {
            assert!(((w[1] - w[0]) - 0.1).abs() < 1e-3, "{times:?}");
        }
        assert!(times[10] > times[9], "{times:?}");
    }

    #[tokio::test]
    async fn a_stream_gives_fresh_readings_and_stale_ones_say_why() {
        let (mut tx, rx) = tokio::io::duplex(1024);
        let compass = NmeaCompass::new(rx, "test", Duration::from_millis(100));
        use tokio::io::AsyncWriteExt;
        let writer = tokio::spawn(async move {
            for i in 0..20 {
                let s = if i == 3 {
                    "$HEHDT,1.0,T*00\r\n".to_string()
                } else {
                    sentence("HEHDT", "90.0,T")
                };
                tx.write_all(s.as_bytes()).await.unwrap();
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
            tokio::time::sleep(Duration::from_millis(300)).await;
        });
        let h = compass.read().await.unwrap();
        assert!(h.validity.is_valid());
        assert!((h.heading_rad + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        tokio::time::sleep(Duration::from_millis(250)).await;
        let stale = compass.read().await.unwrap();
        match stale.validity {
            Validity::Invalid(why) => assert!(
                why.contains("stale") && why.contains("1 bad checksums"),
                "{why}"
            ),
            Validity::Valid => panic!("a silent compass must not read valid"),
        }
        writer.await.unwrap();
    }

    /// CR LF, LF alone and CR alone each end a sentence; a contradicting indicator is counted
    /// as malformed with its reason.
    #[tokio::test]
    async fn any_line_end_ends_a_sentence() {
        for end in ["\r\n", "\n", "\r"] {
            let (mut tx, rx) = tokio::io::duplex(1024);
            let compass = NmeaCompass::new(rx, "test", Duration::from_millis(200));
            use tokio::io::AsyncWriteExt;
            let writer = tokio::spawn(async move {
                for i in 0..30 {
                    let s = if i == 2 {
                        sentence("HCHDT", "123.4,M")
                    } else {
                        sentence("HCHDT", "270.0,T")
                    };
                    let s = s.trim_end().to_string() + end;
                    if tx.write_all(s.as_bytes()).await.is_err() {
                        return;
                    }
                    tokio::time::sleep(Duration::from_millis(10)).await;
                }
            });
            for _ in 0..3 {
                let h = compass.read().await.unwrap();
                assert!(h.validity.is_valid(), "{end:?}: {:?}", h.validity);
                assert!((h.heading_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
            }
            writer.await.unwrap();
            let st = compass.stats();
            assert_eq!(st.malformed, 1, "{end:?}: {st:?}");
            assert!(st.headings >= 25, "{end:?}: {st:?}");
        }
    }

    /// A compass at 0.5 Hz, then one at 0.2 Hz, read several times in a row: each reading waits
    /// for the next sentence (about 2.5 of the compass's intervals at most), none is stale.
    #[tokio::test(start_paused = true)]
    async fn a_slow_compass_is_read_sample_after_sample() {
        for period_s in [2.0, 5.0] {
            let (mut tx, rx) = tokio::io::duplex(1024);
            let compass = NmeaCompass::new(rx, "slow", Duration::from_secs(1));
            use tokio::io::AsyncWriteExt;
            let writer = tokio::spawn(async move {
                loop {
                    let s = sentence("HCHDT", "10.0,T");
                    if tx.write_all(s.as_bytes()).await.is_err() {
                        return;
                    }
                    tokio::time::sleep(Duration::from_secs_f64(period_s)).await;
                }
            });
            for i in 0..5 {
                let h = compass.read().await.unwrap();
                assert!(
                    h.validity.is_valid(),
                    "{period_s} s, reading {i}: {:?}",
                    h.validity
                );
            }
            writer.abort();
        }
        let mut a = VecDeque::new();
        let t = Instant::now();
        assert_eq!(wait_for_fresh(&a, Duration::from_secs(1)), FIRST_WAIT);
        for k in 0..5 {
            a.push_back(t + Duration::from_millis(100 * k));
        }
        assert_eq!(
            wait_for_fresh(&a, Duration::from_secs(1)),
            Duration::from_secs(1)
        );
        assert_eq!(
            wait_for_fresh(&a, Duration::from_millis(100)),
            Duration::from_millis(250)
        );
    }
}
