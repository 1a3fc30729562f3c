//! Every finger a user may plausibly build (the paper's, its springs off by −40/+60 %, the
//! distal one down to −70 %, its rest angles by ±5°, its links by ±5 %, its distal phalanx
//! ±20 % long) gets both
//! estimators' tables: the model accepting a finger and a table refusing it would leave the
//! firmware without an estimate for a file the finger check passed.

use pathfit::q::PathTable;
use pathfit::PathFitConfig;
use proptest::prelude::*;
use pts::fixed::Fx32;
use pts::table::FreeTable;
use pts::{Finger, Model, Real};

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
        k1 in 0.6f64..1.6, k2 in 0.3f64..1.6,
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

/// Soft springs: at K2 × 0.6 the path's excursion band above the free motion reaches the
/// toggle (the path-fit table once refused it); with K1 × 0.6 and K2 × 0.3 the free motion at
/// the two-point table's top torque turns the crank past π, off the model's branch (that table
/// once refused it), so the table ends lower, with the model's free motion where it has one.
#[test]
fn the_softest_springs_get_both_tables() {
    for (k1, k2, d02) in [(1.6, 0.6, 0.0), (0.6, 0.3, 5.0)] {
        let f = finger([k1, k2, 0.0, d02, 0.95, 0.8, 0.95, 0.95, 0.95]);
        PathTable::new(&f, &PathFitConfig::DEFAULT, 1e-4).expect("path-fit table");
        let t = FreeTable::<Fx32>::new(&f).expect("two-point table");
        let m = Model::<f64>::new(&f).unwrap();
        let (lo, hi) = t.theta_a_range();
        assert!(hi < core::f64::consts::PI, "table top θa = {hi} rad");
        for i in 0..=20 {
            let th = lo + (hi - lo) * f64::from(i) / 20.0;
            let exact = m.free_from_theta_a(th).unwrap().theta2;
            let (cfg, _) = t.free_from_theta_a(Fx32::from_f64(th)).unwrap();
            let err = (cfg.theta2.to_f64() - exact).abs();
            assert!(
                err < 1e-5,
                "K1 × {k1}, K2 × {k2}, θa {th}: θ2 off by {err} rad"
            );
        }
    }
}
