//! An NMEA 0183 compass on a serial line as the seam's [`HeadingSource`].

use super::sentence::{azimuth_to_heading, parse, Kind, NmeaError, MAX_SENTENCE};
use crate::base::{
    BaseError, ComponentInfo, Fanout, HeadingKind, HeadingSample, HeadingSource, SampleStream,
    Validity,
};
use async_trait::async_trait;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt};
use tokio::sync::watch;
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
    latest: watch::Receiver<Option<(Instant, HeadingSample)>>,
    stats: Arc<Mutex<(NmeaStats, Option<String>)>>,
    streams: Fanout<HeadingSample>,
    stale: Duration,
}

impl NmeaCompass {
    /// Reads sentences from `stream` (a serial port, PTY, anything); `label` names it.
    pub fn new<S>(stream: S, label: &str, stale: Duration) -> Self
    where
        S: AsyncRead + Unpin + Send + 'static,
    {
        let (tx, latest) = watch::channel(None);
        let stats: Arc<Mutex<(NmeaStats, Option<String>)>> = Arc::default();
        let streams: Fanout<HeadingSample> = Fanout::default();
        tokio::spawn(read_sentences(stream, tx, stats.clone(), streams.clone()));
        NmeaCompass {
            label: label.into(),
            latest,
            stats,
            streams,
            stale,
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
        Ok(Self::new(port, path, stale))
    }

    /// What has been received.
    pub fn stats(&self) -> NmeaStats {
        self.stats.lock().unwrap_or_else(|p| p.into_inner()).0
    }
}

async fn read_sentences<S: AsyncRead + Unpin>(
    mut stream: S,
    tx: watch::Sender<Option<(Instant, HeadingSample)>>,
    stats: Arc<Mutex<(NmeaStats, Option<String>)>>,
    streams: Fanout<HeadingSample>,
) {
    let mut line: Vec<u8> = Vec::with_capacity(MAX_SENTENCE);
    let mut chunk = [0u8; 256];
    let mut chosen: Option<Kind> = None;
    let mut too_long = false;
    loop {
        let n = match stream.read(&mut chunk).await {
            Ok(0) | Err(_) => return,
            Ok(n) => n,
        };
        for &b in &chunk[..n] {
            if b != b'\n' {
                if line.len() < MAX_SENTENCE {
                    line.push(b);
                } else {
                    too_long = true;
                }
                continue;
            }
            let text = String::from_utf8_lossy(&line).into_owned();
            line.clear();
            let mut st = stats.lock().unwrap_or_else(|p| p.into_inner());
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
                    let sample = HeadingSample {
                        time_s: crate::base::host_time_s(),
                        heading_rad: azimuth_to_heading(azimuth),
                        validity: Validity::Valid,
                    };
                    drop(st);
                    streams.send(&sample);
                    let _ = tx.send(Some((Instant::now(), sample)));
                }
                Err(NmeaError::Other(_)) => st.0.ignored += 1,
                Err(e @ NmeaError::Checksum { .. }) => {
                    st.0.bad_checksums += 1;
                    st.1 = Some(e.to_string());
                }
                Err(e) => {
                    st.0.malformed += 1;
                    st.1 = Some(e.to_string());
                }
            }
        }
    }
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
        let mut rx = self.latest.clone();
        let fresh = tokio::time::timeout(
            self.stale,
            rx.wait_for(|h| h.as_ref().is_some_and(|(at, _)| *at >= asked)),
        )
        .await;
        match fresh {
            Ok(Ok(h)) => Ok(h.as_ref().map(|(_, s)| s.clone()).unwrap_or(HeadingSample {
                time_s: 0.0,
                heading_rad: 0.0,
                validity: Validity::Invalid("no reading".into()),
            })),
            Ok(Err(_)) => Err(BaseError::HeadingInvalid {
                reason: format!("{} closed", self.label),
            }),
            Err(_) => {
                let (stats, last_error) =
                    self.stats.lock().unwrap_or_else(|p| p.into_inner()).clone();
                Ok(HeadingSample {
                    time_s: 0.0,
                    heading_rad: 0.0,
                    validity: Validity::Invalid(format!(
                        "stale: no valid heading sentence on {} within {:?} ({} used, {} bad checksums, {} malformed{})",
                        self.label,
                        self.stale,
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
}
