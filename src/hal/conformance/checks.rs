//! The vectors' expectations checked against what a device answered: answers field by field,
//! motion-done events, telemetry counts, and what a rule needs (a capability, a device that never
//! saved) to be run at all.

use super::*;

pub(super) fn message_name(msg: u8) -> String {
    id::name(msg).map_or_else(|| format!("0x{msg:02X}"), str::to_string)
}

pub(super) fn unhex(s: &str) -> Result<Vec<u8>, String> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).map_err(|e| format!("{b:?}: {e}")))
        .collect()
}

/// The one frame a vector's hex holds.
pub(super) fn vector_frame(hex: &str) -> Result<Frame, String> {
    let bytes = unhex(hex)?;
    let mut codec = FrameCodec::new();
    let frames = codec.feed(&mut BytesMut::new(), &bytes);
    match frames.as_slice() {
        [f] => Ok(*f),
        other => Err(format!("{hex:?} holds {} frames", other.len())),
    }
}

/// Motion ids and completed-motion counts of the rule mapped onto the device's counters.
pub(super) struct Counters {
    /// The device's id of the rule's motion 1, less 1 (learned from the first id seen).
    pub(super) id_offset: Option<u64>,
    /// `completed_motions` when the rule started.
    pub(super) completed: u32,
}

impl Counters {
    /// The device's id for the rule's `want`, learning the offset from `got` if it is the
    /// first.
    pub(super) fn id(&mut self, want: u64, got: Option<u64>) -> u64 {
        let offset = *self.id_offset.get_or_insert_with(|| {
            got.filter(|g| (1..=65535).contains(g))
                .map_or(0, |g| (g + 65535 - want % 65535) % 65535)
        });
        (want + 65534 + offset) % 65535 + 1
    }

    /// A vector's expected value of `field`, as this device should show it.
    pub(super) fn expected(&mut self, field: &str, want: &Value, got: &Value) -> Value {
        match (field, want.as_u64()) {
            ("motion_id", Some(w)) => self.id(w, got.as_u64()).into(),
            ("current_motion_id", Some(w)) if w != 0 => self.id(w, got.as_u64()).into(),
            ("completed_motions", Some(w)) => self.completed.wrapping_add(w as u32).into(),
            _ => want.clone(),
        }
    }
}

/// Checks an answer against a vector's expectation: message, kind, NACK code and detail, and
/// the listed fields (spelled as the vectors' packets spell them).
pub(super) fn check_answer(
    answer: &Frame,
    want: &Value,
    counters: &mut Counters,
) -> Result<(), String> {
    if answer.version != VERSION {
        return Err(format!(
            "answered in a frame with VER 0x{:02X}, not 0x{VERSION:02X}",
            answer.version
        ));
    }
    let packet = Packet::from_frame(answer).map_err(|e| format!("undecodable answer: {e}"))?;
    let want_kind = want["kind"].as_str().unwrap_or("");
    match (packet.body, want_kind) {
        (Body::Response { .. }, "response") => {
            let got = serde_json::to_value(packet).map_err(|e| e.to_string())?;
            if let Some(fields) = want.get("fields").and_then(Value::as_object) {
                for (field, value) in fields {
                    let got_value = &got["response"][field];
                    let expected = counters.expected(field, value, got_value);
                    if *got_value != expected {
                        return Err(format!("{field} is {got_value}, expected {expected}"));
                    }
                }
            }
            Ok(())
        }
        (Body::Nack { nack, .. }, "nack") => {
            let code = serde_json::to_value(nack.code).unwrap_or_default();
            if code != want["code"] || Some(u64::from(nack.detail)) != want["detail"].as_u64() {
                return Err(format!(
                    "refused {code} detail {}, expected {} detail {}",
                    nack.detail, want["code"], want["detail"]
                ));
            }
            Ok(())
        }
        (Body::Nack { nack, .. }, _) => Err(format!(
            "refused {} (detail {}), expected a {want_kind}",
            nack.code, nack.detail
        )),
        (Body::Response { response }, _) => Err(format!(
            "answered {}, expected a {want_kind}",
            response.name()
        )),
        (Body::Request { request }, _) => Err(format!(
            "answered with a request ({}), expected a {want_kind}",
            request.name()
        )),
        (Body::Event { .. }, _) => Err(format!("answered with an event, expected a {want_kind}")),
    }
}

pub(super) fn motion_done_of(events: &[Frame]) -> Vec<(u16, u32)> {
    events
        .iter()
        .filter_map(|f| match Packet::from_frame(f).ok()?.body {
            Body::Event {
                event: Event::MotionDone(d),
            } => Some((d.motion_id, d.completed_motions)),
            _ => None,
        })
        .collect()
}

/// Checks a step's MOTION_DONE events against the vector's list.
pub(super) fn check_motion_done(
    events: &[Frame],
    step: &Value,
    c: &mut Counters,
) -> Result<(), String> {
    let Some(want) = step.get("motion_done").and_then(Value::as_array) else {
        return Ok(());
    };
    let got = motion_done_of(events);
    let want: Vec<(u16, u32)> = want
        .iter()
        .enumerate()
        .map(|(i, pair)| {
            let w_id = pair[0].as_u64().unwrap_or(0);
            let id = c.id(w_id, got.get(i).map(|g| u64::from(g.0)));
            let done = c
                .completed
                .wrapping_add(pair[1].as_u64().unwrap_or(0) as u32);
            (id as u16, done)
        })
        .collect();
    if got == want {
        Ok(())
    } else {
        let list = |v: &[(u16, u32)]| match v {
            [] => "none".to_string(),
            v => v
                .iter()
                .map(|(id, done)| format!("motion {id} (completed {done})"))
                .collect::<Vec<_>>()
                .join(", "),
        };
        Err(format!(
            "MOTION_DONE events: {}, expected {}",
            list(&got),
            list(&want)
        ))
    }
}

/// The most TELEMETRY samples whose timestamps fall within `span_us` of each other.
pub(super) fn telemetry_within(events: &[Frame], span_us: u64) -> usize {
    let times: Vec<u32> = events
        .iter()
        .filter_map(|f| match Packet::from_frame(f).ok()?.body {
            Body::Event {
                event: Event::Telemetry(t),
            } => Some(t.timestamp_us),
            _ => None,
        })
        .collect();
    (0..times.len())
        .map(|i| {
            times[i..]
                .iter()
                .take_while(|&&t| u64::from(t.wrapping_sub(times[i])) < span_us)
                .count()
        })
        .max()
        .unwrap_or(0)
}

/// A step's request: the first of a `[request, answer]` pair, or its `send`.
pub(super) fn request_of(step: &Value) -> &Value {
    match step.as_array() {
        Some(pair) => pair.first().unwrap_or(&Value::Null),
        None => &step["send"],
    }
}

/// A step's expected answer.
pub(super) fn answer_of(step: &Value) -> &Value {
    match step.as_array() {
        Some(pair) => pair.get(1).unwrap_or(&Value::Null),
        None => &step["answer"],
    }
}

/// The optional message a rule sends that the device does not report having (SPEC.md §8).
pub(super) fn missing_capability(steps: &[Value], capabilities: u32) -> Option<String> {
    let optional = [
        (id::WHEEL_SPEED, capability::WHEEL_SPEED, 4),
        (id::CONFIGURE_TELEMETRY, capability::TELEMETRY, 1),
        (id::CONFIGURE_WATCHDOG, capability::WATCHDOG, 2),
        (id::HEARTBEAT, capability::WATCHDOG, 2),
    ];
    let sent = steps
        .iter()
        .flat_map(|s| request_of(s).as_str().and_then(|h| vector_frame(h).ok()));
    for frame in sent {
        if let Some((msg, _, bit)) = optional
            .iter()
            .find(|(msg, cap, _)| *msg == frame.msg && capabilities & cap == 0)
        {
            return Some(format!(
                "the rule sends {}, and the device does not report that capability (HELLO \
                 capability bit {bit})",
                message_name(*msg)
            ));
        }
    }
    None
}

/// Whether a rule needs a device that never saved its parameters (it expects GET_PARAMS of
/// the stored copy to be refused STORAGE_FAILURE).
pub(super) fn needs_nothing_saved(steps: &[Value]) -> bool {
    steps.iter().any(|s| {
        answer_of(s)["code"] == "STORAGE_FAILURE"
            && request_of(s)
                .as_str()
                .and_then(|h| vector_frame(h).ok())
                .is_some_and(|f| f.msg == id::GET_PARAMS && f.payload().first() == Some(&1))
    })
}

/// The stored parameter copy as GET_PARAMS reports it (or its refusal).
/// Bytes as hex pairs (`a5 01 …`), for frames in a reason.
pub(super) fn hex(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect::<Vec<_>>()
        .join(" ")
}
