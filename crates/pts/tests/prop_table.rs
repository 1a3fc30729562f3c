//! The free-motion table against the f64 model's Newton solve, and the table-based
//! estimate against the f64 reference estimate.
use pts::fixed::{Fx16, Fx24, Fx32};
use pts::table::{FreeTable, TableReal};
use pts::{Finger, Model, Real};

use proptest::prelude::*;

const L2: f64 = 0.075;

/// Largest deviation of each interpolated field from the f64 Newton solve.
fn table_error<R: TableReal>(n: usize) -> [f64; 5] {
    let m = Model::<f64>::paper().unwrap();
    let t = FreeTable::<R>::new(&Finger::PAPER).unwrap();
    let (lo, hi) = t.theta_a_range();
    let mut worst = [0.0f64; 5];
    for i in 0..=n {
        let th = R::from_f64(lo + (hi - lo) * i as f64 / n as f64);
        let want = m.free_from_theta_a(th.to_f64()).unwrap();
        let (got, cos2) = t.free_from_theta_a(th).unwrap();
        let e = [
            got.theta2.to_f64() - want.theta2,
            got.theta1.to_f64() - want.theta1,
            got.x2.to_f64() - want.x2,
            got.dx2.to_f64() - want.dx2,
            cos2.to_f64() - want.theta2.cos(),
        ];
        for (w, e) in worst.iter_mut().zip(e) {
            *w = w.max(e.abs());
        }
        assert!((got.ta.to_f64() - want.ta).abs() < 1e-3);
    }
    worst
}

#[test]
fn table_matches_newton() {
    let e = table_error::<f64>(5000);
    println!("f64 table: max |error| theta2 theta1 x2 dx2 cos2 = {e:?}");
    assert!(e.iter().all(|&x| x < 1e-7), "{e:?}");
    let e = table_error::<Fx32>(5000);
    println!("Fx32 table: {e:?}");
    assert!(e.iter().all(|&x| x < 1e-7), "{e:?}");
    let e = table_error::<f32>(2000);
    println!("f32 table: {e:?}");
    assert!(e.iter().all(|&x| x < 2e-6), "{e:?}");
    let e = table_error::<Fx24>(2000);
    println!("Fx24 table: {e:?}");
    assert!(e.iter().all(|&x| x < 2e-6), "{e:?}");
    let e = table_error::<Fx16>(2000);
    println!("Fx16 table: {e:?}");
    assert!(e.iter().all(|&x| x < 2e-4), "{e:?}");
}

/// Fingers with softer and stiffer springs (wider and narrower θa ranges, so larger and
/// smaller cubic slopes, on either side of the narrow-evaluation bound): the Fx32 table
/// interpolates like the f64 one.
#[test]
fn fx32_table_matches_f64_table_for_other_fingers() {
    for k1 in [0.2, 0.4, 0.6895, 2.0] {
        let f = Finger {
            k1,
            ..Finger::PAPER
        };
        let (Ok(t64), Ok(tx)) = (FreeTable::<f64>::new(&f), FreeTable::<Fx32>::new(&f)) else {
            continue;
        };
        let (lo, hi) = t64.theta_a_range();
        let mut worst = 0.0f64;
        for i in 0..=2000 {
            let th = Fx32::from_f64(lo + (hi - lo) * i as f64 / 2000.0);
            let (a, ca) = t64.free_from_theta_a(th.to_f64()).unwrap();
            let (b, cb) = tx.free_from_theta_a(th).unwrap();
            for (x, y) in [
                (a.theta2, b.theta2),
                (a.theta1, b.theta1),
                (a.x2, b.x2),
                (a.dx2, b.dx2),
                (ca, cb),
            ] {
                worst = worst.max((x - y.to_f64()).abs());
            }
        }
        println!("k1 {k1}: range {lo:.3}..{hi:.3}, max |Fx32 − f64| {worst:.2e}");
        assert!(worst < 1e-8, "k1 {k1}: {worst:e}");
    }
}

#[test]
fn table_covers_working_range_and_falls_back_outside() {
    let m = Model::<f64>::paper().unwrap();
    let t = FreeTable::<Fx32>::new(&Finger::PAPER).unwrap();
    let (lo, hi) = t.theta_a_range();
    let at = |ta: f64| m.free_from_torque(ta).unwrap().theta_a;
    assert!(lo < at(0.0) && hi > at(1.5), "range {lo}..{hi}");
    // Outside: the Newton solve on the same back end, so still the f64 answer.
    for th in [lo - 0.1, hi + 0.05] {
        let (c, cos2) = t.free_from_theta_a(Fx32::from_f64(th)).unwrap();
        let want = m.free_from_theta_a(Fx32::from_f64(th).to_f64()).unwrap();
        assert!((c.theta2.to_f64() - want.theta2).abs() < 1e-7);
        assert!((cos2.to_f64() - want.theta2.cos()).abs() < 1e-7);
    }
    assert!(t.free_from_theta_a(Fx32::MAX).is_err());
}

fn measurement(ta_c: f64, k2: f64, dta: f64) -> Option<[f64; 4]> {
    let m = Model::<f64>::paper().unwrap();
    let cfg = m.free_from_torque(ta_c).ok()?;
    let kc = m.kc_distal(cfg.theta2, ta_c, k2).ok()?;
    Some([cfg.theta_a, ta_c, cfg.theta_a + dta / kc, ta_c + dta])
}

/// Max |Δk2|/l2 and max relative ΔK̂c of the table estimate on `R` against the f64
/// Newton estimate, over a grid of contact torques, locations and steps.
fn estimate_error<R: TableReal>() -> (usize, usize, f64, f64, usize) {
    let m = Model::<f64>::paper().unwrap();
    let t = FreeTable::<R>::new(&Finger::PAPER).unwrap();
    let (mut n, mut both, mut ek, mut ec, mut mism) = (0, 0, 0.0f64, 0.0f64, 0);
    for i in 0..=30 {
        for j in 0..=30 {
            let ta_c = 1.5 * i as f64 / 30.0;
            let k2 = L2 * (0.02 + 0.97 * j as f64 / 30.0);
            let Some(v) = measurement(ta_c, k2, 0.5) else {
                continue;
            };
            let q = v.map(R::from_f64);
            n += 1;
            let want =
                m.estimate_two_point(q[0].to_f64(), q[1].to_f64(), q[2].to_f64(), q[3].to_f64());
            let got = t.estimate_two_point(q[0], q[1], q[2], q[3]);
            match (want, got) {
                (Ok(w), Ok(g)) => {
                    assert_eq!(w.contact.phalanx, g.contact.phalanx);
                    if let (Some(a), Some(b)) = (w.contact.k2, g.contact.k2) {
                        both += 1;
                        ek = ek.max((a - b.to_f64()).abs() / L2);
                        ec = ec.max(((g.kc_hat.to_f64() - w.kc_hat) / w.kc_hat).abs());
                    }
                }
                (Err(a), Err(b)) if a == b => {}
                _ => mism += 1,
            }
        }
    }
    (n, both, ek, ec, mism)
}

#[test]
fn table_estimate_matches_f64_reference() {
    let (n, both, ek, ec, mism) = estimate_error::<Fx32>();
    println!("Fx32 table: {both}/{n} distal, max dk2/l2 {ek:.2e}, max rel dKc {ec:.2e}, {mism} mismatches");
    assert!(both * 10 >= n * 6 && ek < 1e-4 && ec < 1e-4 && mism == 0);
    let (n, both, ek, ec, mism) = estimate_error::<f32>();
    println!("f32 table: {both}/{n} distal, max dk2/l2 {ek:.2e}, max rel dKc {ec:.2e}, {mism} mismatches");
    assert!(both * 10 >= n * 6 && ek < 1e-4 && ec < 1e-4 && mism == 0);
    let (n, both, ek, ec, mism) = estimate_error::<f64>();
    println!("f64 table: {both}/{n} distal, max dk2/l2 {ek:.2e}, max rel dKc {ec:.2e}, {mism} mismatches");
    assert!(both * 10 >= n * 6 && ek < 1e-6 && ec < 1e-9 && mism == 0);
    // The narrow types, for the record: Fx24 cannot hold K_c above 128 N·m/rad (contacts
    // near the tip at T_a,c ≳ 1 N·m are refused); Fx16 lacks resolution.
    for (name, r) in [
        ("Fx24", estimate_error::<Fx24>()),
        ("Fx16", estimate_error::<Fx16>()),
    ] {
        println!(
            "{name} table: {}/{} distal, max dk2/l2 {:.2e}, max rel dKc {:.2e}, {} mismatches",
            r.1, r.0, r.2, r.3, r.4
        );
        assert!(r.1 > 0);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(500))]

    #[test]
    fn fx32_table_estimate_property(ta_c in 0.0f64..1.5, k2f in 0.01f64..0.99, dta in 0.05f64..1.0) {
        let Some(v) = measurement(ta_c, (k2f * L2).max(1e-6), dta) else { return Ok(()) };
        let m = Model::<f64>::paper().unwrap();
        let t = FreeTable::<Fx32>::new(&Finger::PAPER).unwrap();
        let q = v.map(Fx32::from_f64);
        let want = m.estimate_two_point(q[0].to_f64(), q[1].to_f64(), q[2].to_f64(), q[3].to_f64());
        match (want, t.estimate_two_point(q[0], q[1], q[2], q[3])) {
            (Ok(w), Ok(g)) => {
                prop_assert_eq!(w.contact.phalanx, g.contact.phalanx);
                if let (Some(a), Some(b)) = (w.contact.k2, g.contact.k2) {
                    prop_assert!((a - b.to_f64()).abs() < 1e-4 * L2);
                }
            }
            (Err(a), Err(b)) => prop_assert_eq!(a, b),
            (w, g) => prop_assert!(false, "f64 {w:?} vs {g:?}"),
        }
    }

    /// The fixed-point cubics against f64: the full one (Σ|c_i| ≤ 1e6) and the narrow one
    /// (|c1| + |c2| + |c3| ≤ ¼) within a few units of 2^-32, at any fraction.
    #[test]
    fn fx32_cubics_match_f64(c0 in -1e5f64..1e5, c in prop::array::uniform3(-1.0f64..1.0),
                             scale in 0.0f64..1.0, u in 0u32..=u32::MAX) {
        let big = [c0, 3e3 * c[0], 3e3 * c[1], 3e3 * c[2]].map(Fx32::from_f64);
        let small = [c0, 0.08 * scale * c[0], 0.08 * scale * c[1], 0.08 * scale * c[2]].map(Fx32::from_f64);
        let uf = Fx32::from_bits(u as i64);
        let exact = |k: &[Fx32; 4]| {
            let (k, x) = (k.map(|v| v.to_f64()), uf.to_f64());
            k[0] + x * (k[1] + x * (k[2] + x * k[3]))
        };
        let ulp = 2f64.powi(-32);
        // Truncated steps (≤ 1 unit each) plus f64 rounding of the 1e5-sized sum.
        let tol = 4.0 * ulp + 1e-16 * c0.abs();
        prop_assert!((<Fx32 as TableReal>::cubic(&big, uf).to_f64() - exact(&big)).abs() <= tol + 1e-15 * 1e4);
        prop_assert!((<Fx32 as TableReal>::cubic_small(&small, uf).to_f64() - exact(&small)).abs() <= tol);
        prop_assert!((<Fx32 as TableReal>::cubic(&small, uf).to_f64() - exact(&small)).abs() <= tol);
    }

    /// Any input, every back end: Ok with finite unsaturated values or a typed Err.
    #[test]
    fn table_any_input(v in prop::array::uniform4(prop_oneof![
        any::<f64>(), -2.0f64..2.0, Just(f64::NAN), Just(f64::INFINITY), Just(-1e300)
    ])) {
        fn run<R: TableReal>(v: &[f64; 4]) -> Result<(), TestCaseError> {
            let t = FreeTable::<R>::new(&Finger::PAPER).unwrap();
            let q = v.map(R::from_f64);
            let ok = |x: R| x.is_finite() && !x.is_saturated();
            if let Ok((c, cos2)) = t.free_from_theta_a(q[0]) {
                prop_assert!(ok(c.theta2) && ok(c.x2) && ok(c.dx2) && ok(cos2) && ok(c.ta));
            }
            if let Ok(e) = t.estimate_two_point(q[0], q[1], q[2], q[3]) {
                prop_assert!(ok(e.kc_hat) && ok(e.dtheta_a));
                prop_assert!(e.contact.k2.is_none_or(|k| ok(k) && k > R::zero()));
            }
            Ok(())
        }
        run::<f64>(&v)?;
        run::<f32>(&v)?;
        run::<Fx32>(&v)?;
        run::<Fx24>(&v)?;
        run::<Fx16>(&v)?;
    }
}
