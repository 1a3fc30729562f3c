//! Every public entry point of the model, on every back end, over arbitrary inputs
//! (NaN, ±inf, huge, tiny, negative, and the special configurations of MODEL.md):
//! the result is `Ok` with finite, unsaturated values, or a typed `Err`; never a panic
//! (overflow checks are on in the test profile, so an integer overflow would panic).
use pts::fixed::{Fx16, Fx24, Fx32};
use pts::{Config, Contact, Finger, Model, Real};

use proptest::prelude::*;

/// Interesting f64 inputs: anything, the specials, and values near the model's features.
fn value() -> impl Strategy<Value = f64> {
    prop_oneof![
        2 => any::<f64>(),
        2 => prop::sample::select(vec![
            f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 0.0, -0.0, 1e300, -1e300, 1e-300,
            -1e-300, f64::MIN_POSITIVE, f64::MAX, f64::MIN, 1.0, -1.0,
            // toggles, D = 0, the monotone limit, the rest pose, the Table 2 contact
            2.3557, -1.1761, -0.5267, 3.6683, 0.868, -0.8503608, -0.223771, 0.209196,
            0.340821, 0.075, 0.02927, 9.965, 6.7249, 2.6179, 30.2825, 0.54390,
            4.0 * core::f64::consts::PI, 1e3, 1e4, 32767.0, 2147483647.0,
        ]),
        3 => -2.0f64..2.0,
        1 => -1e5f64..1e5,
        1 => -1e-5f64..1e-5,
    ]
}

/// A finger: mostly the paper's with some fields replaced by arbitrary values.
fn finger() -> impl Strategy<Value = Finger> {
    (prop::collection::vec(prop::option::weighted(0.15, value()), 10)).prop_map(|o| {
        let p = Finger::PAPER;
        let g = |i: usize, d: f64| o.get(i).copied().flatten().unwrap_or(d);
        Finger {
            l1: g(0, p.l1),
            l2: g(1, p.l2),
            a: g(2, p.a),
            b: g(3, p.b),
            c: g(4, p.c),
            phi2: g(5, p.phi2),
            theta01: g(6, p.theta01),
            theta02: g(7, p.theta02),
            k1: g(8, p.k1),
            k2: g(9, p.k2),
        }
    })
}

fn sane<R: Real>(x: R) -> bool {
    x.is_finite() && !x.is_saturated()
}

fn sane_config<R: Real>(c: &Config<R>) -> bool {
    [c.theta1, c.theta2, c.theta_a, c.ta, c.x2, c.dx2]
        .iter()
        .all(|&v| sane(v))
}

fn sane_contact<R: Real>(m: &Model<R>, c: &Contact<R>) -> bool {
    let k2_ok = match c.k2 {
        None => true,
        Some(k) => sane(k) && k > R::zero() && k <= m.l2(),
    };
    k2_ok && sane(c.kc_free) && sane(c.kc_proximal) && sane(c.kc_tip)
}

/// Calls every entry point with inputs `v` (converted saturating: NaN → 0 for fixed point)
/// and checks what comes back.
fn exercise<R: Real>(f: &Finger, v: &[f64; 8]) -> Result<(), TestCaseError> {
    let Ok(m) = Model::<R>::new(f) else {
        return Ok(());
    };
    let r = |i: usize| R::from_f64(v[i]);
    if let Ok(c) = m.closure(r(0)) {
        prop_assert!(sane(c.gamma) && sane(c.x2) && sane(c.dx2), "closure {c:?}");
    }
    if let Ok(t) = m.theta_a(r(1), r(0)) {
        prop_assert!(sane(t), "theta_a {t:?}");
    }
    if let Ok(k) = m.kc_proximal(r(0), r(2)) {
        prop_assert!(sane(k), "kc_proximal {k:?}");
    }
    if let Ok(k) = m.kc_distal(r(0), r(2), r(3)) {
        prop_assert!(sane(k), "kc_distal {k:?}");
    }
    if let Ok(k) = m.kc_free(r(0), r(2)) {
        prop_assert!(sane(k), "kc_free {k:?}");
    }
    if let Ok(c) = m.free_from_torque(r(2)) {
        prop_assert!(sane_config(&c), "free_from_torque {c:?}");
        if let Ok(ct) = m.invert(&c, r(4)) {
            prop_assert!(sane_contact(&m, &ct), "invert {ct:?}");
        }
    }
    if let Ok(c) = m.free_from_theta_a(r(1)) {
        prop_assert!(sane_config(&c), "free_from_theta_a {c:?}");
    }
    // An arbitrary (not necessarily consistent) configuration.
    let cfg = Config {
        theta1: r(1),
        theta2: r(0),
        theta_a: r(5),
        ta: r(2),
        x2: r(6),
        dx2: r(7),
    };
    let _ = m.check_monotone(&cfg);
    if let Ok(ct) = m.invert(&cfg, r(4)) {
        prop_assert!(sane_contact(&m, &ct), "invert arbitrary {ct:?}");
    }
    if let Ok(e) = m.estimate_two_point(r(5), r(2), r(6), r(7)) {
        prop_assert!(
            sane(e.kc_hat) && sane(e.dta) && sane(e.dtheta_a),
            "estimate {e:?}"
        );
        prop_assert!(sane_config(&e.contact_config) && sane_contact(&m, &e.contact));
    }
    Ok(())
}

fn all_backends(f: &Finger, v: &[f64; 8]) -> Result<(), TestCaseError> {
    exercise::<f64>(f, v)?;
    exercise::<f32>(f, v)?;
    exercise::<Fx32>(f, v)?;
    exercise::<Fx24>(f, v)?;
    exercise::<Fx16>(f, v)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(3000))]

    #[test]
    fn any_input_paper_finger(v in prop::array::uniform8(value())) {
        all_backends(&Finger::PAPER, &v)?;
    }

    #[test]
    fn any_input_any_finger(f in finger(), v in prop::array::uniform8(value())) {
        all_backends(&f, &v)?;
    }

    /// Estimates around a real contact: θa,c on the free-motion curve, K̂c anywhere from
    /// below free motion to beyond the tip, Δθa down to zero.
    #[test]
    fn estimate_near_real_contacts(ta_c in -0.5f64..3.0, kc in -1.0f64..100.0, dth in prop_oneof![0.0f64..1e-5, 0.0f64..0.5]) {
        let m = Model::<f64>::paper().unwrap();
        if let Ok(c) = m.free_from_torque(ta_c) {
            let v = [c.theta2, c.theta1, ta_c, 0.03, kc, c.theta_a, c.theta_a + dth, ta_c + kc * dth];
            all_backends(&Finger::PAPER, &v)?;
        }
    }
}

/// Fixed-point models built from raw bit patterns (every representable value reachable).
mod raw_bits {
    use super::*;
    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]
        #[test]
        fn fx32_any_bits(b in prop::array::uniform8(any::<i64>())) {
            let v = b.map(|x| Fx32::from_bits(x).to_f64());
            exercise::<Fx32>(&Finger::PAPER, &v)?;
        }
        #[test]
        fn fx24_any_bits(b in prop::array::uniform8(any::<i32>())) {
            let v = b.map(|x| Fx24::from_bits(x).to_f64());
            exercise::<Fx24>(&Finger::PAPER, &v)?;
        }
        #[test]
        fn fx16_any_bits(b in prop::array::uniform8(any::<i32>())) {
            let v = b.map(|x| Fx16::from_bits(x).to_f64());
            exercise::<Fx16>(&Finger::PAPER, &v)?;
        }
    }
}
