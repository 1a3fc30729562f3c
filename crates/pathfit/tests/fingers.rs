//! Every finger a user may plausibly build (the paper's, its springs off by up to −40/+60 %,
//! its rest angles by ±5°, its links by ±5 %, its distal phalanx ±20 % long) gets both
//! estimators' tables: the model accepting a finger and a table refusing it would leave the
//! firmware without an estimate for a file the finger check passed.

use pathfit::q::PathTable;
use pathfit::PathFitConfig;
use proptest::prelude::*;
use pts::fixed::Fx32;
use pts::table::FreeTable;
use pts::{Finger, Model};

fn finger(s: [f64; 9]) -> Finger {
    let p = Finger::PAPER;
    Finger {
        k1: p.k1 * s[0],
        k2: p.k2 * s[1],
        theta01: p.theta01 + s[2].to_radians(),
        theta02: p.theta02 + s[3].to_radians(),
        l1: p.l1 * s[4],
        l2: p.l2 * s[5],
        a: p.a * s[6],
        b: p.b * s[7],
        c: p.c * s[8],
        ..p
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn a_plausible_finger_gets_both_tables(
        k1 in 0.6f64..1.6, k2 in 0.6f64..1.6,
        d01 in -5.0f64..5.0, d02 in -5.0f64..5.0,
        l1 in 0.95f64..1.05, l2 in 0.8f64..1.2,
        a in 0.95f64..1.05, b in 0.95f64..1.05, c in 0.95f64..1.05,
    ) {
        let f = finger([k1, k2, d01, d02, l1, l2, a, b, c]);
        // Only fingers the model itself accepts, at rest as well.
        prop_assume!(f.validate().is_ok());
        let Ok(m) = Model::<f64>::new(&f) else { return Ok(()); };
        prop_assume!(m.theta_a(f.theta01, f.theta02).is_ok());
        let path = PathTable::new(&f, &PathFitConfig::DEFAULT, 1e-4);
        prop_assert!(path.is_ok(), "path-fit table refused {:?}: {:?}", f, path.err());
        let free = FreeTable::<Fx32>::new(&f);
        prop_assert!(free.is_ok(), "two-point table refused {:?}: {:?}", f, free.err());
    }
}

/// The softest distal spring of the range, where the path's excursion band above the free
/// motion reaches the toggle (the table once refused it).
#[test]
fn the_softest_distal_spring_gets_both_tables() {
    let f = finger([1.6, 0.6, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0]);
    PathTable::new(&f, &PathFitConfig::DEFAULT, 1e-4).expect("path-fit table");
    FreeTable::<Fx32>::new(&f).expect("two-point table");
}
