//! The codec against `vectors/vectors.json`, which an independent implementation of SPEC.md
//! (`vectors/generate.py`) wrote: every golden frame decodes to its typed packet and encodes
//! back to the same bytes, every stream case gives the expected frames, and every malformed
//! payload maps to the expected NACK.
//!
//! The byte-level checks use the fixed-buffer [`FrameDecoder`] firmware links, and run without
//! any feature (`cargo test -p odocal-protocol --no-default-features`); comparing decoded
//! packets with the vectors' JSON form needs the `serde` feature.

use odocal_protocol::frame::{FrameDecoder, MAX_FRAME};
use odocal_protocol::message::{id, NackCode};
use odocal_protocol::{Frame, FrameKind, Packet};
use serde_json::Value;
use std::collections::BTreeSet;

fn vectors() -> Value {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/vectors/vectors.json");
    let text = std::fs::read_to_string(path).expect("vectors.json is part of the repository");
    serde_json::from_str(&text).expect("vectors.json is valid JSON")
}

fn unhex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|h| u8::from_str_radix(h, 16).expect("hex byte"))
        .collect()
}

fn frames_of(chunks: &[Vec<u8>]) -> (Vec<Frame>, odocal_protocol::DecoderStats) {
    let mut decoder = FrameDecoder::<{ MAX_FRAME + 16 }>::new();
    let mut got = Vec::new();
    for c in chunks {
        decoder.feed(c, |f| got.push(f));
    }
    (got, decoder.stats())
}

fn encode(frame: &Frame) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    let n = frame.encode(&mut out).unwrap();
    out[..n].to_vec()
}

#[test]
fn every_golden_frame_decodes_and_encodes_exactly() {
    let v = vectors();
    let mut seen = BTreeSet::new();
    for case in v["frames"].as_array().unwrap() {
        let name = case["name"].as_str().unwrap();
        let bytes = unhex(case["hex"].as_str().unwrap());
        let (frames, _) = frames_of(std::slice::from_ref(&bytes));
        assert_eq!(frames.len(), 1, "{name}");
        let decoded = Packet::from_frame(&frames[0]).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(encode(&decoded.to_frame()), bytes, "{name}");
        #[cfg(feature = "serde")]
        {
            let expected: Packet = serde_json::from_value(case["packet"].clone())
                .unwrap_or_else(|e| panic!("{name}: packet does not parse: {e}"));
            assert_eq!(decoded, expected, "{name}");
        }
        seen.insert((frames[0].kind as u8, frames[0].msg));
    }
    for msg in id::REQUESTS {
        for kind in [FrameKind::Request, FrameKind::Response] {
            assert!(
                seen.contains(&(kind as u8, msg)),
                "no {kind:?} vector for 0x{msg:02X}"
            );
        }
    }
    for msg in id::EVENTS {
        assert!(
            seen.contains(&(FrameKind::Event as u8, msg)),
            "no vector for event 0x{msg:02X}"
        );
    }
    assert!(seen.iter().any(|(k, _)| *k == FrameKind::Nack as u8));
}

#[test]
fn every_stream_case_gives_the_expected_frames() {
    let v = vectors();
    for case in v["streams"].as_array().unwrap() {
        let name = case["name"].as_str().unwrap();
        let chunks: Vec<Vec<u8>> = case["chunks"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| unhex(c.as_str().unwrap()))
            .collect();
        let (frames, stats) = frames_of(&chunks);
        let got: Vec<Vec<u8>> = frames.iter().map(encode).collect();
        let want: Vec<Vec<u8>> = case["frames"]
            .as_array()
            .unwrap()
            .iter()
            .map(|h| unhex(h.as_str().unwrap()))
            .collect();
        assert_eq!(got, want, "{name}");
        if let Some(n) = case["bad_crcs"].as_u64() {
            assert_eq!(stats.bad_crcs, n, "{name}");
        }
        if let Some(n) = case["bad_headers"].as_u64() {
            assert_eq!(stats.bad_headers, n, "{name}");
        }
    }
}

#[test]
fn every_malformed_payload_maps_to_its_nack() {
    let v = vectors();
    for case in v["payload_errors"].as_array().unwrap() {
        let name = case["name"].as_str().unwrap();
        let (frames, _) = frames_of(&[unhex(case["hex"].as_str().unwrap())]);
        assert_eq!(frames.len(), 1, "{name}: the frame itself is valid");
        let err = Packet::from_frame(&frames[0]).expect_err(name);
        let nack = err.nack();
        let code = case["nack"]["code"].as_str().unwrap();
        let want_code = match code {
            "UNKNOWN_MESSAGE" => NackCode::UnknownMessage,
            "BAD_LENGTH" => NackCode::BadLength,
            "OUT_OF_RANGE" => NackCode::OutOfRange,
            "INVALID_STATE" => NackCode::InvalidState,
            other => panic!("{name}: unexpected code {other}"),
        };
        assert_eq!(nack.code, want_code, "{name}");
        assert_eq!(
            u64::from(nack.detail),
            case["nack"]["detail"].as_u64().unwrap(),
            "{name}"
        );
    }
}
