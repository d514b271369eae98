//! The device rules of SPEC.md §7 (1.1), as written by the independent generator
//! (`protocol/vectors/generate.py`, `device_rules`), replayed against our mock device: each
//! request frame to a freshly powered-up device in virtual time, each answer checked.

mod common;

use bytes::BytesMut;
use odocal::mock::lock;
use odocal::protocol::message::NackCode;
use odocal::protocol::{Body, FrameCodec, FrameKind, Packet};
use serde_json::Value;

fn unhex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).expect("hex byte"))
        .collect()
}

fn code(name: &str) -> NackCode {
    match name {
        "UNKNOWN_MESSAGE" => NackCode::UnknownMessage,
        "BAD_LENGTH" => NackCode::BadLength,
        "OUT_OF_RANGE" => NackCode::OutOfRange,
        "INVALID_STATE" => NackCode::InvalidState,
        "BUSY" => NackCode::Busy,
        "STORAGE_FAILURE" => NackCode::StorageFailure,
        "VERSION_MISMATCH" => NackCode::VersionMismatch,
        other => panic!("unknown NACK code {other}"),
    }
}

#[test]
fn the_mock_device_follows_every_device_rule_of_the_spec() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/protocol/vectors/vectors.json");
    let v: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let rules = v["device_rules"].as_array().expect("device_rules");
    assert!(rules.len() >= 7);
    for rule in rules {
        let name = rule["name"].as_str().unwrap();
        let device = common::mock_device(0.0, 1);
        for (i, step) in rule["steps"].as_array().unwrap().iter().enumerate() {
            let mut codec = FrameCodec::new();
            let mut buf = BytesMut::new();
            let frames = codec.feed(&mut buf, &unhex(step[0].as_str().unwrap()));
            assert_eq!(frames.len(), 1, "{name} step {i}: one request frame");
            let answers = {
                let mut d = lock(&device);
                let mut out = d.handle(&frames[0]);
                out.extend(d.run_until_idle());
                out
            };
            let answer = answers
                .iter()
                .find(|f| f.kind != FrameKind::Event)
                .unwrap_or_else(|| panic!("{name} step {i}: no answer"));
            // Every answer to HELLO, and every other, goes out in a VER 0x10 frame.
            assert_eq!(answer.to_bytes()[3], 0x10, "{name} step {i}: VER");
            let want = &step[1];
            assert_eq!(
                u64::from(answer.msg),
                want["msg"].as_u64().unwrap(),
                "{name} step {i}"
            );
            match (
                Packet::from_frame(answer).unwrap().body,
                want["kind"].as_str().unwrap(),
            ) {
                (Body::Response { .. }, "response") => {}
                (Body::Nack { nack, .. }, "nack") => {
                    assert_eq!(
                        nack.code,
                        code(want["code"].as_str().unwrap()),
                        "{name} step {i}"
                    );
                    assert_eq!(
                        u64::from(nack.detail),
                        want["detail"].as_u64().unwrap(),
                        "{name} step {i}"
                    );
                }
                (got, kind) => panic!("{name} step {i}: expected a {kind}, got {got:?}"),
            }
        }
    }
}
