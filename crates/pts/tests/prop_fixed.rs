//! The fixed-point back ends against independent references: the elementary functions
//! against libm, the fixed-point model against the f64 model over the working range, and
//! the transmission against finite differences of θa(θ1, θ2).
use pts::fixed::{Fx16, Fx24, Fx32};
use pts::{Finger, Model, Phalanx, Real};

use proptest::prelude::*;

const L2: f64 = 0.075;

fn m64() -> Model<f64> {
    Model::new(&Finger::PAPER).unwrap()
}

// ---------------------------------------------------------------------------------------
// Elementary functions against libm, evaluated at the exactly representable input.
// ---------------------------------------------------------------------------------------

/// Largest |fixed − libm| of a unary function over a set of inputs.
fn max_err<R: Real>(xs: &[f64], f: impl Fn(R) -> R, g: impl Fn(f64) -> f64) -> (f64, f64) {
    let mut worst = (0.0, 0.0);
    for &x in xs {
        let xr = R::from_f64(x);
        let e = (f(xr).to_f64() - g(xr.to_f64())).abs();
        if e > worst.0 {
            worst = (e, xr.to_f64());
        }
    }
    worst
}

fn grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    (0..=n)
        .map(|i| lo + (hi - lo) * i as f64 / n as f64)
        .collect()
}

#[test]
fn fx32_trig_matches_libm() {
    let xs = grid(
        -4.0 * core::f64::consts::PI,
        4.0 * core::f64::consts::PI,
        20_001,
    );
    let (e, at) = max_err::<Fx32>(&xs, |x| x.sin(), libm::sin);
    assert!(e < 1e-9, "sin err {e:e} at {at}");
    let (e, at) = max_err::<Fx32>(&xs, |x| x.cos(), libm::cos);
    assert!(e < 1e-9, "cos err {e:e} at {at}");
    // Far from the origin the reduction still holds to the input's own resolution.
    let far = grid(-1e6, 1e6, 2_001);
    let (e, at) = max_err::<Fx32>(&far, |x| x.sin(), libm::sin);
    assert!(e < 1e-8, "sin far err {e:e} at {at}");
    let xs = grid(-1.0, 1.0, 20_001);
    let (e, at) = max_err::<Fx32>(&xs, |x| x.acos(), libm::acos);
    assert!(e < 2e-9, "acos err {e:e} at {at}");
    let xs = grid(0.0, 100.0, 20_001);
    let (e, at) = max_err::<Fx32>(&xs, |x| x.sqrt(), libm::sqrt);
    assert!(e < 1e-9, "sqrt err {e:e} at {at}");
}

#[test]
fn fx16_trig_matches_libm() {
    let lsb = 1.0 / 65536.0;
    let xs = grid(
        -4.0 * core::f64::consts::PI,
        4.0 * core::f64::consts::PI,
        20_001,
    );
    let (e, at) = max_err::<Fx16>(&xs, |x| x.sin(), libm::sin);
    assert!(e <= lsb, "sin err {e:e} at {at}");
    let (e, at) = max_err::<Fx16>(&xs, |x| x.cos(), libm::cos);
    assert!(e <= lsb, "cos err {e:e} at {at}");
    let xs = grid(-1.0, 1.0, 20_001);
    let (e, at) = max_err::<Fx16>(&xs, |x| x.acos(), libm::acos);
    assert!(e <= lsb, "acos err {e:e} at {at}");
    let xs = grid(0.0, 30_000.0, 20_001);
    let (e, at) = max_err::<Fx16>(&xs, |x| x.sqrt(), libm::sqrt);
    assert!(e <= lsb, "sqrt err {e:e} at {at}");
}

proptest! {
    #[test]
    fn fx32_atan2_matches_libm(y in -1e4f64..1e4, x in -1e4f64..1e4, scale in -20i32..20) {
        let s = 2f64.powi(scale);
        let (yr, xr) = (Fx32::from_f64(y * s), Fx32::from_f64(x * s));
        let want = libm::atan2(yr.to_f64(), xr.to_f64());
        let got = yr.atan2(xr).to_f64();
        // Inputs at tiny scales are quantised; compare at the quantised point.
        prop_assert!((got - want).abs() < 1e-9, "atan2({}, {}) = {got} want {want}", yr.to_f64(), xr.to_f64());
    }

    #[test]
    fn fx32_sin_cos_any_bits(bits in any::<i64>()) {
        let x = Fx32::from_bits(bits);
        let (s, c) = (x.sin().to_f64(), x.cos().to_f64());
        // Identity checks that do not depend on the (huge) argument's reduction in f64.
        prop_assert!(s.abs() <= 1.0 + 1e-9 && c.abs() <= 1.0 + 1e-9);
        prop_assert!((s * s + c * c - 1.0).abs() < 1e-8);
    }

    #[test]
    fn fx32_sqrt_any_bits(bits in 0i64..i64::MAX) {
        let x = Fx32::from_bits(bits);
        let got = x.sqrt().to_f64();
        let want = libm::sqrt(x.to_f64());
        prop_assert!((got - want).abs() <= 1e-12 * want + 3e-10, "sqrt({}) = {got} want {want}", x.to_f64());
    }

    #[test]
    fn fx16_atan2_acos_any_bits(y in any::<i32>(), x in any::<i32>()) {
        let (yr, xr) = (Fx16::from_bits(y), Fx16::from_bits(x));
        let want = libm::atan2(yr.to_f64(), xr.to_f64());
        prop_assert!((yr.atan2(xr).to_f64() - want).abs() <= 1.0 / 65536.0);
        let a = yr.acos().to_f64();
        prop_assert!((0.0..=core::f64::consts::PI + 1e-4).contains(&a));
    }

    #[test]
    fn fx32_atan2_any_bits(y in any::<i64>(), x in any::<i64>()) {
        let (yr, xr) = (Fx32::from_bits(y), Fx32::from_bits(x));
        let want = libm::atan2(yr.to_f64(), xr.to_f64());
        prop_assert!((yr.atan2(xr).to_f64() - want).abs() < 1e-9);
    }
}

// ---------------------------------------------------------------------------------------
// Saturating arithmetic.
// ---------------------------------------------------------------------------------------

fn saturation_laws<R: Real>() {
    let max = R::from_f64(1e300);
    let min = R::from_f64(-1e300);
    let two = R::from_f64(2.0);
    assert!(max.is_saturated() && min.is_saturated());
    assert!(!R::one().is_saturated() && !R::zero().is_saturated());
    assert_eq!(max + R::one(), max);
    assert_eq!(min - R::one(), min);
    assert_eq!(max * two, max);
    assert_eq!(max * -two, min);
    assert_eq!(min * min, max);
    assert_eq!(R::one() / R::zero(), max);
    assert_eq!(-R::one() / R::zero(), min);
    assert_eq!(R::zero() / R::zero(), max);
    assert_eq!(-min, max);
    assert_eq!(min.abs(), max);
    assert_eq!(min / -R::one(), max);
    assert_eq!(max / R::from_f64(0.5), max);
    assert_eq!(R::from_f64(f64::NAN), R::zero());
    assert_eq!(R::from_f64(f64::INFINITY), max);
    assert_eq!(R::try_from_f64(f64::NAN), None);
    assert_eq!(R::try_from_f64(f64::NEG_INFINITY), None);
    assert_eq!(R::try_from_f64(1e300), None);
    assert_eq!(R::from_f64(-4.0).sqrt(), R::zero());
    assert_eq!(R::from_f64(3.0).acos(), R::zero());
    assert!((R::from_f64(-3.0).acos().to_f64() - core::f64::consts::PI).abs() < 1e-4);
    assert_eq!(R::zero().atan2(R::zero()), R::zero());
    // Round-to-nearest products of exact values are exact; quotients within 2e-9.
    assert_eq!((R::from_f64(1.5) * R::from_f64(-2.5)).to_f64(), -3.75);
    assert!(((R::from_f64(-7.5) / R::from_f64(2.5)).to_f64() + 3.0).abs() < 6e-9);
}

#[test]
fn fx32_saturates() {
    saturation_laws::<Fx32>();
    assert_eq!(Fx32::MAX.to_bits(), i64::MAX);
    assert_eq!(Fx32::from_bits(1 << 32).to_f64(), 1.0);
}

#[test]
fn fx24_saturates_and_matches_libm() {
    saturation_laws::<Fx24>();
    assert_eq!(Fx24::MAX.to_bits(), i32::MAX);
    assert_eq!(Fx32::from(Fx24::from_f64(-1.25)).to_f64(), -1.25);
    let lsb = 1.0 / 16_777_216.0;
    let xs = grid(
        -4.0 * core::f64::consts::PI,
        4.0 * core::f64::consts::PI,
        20_001,
    );
    let (e, at) = max_err::<Fx24>(&xs, |x| x.sin(), libm::sin);
    assert!(e <= lsb, "sin err {e:e} at {at}");
    let (e, at) = max_err::<Fx24>(&xs, |x| x.cos(), libm::cos);
    assert!(e <= lsb, "cos err {e:e} at {at}");
    let xs = grid(-1.0, 1.0, 20_001);
    let (e, at) = max_err::<Fx24>(&xs, |x| x.acos(), libm::acos);
    assert!(e <= lsb, "acos err {e:e} at {at}");
    let xs = grid(0.0, 127.0, 20_001);
    let (e, at) = max_err::<Fx24>(&xs, |x| x.sqrt(), libm::sqrt);
    assert!(e <= lsb, "sqrt err {e:e} at {at}");
}

#[test]
fn fx16_saturates() {
    saturation_laws::<Fx16>();
    assert_eq!(Fx16::MAX.to_bits(), i32::MAX);
    assert_eq!(Fx32::from(Fx16::from_f64(-1.25)).to_f64(), -1.25);
}

proptest! {
    #[test]
    fn fx32_ops_match_exact_or_saturate(a in any::<i64>(), b in any::<i64>()) {
        let (x, y) = (Fx32::from_bits(a), Fx32::from_bits(b));
        let lim = |v: f64| v.clamp(Fx32::MIN.to_f64(), Fx32::MAX.to_f64());
        let (xf, yf) = (x.to_f64(), y.to_f64());
        let ulp = 2f64.powi(-32);
        // to_f64 rounds 64-bit values to 53 bits: allow that rounding of each operand.
        let tol = ulp + 4e-16 * (xf.abs() + yf.abs() + (xf * yf).abs());
        let close = |got: Fx32, want: f64| (got.to_f64() - lim(want)).abs() <= tol + 4e-16 * want.abs();
        prop_assert!(close(x + y, xf + yf));
        prop_assert!(close(x - y, xf - yf));
        prop_assert!(close(x * y, xf * yf));
        if b != 0 {
            prop_assert!(close(x / y, xf / yf));
        }
    }

    #[test]
    fn fx24_ops_match_exact_or_saturate(a in any::<i32>(), b in any::<i32>()) {
        let (x, y) = (Fx24::from_bits(a), Fx24::from_bits(b));
        let lim = |v: f64| v.clamp(Fx24::MIN.to_f64(), Fx24::MAX.to_f64());
        let (xf, yf) = (x.to_f64(), y.to_f64());
        let ulp = 2f64.powi(-24);
        let close = |got: Fx24, want: f64| (got.to_f64() - lim(want)).abs() <= ulp;
        prop_assert!(close(x + y, xf + yf));
        prop_assert!(close(x - y, xf - yf));
        prop_assert!(close(x * y, xf * yf));
        if b != 0 {
            prop_assert!(close(x / y, xf / yf));
        }
    }

    #[test]
    fn fx16_ops_match_exact_or_saturate(a in any::<i32>(), b in any::<i32>()) {
        let (x, y) = (Fx16::from_bits(a), Fx16::from_bits(b));
        let lim = |v: f64| v.clamp(Fx16::MIN.to_f64(), Fx16::MAX.to_f64());
        let (xf, yf) = (x.to_f64(), y.to_f64());
        let ulp = 2f64.powi(-16);
        let close = |got: Fx16, want: f64| (got.to_f64() - lim(want)).abs() <= ulp;
        prop_assert!(close(x + y, xf + yf));
        prop_assert!(close(x - y, xf - yf));
        prop_assert!(close(x * y, xf * yf));
        if b != 0 {
            prop_assert!(close(x / y, xf / yf));
        }
    }
}

// ---------------------------------------------------------------------------------------
// The model in fixed point against the f64 model over the working range.
// ---------------------------------------------------------------------------------------

/// Free-motion contact configuration (f64) holding T_a,c, then the quasi-static-free
/// two-point measurement a contact at k2 would give for a torque step ΔT_a: Δθa = ΔT_a/K_c.
fn measurement(ta_c: f64, k2: f64, dta: f64) -> Option<(f64, f64, f64, f64)> {
    let m = m64();
    let cfg = m.free_from_torque(ta_c).ok()?;
    let kc = m.kc_distal(cfg.theta2, ta_c, k2).ok()?;
    Some((cfg.theta_a, ta_c, cfg.theta_a + dta / kc, ta_c + dta))
}

#[test]
fn fx32_table2_column() {
    let m = Model::<Fx32>::paper().unwrap();
    let ta_c = 0.6895 * (1.2797 - core::f64::consts::FRAC_PI_4);
    let cfg = m.free_from_torque(Fx32::from_f64(ta_c)).unwrap();
    assert!((cfg.theta2.to_f64() - 0.209196).abs() < 1e-6);
    assert!((cfg.theta_a.to_f64() - -0.223771).abs() < 1e-6);
    let kc = m
        .kc_distal(cfg.theta2, cfg.ta, Fx32::from_f64(0.02927))
        .unwrap();
    assert!((kc.to_f64() - 6.7249).abs() < 1e-4, "kc {kc}");
    let est = m
        .estimate_two_point(
            cfg.theta_a,
            Fx32::from_f64(ta_c),
            cfg.theta_a + Fx32::from_f64(0.0802814),
            Fx32::from_f64(ta_c + 0.8),
        )
        .unwrap();
    assert_eq!(est.contact.phalanx, Phalanx::Distal);
    let k2 = est.contact.k2.unwrap().to_f64();
    assert!((k2 - 0.041529).abs() < 1e-4 * L2, "k2 {k2}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    /// Closure, stiffness closed forms and the free-motion solves, Fx32 vs f64.
    #[test]
    fn fx32_model_matches_f64(theta2 in -0.5f64..1.5, ta in 0.0f64..1.5, k2f in 0.001f64..=1.0) {
        let (m, mx) = (m64(), Model::<Fx32>::paper().unwrap());
        let t2 = Fx32::from_f64(theta2);
        let (t2e, tae) = (t2.to_f64(), Fx32::from_f64(ta).to_f64());
        let c = m.closure(t2e).unwrap();
        let cx = mx.closure(t2).unwrap();
        prop_assert!((cx.gamma.to_f64() - c.gamma).abs() < 1e-8);
        prop_assert!((cx.x2.to_f64() - c.x2).abs() < 1e-8);
        prop_assert!((cx.dx2.to_f64() - c.dx2).abs() < 1e-7);
        let rel = |a: f64, b: f64| (a - b).abs() / b.abs();
        let kp = m.kc_proximal(t2e, tae).unwrap();
        prop_assert!(rel(mx.kc_proximal(t2, Fx32::from_f64(ta)).unwrap().to_f64(), kp) < 1e-6);
        let kf = m.kc_free(t2e, tae).unwrap();
        prop_assert!(rel(mx.kc_free(t2, Fx32::from_f64(ta)).unwrap().to_f64(), kf) < 1e-6);
        let k2 = Fx32::from_f64(k2f * L2);
        // Up to the largest stiffness the estimator accepts: near the locking point
        // (d = s − x2 → 0) Q32 keeps only 2.3e-10/d² relative precision in d².
        if let Ok(kd) = m.kc_distal(t2e, tae, k2.to_f64()).and_then(|k| if k <= pts::model::MAX_STIFFNESS { Ok(k) } else { Err(pts::PtsError::OutOfRange) }) {
            let kdx = mx.kc_distal(t2, Fx32::from_f64(ta), k2).unwrap().to_f64();
            prop_assert!(rel(kdx, kd) < 1e-4, "K_c {kdx} vs {kd}");
        }
        let f = m.free_from_torque(tae).unwrap();
        let fx = mx.free_from_torque(Fx32::from_f64(ta)).unwrap();
        prop_assert!((fx.theta2.to_f64() - f.theta2).abs() < 1e-7);
        prop_assert!((fx.theta_a.to_f64() - f.theta_a).abs() < 1e-7);
        let g = mx.free_from_theta_a(Fx32::from_f64(f.theta_a)).unwrap();
        prop_assert!((g.theta2.to_f64() - f.theta2).abs() < 1e-7);
        prop_assert!((g.ta.to_f64() - f.ta).abs() < 1e-6);
    }

    /// The full estimate from contact configurations of free motion: k2 within 1e-4·l2 and
    /// K̂c within 1e-4 relative of the f64 reference, same classification.
    #[test]
    fn fx32_estimate_matches_f64(ta_c in 0.0f64..1.5, k2f in 0.0f64..=1.0, dta in 0.05f64..1.0) {
        let k2 = (k2f * L2).max(1e-6);
        let Some((tac, tc, ta, t)) = measurement(ta_c, k2, dta) else { return Ok(()) };
        let m = m64();
        let mx = Model::<Fx32>::paper().unwrap();
        let q = |v: f64| Fx32::from_f64(v);
        let want = m.estimate_two_point(q(tac).to_f64(), q(tc).to_f64(), q(ta).to_f64(), q(t).to_f64());
        let got = mx.estimate_two_point(q(tac), q(tc), q(ta), q(t));
        match (want, got) {
            (Ok(w), Ok(g)) => {
                prop_assert!(((g.kc_hat.to_f64() - w.kc_hat) / w.kc_hat).abs() < 1e-4);
                prop_assert_eq!(w.contact.phalanx, g.contact.phalanx);
                if let (Some(a), Some(b)) = (w.contact.k2, g.contact.k2) {
                    prop_assert!((a - b.to_f64()).abs() < 1e-4 * L2, "k2 {} vs {a}", b.to_f64());
                }
            }
            (Err(a), Err(b)) => prop_assert_eq!(a, b),
            (w, g) => prop_assert!(false, "f64 {w:?} vs Fx32 {g:?}"),
        }
    }
}

// ---------------------------------------------------------------------------------------
// Transmission against central finite differences of θa(θ1, θ2).
// ---------------------------------------------------------------------------------------

#[test]
fn x2_and_dx2_match_finite_differences() {
    let m = m64();
    let mx = Model::<Fx32>::paper().unwrap();
    let t1 = core::f64::consts::FRAC_PI_4;
    let ta = |t2: f64| m.theta_a(t1, t2).unwrap();
    for t2 in grid(-0.5, 1.5, 400) {
        let c = m.closure(t2).unwrap();
        let h = 1e-5;
        let fd1 = (ta(t2 + h) - ta(t2 - h)) / (2.0 * h);
        assert!((c.x2 - fd1).abs() < 1e-8, "x2 {} fd {fd1} at {t2}", c.x2);
        let h = 1e-4;
        let fd2 = (ta(t2 + h) - 2.0 * ta(t2) + ta(t2 - h)) / (h * h);
        assert!((c.dx2 - fd2).abs() < 1e-5, "dx2 {} fd {fd2} at {t2}", c.dx2);
        // The fixed-point transmission against the same differences.
        let cx = mx.closure(Fx32::from_f64(t2)).unwrap();
        let t2q = Fx32::from_f64(t2).to_f64();
        let h = 1e-5;
        let fdq = (ta(t2q + h) - ta(t2q - h)) / (2.0 * h);
        assert!((cx.x2.to_f64() - fdq).abs() < 1e-7);
        assert!((cx.dx2.to_f64() - fd2).abs() < 1e-4);
    }
}

/// The same comparison on a deterministic grid, with the error reported; most of the grid
/// must give a distal estimate on both back ends (so the property above is not vacuous).
#[test]
fn fx32_estimate_grid_error() {
    let m = m64();
    let mx = Model::<Fx32>::paper().unwrap();
    let q = Fx32::from_f64;
    let (mut n, mut both, mut worst_k2, mut worst_kc) = (0, 0, 0.0f64, 0.0f64);
    for ta_c in grid(0.0, 1.5, 30) {
        for k2 in grid(0.002, L2, 30) {
            let Some((tac, tc, ta, t)) = measurement(ta_c, k2, 0.5) else {
                continue;
            };
            n += 1;
            let want = m.estimate_two_point(
                q(tac).to_f64(),
                q(tc).to_f64(),
                q(ta).to_f64(),
                q(t).to_f64(),
            );
            let got = mx.estimate_two_point(q(tac), q(tc), q(ta), q(t));
            if let (Ok(w), Ok(g)) = (want, got) {
                if let (Some(a), Some(b)) = (w.contact.k2, g.contact.k2) {
                    both += 1;
                    worst_k2 = worst_k2.max((a - b.to_f64()).abs() / L2);
                    worst_kc = worst_kc.max(((g.kc_hat.to_f64() - w.kc_hat) / w.kc_hat).abs());
                }
            }
        }
    }
    println!("grid {n} points, {both} distal on both; max |Δk2|/l2 = {worst_k2:e}, max rel ΔK̂c = {worst_kc:e}");
    assert!(
        both * 10 >= n * 6,
        "only {both} of {n} grid points gave a distal estimate"
    );
    assert!(worst_k2 < 1e-4 && worst_kc < 1e-4);
}

proptest! {
    /// Quotients of moderate values: Fx32 division is good to 2e-9 relative (reciprocal of
    /// the divisor's top 32 bits), Fx16 division is the exact truncated quotient.
    #[test]
    fn division_accuracy(a in -1e4f64..1e4, b in prop_oneof![-1e4f64..1e4, -1.0f64..1.0]) {
        let (x, y) = (Fx32::from_f64(a), Fx32::from_f64(b));
        prop_assume!(y.to_bits() != 0);
        let want = x.to_f64() / y.to_f64();
        prop_assume!(want.abs() < 2e9);
        let got = (x / y).to_f64();
        prop_assert!((got - want).abs() <= 2e-9 * want.abs() + 2.5e-10, "{got} vs {want}");
        let (x, y) = (Fx16::from_f64(a), Fx16::from_f64(b));
        prop_assume!(y.to_bits() != 0);
        let want = (((x.to_bits() as i64) << 16) / y.to_bits() as i64).clamp(i32::MIN as i64, i32::MAX as i64);
        prop_assert_eq!((x / y).to_bits() as i64, want);
    }
}
