//! An NMEA 0183 compass as the seam's [`HeadingSource`]: `$--HDT` (true heading), `$--HDG`
//! (magnetic sensor heading with deviation and variation) and `$--HDM` (magnetic heading),
//! checksums verified, any talker, 4800–115200 baud.
//!
//! A compass azimuth is clockwise from north; the seam's heading is counter-clockwise positive
//! ([`crate::kinematics`]): [`azimuth_to_heading`] is the one conversion. A heading calibration
//! needs only changes of heading, so true and magnetic serve equally as long as one source is
//! used throughout: the first sentence type heard is kept, in the order HDT, HDG, HDM.

use crate::base::{
    BaseError, ComponentInfo, Fanout, HeadingSample, HeadingSource, SampleStream, Validity,
};
use crate::kinematics::wrap_angle;
use async_trait::async_trait;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt};
use tokio::sync::watch;
use tokio::time::Instant;

/// Longest sentence NMEA 0183 allows (82 characters including `$` and CR LF).
pub const MAX_SENTENCE: usize = 82;

/// Which sentence a heading came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
pub enum Kind {
    /// `HDT`, true.
    Hdt,
    /// `HDG`, magnetic with deviation and variation.
    Hdg,
    /// `HDM`, magnetic.
    Hdm,
}

/// A sentence that gives no heading.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NmeaError {
    /// Not `$…*hh`.
    #[error("not an NMEA sentence")]
    Framing,
    /// The checksum does not match.
    #[error("bad checksum: sentence says {stated:02X}, content gives {computed:02X}")]
    Checksum {
        /// The checksum written.
        stated: u8,
        /// The checksum of the content.
        computed: u8,
    },
    /// Not a heading sentence (another type this source ignores).
    #[error("`{0}` is not a heading sentence")]
    Other(String),
    /// A heading sentence whose fields are empty or malformed.
    #[error("{kind:?}: {reason}")]
    Field {
        /// The sentence type.
        kind: Kind,
        /// What is wrong.
        reason: String,
    },
}

/// Converts a compass azimuth (degrees clockwise from north) to the seam's heading (radians,
/// counter-clockwise positive, wrapped to (−π, π]).
pub fn azimuth_to_heading(azimuth_deg: f64) -> f64 {
    wrap_angle(-azimuth_deg.to_radians())
}

/// Parses one sentence (without CR LF) into its azimuth (degrees clockwise; true for HDT, HDG
/// with variation; magnetic otherwise).
pub fn parse(sentence: &str) -> Result<(Kind, f64), NmeaError> {
    let s = sentence.trim_end_matches(['\r', '\n']);
    let body = s.strip_prefix('$').ok_or(NmeaError::Framing)?;
    let (content, checksum) = body.rsplit_once('*').ok_or(NmeaError::Framing)?;
    let stated = u8::from_str_radix(checksum.trim(), 16).map_err(|_| NmeaError::Framing)?;
    let computed = content.bytes().fold(0u8, |a, b| a ^ b);
    if stated != computed {
        return Err(NmeaError::Checksum { stated, computed });
    }
    let mut fields = content.split(',');
    let address = fields.next().unwrap_or("");
    if address.len() != 5 || !address.is_ascii() {
        return Err(NmeaError::Other(address.into()));
    }
    let kind = match &address[2..] {
        "HDT" => Kind::Hdt,
        "HDG" => Kind::Hdg,
        "HDM" => Kind::Hdm,
        other => return Err(NmeaError::Other(other.into())),
    };
    let f: Vec<&str> = fields.collect();
    let field = |reason: String| NmeaError::Field { kind, reason };
    let num = |i: usize, name: &str| -> Result<Option<f64>, NmeaError> {
        match f.get(i).map(|v| v.trim()) {
            None | Some("") => Ok(None),
            Some(v) => v
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .map(Some)
                .ok_or_else(|| field(format!("{name} {v:?} is not a number"))),
        }
    };
    let heading = num(0, "heading")?.ok_or_else(|| field("no heading".into()))?;
    if !(0.0..=360.0).contains(&heading) {
        return Err(field(format!("heading {heading} is outside 0–360°")));
    }
    let signed = |i: usize, name: &str| -> Result<f64, NmeaError> {
        match (num(i, name)?, f.get(i + 1).map(|v| v.trim())) {
            (None, _) => Ok(0.0),
            (Some(v), Some("E")) => Ok(v),
            (Some(v), Some("W")) => Ok(-v),
            (Some(_), other) => Err(field(format!("{name} direction {other:?} is not E or W"))),
        }
    };
    let azimuth = match kind {
        Kind::Hdt | Kind::Hdm => heading,
        // Sensor heading + deviation = magnetic; + variation = true.
        Kind::Hdg => heading + signed(1, "deviation")? + signed(3, "variation")?,
    };
    Ok((kind, azimuth.rem_euclid(360.0)))
}

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
        use tokio_serial::SerialPortBuilderExt;
        if !(4800..=115_200).contains(&baud) {
            return Err(BaseError::InvalidArgument {
                component: "heading (NMEA)".into(),
                reason: format!("baud {baud} is outside NMEA 0183's 4800–115200"),
            });
        }
        let port = tokio_serial::new(path, baud)
            .open_native_async()
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
    let start = Instant::now();
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
                        time_s: start.elapsed().as_secs_f64(),
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
}

/// Writes a sentence with its checksum and CR LF: `sentence("HCHDT", "123.4,T")`.
pub fn sentence(address: &str, fields: &str) -> String {
    let content = format!("{address},{fields}");
    let sum = content.bytes().fold(0u8, |a, b| a ^ b);
    format!("${content}*{sum:02X}\r\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heading_sentences_parse_with_any_talker_and_bad_ones_are_named() {
        // Checksums from an independent XOR (Python) of the content between `$` and `*`.
        assert_eq!(parse("$HEHDT,274.07,T*19"), Ok((Kind::Hdt, 274.07)));
        assert_eq!(parse("$GPHDT,274.07,T*03\r\n").map(|(_, a)| a), Ok(274.07));
        // A talker never seen, and the checksum round trip of our own writer.
        let s = sentence("QZHDM", "10.5,M");
        assert_eq!(parse(&s), Ok((Kind::Hdm, 10.5)));
        // HDG: 101.1 sensor, deviation 0, variation 7.1 W → true 94.0.
        let (k, a) = parse(&sentence("HCHDG", "101.1,,,7.1,W")).unwrap();
        assert_eq!(k, Kind::Hdg);
        assert!((a - 94.0).abs() < 1e-9);
        let (_, a) = parse(&sentence("HCHDG", "359.0,2.0,E,,")).unwrap();
        assert!((a - 1.0).abs() < 1e-9, "wraps past north: {a}");
        assert!(matches!(
            parse("$HEHDT,274.07,T*04"),
            Err(NmeaError::Checksum {
                stated: 4,
                computed: 0x19
            })
        ));
        assert!(matches!(
            parse(&sentence("HEHDT", ",T")),
            Err(NmeaError::Field { .. })
        ));
        assert!(matches!(
            parse(&sentence("HEHDT", "abc,T")),
            Err(NmeaError::Field { .. })
        ));
        assert!(matches!(
            parse(&sentence("HCHDG", "10,1,X,,")),
            Err(NmeaError::Field { .. })
        ));
        assert!(matches!(
            parse(&sentence("GPGGA", "1,2")),
            Err(NmeaError::Other(_))
        ));
        assert!(matches!(
            parse("HEHDT,274.07,T*03"),
            Err(NmeaError::Framing)
        ));
        assert!(matches!(
            parse(&sentence("HEHDT", "400.0,T")),
            Err(NmeaError::Field { .. })
        ));
    }

    #[test]
    fn azimuths_turn_the_other_way() {
        assert!((azimuth_to_heading(90.0) + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((azimuth_to_heading(270.0) - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((azimuth_to_heading(180.0).abs() - std::f64::consts::PI).abs() < 1e-12);
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
}
