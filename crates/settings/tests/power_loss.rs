//! Power lost at every primitive step of a store (each erase, each program unit, each torn
//! in three ways, plus not started and completed): the next load gives exactly the old or
//! exactly the new payload.

mod common;

use common::*;
use embedded_storage::nor_flash::NorFlash;
use settings::sim::SimFlash;
use settings::{LoadStatus, Store, StoreError};

const OLDER: &[u8] = b"older settings, seq 1";
const OLD: &[u8] = b"the old settings: dta=0.8 estimator=two-point";
const NEW: &[u8] = b"the NEW settings: dta=0.5 estimator=path-fit, rate=50";

/// Every base state for one geometry: old in A only, old in B with an older record in A,
/// empty, corrupt, and old at the top of the sequence space.
fn every_base<const R: usize, const W: usize, const E: usize>() {
    let (store, cap) = layout(E as u32);
    let op: Op<'_, SimFlash<R, W, E>> = &real;

    // Old settings in A (sequence 1), B erased: the new record goes to B.
    let mut one = SimFlash::<R, W, E>::new(cap);
    store.store(&mut one, OLD).unwrap();
    let n = all_cuts(&store, &one, Some((OLD, 1)), NEW, op).unwrap();
    assert!(
        n >= 3,
        "a store is at least an erase and two programs, got {n} steps"
    );
    eprintln!(
        "write size {W}: {n} steps per store, {} cut cases per base state",
        n * TEARS.len() as u64
    );

    // Older in A (1), old in B (2): the new record replaces the older one in A; the older
    // one must never come back.
    let mut two = SimFlash::<R, W, E>::new(cap);
    store.store(&mut two, OLDER).unwrap();
    store.store(&mut two, OLD).unwrap();
    all_cuts(&store, &two, Some((OLD, 2)), NEW, op).unwrap();

    // No settings yet.
    let empty = SimFlash::<R, W, E>::new(cap);
    all_cuts(&store, &empty, None, NEW, op).unwrap();

    // A corrupt store: garbage in A, a record with a broken CRC in B.
    let mut bad = SimFlash::<R, W, E>::new(cap);
    plant(&mut bad, E as u32, &[0x5A; 40]);
    let mut rec = encode(7, 1, OLD);
    rec[20] ^= 0x10;
    plant(&mut bad, 3 * E as u32, &rec);
    assert!(matches!(
        loaded(&store, &mut bad).1,
        LoadStatus::Corrupt { .. }
    ));
    all_cuts(&store, &bad, None, NEW, op).unwrap();

    // The old record at the last sequence number: the new one is 0 and must win.
    let mut top = SimFlash::<R, W, E>::new(cap);
    plant(&mut top, E as u32, &encode(u32::MAX, 1, OLD));
    all_cuts(&store, &top, Some((OLD, u32::MAX)), NEW, op).unwrap();
}

#[test]
fn every_cut_leaves_old_or_new_byte_programmed_flash() {
    every_base::<1, 1, 256>();
}

#[test]
fn every_cut_leaves_old_or_new_word_programmed_flash() {
    every_base::<4, 4, 512>();
}

#[test]
fn every_cut_leaves_old_or_new_row_programmed_flash() {
    every_base::<1, 16, 1024>();
}

/// Slots of two erase units: a cut between the two erases too.
#[test]
fn every_cut_leaves_old_or_new_with_multi_unit_slots() {
    let store = Store::new(0, 1024, 512).unwrap();
    let mut f = SimFlash::<1, 4, 256>::new(2048);
    store.store(&mut f, OLD).unwrap();
    let big: Vec<u8> = (0..400u32).map(|i| (i * 7 + 3) as u8).collect();
    let n = all_cuts(&store, &f, Some((OLD, 1)), &big, &real).unwrap();
    assert!(
        n > 100,
        "two erases and 104 word programs expected, got {n}"
    );
}

/// The harness can fail: a writer that erases both slots before writing (no A/B) is caught.
#[test]
fn the_harness_catches_a_writer_without_two_slots() {
    let (store, cap) = layout(256);
    let mut f = ByteFlash::new(cap);
    store.store(&mut f, OLD).unwrap();
    // Erases both slots, then writes the record (committed last, sequence advanced).
    let broken = |_: &Store, f: &mut ByteFlash, p: &[u8]| -> Result<u32, StoreError> {
        let e = |_| StoreError::Flash(settings::FlashError::Other);
        f.erase(256, 512).map_err(e)?;
        f.erase(768, 1024).map_err(e)?;
        let rec = encode(2, 1, p);
        f.write(260, &rec[4..]).map_err(e)?;
        f.write(256, &rec[..4]).map_err(e)?;
        Ok(2)
    };
    let err = all_cuts(&store, &f, Some((OLD, 1)), NEW, &broken).unwrap_err();
    assert!(err.contains("expected old"), "{err}");
}

/// The harness can fail: a writer whose record does not advance the sequence number (the
/// new record is written to the free slot but the old one stays newest) is caught.
#[test]
fn the_harness_catches_a_writer_that_keeps_the_sequence() {
    let (store, cap) = layout(256);
    let mut f = ByteFlash::new(cap);
    store.store(&mut f, OLD).unwrap();
    let stale = |_: &Store, f: &mut ByteFlash, p: &[u8]| -> Result<u32, StoreError> {
        let e = |_| StoreError::Flash(settings::FlashError::Other);
        f.erase(768, 1024).map_err(e)?;
        let rec = encode(1, 1, p);
        f.write(772, &rec[4..]).map_err(e)?;
        f.write(768, &rec[..4]).map_err(e)?;
        Ok(1)
    };
    let err = all_cuts(&store, &f, Some((OLD, 1)), NEW, &stale).unwrap_err();
    assert!(err.contains("uncut store"), "{err}");
}
