//! Decode throughput on a mixed stream: telemetry, responses and requests with 10 % of the bytes
//! garbage between frames, fed in 64-byte reads as a UART driver delivers them.
//! Target (issue 3): ≥ 50 MB/s on one core, ≥ 500× a 1 Mbaud UART (~100 kB/s).

use bytes::BytesMut;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use odocal_protocol::frame::FrameDecoder;
use odocal_protocol::message::*;
use odocal_protocol::FrameCodec;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn mixed_stream() -> (Vec<u8>, u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut out = Vec::new();
    let mut frames = 0;
    while out.len() < 1 << 20 {
        let p = match rng.random_range(0..3) {
            0 => Packet::event(
                rng.random(),
                Event::Telemetry(Telemetry {
                    sample_index: rng.random(),
                    timestamp_us: rng.random(),
                    left_counts: rng.random(),
                    right_counts: rng.random(),
                    heading_urad: rng.random(),
                    heading_valid: true,
                    motion_state: MotionState::Moving,
                    queue_depth: 1,
                }),
            ),
            1 => Packet::response(
                rng.random(),
                Response::ReadEncoders(Encoders {
                    timestamp_us: rng.random(),
                    left_counts: rng.random(),
                    right_counts: rng.random(),
                }),
            ),
            _ => Packet::request(
                rng.random(),
                Request::MoveStraight(MoveStraightRequest {
                    distance_um: rng.random(),
                    max_speed_mm_s: 200,
                    mode: MotionMode::Queue,
                }),
            ),
        };
        let bytes = p.to_frame().to_bytes();
        let garbage = bytes.len() / 9;
        out.extend((0..garbage).map(|_| rng.random::<u8>()));
        out.extend_from_slice(&bytes);
        frames += 1;
    }
    (out, frames)
}

fn decode_stream(stream: &[u8]) -> usize {
    let mut codec = FrameCodec::new();
    let mut buf = BytesMut::with_capacity(512);
    let mut n = 0;
    for chunk in stream.chunks(64) {
        n += codec.feed(&mut buf, chunk).len();
    }
    n
}

/// The same with the fixed-buffer decoder firmware uses.
fn decode_stream_fixed(stream: &[u8]) -> usize {
    let mut decoder = FrameDecoder::<512>::new();
    let mut n = 0;
    for chunk in stream.chunks(64) {
        decoder.feed(chunk, |_| n += 1);
    }
    n
}

fn bench(c: &mut Criterion) {
    let (stream, frames) = mixed_stream();
    // The figure means nothing unless every frame is actually recovered.
    assert_eq!(decode_stream(&stream) as u64, frames);
    assert_eq!(decode_stream_fixed(&stream) as u64, frames);
    let mut g = c.benchmark_group("decode_mixed_stream");
    g.throughput(Throughput::Bytes(stream.len() as u64));
    g.bench_function("bytes", |b| {
        b.iter(|| decode_stream(std::hint::black_box(&stream)))
    });
    g.bench_function("bytes_fixed_buffer", |b| {
        b.iter(|| decode_stream_fixed(std::hint::black_box(&stream)))
    });
    g.throughput(Throughput::Elements(frames));
    g.bench_function("frames", |b| {
        b.iter(|| decode_stream(std::hint::black_box(&stream)))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
