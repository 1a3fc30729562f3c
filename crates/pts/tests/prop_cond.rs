//! Conditioning of the distal inversion and where the solver refuses.
//!
//! The reference for the condition number κ = (K_c/l2)/(dK_c/dk2) is a central finite
//! difference of the closed form `kc_distal` along the phalanx, not the division-free
//! expression inside `invert`.
use pts::model::{MAX_CONDITION, MAX_K2_NOISE, THETA_A_NOISE_RAD};
use pts::{Finger, Model, Phalanx, PtsError};

use proptest::prelude::*;

/// κ by central differences of K_c(k2) (f64), with dk2/dK̂c (m per N·m/rad).
fn kappa_fd(m: &Model<f64>, theta2: f64, ta: f64, k2: f64) -> Option<(f64, f64)> {
    let l2 = m.l2();
    let h = 1e-7 * l2;
    let (lo, hi) = ((k2 - h).max(1e-9), (k2 + h).min(l2));
    let kc = m.kc_distal(theta2, ta, k2).ok()?;
    let d = (m.kc_distal(theta2, ta, hi).ok()? - m.kc_distal(theta2, ta, lo).ok()?) / (hi - lo);
    Some((kc / d / l2, 1.0 / d))
}

/// The table in the report: dk2/dK̂c and κ along the phalanx for free-motion contact
/// configurations up to and past the monotone limit (θ2 = 0.868 rad).
#[test]
fn condition_along_phalanx() {
    let m = Model::<f64>::paper().unwrap();
    let l2 = m.l2();
    let mut worst: f64 = 0.0;
    println!("ta_c  theta2  | kappa at k2/l2 = 0.01 0.25 0.5 0.75 1.0 | dk2/dKc (mm per N·m/rad)");
    for ta in [0.0, 0.3, 0.6, 0.9, 1.2, 1.5, 1.55] {
        let cfg = m.free_from_torque(ta).unwrap();
        let mono = m.check_monotone(&cfg).is_ok();
        let mut ks = String::new();
        let mut ds = String::new();
        for f in [0.01, 0.25, 0.5, 0.75, 1.0] {
            let (k, d) = kappa_fd(&m, cfg.theta2, ta, f * l2).unwrap();
            ks += &format!(" {k:.3}");
            ds += &format!(" {:.2}", d * 1e3);
            if mono {
                worst = worst.max(k);
            }
        }
        println!(
            "{ta:4.2} {:7.4} {} |{ks} |{ds}",
            cfg.theta2,
            if mono { "mono" } else { "NOT " }
        );
    }
    // MODEL.md: a 10 % error in K_c moves k2 by about 4 % of l2.
    assert!(
        (0.3..0.45).contains(&worst),
        "max kappa over the monotone range {worst}"
    );
}

/// A finger whose distal phalanx is short against l1·cos θ2: K_c hardly changes along it,
/// κ(k2 → 0) = l1 cos θ2 x2 / (2 l2) ≈ 3 > MAX_CONDITION: every distal inversion is refused.
#[test]
fn short_distal_phalanx_is_refused() {
    let f = Finger {
        l2: 0.01,
        ..Finger::PAPER
    };
    let m = Model::<f64>::new(&f).unwrap();
    let cfg = m.free_from_torque(0.3).unwrap();
    let mut refused = 0;
    for i in 1..=20 {
        let k2 = 0.01 * i as f64 / 20.0;
        let (k, _) = kappa_fd(&m, cfg.theta2, 0.3, k2).unwrap();
        assert!(k > MAX_CONDITION, "kappa {k}");
        let kc = m.kc_distal(cfg.theta2, 0.3, k2).unwrap();
        if m.invert(&cfg, kc) == Err(PtsError::IllConditioned) {
            refused += 1;
        }
    }
    assert_eq!(refused, 20);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// The refusal boundary of `invert` sits where the finite-difference κ crosses
    /// MAX_CONDITION (fingers with l2 from 5 mm to 100 mm, any monotone configuration).
    #[test]
    fn refusal_matches_fd_condition(l2 in 0.005f64..0.1, ta in 0.0f64..1.5, k2f in 0.01f64..1.0) {
        let f = Finger { l2, ..Finger::PAPER };
        let m = Model::<f64>::new(&f).unwrap();
        let cfg = m.free_from_torque(ta).unwrap();
        prop_assume!(m.check_monotone(&cfg).is_ok());
        let k2 = k2f * l2;
        let (k, _) = kappa_fd(&m, cfg.theta2, ta, k2).unwrap();
        let kc = m.kc_distal(cfg.theta2, ta, k2).unwrap();
        prop_assume!(kc <= pts::model::MAX_STIFFNESS);
        let r = m.invert(&cfg, kc);
        if k > MAX_CONDITION * 1.001 {
            prop_assert_eq!(r, Err(PtsError::IllConditioned));
        } else if k < MAX_CONDITION * 0.999 {
            let c = r.unwrap();
            prop_assert_eq!(c.phalanx, Phalanx::Distal);
            prop_assert!((c.k2.unwrap() - k2).abs() < 1e-9);
        }
    }

    /// The noise refusal of the two-point estimate sits where κ·δθa/Δθa crosses
    /// MAX_K2_NOISE, with κ from finite differences and Δθa = ΔT_a/K_c.
    #[test]
    fn noise_refusal_matches_fd(ta_c in 0.0f64..1.4, k2f in 0.02f64..1.0, dta in 1e-4f64..0.05) {
        let m = Model::<f64>::paper().unwrap();
        let cfg = m.free_from_torque(ta_c).unwrap();
        let k2 = k2f * m.l2();
        let (k, _) = kappa_fd(&m, cfg.theta2, ta_c, k2).unwrap();
        let kc = m.kc_distal(cfg.theta2, ta_c, k2).unwrap();
        let dth = dta / kc;
        prop_assume!(dth > 1e-6 && kc < pts::model::MAX_STIFFNESS);
        let r = m.estimate_two_point(cfg.theta_a, ta_c, cfg.theta_a + dth, ta_c + dta);
        let noise = k * THETA_A_NOISE_RAD / dth;
        if noise > MAX_K2_NOISE * 1.01 {
            prop_assert_eq!(r.map(|e| e.contact.phalanx), Err(PtsError::IllConditioned));
        } else if noise < MAX_K2_NOISE * 0.99 {
            let e = r.unwrap();
            prop_assert!((e.contact.k2.unwrap() - k2).abs() < 1e-6 * m.l2());
        }
    }
}

/// How the k2 error grows with noise on θa: the spread of k̂2 under a θa error of ±δ at the
/// end of the step is κ·δ/Δθa·l2 to first order (checked against the finite-difference κ).
#[test]
fn k2_error_grows_as_kappa_over_dtheta() {
    let m = Model::<f64>::paper().unwrap();
    let l2 = m.l2();
    println!("ta_c k2/l2 dTa | dtheta_a  kappa | dk2/l2 per 1e-4 rad: measured  kappa*1e-4/dth");
    for (ta_c, k2f, dta) in [
        (0.34, 0.39, 0.8),
        (0.34, 0.39, 0.05),
        (0.34, 0.9, 0.05),
        (1.2, 0.5, 0.05),
        (1.4, 0.95, 0.2),
    ] {
        let cfg = m.free_from_torque(ta_c).unwrap();
        let k2 = k2f * l2;
        let kc = m.kc_distal(cfg.theta2, ta_c, k2).unwrap();
        let dth = dta / kc;
        let (kappa, _) = kappa_fd(&m, cfg.theta2, ta_c, k2).unwrap();
        let d = 1e-4;
        let est = |e: f64| {
            m.estimate_two_point(cfg.theta_a, ta_c, cfg.theta_a + dth + e, ta_c + dta)
                .map(|x| x.contact.k2.unwrap_or(f64::NAN))
        };
        let (Ok(a), Ok(b)) = (est(-d), est(d)) else {
            println!("{ta_c:4} {k2f:4} {dta:4} | refused");
            continue;
        };
        let measured = (a - b).abs() / 2.0 / l2;
        let predicted = kappa * d / dth;
        println!("{ta_c:4} {k2f:4} {dta:4} | {dth:.5} {kappa:.3} | {measured:.5} {predicted:.5}");
        assert!(
            (measured - predicted).abs() < 0.2 * predicted,
            "{measured} vs {predicted}"
        );
    }
}
