//! The record format against the documented layout, the load statuses, sequence-number
//! wrap-around, damage, and the typed errors.

mod common;

use common::*;
use settings::sim::SimFlash;
use settings::{newer, Corruption, LoadStatus, Slot, SlotState, Store, StoreError};

#[test]
fn a_stored_record_is_the_documented_layout_byte_for_byte() {
    let (store, cap) = layout(256);
    let mut f = ByteFlash::new(cap);
    let payload = b"\x01\x02postcard bytes\xff\x00";
    assert_eq!(store.store(&mut f, payload).unwrap(), 1);
    let rec = encode(1, 1, payload);
    assert_eq!(&f.bytes()[256..256 + rec.len()], &rec[..]);
    // The rest of the slot stays erased, slot B untouched.
    assert!(f.bytes()[256 + rec.len()..512].iter().all(|&b| b == 0xFF));
    assert!(f.bytes()[768..].iter().all(|&b| b == 0xFF));
    // Padding to the write size on a 16-byte-row flash.
    let (store, cap) = layout(1024);
    let mut f = RowFlash::new(cap);
    store.store(&mut f, payload).unwrap();
    assert_eq!(&f.bytes()[1024..1024 + rec.len()], &rec[..]);
}

#[test]
fn a_record_written_by_the_documented_layout_loads() {
    let (store, cap) = layout(512);
    let mut f = WordFlash::new(cap);
    plant(&mut f, 1536, &encode(41, 1, b"from elsewhere"));
    let (got, st) = loaded(&store, &mut f);
    assert_eq!(got.as_deref(), Some(&b"from elsewhere"[..]));
    assert_eq!(
        st,
        LoadStatus::Loaded {
            sequence: 41,
            len: 14,
            slot: Slot::B
        }
    );
}

#[test]
fn stores_alternate_slots_and_count_up() {
    let (store, cap) = layout(256);
    let mut f = ByteFlash::new(cap);
    assert_eq!(loaded(&store, &mut f).1, LoadStatus::Empty);
    let mut slots = Vec::new();
    for i in 1..=5u32 {
        let p = format!("settings #{i}");
        assert_eq!(store.store(&mut f, p.as_bytes()).unwrap(), i);
        let (got, st) = loaded(&store, &mut f);
        assert_eq!(got.as_deref(), Some(p.as_bytes()));
        let LoadStatus::Loaded { sequence, slot, .. } = st else {
            panic!("{st:?}")
        };
        assert_eq!(sequence, i);
        slots.push(slot);
    }
    assert_eq!(slots, [Slot::A, Slot::B, Slot::A, Slot::B, Slot::A]);
}

#[test]
fn the_sequence_number_wraps() {
    let (store, cap) = layout(256);
    let mut f = ByteFlash::new(cap);
    plant(&mut f, 256, &encode(u32::MAX - 1, 1, b"max-1"));
    assert_eq!(store.store(&mut f, b"max").unwrap(), u32::MAX);
    assert_eq!(store.store(&mut f, b"zero").unwrap(), 0);
    let (got, st) = loaded(&store, &mut f);
    assert_eq!(got.as_deref(), Some(&b"zero"[..]));
    assert_eq!(sequence(&st), Some(0));
    // The record at u32::MAX is still in the other slot and loses.
    assert_eq!(
        store.slot_state(&mut f, Slot::B).unwrap(),
        SlotState::Valid {
            sequence: u32::MAX,
            len: 3
        }
    );
    assert_eq!(store.store(&mut f, b"one").unwrap(), 1);
    assert_eq!(loaded(&store, &mut f).0.as_deref(), Some(&b"one"[..]));
}

#[test]
fn serial_number_order_matches_modular_distance() {
    // Reference: a is newer than b when (a - b) mod 2^32 lies in 1..2^31, in i64 arithmetic.
    let reference = |a: u32, b: u32| {
        let d = (i64::from(a) - i64::from(b)).rem_euclid(1 << 32);
        (1..(1i64 << 31)).contains(&d)
    };
    let points = [
        0u32,
        1,
        2,
        0x7FFF_FFFF,
        0x8000_0000,
        0x8000_0001,
        u32::MAX - 1,
        u32::MAX,
    ];
    for &a in &points {
        for &b in &points {
            assert_eq!(newer(a, b), reference(a, b), "newer({a}, {b})");
        }
    }
}

#[test]
fn another_format_version_is_foreign_and_a_valid_record_still_wins() {
    let (store, cap) = layout(256);
    let mut f = ByteFlash::new(cap);
    plant(&mut f, 256, &encode(9, 2, b"a future format"));
    assert_eq!(
        loaded(&store, &mut f),
        (None, LoadStatus::Foreign { version: 2 })
    );
    // A store over it works, and the valid record wins over the foreign one.
    store.store(&mut f, b"ours").unwrap();
    assert_eq!(loaded(&store, &mut f).0.as_deref(), Some(&b"ours"[..]));
}

#[test]
fn every_single_bit_flip_of_the_newest_record_falls_back() {
    let (store, cap) = layout(256);
    let mut f = ByteFlash::new(cap);
    store.store(&mut f, b"older").unwrap();
    store.store(&mut f, b"newest settings").unwrap();
    let len = encode(2, 1, b"newest settings").len();
    for byte in 0..len {
        for bit in 0..8 {
            let mut g = f.clone();
            g.bytes_mut()[768 + byte] ^= 1 << bit;
            let (got, st) = loaded(&store, &mut g);
            // Never the damaged record: the older one (flips in the version byte make the
            // slot foreign, the others corrupt).
            assert_eq!(got.as_deref(), Some(&b"older"[..]), "byte {byte} bit {bit}");
            assert_eq!(sequence(&st), Some(1));
            let s = store.slot_state(&mut g, Slot::B).unwrap();
            assert!(
                matches!(s, SlotState::Corrupt(_) | SlotState::Foreign { .. }),
                "byte {byte} bit {bit}: {s:?}"
            );
        }
    }
}

#[test]
fn damage_is_reported_with_its_values() {
    let (store, cap) = layout(256);
    let mut f = ByteFlash::new(cap);
    plant(&mut f, 256, &[0x12, 0x34, 0x56, 0x78]);
    assert_eq!(
        loaded(&store, &mut f).1,
        LoadStatus::Corrupt {
            slot: Slot::A,
            why: Corruption::Magic { found: 0x7856_3412 }
        }
    );
    let mut g = ByteFlash::new(cap);
    let mut rec = encode(3, 1, b"x");
    rec[12..16].copy_from_slice(&1000u32.to_le_bytes());
    plant(&mut g, 768, &rec);
    assert_eq!(
        loaded(&store, &mut g).1,
        LoadStatus::Corrupt {
            slot: Slot::B,
            why: Corruption::Length {
                len: 1000,
                max: 256 - 20
            }
        }
    );
    let mut h = ByteFlash::new(cap);
    let mut rec = encode(3, 1, b"xyz");
    let stored = u32::from_le_bytes(rec[19..23].try_into().unwrap());
    rec[17] = b'Y';
    plant(&mut h, 256, &rec);
    let computed = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&rec[4..19]);
    assert_eq!(
        loaded(&store, &mut h).1,
        LoadStatus::Corrupt {
            slot: Slot::A,
            why: Corruption::Crc { stored, computed }
        }
    );
}

#[test]
fn an_interrupted_first_store_is_empty_not_corrupt() {
    // Body written, commit word still erased.
    let (store, cap) = layout(256);
    let mut f = ByteFlash::new(cap);
    let rec = encode(1, 1, b"half");
    plant(&mut f, 260, &rec[4..]);
    assert_eq!(loaded(&store, &mut f).1, LoadStatus::Empty);
}

#[test]
fn layout_and_size_errors_name_the_value_and_the_limit() {
    let mut f = ByteFlash::new(1024);
    let s = Store::new(100, 512, 256).unwrap();
    assert_eq!(
        s.store(&mut f, b"x"),
        Err(StoreError::SlotMisaligned {
            offset: 100,
            align: 256
        })
    );
    assert_eq!(
        Store::new(0, 128, 256),
        Err(StoreError::SlotsOverlap {
            a: 0,
            b: 128,
            len: 256
        })
    );
    let s = Store::new(0, 768, 512).unwrap();
    assert_eq!(
        s.store(&mut f, b"x"),
        Err(StoreError::SlotOutOfFlash {
            end: 1280,
            capacity: 1024
        })
    );
    let s = Store::new(0, 16, 16).unwrap();
    assert_eq!(
        s.load(&mut f, &mut [0u8; 4]),
        Err(StoreError::SlotLength {
            len: 16,
            erase_size: 1
        })
    );
    let s = Store::new(0, 256, 256).unwrap();
    let big = [0u8; 237];
    assert_eq!(
        s.store(&mut f, &big),
        Err(StoreError::PayloadTooLarge { len: 237, max: 236 })
    );
    s.store(&mut f, &big[..236]).unwrap();
    let mut small = [0u8; 10];
    assert_eq!(
        s.load(&mut f, &mut small),
        Err(StoreError::BufferTooSmall {
            needed: 236,
            available: 10
        })
    );
    // Word-programmed flash: the record rounds up to 4 bytes, so 236 still fits in 256.
    let mut w = SimFlash::<1, 4, 256>::new(1024);
    assert_eq!(s.max_payload::<SimFlash<1, 4, 256>>(), 236);
    s.store(&mut w, &big[..236]).unwrap();
}

/// A flash that silently ignores programs of one byte offset (a worn cell that stays 1).
struct Worn {
    inner: ByteFlash,
    dead: u32,
}

impl embedded_storage::nor_flash::ErrorType for Worn {
    type Error = settings::sim::SimError;
}

impl embedded_storage::nor_flash::ReadNorFlash for Worn {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.inner.read(offset, bytes)
    }
    fn capacity(&self) -> usize {
        self.inner.capacity()
    }
}

impl embedded_storage::nor_flash::NorFlash for Worn {
    const WRITE_SIZE: usize = 1;
    const ERASE_SIZE: usize = 256;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.inner.erase(from, to)
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        for (i, b) in bytes.iter().enumerate() {
            let at = offset + i as u32;
            if at != self.dead {
                self.inner.write(at, &[*b])?;
            }
        }
        Ok(())
    }
}

#[test]
fn a_program_the_flash_did_not_take_is_reported_and_the_old_settings_stay() {
    let (store, cap) = layout(256);
    let mut inner = ByteFlash::new(cap);
    store.store(&mut inner, b"old").unwrap();
    // The new record goes to slot B (768); its payload byte 2 never programs.
    let mut f = Worn {
        inner,
        dead: 768 + 16 + 2,
    };
    let err = store.store(&mut f, b"new settings").unwrap_err();
    assert!(
        matches!(
            err,
            StoreError::Verify {
                slot: Slot::B,
                found: SlotState::Corrupt(Corruption::Crc { .. })
            }
        ),
        "{err:?}"
    );
    assert_eq!(loaded(&store, &mut f.inner).0.as_deref(), Some(&b"old"[..]));
}
