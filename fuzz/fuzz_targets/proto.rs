//! The protocol's streaming decoders (`proto::Decoder`, both directions) on arbitrary bytes:
//! any panic is a finding; every decoded request re-encodes and decodes to itself. The same
//! bytes as stored settings (`proto::Settings::from_bytes`, either layout): settings that load
//! store and load back to themselves.
#![no_main]

use libfuzzer_sys::fuzz_target;
use proto::{encode, Decoder, DeviceMsg, Request, Settings, MAX_FRAME};

fuzz_target!(|data: &[u8]| {
    if let Ok(s) = Settings::from_bytes(data) {
        let mut buf = [0u8; Settings::MAX_BYTES];
        let bytes = s.to_bytes(&mut buf).expect("loaded settings store");
        assert_eq!(Settings::from_bytes(bytes), Ok(s));
    }
    let mut requests = Decoder::<Request, MAX_FRAME>::new();
    let mut replies = Decoder::<DeviceMsg, MAX_FRAME>::new();
    // A small buffer too: overflow handling on every frame.
    let mut small = Decoder::<Request, 8>::new();
    for &b in data {
        let _ = small.push(b);
        let _ = replies.push(b);
        if let Some(Ok(req)) = requests.push(b) {
            let mut out = [0u8; MAX_FRAME];
            let n = encode(&req, &mut out).expect("a decoded request re-encodes");
            let mut again = Decoder::<Request, MAX_FRAME>::new();
            let mut got = None;
            again.feed(&out[..n], |r| got = Some(r));
            assert_eq!(got, Some(Ok(req)));
        }
        assert!(requests.pending() <= MAX_FRAME);
    }
});
