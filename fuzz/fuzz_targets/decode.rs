//! Fuzz the frame decoder and the message layer: any bytes, split anywhere, must neither panic
//! nor lose a frame the decoder already accepted; every accepted frame must re-encode to itself.
#![no_main]

use bytes::BytesMut;
use libfuzzer_sys::fuzz_target;
use odocal::protocol::{FrameCodec, Packet};

fuzz_target!(|data: &[u8]| {
    let split = data.first().map_or(0, |&b| usize::from(b)).min(data.len());
    let mut codec = FrameCodec::new();
    let mut buf = BytesMut::new();
    let mut frames = codec.feed(&mut buf, &data[..split]);
    frames.extend(codec.feed(&mut buf, &data[split..]));
    for f in frames {
        let bytes = f.to_bytes().expect("a decoded frame fits");
        let again = FrameCodec::new().feed(&mut BytesMut::new(), &bytes);
        assert_eq!(again, vec![f.clone()]);
        if let Ok(p) = Packet::from_frame(&f) {
            // Typed packets re-encode; the payload may have been longer than needed.
            let re = p.to_frame().expect("decoded packets encode");
            assert_eq!(Packet::from_frame(&re).expect("re-decodes"), p);
        }
    }
});
