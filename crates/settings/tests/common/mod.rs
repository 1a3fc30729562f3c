//! Shared by the tests: an independent encoder of the documented record layout, the
//! power-cut harness and the flash geometries tested.
#![allow(dead_code)]

use settings::sim::{Cut, SimFlash, Tear};
use settings::{LoadStatus, Store, StoreError};

/// Byte-programmed like the STM32F4 (read 1, write 1, erase 256).
pub type ByteFlash = SimFlash<1, 1, 256>;
/// Word-programmed, word-read (read 4, write 4, erase 512).
pub type WordFlash = SimFlash<4, 4, 512>;
/// 16-byte program rows (read 1, write 16, erase 1024).
pub type RowFlash = SimFlash<1, 16, 1024>;

/// Slots one erase unit long at units 1 and 3 (not at 0: offsets matter), flash of 4 units.
pub fn layout(erase: u32) -> (Store, usize) {
    (
        Store::new(erase, 3 * erase, erase).unwrap(),
        4 * erase as usize,
    )
}

/// The documented record layout, written here from the crate docs (not from its code).
pub fn encode(sequence: u32, version: u16, payload: &[u8]) -> Vec<u8> {
    let mut r = Vec::new();
    r.extend_from_slice(b"FSET");
    r.extend_from_slice(&version.to_le_bytes());
    r.extend_from_slice(&[0xFF, 0xFF]);
    r.extend_from_slice(&sequence.to_le_bytes());
    r.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    r.extend_from_slice(payload);
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&r[4..]);
    r.extend_from_slice(&crc.to_le_bytes());
    r
}

/// Plants bytes at a flash offset (a record or damage).
pub fn plant<const R: usize, const W: usize, const E: usize>(
    f: &mut SimFlash<R, W, E>,
    at: u32,
    bytes: &[u8],
) {
    f.bytes_mut()[at as usize..at as usize + bytes.len()].copy_from_slice(bytes);
}

/// What a load found, reduced to what the caller gets: the payload (None: defaults).
pub fn loaded<const R: usize, const W: usize, const E: usize>(
    store: &Store,
    f: &mut SimFlash<R, W, E>,
) -> (Option<Vec<u8>>, LoadStatus) {
    let mut buf = [0u8; 2048];
    let st = store.load(f, &mut buf).expect("load reads a powered flash");
    (st.payload(&buf).map(<[u8]>::to_vec), st)
}

/// The sequence number of a `Loaded` status.
pub fn sequence(st: &LoadStatus) -> Option<u32> {
    match st {
        LoadStatus::Loaded { sequence, .. } => Some(*sequence),
        _ => None,
    }
}

/// The tears tried at every cut point.
pub const TEARS: [Tear; 5] = [
    Tear::Before,
    Tear::After,
    Tear::Partial(1),
    Tear::Partial(0xDEAD_BEEF),
    Tear::Partial(42),
];

/// A write operation under test: stores `new` on the flash (the real store, or a broken
/// writer to show that the harness catches it).
pub type Op<'a, F> = &'a dyn Fn(&Store, &mut F, &[u8]) -> Result<u32, StoreError>;

/// For every step of `op` storing `new` over `base` and every tear of that step: the next
/// load gives exactly `old` (with its sequence `old_seq`) or exactly `new` (with
/// `old_seq + 1`, or 1 over no settings), and a store after the power comes back succeeds
/// and loads. `old = None`: no settings before (empty or corrupt store). Returns the number
/// of cut points tried, or the first violation.
pub fn all_cuts<const R: usize, const W: usize, const E: usize>(
    store: &Store,
    base: &SimFlash<R, W, E>,
    old: Option<(&[u8], u32)>,
    new: &[u8],
    op: Op<'_, SimFlash<R, W, E>>,
) -> Result<u64, String> {
    let mut dry = base.clone();
    dry.power_on();
    op(store, &mut dry, new).map_err(|e| format!("uncut store failed: {e:?}"))?;
    let n = dry.steps();
    let new_seq = old.map_or(1, |(_, q)| q.wrapping_add(1));
    dry.power_on();
    let (got, st) = loaded(store, &mut dry);
    if got.as_deref() != Some(new) || sequence(&st) != Some(new_seq) {
        return Err(format!(
            "uncut store: loaded {got:?} ({st:?}), expected {new:?} with sequence {new_seq}"
        ));
    }
    for at in 0..n {
        for tear in TEARS {
            let mut f = base.clone();
            f.power_on();
            f.cut(Cut { at, tear });
            if op(store, &mut f, new).is_ok() {
                return Err(format!("step {at}/{n} {tear:?}: store reported success"));
            }
            f.power_on();
            let (got, st) = loaded(store, &mut f);
            let ok = match (&got, old) {
                (Some(p), _) if p == new => sequence(&st) == Some(new_seq),
                (Some(p), Some((o, q))) if p == o => sequence(&st) == Some(q),
                (None, None) => true,
                _ => false,
            };
            if !ok {
                return Err(format!(
                    "step {at}/{n} {tear:?}: loaded {got:?} ({st:?}); expected old {old:?} or new {new:?} (seq {new_seq})"
                ));
            }
            // The next load gives the same, and a new store after power-up works.
            if loaded(store, &mut f).0 != got {
                return Err(format!("step {at}/{n} {tear:?}: a second load differs"));
            }
            let again = b"after the power came back";
            store
                .store(&mut f, again)
                .map_err(|e| format!("step {at}/{n} {tear:?}: store after power-up: {e:?}"))?;
            if loaded(store, &mut f).0.as_deref() != Some(&again[..]) {
                return Err(format!(
                    "step {at}/{n} {tear:?}: store after power-up does not load"
                ));
            }
        }
    }
    Ok(n)
}

/// The store under test as an [`Op`].
pub fn real<F: embedded_storage::nor_flash::NorFlash>(
    store: &Store,
    f: &mut F,
    payload: &[u8],
) -> Result<u32, StoreError> {
    store.store(f, payload)
}
