//! A mock NMEA 0183 compass: `$--HDT` sentences of whatever heading it is handed, at a fixed
//! rate of robot time, with occasional bad checksums. It serves any byte stream or a real
//! pseudo-terminal, and it reads its heading from any simulated robot (the mock RoboClaw's,
//! the mock device's, the mock ROS robot's), so any drive can be tried with a compass.

use super::pty::{spawn_on_pty, PtyServer};
use crate::nmea::sentence;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncWrite, AsyncWriteExt};

/// The heading the compass reports now (rad, counter-clockwise positive): the robot's, with
/// whatever sensor errors the robot's simulator adds; `None` when the sensor has no reading
/// (no sentence is sent).
pub type HeadingFn = Arc<dyn Fn() -> Option<f64> + Send + Sync>;

/// How the compass talks.
#[derive(Debug, Clone, PartialEq)]
pub struct MockCompassConfig {
    /// Sentences per second of robot time.
    pub hz: f64,
    /// Talker id (two letters).
    pub talker: String,
    /// Probability of a sentence with a wrong checksum.
    pub bad_checksum_rate: f64,
    /// Noise of each reading (rad, Gaussian), added to what the heading function gives.
    pub sigma_rad: f64,
    /// Robot seconds per wall-clock second.
    pub time_scale: f64,
    /// Seed of the checksum faults.
    pub seed: u64,
    /// How each sentence ends.
    pub line_end: LineEnd,
}

/// How a compass ends its sentences: NMEA says CR LF; some devices send one of the two.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum LineEnd {
    /// `\r\n`.
    #[default]
    CrLf,
    /// `\n` alone.
    Lf,
    /// `\r` alone.
    Cr,
}

impl std::str::FromStr for LineEnd {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "crlf" => Ok(LineEnd::CrLf),
            "lf" => Ok(LineEnd::Lf),
            "cr" => Ok(LineEnd::Cr),
            other => Err(format!("{other:?}: use crlf, lf or cr")),
        }
    }
}

impl Default for MockCompassConfig {
    fn default() -> Self {
        MockCompassConfig {
            hz: 10.0,
            talker: "HC".into(),
            bad_checksum_rate: 0.0,
            sigma_rad: 0.0,
            time_scale: 1.0,
            seed: 1,
            line_end: LineEnd::CrLf,
        }
    }
}

/// The sentence for `heading_rad`, its checksum spoilt when `bad`.
fn hdt(talker: &str, heading_rad: f64, bad: bool) -> String {
    let azimuth = (-heading_rad.to_degrees()).rem_euclid(360.0);
    let mut s = sentence(&format!("{talker}HDT"), &format!("{azimuth:.2},T"));
    if bad {
        // Flip the checksum's last digit.
        let at = s.len() - 3;
        let c = if &s[at..at + 1] == "0" { "1" } else { "0" };
        s.replace_range(at..at + 1, c);
    }
    s
}

/// Streams heading sentences on `stream` until it closes.
pub async fn serve_compass<S>(
    mut stream: S,
    cfg: MockCompassConfig,
    heading: HeadingFn,
) -> std::io::Result<()>
where
    S: AsyncWrite + Unpin,
{
    let rate = cfg.hz.clamp(0.1, 100.0) * cfg.time_scale.max(1e-3);
    let mut tick = tokio::time::interval(Duration::from_secs_f64(1.0 / rate));
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let bad_rate = cfg.bad_checksum_rate.clamp(0.0, 1.0);
    let noise = rand_distr::Normal::new(0.0, cfg.sigma_rad.max(0.0))
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e.to_string()))?;
    loop {
        tick.tick().await;
        let bad = bad_rate > 0.0 && rng.random_bool(bad_rate);
        let Some(value) = heading() else { continue };
        let reading = value + rand_distr::Distribution::sample(&noise, &mut rng);
        let mut line = hdt(&cfg.talker, reading, bad);
        match cfg.line_end {
            LineEnd::CrLf => {}
            LineEnd::Lf => {
                line.remove(line.len() - 2);
            }
            LineEnd::Cr => {
                line.pop();
            }
        }
        stream.write_all(line.as_bytes()).await?;
        stream.flush().await?;
    }
}

/// Serves a compass on a new pseudo-terminal (open it as `nmea:PATH`).
pub fn spawn_pty(cfg: MockCompassConfig, heading: HeadingFn) -> std::io::Result<PtyServer<()>> {
    spawn_on_pty(Box::new(move |master| {
        Box::pin(serve_compass(master, cfg.clone(), heading.clone()))
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sentences_read_back_and_spoilt_ones_fail_their_checksum() {
        let good = hdt("HC", -std::f64::consts::FRAC_PI_2, false);
        assert_eq!(good, sentence("HCHDT", "90.00,T"));
        assert_eq!(
            crate::nmea::parse(&good),
            Ok((crate::nmea::Kind::Hdt, 90.0))
        );
        let bad = hdt("HC", 0.3, true);
        assert!(matches!(
            crate::nmea::parse(&bad),
            Err(crate::nmea::NmeaError::Checksum { .. })
        ));
    }
}
