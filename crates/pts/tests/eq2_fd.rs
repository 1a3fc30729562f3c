//! Eq. 2 (the closed forms in `Model::kc_*`) against finite differences of an independent
//! quasi-static equilibrium solve at the contact instant.
//!
//! The reference here shares no formula with the model: θa comes from intersecting the
//! circle of the input crank with the circle of the coupler (plain geometry in the world
//! frame), the transmission from numeric derivatives of that, and the contact from a
//! Lagrange multiplier on the signed distance between a fixed vertex and the phalanx line.
//! The stiffness is then ΔT/Δθa along the solved path, extrapolated to a zero step.
use pts::{Finger, Model};

const F: Finger = Finger::PAPER;

/// θa by circle intersection: |a·e(θa) − Ob| = b, on the branch through the rest pose.
fn theta_a_geom(t1: f64, t2: f64) -> f64 {
    let o2 = (F.l1 * t1.cos(), F.l1 * t1.sin());
    let crank = t1 + t2 - F.phi2;
    let ob = (o2.0 + F.c * crank.cos(), o2.1 + F.c * crank.sin());
    let r = (ob.0 * ob.0 + ob.1 * ob.1).sqrt();
    let m = (F.a * F.a + r * r - F.b * F.b) / (2.0 * F.a);
    ob.1.atan2(ob.0) - (m / r).acos()
}

/// Signed distance (m) from the vertex p to the phalanx line, positive on the flexion side.
fn gap(p: (f64, f64), t1: f64, t2: f64, distal: bool) -> f64 {
    let (base, ang) = if distal {
        ((F.l1 * t1.cos(), F.l1 * t1.sin()), t1 + t2)
    } else {
        ((0.0, 0.0), t1)
    };
    let n = (-ang.sin(), ang.cos());
    (p.0 - base.0) * n.0 + (p.1 - base.1) * n.1
}

/// Residual of the equilibrium T ∇θa − K(θ − θ0) + f ∇h = 0 and h = 0.
fn residual(q: [f64; 3], t: f64, p: (f64, f64), distal: bool) -> [f64; 3] {
    let [t1, t2, f] = q;
    let e = 1e-6;
    let d1 = (theta_a_geom(t1 + e, t2) - theta_a_geom(t1 - e, t2)) / (2.0 * e);
    let d2 = (theta_a_geom(t1, t2 + e) - theta_a_geom(t1, t2 - e)) / (2.0 * e);
    let h1 = (gap(p, t1 + e, t2, distal) - gap(p, t1 - e, t2, distal)) / (2.0 * e);
    let h2 = (gap(p, t1, t2 + e, distal) - gap(p, t1, t2 - e, distal)) / (2.0 * e);
    [
        t * d1 - F.k1 * (t1 - F.theta01) + f * h1,
        t * d2 - F.k2 * (t2 - F.theta02) + f * h2,
        gap(p, t1, t2, distal),
    ]
}

fn solve(mut q: [f64; 3], t: f64, p: (f64, f64), distal: bool) -> [f64; 3] {
    for _ in 0..60 {
        let r = residual(q, t, p, distal);
        let mut jac = [[0.0; 3]; 3];
        for j in 0..3 {
            let mut qp = q;
            let mut qm = q;
            let h = 1e-6;
            qp[j] += h;
            qm[j] -= h;
            let (rp, rm) = (residual(qp, t, p, distal), residual(qm, t, p, distal));
            for i in 0..3 {
                jac[i][j] = (rp[i] - rm[i]) / (2.0 * h);
            }
        }
        let dx = solve3(jac, r);
        for i in 0..3 {
            q[i] -= dx[i];
        }
        if dx.iter().all(|d| d.abs() < 1e-14) {
            break;
        }
    }
    q
}

fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> [f64; 3] {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(a);
    let mut x = [0.0; 3];
    for (k, xk) in x.iter_mut().enumerate() {
        let mut m = a;
        for i in 0..3 {
            m[i][k] = b[i];
        }
        *xk = det(m) / d;
    }
    x
}

/// Free-motion equilibrium at torque t, solved on the geometric θa (no contact).
fn free(t: f64) -> (f64, f64) {
    let t1 = F.theta01 + t / F.k1;
    let mut t2 = 0.0;
    for _ in 0..60 {
        let e = 1e-6;
        let g = |t2: f64| {
            t * (theta_a_geom(t1, t2 + e) - theta_a_geom(t1, t2 - e)) / (2.0 * e)
                - F.k2 * (t2 - F.theta02)
        };
        let dg = (g(t2 + 1e-5) - g(t2 - 1e-5)) / 2e-5;
        let step = g(t2) / dg;
        t2 -= step;
        if step.abs() < 1e-15 {
            break;
        }
    }
    (t1, t2)
}

/// K_c = dT/dθa at the contact instant for a vertex at k on the given phalanx.
fn kc_reference(tc: f64, k: f64, distal: bool) -> f64 {
    let (t1, t2) = free(tc);
    let p = if distal {
        let o2 = (F.l1 * t1.cos(), F.l1 * t1.sin());
        (o2.0 + k * (t1 + t2).cos(), o2.1 + k * (t1 + t2).sin())
    } else {
        (k * t1.cos(), k * t1.sin())
    };
    let ta_c = theta_a_geom(t1, t2);
    let ratio = |eps: f64| {
        let q = solve([t1, t2, 0.0], tc + eps, p, distal);
        assert!(q[2] > 0.0, "contact force must be compressive");
        eps / (theta_a_geom(q[0], q[1]) - ta_c)
    };
    // Richardson: K(ε) = K_c + cε + O(ε²).
    let e = 2e-4;
    2.0 * ratio(e) - ratio(2.0 * e)
}

#[test]
fn geometric_closure_matches_model_theta_a() {
    let m = Model::<f64>::new(&F).unwrap();
    for i in 0..=40 {
        let t2 = -0.5 + 2.0 * i as f64 / 40.0;
        for t1 in [0.5, 0.8, 1.2, 1.6] {
            let a = m.theta_a(t1, t2).unwrap();
            assert!((a - theta_a_geom(t1, t2)).abs() < 1e-12, "θ1 {t1} θ2 {t2}");
        }
    }
}

#[test]
fn eq2_distal_matches_finite_differences_of_equilibrium() {
    let m = Model::<f64>::new(&F).unwrap();
    for tc in [0.05, 0.340821, 0.7, 1.0] {
        let cfg = m.free_from_torque(tc).unwrap();
        for k in [0.005, 0.02927, 0.045, 0.06, 0.075] {
            let model = m.kc_distal(cfg.theta2, tc, k).unwrap();
            let reference = kc_reference(tc, k, true);
            let rel = (model / reference - 1.0).abs();
            assert!(
                rel < 2e-5,
                "Tc {tc} k2 {k}: model {model} reference {reference} rel {rel:e}"
            );
        }
    }
}

#[test]
fn eq2_proximal_matches_finite_differences_and_is_independent_of_k1() {
    let m = Model::<f64>::new(&F).unwrap();
    for tc in [0.1, 0.5, 0.9] {
        let cfg = m.free_from_torque(tc).unwrap();
        let model = m.kc_proximal(cfg.theta2, tc).unwrap();
        for k1 in [0.02, 0.05, 0.09] {
            let reference = kc_reference(tc, k1, false);
            let rel = (model / reference - 1.0).abs();
            assert!(
                rel < 2e-5,
                "Tc {tc} k1 {k1}: model {model} reference {reference}"
            );
        }
    }
}

#[test]
fn free_motion_stiffness_matches_finite_differences() {
    let m = Model::<f64>::new(&F).unwrap();
    for tc in [0.0, 0.3, 0.8] {
        let cfg = m.free_from_torque(tc).unwrap();
        let e = 1e-4;
        let (a1, a2) = free(tc + e);
        let (b1, b2) = free(tc - e);
        let reference = 2.0 * e / (theta_a_geom(a1, a2) - theta_a_geom(b1, b2));
        let model = m.kc_free(cfg.theta2, tc).unwrap();
        assert!(
            (model / reference - 1.0).abs() < 1e-6,
            "Tc {tc}: {model} vs {reference}"
        );
    }
}
