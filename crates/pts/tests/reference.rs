//! The f64 model against MODEL.md's reference numbers and the paper's Table 2.
use pts::{Finger, Model, Phalanx};

fn m() -> Model<f64> {
    Model::new(&Finger::PAPER).expect("paper finger is valid")
}

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * b.abs().max(1e-300)
}

#[test]
fn rest_configuration() {
    let m = m();
    let cl = m.closure(0.0).unwrap();
    assert!((cl.gamma - 0.0649626).abs() < 1e-7, "gamma {}", cl.gamma);
    assert!((cl.x2 - 0.6315740).abs() < 1e-7, "x2 {}", cl.x2);
    assert!((cl.dx2 - 0.0328355).abs() < 1e-7, "dx2 {}", cl.dx2);
    let ta = m.theta_a(core::f64::consts::FRAC_PI_4, 0.0).unwrap();
    assert!((ta - -0.8503608).abs() < 1e-7, "theta_a {ta}");
    let kf = m.kc_free(0.0, 0.0).unwrap();
    assert!((kf - 0.54390).abs() < 1e-5, "kc_free {kf}");
    // Rest from both free-motion solves.
    let c = m.free_from_torque(0.0).unwrap();
    assert!(c.theta2.abs() < 1e-12 && (c.theta1 - core::f64::consts::FRAC_PI_4).abs() < 1e-12);
    let c = m.free_from_theta_a(ta).unwrap();
    assert!(c.theta2.abs() < 1e-9 && c.ta.abs() < 1e-9);
}

#[test]
fn table2_contact_and_estimate() {
    let m = m();
    let ta_c = 0.6895 * (1.2797 - core::f64::consts::FRAC_PI_4);
    let cfg = m.free_from_torque(ta_c).unwrap();
    assert!(
        (cfg.theta2 - 0.209196).abs() < 1e-6,
        "theta2 {}",
        cfg.theta2
    );
    assert!(
        (cfg.theta_a - -0.223771).abs() < 1e-6,
        "theta_a {}",
        cfg.theta_a
    );
    let kc = m.kc_distal(cfg.theta2, ta_c, 0.02927).unwrap();
    assert!((kc - 6.7249).abs() < 5e-5, "kc {kc}");
    let k_prox = m.kc_proximal(cfg.theta2, ta_c).unwrap();
    let k_tip = m.kc_distal(cfg.theta2, ta_c, 0.075).unwrap();
    assert!((k_prox - 2.6179).abs() < 5e-5 && (k_tip - 30.2825).abs() < 5e-5);
    // Two-point estimate with the quasi-static Δθa of the table.
    let est = m
        .estimate_two_point(cfg.theta_a, ta_c, cfg.theta_a + 0.0802814, ta_c + 0.8)
        .unwrap();
    assert!((est.kc_hat - 9.9650).abs() < 5e-4, "kc_hat {}", est.kc_hat);
    assert_eq!(est.contact.phalanx, Phalanx::Distal);
    let k2 = est.contact.k2.unwrap();
    assert!(close(k2, 0.041529, 2e-5), "k2 {k2}");
}

#[test]
fn inversion_round_trip_along_phalanx() {
    let m = m();
    let cfg = m.free_from_torque(0.3).unwrap();
    for i in 1..=100 {
        let k2 = 0.075 * i as f64 / 100.0;
        let kc = m.kc_distal(cfg.theta2, cfg.ta, k2).unwrap();
        let c = m.invert(&cfg, kc).unwrap();
        assert_eq!(c.phalanx, Phalanx::Distal);
        assert!((c.k2.unwrap() - k2).abs() < 1e-12, "{k2} -> {:?}", c.k2);
    }
}

#[test]
fn leaving_g_out_is_detectably_different() {
    // MODEL.md trap: without the G term K_c is 1.3 % lower; our model includes G.
    let m = m();
    let ta_c = 0.6895 * (1.2797 - core::f64::consts::FRAC_PI_4);
    let cfg = m.free_from_torque(ta_c).unwrap();
    let with_g = m.kc_distal(cfg.theta2, ta_c, 0.02927).unwrap();
    let without_g = m.kc_distal(cfg.theta2, 0.0, 0.02927).unwrap();
    assert!((with_g / without_g - 1.0).abs() > 0.01);
}

/// A soft distal spring (K2 × 0.31, θ02 + 4.4°, links a few % off): near the top of the
/// free motion the solve from θa passes the θ2 where the linkage angle γ (an atan2) jumps by
/// 2π. The solve from θa must still land where the solve from T_a (which needs no θ1 from
/// γ) puts the finger, up to the torque where θa itself wraps.
#[test]
fn free_motion_from_theta_a_across_the_atan2_cut() {
    let p = Finger::PAPER;
    let f = Finger {
        k1: p.k1 * 1.0435,
        k2: p.k2 * 0.3099,
        theta01: p.theta01 - 1.254f64.to_radians(),
        theta02: p.theta02 + 4.370f64.to_radians(),
        l1: p.l1 * 1.0387,
        l2: p.l2 * 1.1926,
        b: p.b * 0.9866,
        c: p.c * 1.0378,
        ..p
    };
    let m = Model::<f64>::new(&f).unwrap();
    for i in 0..=60 {
        let ta = 1.0 + 0.01 * f64::from(i);
        let want = m.free_from_torque(ta).unwrap();
        if want.theta_a > core::f64::consts::PI {
            // θa wrapped: past the model's branch (FreeTable's top stops below it).
            assert!(ta > 1.5, "θa wrapped already at {ta} N·m");
            break;
        }
        let got = m
            .free_from_theta_a(want.theta_a)
            .unwrap_or_else(|e| panic!("T_a {ta} N·m, θa {}: {e:?}", want.theta_a));
        assert!(
            (got.theta2 - want.theta2).abs() < 1e-9 && (got.ta - ta).abs() < 1e-9,
            "T_a {ta} N·m: θ2 {} vs {}, T_a {}",
            got.theta2,
            want.theta2,
            got.ta
        );
    }
}
