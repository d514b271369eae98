//! The frame decoder against random input: no input panics or ends the stream, and valid frames
//! hidden in garbage are all recovered in order, by the host codec and the fixed-buffer
//! decoder alike.
#![cfg(feature = "tokio")]

use bytes::BytesMut;
use odocal_protocol::{Frame, FrameCodec, FrameDecoder, FrameKind};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tokio_util::codec::Decoder;

fn random_frame(rng: &mut ChaCha8Rng) -> Frame {
    let kind = [
        FrameKind::Request,
        FrameKind::Response,
        FrameKind::Nack,
        FrameKind::Event,
    ][rng.random_range(0..4)];
    let len = rng.random_range(0..=240);
    let payload: Vec<u8> = (0..len).map(|_| rng.random()).collect();
    Frame::new(kind, rng.random(), rng.random(), &payload).unwrap()
}

/// Garbage biased towards sync bytes and plausible headers, the worst case for a resyncer.
fn garbage(rng: &mut ChaCha8Rng, max: usize) -> Vec<u8> {
    let n = rng.random_range(0..=max);
    (0..n)
        .map(|_| match rng.random_range(0..8) {
            0 => 0xAA,
            1 => 0x55,
            2 => 0x10,
            _ => rng.random(),
        })
        .collect()
}

#[test]
fn a_million_random_streams_never_panic() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut frames = 0u64;
    let mut codec = FrameCodec::new();
    for _ in 0..1_000_000 {
        let bytes = garbage(&mut rng, 48);
        let mut buf = BytesMut::from(&bytes[..]);
        while let Some(f) = codec
            .decode(&mut buf)
            .expect("bad bytes are never an error")
        {
            assert!(f.payload().len() <= 240);
            frames += 1;
        }
        // Whatever is left is at most one incomplete candidate frame.
        assert!(buf.len() <= 249);
    }
    let s = codec.stats();
    assert_eq!(s.frames, frames);
    assert!(s.bytes_dropped > 1_000_000);
}

/// Seed 2 includes garbage forming a plausible long header (`AA 55 B4 10 02 ..`) right before
/// the last frame: the look-ahead rule (SPEC.md §2.1 rule 4) must still release that frame.
#[test]
fn valid_frames_in_garbage_are_all_recovered_at_any_split() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    for _ in 0..20_000 {
        let sent = [random_frame(&mut rng), random_frame(&mut rng)];
        let mut stream = garbage(&mut rng, 40);
        stream.extend_from_slice(&sent[0].to_bytes());
        stream.extend(garbage(&mut rng, 40));
        stream.extend_from_slice(&sent[1].to_bytes());
        let split = rng.random_range(0..=stream.len());
        let mut codec = FrameCodec::new();
        let mut buf = BytesMut::new();
        let mut got = codec.feed(&mut buf, &stream[..split]);
        got.extend(codec.feed(&mut buf, &stream[split..]));
        // Every sent frame appears, in order (garbage could, rarely, also forge a frame).
        let mut it = got.iter();
        for s in &sent {
            assert!(it.any(|g| g == s), "lost {s:?} in {stream:02X?}");
        }
        // The firmware's fixed-buffer decoder finds exactly the same frames.
        let mut fixed = FrameDecoder::<256>::new();
        let mut same = Vec::new();
        fixed.feed(&stream[..split], |f| same.push(f));
        fixed.feed(&stream[split..], |f| same.push(f));
        assert_eq!(same, got);
        assert_eq!(fixed.stats(), codec.stats());
    }
}
