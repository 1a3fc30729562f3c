//! Property tests: random payload sequences with random power cuts against a model of what
//! was committed, and random flash contents.

mod common;

use common::*;
use proptest::prelude::*;
use settings::sim::{Cut, SimFlash, Tear};
use settings::LoadStatus;

fn tear() -> impl Strategy<Value = Tear> {
    prop_oneof![
        Just(Tear::Before),
        Just(Tear::After),
        any::<u64>().prop_map(Tear::Partial),
    ]
}

/// One store of a payload, with a power cut at a point (`None`: no cut).
type StoreOp = (Vec<u8>, Option<(u16, Tear)>);

/// Stores of random payloads, with power cuts at random points.
fn ops() -> impl Strategy<Value = Vec<StoreOp>> {
    prop::collection::vec(
        (
            prop::collection::vec(any::<u8>(), 0..120),
            prop::option::weighted(0.6, (any::<u16>(), tear())),
        ),
        1..12,
    )
}

/// The model: the last payload known to be committed and how many commits there were. After
/// every (possibly cut) store the load must be the committed payload or the new one, with the
/// sequence number equal to the count of commits.
///
/// `start`: a record already in the flash (its sequence number, and whether it is in slot B),
/// planted from the documented layout; the count of commits then starts at its sequence.
fn run_model<const R: usize, const W: usize, const E: usize>(
    ops: &[StoreOp],
    start: Option<(u32, bool)>,
) -> Result<(), TestCaseError> {
    let (store, cap) = layout(E as u32);
    let mut f = SimFlash::<R, W, E>::new(cap);
    let mut committed: Option<Vec<u8>> = None;
    let mut commits = 0u32;
    if let Some((seq, in_b)) = start {
        let initial = b"planted before the test".to_vec();
        plant(
            &mut f,
            if in_b { 3 * E as u32 } else { E as u32 },
            &encode(seq, 1, &initial),
        );
        committed = Some(initial);
        commits = seq;
    }
    for (payload, cut) in ops {
        f.power_on();
        if let Some((frac, tear)) = cut {
            let mut dry = f.clone();
            store.store(&mut dry, payload).unwrap();
            let at = u64::from(*frac) % dry.steps();
            f.cut(Cut { at, tear: *tear });
            prop_assert!(store.store(&mut f, payload).is_err());
            f.power_on();
        } else {
            prop_assert_eq!(
                store.store(&mut f, payload).unwrap(),
                commits.wrapping_add(1)
            );
        }
        let (got, st) = loaded(&store, &mut f);
        if got.as_deref() == Some(&payload[..]) && sequence(&st) == Some(commits.wrapping_add(1)) {
            committed = Some(payload.clone());
            commits = commits.wrapping_add(1);
        } else {
            prop_assert_eq!(&got, &committed, "neither old nor new: {:?}", st);
            if committed.is_some() {
                prop_assert_eq!(sequence(&st), Some(commits));
            } else {
                // Nothing committed yet: no payload (Empty, or Corrupt after a torn commit).
                prop_assert!(!matches!(st, LoadStatus::Loaded { .. }), "{:?}", st);
            }
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    #[test]
    fn random_stores_and_cuts_byte_flash(ops in ops()) {
        run_model::<1, 1, 256>(&ops, None)?;
    }

    #[test]
    fn random_stores_and_cuts_word_flash(ops in ops()) {
        run_model::<4, 4, 512>(&ops, None)?;
    }

    #[test]
    fn random_stores_and_cuts_row_flash(ops in ops()) {
        run_model::<1, 16, 1024>(&ops, None)?;
    }

    /// The same from a record at any sequence number, most near the top so the counter wraps
    /// during the run.
    #[test]
    fn random_stores_and_cuts_across_the_wrap(
        ops in ops(),
        seq in prop_oneof![any::<u32>(), (u32::MAX - 8)..=u32::MAX],
        in_b in any::<bool>(),
    ) {
        run_model::<1, 1, 256>(&ops, Some((seq, in_b)))?;
    }

    /// A flash full of random bytes never panics and loads as Corrupt or Empty, and a store
    /// over it then loads.
    #[test]
    fn random_flash_is_corrupt_or_empty(bytes in prop::collection::vec(any::<u8>(), 1024)) {
        let (store, _) = layout(256);
        let mut f = ByteFlash::from_bytes(bytes);
        let (got, st) = loaded(&store, &mut f);
        prop_assert!(got.is_none());
        prop_assert!(matches!(st, LoadStatus::Corrupt { .. } | LoadStatus::Empty), "{:?}", st);
        store.store(&mut f, b"fresh").unwrap();
        let (got, _) = loaded(&store, &mut f);
        prop_assert_eq!(got.as_deref(), Some(&b"fresh"[..]));
    }

    /// Random bytes behind a valid magic and version (every header field random): never a
    /// panic, never a load (the length or the CRC rejects them).
    #[test]
    fn random_records_behind_a_valid_magic_are_rejected(
        a in prop::collection::vec(any::<u8>(), 252),
        b in prop::collection::vec(any::<u8>(), 252),
        erased_b in any::<bool>(),
    ) {
        let (store, cap) = layout(512);
        let mut f = WordFlash::new(cap);
        let mut slot = b"FSET\x01\x00".to_vec();
        slot.extend_from_slice(&a[2..]);
        plant(&mut f, 512, &slot);
        if !erased_b {
            let mut slot = b"FSET\x01\x00".to_vec();
            slot.extend_from_slice(&b[2..]);
            plant(&mut f, 1536, &slot);
        }
        let (got, st) = loaded(&store, &mut f);
        prop_assert!(got.is_none());
        prop_assert!(matches!(st, LoadStatus::Corrupt { .. }), "{:?}", st);
    }

    /// A cut store over random flash: the next load is the new payload or no payload.
    #[test]
    fn cut_store_over_random_flash(
        bytes in prop::collection::vec(any::<u8>(), 1024),
        frac in any::<u16>(),
        t in tear(),
    ) {
        let (store, _) = layout(256);
        let base = ByteFlash::from_bytes(bytes);
        let mut dry = base.clone();
        store.store(&mut dry, b"new").unwrap();
        let mut f = base.clone();
        f.cut(Cut { at: u64::from(frac) % dry.steps(), tear: t });
        prop_assert!(store.store(&mut f, b"new").is_err());
        f.power_on();
        let (got, _) = loaded(&store, &mut f);
        prop_assert!(got.is_none() || got.as_deref() == Some(&b"new"[..]), "{:?}", got);
    }
}
