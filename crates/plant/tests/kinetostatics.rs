//! The solved paths against independent references: MODEL.md numbers, the corrected paper
//! closure with finite-difference Jacobians (tests/common), and energy conservation.

mod common;
use common::*;
use plant::kin::Phalanx;
use plant::{quasi_static_path, quasi_static_path_with, ContactSpec, FingerGeom, PlantError};

fn spec(t1: f64, ph: Phalanx, k: f64, r: f64) -> ContactSpec {
    ContactSpec {
        theta1_c_rad: t1,
        phalanx: ph,
        k_c_m: k,
        radius_m: r,
    }
}

fn rel(a: f64, b: f64) -> f64 {
    ((a - b) / b).abs()
}

/// K_c at contact (f = 0) from a tiny step: MODEL.md 6.7249 (k2 = 0.02927), proximal 2.6179,
/// tip 30.2825, all at θ1,c = 1.2797.
#[test]
fn stiffness_at_contact_matches_model_md() {
    let f = FingerGeom::PAPER;
    let dta = 1e-7;
    let kc = |s: ContactSpec| dta / quasi_static_path(&f, &s, dta).unwrap().dtheta_a_rad;
    let t1 = 1.2797;
    let mid = kc(spec(t1, Phalanx::Distal, 0.02927, 0.0));
    let mid_cyl = kc(spec(t1, Phalanx::Distal, 0.02927, 0.05));
    let prox = kc(spec(t1, Phalanx::Proximal, 0.05, 0.0));
    let tip = kc(spec(t1, Phalanx::Distal, 0.075 - 1e-6, 0.0));
    println!("K_c at contact: k2=2.927cm vertex {mid:.5}, R=5cm {mid_cyl:.5}, proximal {prox:.5}, tip {tip:.5}");
    assert!(rel(mid, 6.7249) < 2e-4, "K_c = {mid}");
    // At f = 0 the curvature does not matter (Γ = J for a vertex and a cylinder).
    assert!(rel(mid_cyl, 6.7249) < 2e-4, "K_c cylinder = {mid_cyl}");
    assert!(rel(prox, 2.6179) < 2e-4, "K_c proximal = {prox}");
    assert!(rel(tip, 30.2825) < 2e-4, "K_c tip = {tip}");
}

/// At every sample of the path: the contact constraint (distance from the object's centre to
/// the phalanx line = R, projection inside the phalanx), f ≥ 0, and the virtual-work balance
/// T_a x = K(θ − θ0) + Jᵀ f with x2 and J from independent finite differences.
fn check_path(s: ContactSpec, dta: f64) -> usize {
    let f = FingerGeom::PAPER;
    let ph = s.phalanx.index();
    let obj = plant::path::place_object(&f, &s).unwrap().0;
    let mut n = 0usize;
    let mut work = 0.0;
    let mut prev: Option<(f64, f64)> = None;
    let mut first_energy = None;
    let mut last = (0.0, 0.0);
    let r = quasi_static_path_with(&f, &s, dta, &mut |smp| {
        let p = smp.pose;
        let (t1, t2) = (p.theta1_rad, p.theta2_rad);
        // θa consistent with the independent closure.
        assert!(
            (theta_a(t1, t2) - p.theta_a_rad).abs() < 1e-10,
            "closure {p:?}"
        );
        let (h, k) = line_dist(ph, t1, t2, obj.x_m, obj.y_m);
        assert!(
            (h - s.radius_m).abs() < 1e-10,
            "contact constraint: h − R = {}",
            h - s.radius_m
        );
        assert!((k - p.k_m).abs() < 1e-10, "k {k} vs {}", p.k_m);
        let len = if ph == 1 { L1 } else { L2 };
        assert!((0.0..=len).contains(&k));
        assert!(p.lambda >= -1e-9, "f = {}", p.lambda);
        let j = jac(ph, t1, t2, k);
        let e1 = p.torque_nm - K1 * (t1 - TH01) - p.lambda * j[0];
        let e2 = p.torque_nm * x2(t2) - K2 * t2 - p.lambda * j[1];
        assert!(
            e1.abs() < 1e-7 && e2.abs() < 1e-7,
            "balance residuals {e1} {e2} at {p:?}"
        );
        if let Some((ta0, tq0)) = prev {
            work += 0.5 * (tq0 + p.torque_nm) * (p.theta_a_rad - ta0);
        }
        prev = Some((p.theta_a_rad, p.torque_nm));
        first_energy.get_or_insert(energy(t1, t2));
        last = (t1, t2);
        n += 1;
    })
    .unwrap();
    // Frictionless, fixed object: the actuator's work all goes into the springs
    // (trapezoid rule over ≤ 2 mrad steps).
    let de = energy(last.0, last.1) - first_energy.unwrap();
    assert!(
        (work - de).abs() < 2e-4 * de.abs().max(1e-3),
        "work {work} vs ΔV {de}"
    );
    assert!(r.force_n > 0.0);
    n
}

#[test]
fn table2_path_satisfies_balance_and_constraint_everywhere() {
    let n = check_path(spec(1.2797, Phalanx::Distal, 0.02927, 0.05), 0.8);
    assert!(n > 30);
}

#[test]
fn vertex_and_cylinder_paths_satisfy_balance() {
    for (k, r) in [
        (0.0075, 0.0),
        (0.0375, 0.0),
        (0.015, 0.01),
        (0.03, 0.03),
        (0.06, 0.0),
    ] {
        check_path(spec(1.2797, Phalanx::Distal, k, r), 0.6);
        check_path(spec(1.0, Phalanx::Distal, k, r), 0.6);
    }
}

#[test]
fn proximal_path_satisfies_balance() {
    check_path(spec(1.0, Phalanx::Proximal, 0.05, 0.0), 1.0);
    check_path(spec(1.2797, Phalanx::Proximal, 0.03, 0.02), 1.0);
}

#[test]
fn path_errors_are_typed() {
    let f = FingerGeom::PAPER;
    // A vertex near the tip slides past it.
    assert_eq!(
        quasi_static_path(&f, &spec(1.2797, Phalanx::Distal, 0.074, 0.0), 0.8),
        Err(PlantError::BeyondTip)
    );
    // A large cylinder touching near O2 already cuts the proximal phalanx (MODEL.md trap).
    assert_eq!(
        quasi_static_path(&f, &spec(1.2797, Phalanx::Distal, 0.005, 0.0975), 0.8),
        Err(PlantError::SecondContact)
    );
    // A large cylinder on the proximal phalanx: the distal phalanx wraps onto it.
    assert_eq!(
        quasi_static_path(&f, &spec(1.0, Phalanx::Proximal, 0.08, 0.05), 1.5),
        Err(PlantError::SecondContact)
    );
    // Lowering the torque from a zero-force contact leaves the object at once.
    assert_eq!(
        quasi_static_path(&f, &spec(1.2797, Phalanx::Distal, 0.03, 0.05), -0.1),
        Err(PlantError::LossOfContact)
    );
    // Bad input.
    assert!(quasi_static_path(&f, &spec(f64::NAN, Phalanx::Distal, 0.03, 0.05), 0.1).is_err());
    assert!(quasi_static_path(&f, &spec(1.2, Phalanx::Distal, 0.2, 0.05), 0.1).is_err());
    assert!(quasi_static_path(&f, &spec(1.2, Phalanx::Distal, 0.03, -1.0), 0.1).is_err());
    assert!(quasi_static_path(&f, &spec(1.2, Phalanx::Distal, 0.03, 0.0), f64::INFINITY).is_err());
}

/// MODEL.md: the paper's two-point estimate error grows with the radius; here only the path
/// part: a larger cylinder slides farther for the same step (dk2 = R(dθ1 + dθ2) − l1 sin θ2 dθ1).
#[test]
fn larger_cylinders_slide_farther() {
    let f = FingerGeom::PAPER;
    let k = |r: f64| {
        quasi_static_path(&f, &spec(1.2797, Phalanx::Distal, 0.02927, r), 0.8)
            .unwrap()
            .k_m
    };
    assert!(k(0.0) < k(0.01) && k(0.01) < k(0.05) && k(0.05) < k(0.0975));
}

/// The time-stepped plant (ideal drive, slow current ramp) against MODEL.md: where its true
/// T_a reaches T_a,c + 0.8 N·m, θa − θa,c = 0.08028 rad; and at every contact step the truth
/// satisfies the independent balance and contact constraint.
#[test]
fn time_stepped_plant_follows_the_table2_path() {
    use plant::drive::Input;
    let s = plant::Scene {
        start_theta_a_rad: Some(-0.26),
        ..plant::scenes::table2().ideal()
    };
    let obj = s.resolve_object().unwrap().unwrap();
    let mut p = plant::Plant::new(&s).unwrap();
    let target = 0.340_821 + 0.8;
    let mut prev = p.truth();
    let mut hit = None;
    let mut checked = 0;
    for k in 0..200_000 {
        // Ramp the current slowly (quasi-static): 0.025 A → 0.1 A over 15 s.
        let i = 0.025 + 0.075 * (k as f64 / 150_000.0).min(1.0);
        p.step_input(Input::Current(i));
        let t = p.truth();
        if t.contact == plant::ContactState::Distal {
            let (h, kk) = line_dist(2, t.theta1_rad, t.theta2_rad, obj.x_m, obj.y_m);
            assert!((h - 0.05).abs() < 1e-9);
            let j = jac(2, t.theta1_rad, t.theta2_rad, kk);
            let e1 = t.torque_a_nm - K1 * (t.theta1_rad - TH01) - t.force * j[0];
            let e2 = t.torque_a_nm * x2(t.theta2_rad) - K2 * t.theta2_rad - t.force * j[1];
            assert!(e1.abs() < 1e-7 && e2.abs() < 1e-7, "{e1} {e2}");
            checked += 1;
        }
        if prev.torque_a_nm < target && t.torque_a_nm >= target {
            let f = (target - prev.torque_a_nm) / (t.torque_a_nm - prev.torque_a_nm);
            hit = Some(prev.theta_a_rad + f * (t.theta_a_rad - prev.theta_a_rad));
            break;
        }
        prev = t;
    }
    let th = hit.expect("torque never reached T_a,c + 0.8");
    assert!(checked > 1000);
    let dth = th - -0.223_771_185;
    println!("time-stepped plant: Δθa = {dth:.7} at T_a,c + 0.8 ({checked} contact steps checked)");
    assert!(rel(dth, 0.080_281_4) < 1e-4, "Δθa = {dth}");
}
