//! Fuzz the frame decoders and the message layer: any bytes, split anywhere, must neither panic
//! nor lose a frame the decoder already accepted; the host codec and the firmware's
//! fixed-buffer decoder must agree; every accepted frame must re-encode to itself.
#![no_main]

use bytes::BytesMut;
use libfuzzer_sys::fuzz_target;
use odocal_protocol::{FrameCodec, FrameDecoder, Packet};

fuzz_target!(|data: &[u8]| {
    let split = data.first().map_or(0, |&b| usize::from(b)).min(data.len());
    let mut codec = FrameCodec::new();
    let mut buf = BytesMut::new();
    let mut frames = codec.feed(&mut buf, &data[..split]);
    frames.extend(codec.feed(&mut buf, &data[split..]));
    let mut fixed = FrameDecoder::<256>::new();
    let mut same = Vec::new();
    fixed.feed(&data[..split], |f| same.push(f));
    fixed.feed(&data[split..], |f| same.push(f));
    assert_eq!(same, frames);
    for f in frames {
        let bytes = f.to_bytes();
        let again = FrameCodec::new().feed(&mut BytesMut::new(), &bytes);
        assert_eq!(again, vec![f]);
        if let Ok(p) = Packet::from_frame(&f) {
            // Typed packets re-encode; the payload may have been longer than needed.
            assert_eq!(Packet::from_frame(&p.to_frame()).expect("re-decodes"), p);
        }
    }
});
