//! The settings store's loader on arbitrary flash contents (two slots on a byte-programmed
//! and on a word-programmed flash): never a panic; a load either gives a payload that fits
//! the buffer or a status; a store over whatever was there then loads exactly its payload.
#![no_main]

use libfuzzer_sys::fuzz_target;
use settings::sim::SimFlash;
use settings::{LoadStatus, Store};

fn check<const R: usize, const W: usize, const E: usize>(data: &[u8]) {
    let cap = 4 * E;
    let mut mem = vec![0xFF; cap];
    let n = data.len().min(cap);
    mem[..n].copy_from_slice(&data[..n]);
    let mut flash = SimFlash::<R, W, E>::from_bytes(mem);
    let store = Store::new(E as u32, 3 * E as u32, E as u32).expect("fixed layout");
    let mut buf = [0u8; 64];
    match store.load(&mut flash, &mut buf) {
        Ok(st @ LoadStatus::Loaded { len, .. }) => {
            assert!(len <= buf.len());
            assert_eq!(st.payload(&buf).map(<[u8]>::len), Some(len));
        }
        Ok(_) | Err(settings::StoreError::BufferTooSmall { .. }) => {}
        Err(e) => panic!("load of a powered flash failed: {e:?}"),
    }
    let payload = b"fuzzed";
    store.store(&mut flash, payload).expect("store");
    let st = store.load(&mut flash, &mut buf).expect("load");
    assert_eq!(st.payload(&buf), Some(&payload[..]));
}

fuzz_target!(|data: &[u8]| {
    let Some((&which, rest)) = data.split_first() else {
        return;
    };
    if which & 1 == 0 {
        check::<1, 1, 128>(rest);
    } else {
        check::<4, 4, 256>(rest);
    }
});
