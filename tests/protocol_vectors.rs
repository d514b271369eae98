//! The codec against `protocol/vectors/vectors.json`, which an independent implementation of
//! SPEC.md (`protocol/vectors/generate.py`) wrote: every golden frame decodes to its typed
//! packet and encodes back to the same bytes, every stream case gives the expected frames, and
//! every malformed payload maps to the expected NACK.

use bytes::BytesMut;
use odocal::protocol::message::{id, Nack};
use odocal::protocol::{FrameCodec, FrameKind, Packet};
use serde_json::Value;
use std::collections::BTreeSet;

fn vectors() -> Value {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/protocol/vectors/vectors.json");
    let text = std::fs::read_to_string(path).expect("vectors.json is part of the repository");
    serde_json::from_str(&text).expect("vectors.json is valid JSON")
}

fn unhex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|h| u8::from_str_radix(h, 16).expect("hex byte"))
        .collect()
}

#[test]
fn every_golden_frame_decodes_and_encodes_exactly() {
    let v = vectors();
    let mut seen = BTreeSet::new();
    for case in v["frames"].as_array().unwrap() {
        let name = case["name"].as_str().unwrap();
        let bytes = unhex(case["hex"].as_str().unwrap());
        let expected: Packet = serde_json::from_value(case["packet"].clone())
            .unwrap_or_else(|e| panic!("{name}: packet does not parse: {e}"));
        let mut codec = FrameCodec::new();
        let frames = codec.feed(&mut BytesMut::new(), &bytes);
        assert_eq!(frames.len(), 1, "{name}");
        let decoded = Packet::from_frame(&frames[0]).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(decoded, expected, "{name}");
        let encoded = expected.to_frame().unwrap().to_bytes().unwrap();
        assert_eq!(encoded[..], bytes[..], "{name}");
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
        let mut codec = FrameCodec::new();
        let mut buf = BytesMut::new();
        let mut got = Vec::new();
        for chunk in case["chunks"].as_array().unwrap() {
            for f in codec.feed(&mut buf, &unhex(chunk.as_str().unwrap())) {
                got.push(f.to_bytes().unwrap().to_vec());
            }
        }
        let want: Vec<Vec<u8>> = case["frames"]
            .as_array()
            .unwrap()
            .iter()
            .map(|h| unhex(h.as_str().unwrap()))
            .collect();
        assert_eq!(got, want, "{name}");
        let stats = codec.stats();
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
        let frames =
            FrameCodec::new().feed(&mut BytesMut::new(), &unhex(case["hex"].as_str().unwrap()));
        assert_eq!(frames.len(), 1, "{name}: the frame itself is valid");
        let err = Packet::from_frame(&frames[0]).expect_err(name);
        let want: Nack = serde_json::from_value(case["nack"].clone()).unwrap();
        assert_eq!(err.nack(), want, "{name}");
    }
}
