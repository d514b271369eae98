//! The device rules of SPEC.md §7 (1.1), as written by the independent generator
//! (`protocol/vectors/generate.py`, `device_rules`), replayed against our mock device: each
//! rule to a freshly powered-up device, whose time the harness holds, advances or runs until
//! idle as the step says; each answer, its listed fields and the MOTION_DONE events checked.

mod common;

use bytes::BytesMut;
use odocal::mock::{lock, SharedDevice};
use odocal::protocol::message::{id, Event, NackCode};
use odocal::protocol::{Body, Frame, FrameCodec, FrameKind, Packet};
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

/// What one step did: the answer to its request (if it sent one) and the MOTION_DONE events
/// the device emitted during it, as `[motion_id, completed_motions]`.
struct StepResult {
    answer: Option<Frame>,
    motion_done: Vec<[u64; 2]>,
}

fn motion_done_of(frames: &[Frame]) -> Vec<[u64; 2]> {
    frames
        .iter()
        .filter(|f| f.kind == FrameKind::Event)
        .filter_map(|f| match Packet::from_frame(f).ok()?.body {
            Body::Event {
                event: Event::MotionDone(d),
            } => Some([u64::from(d.motion_id), u64::from(d.completed_motions)]),
            _ => None,
        })
        .collect()
}

/// Sends one request; with `run`, device time then passes until the base is idle.
fn send(device: &SharedDevice, hex: &str, run: bool, name: &str) -> StepResult {
    let mut codec = FrameCodec::new();
    let mut buf = BytesMut::new();
    let frames = codec.feed(&mut buf, &unhex(hex));
    assert_eq!(frames.len(), 1, "{name}: one request frame");
    let out = {
        let mut d = lock(device);
        let mut out = d.handle(&frames[0]);
        if run {
            out.extend(d.run_until_idle());
        }
        out
    };
    StepResult {
        answer: out.iter().find(|f| f.kind != FrameKind::Event).copied(),
        motion_done: motion_done_of(&out),
    }
}

/// Checks an answer against the rule's expectation: message, kind, NACK code and detail, and
/// the listed response fields (in the vectors' JSON form of a packet).
fn check_answer(answer: Option<Frame>, want: &Value, name: &str) {
    let answer = answer.unwrap_or_else(|| panic!("{name}: no answer"));
    // Every answer to HELLO, and every other, goes out in a VER 0x10 frame.
    assert_eq!(answer.to_bytes()[3], 0x10, "{name}: VER");
    assert_eq!(
        u64::from(answer.msg),
        want["msg"].as_u64().unwrap(),
        "{name}"
    );
    let packet = Packet::from_frame(&answer).unwrap();
    match (packet.body, want["kind"].as_str().unwrap()) {
        (Body::Response { .. }, "response") => {
            let got = serde_json::to_value(packet).unwrap();
            if let Some(fields) = want.get("fields").and_then(Value::as_object) {
                for (field, value) in fields {
                    assert_eq!(
                        &got["response"][field], value,
                        "{name}: field {field} of {got}"
                    );
                }
            }
        }
        (Body::Nack { nack, .. }, "nack") => {
            assert_eq!(nack.code, code(want["code"].as_str().unwrap()), "{name}");
            assert_eq!(
                u64::from(nack.detail),
                want["detail"].as_u64().unwrap(),
                "{name}"
            );
        }
        (got, kind) => panic!("{name}: expected a {kind}, got {got:?}"),
    }
}

fn check_motion_done(got: &[[u64; 2]], step: &Value, name: &str) {
    if let Some(want) = step.get("motion_done") {
        let want: Vec<[u64; 2]> = serde_json::from_value(want.clone()).unwrap();
        assert_eq!(got, want.as_slice(), "{name}: MOTION_DONE events");
    }
}

#[test]
fn the_mock_device_follows_every_device_rule_of_the_spec() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/protocol/vectors/vectors.json");
    let v: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let rules = v["device_rules"].as_array().expect("device_rules");
    let mut sections = std::collections::BTreeSet::new();
    for rule in rules {
        let rule_name = rule["name"].as_str().unwrap();
        sections.insert(rule_name.split(' ').next().unwrap().to_string());
        let device = common::mock_device(0.0, 1);
        for (i, step) in rule["steps"].as_array().unwrap().iter().enumerate() {
            let name = format!("{rule_name} step {i}");
            if let Some(pair) = step.as_array() {
                let r = send(&device, pair[0].as_str().unwrap(), true, &name);
                check_answer(r.answer, &pair[1], &name);
            } else if let Some(hex) = step["send"].as_str() {
                let r = send(&device, hex, false, &name);
                check_answer(r.answer, &step["answer"], &name);
                check_motion_done(&r.motion_done, step, &name);
            } else if let Some(ms) = step["advance_ms"].as_u64() {
                let events = lock(&device).advance(ms as f64 / 1e3);
                check_motion_done(&motion_done_of(&events), step, &name);
                if let Some(min) = step["telemetry_min"].as_u64() {
                    let telemetry = events
                        .iter()
                        .filter(|f| f.kind == FrameKind::Event && f.msg == id::TELEMETRY)
                        .count();
                    assert!(
                        telemetry as u64 >= min,
                        "{name}: {telemetry} TELEMETRY events"
                    );
                }
            } else if let Some(n) = step["repeat"].as_u64() {
                let cycle = step["send_cycle"].as_array().unwrap();
                for k in 0..n as usize {
                    let hex = cycle[k % cycle.len()].as_str().unwrap();
                    let r = send(&device, hex, true, &name);
                    check_answer(r.answer, &step["answer"], &format!("{name} #{k}"));
                }
            } else {
                panic!("{name}: unknown step {step}");
            }
        }
    }
    // Every rule of §7 that the wire can show has a sequence (7.3, 7.4, 7.7 and 7.10 with
    // device time that the harness holds or advances).
    for s in [
        "7.1", "7.2", "7.3", "7.4", "7.5", "7.6", "7.7", "7.8", "7.9", "7.10", "7.11",
    ] {
        assert!(
            sections.contains(s),
            "no device_rules sequence for SPEC §{s}"
        );
    }
}
