//! NMEA 0183 heading sentences: `$--HDT` (true heading), `$--HDG` (magnetic sensor heading with
//! deviation and variation) and `$--HDM` (magnetic heading), checksums verified, any talker;
//! and the one conversion from a compass azimuth to the crate's heading.

use crate::kinematics::wrap_angle;

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

impl std::fmt::Display for Kind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Kind::Hdt => "HDT",
            Kind::Hdg => "HDG",
            Kind::Hdm => "HDM",
        })
    }
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
    #[error("{kind}: {reason}")]
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
    // HDT's indicator is `T` (true), HDM's `M` (magnetic): a sentence that contradicts its
    // own type is not trusted either way.
    let indicator = |want: &str| -> Result<(), NmeaError> {
        match f.get(1).map(|v| v.trim()) {
            Some(v) if v == want => Ok(()),
            other => Err(field(format!(
                "indicator {:?} contradicts the sentence type (want {want:?})",
                other.unwrap_or("")
            ))),
        }
    };
    match kind {
        Kind::Hdt => indicator("T")?,
        Kind::Hdm => indicator("M")?,
        Kind::Hdg => {}
    }
    let azimuth = match kind {
        Kind::Hdt | Kind::Hdm => heading,
        // Sensor heading + deviation = magnetic; + variation = true.
        Kind::Hdg => heading + signed(1, "deviation")? + signed(3, "variation")?,
    };
    Ok((kind, azimuth.rem_euclid(360.0)))
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
        // The indicator must agree with the type: `$HCHDT,…,M` is not a true heading.
        for (address, fields) in [
            ("HCHDT", "123.4,M"),
            ("HCHDT", "123.4,"),
            ("HCHDT", "123.4"),
            ("HCHDM", "123.4,T"),
        ] {
            let e = parse(&sentence(address, fields)).unwrap_err();
            assert!(
                e.to_string().contains("indicator"),
                "{address},{fields}: {e}"
            );
        }
    }

    #[test]
    fn azimuths_turn_the_other_way() {
        assert!((azimuth_to_heading(90.0) + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((azimuth_to_heading(270.0) - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((azimuth_to_heading(180.0).abs() - std::f64::consts::PI).abs() < 1e-12);
    }
}
