//! The safe-retry cache of SPEC.md §3 and §7.2: the last executed request (its `SEQ`, `MSG`
//! and payload CRC) and the answer sent, NACKs included, so a retry is answered again without
//! being executed twice.

use crate::frame::{Frame, CRC16};

/// The remembered request and its answer.
#[derive(Debug, Clone)]
struct Remembered {
    seq: u8,
    msg: u8,
    crc: u16,
    answer: Frame,
}

/// Remembers one request and its answer.
#[derive(Debug, Clone, Default)]
pub struct RetryCache {
    last: Option<Remembered>,
}

impl RetryCache {
    /// An empty cache (power-up).
    pub const fn new() -> Self {
        RetryCache { last: None }
    }

    /// The answer to send again if `request` repeats the remembered request.
    pub fn replay(&self, request: &Frame) -> Option<&Frame> {
        let last = self.last.as_ref()?;
        (last.seq == request.seq
            && last.msg == request.msg
            && last.crc == CRC16.checksum(request.payload()))
        .then_some(&last.answer)
    }

    /// Remembers `answer` as the answer to `request`, replacing what was remembered.
    pub fn remember(&mut self, request: &Frame, answer: Frame) {
        self.last = Some(Remembered {
            seq: request.seq,
            msg: request.msg,
            crc: CRC16.checksum(request.payload()),
            answer,
        });
    }

    /// Forgets the remembered answer (HELLO clears it).
    pub fn forget(&mut self) {
        self.last = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::FrameKind;

    fn frame(kind: FrameKind, seq: u8, msg: u8, payload: &[u8]) -> Frame {
        Frame::new(kind, seq, msg, payload).unwrap()
    }

    #[test]
    fn only_the_same_seq_msg_and_payload_is_answered_from_the_cache() {
        let mut cache = RetryCache::new();
        let request = frame(FrameKind::Request, 7, 0x30, &[1, 2, 3]);
        let answer = frame(FrameKind::Nack, 7, 0x30, &[3, 1]);
        assert!(cache.replay(&request).is_none());
        cache.remember(&request, answer);
        assert_eq!(cache.replay(&request), Some(&answer));
        // A new sequence number, another message or another payload is a new request.
        assert!(cache
            .replay(&frame(FrameKind::Request, 8, 0x30, &[1, 2, 3]))
            .is_none());
        assert!(cache
            .replay(&frame(FrameKind::Request, 7, 0x31, &[1, 2, 3]))
            .is_none());
        assert!(cache
            .replay(&frame(FrameKind::Request, 7, 0x30, &[1, 2, 4]))
            .is_none());
        cache.forget();
        assert!(cache.replay(&request).is_none());
    }
}
