//! Every solver entry point on every back end (f64, f32, Fx32, Fx24, Fx16, and the
//! free-motion table on each) with inputs taken from the fuzzer's bytes: raw f64 bit
//! patterns (NaN, ±inf, subnormals, huge) and raw fixed-point bits. Any panic (including an
//! integer overflow: overflow checks are on) or a non-finite / saturated value inside `Ok`
//! is a finding.
#![no_main]

use libfuzzer_sys::fuzz_target;
use pts::fixed::{Fx16, Fx24, Fx32};
use pts::table::{FreeTable, TableReal};
use pts::{Config, Finger, Model, Real};
use std::sync::OnceLock;

fn sane<R: Real>(x: R) -> bool {
    x.is_finite() && !x.is_saturated()
}

fn exercise<R: TableReal>(m: &Model<R>, t: &FreeTable<R>, v: &[R; 8]) {
    if let Ok(c) = m.closure(v[0]) {
        assert!(sane(c.gamma) && sane(c.x2) && sane(c.dx2), "{c:?}");
    }
    if let Ok(x) = m.theta_a(v[1], v[0]) {
        assert!(sane(x));
    }
    for r in [
        m.kc_proximal(v[0], v[2]),
        m.kc_distal(v[0], v[2], v[3]),
        m.kc_free(v[0], v[2]),
    ] {
        if let Ok(x) = r {
            assert!(sane(x), "{x:?}");
        }
    }
    let cfg = Config {
        theta1: v[1],
        theta2: v[0],
        theta_a: v[5],
        ta: v[2],
        x2: v[6],
        dx2: v[7],
    };
    let _ = m.check_monotone(&cfg);
    let _ = m.check_monotone_cos(&cfg, v[3]);
    for r in [m.invert(&cfg, v[4]), m.invert_cos(&cfg, v[3], v[4])] {
        if let Ok(c) = r {
            assert!(
                sane(c.kc_free) && sane(c.kc_proximal) && sane(c.kc_tip),
                "{c:?}"
            );
            assert!(
                c.k2.is_none_or(|k| sane(k) && k > R::zero() && k <= m.l2()),
                "{c:?}"
            );
        }
    }
    for r in [
        m.free_from_torque(v[2]),
        m.free_from_theta_a(v[1]),
        t.free_from_theta_a(v[1]).map(|c| c.0),
    ] {
        if let Ok(c) = r {
            assert!(
                [c.theta1, c.theta2, c.theta_a, c.ta, c.x2, c.dx2]
                    .iter()
                    .all(|&x| sane(x)),
                "{c:?}"
            );
        }
    }
    for r in [
        m.estimate_two_point(v[5], v[2], v[6], v[7]),
        t.estimate_two_point(v[5], v[2], v[6], v[7]),
    ] {
        if let Ok(e) = r {
            assert!(sane(e.kc_hat) && sane(e.dta) && sane(e.dtheta_a), "{e:?}");
            assert!(
                e.contact.k2.is_none_or(|k| sane(k) && k > R::zero()),
                "{e:?}"
            );
        }
    }
}

struct All {
    f64_: (Model<f64>, FreeTable<f64>),
    f32_: (Model<f32>, FreeTable<f32>),
    x32: (Model<Fx32>, FreeTable<Fx32>),
    x24: (Model<Fx24>, FreeTable<Fx24>),
    x16: (Model<Fx16>, FreeTable<Fx16>),
}

fn all() -> &'static All {
    static ALL: OnceLock<All> = OnceLock::new();
    ALL.get_or_init(|| {
        let f = Finger::PAPER;
        fn both<R: TableReal>(f: &Finger) -> (Model<R>, FreeTable<R>) {
            (Model::new(f).unwrap(), FreeTable::new(f).unwrap())
        }
        All {
            f64_: both(&f),
            f32_: both(&f),
            x32: both(&f),
            x24: both(&f),
            x16: both(&f),
        }
    })
}

fuzz_target!(|data: &[u8]| {
    let mut w = [0u64; 8];
    for (i, c) in data.chunks(8).take(8).enumerate() {
        let mut b = [0u8; 8];
        b[..c.len()].copy_from_slice(c);
        w[i] = u64::from_le_bytes(b);
    }
    let mode = data.get(64).copied().unwrap_or(0);
    let a = all();
    // As f64 (values near the working range when mode is odd: scale the mantissa down).
    let f = w.map(|x| {
        let v = f64::from_bits(x);
        if mode & 1 == 1 {
            (x as i64 as f64) / 9.2e18 * 4.0
        } else {
            v
        }
    });
    exercise(&a.f64_.0, &a.f64_.1, &f);
    exercise(&a.f32_.0, &a.f32_.1, &f.map(|x| x as f32));
    if mode & 2 == 0 {
        exercise(&a.x32.0, &a.x32.1, &f.map(Fx32::from_f64));
        exercise(&a.x24.0, &a.x24.1, &f.map(Fx24::from_f64));
        exercise(&a.x16.0, &a.x16.1, &f.map(Fx16::from_f64));
    } else {
        exercise(&a.x32.0, &a.x32.1, &w.map(|x| Fx32::from_bits(x as i64)));
        exercise(&a.x24.0, &a.x24.1, &w.map(|x| Fx24::from_bits(x as i32)));
        exercise(
            &a.x16.0,
            &a.x16.1,
            &w.map(|x| Fx16::from_bits((x >> 32) as i32)),
        );
    }
    // A finger from the bytes too (Model::new must refuse or work).
    let g = Finger {
        l1: f[0],
        l2: f[1],
        a: f[2],
        b: f[3],
        c: f[4],
        phi2: f[5],
        theta01: f[6],
        k1: f[7],
        ..Finger::PAPER
    };
    if let Ok(m) = Model::<Fx32>::new(&g) {
        let _ = m.estimate_two_point(
            Fx32::from_f64(f[5]),
            Fx32::from_f64(f[2]),
            Fx32::from_f64(f[6]),
            Fx32::from_f64(f[7]),
        );
    }
    let _ = FreeTable::<Fx32>::new(&g);
});
