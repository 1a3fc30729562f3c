//! Acceptance numbers from MODEL.md (independent of this crate's code: published reference values).

use plant::kin::{Kin, Phalanx};
use plant::{quasi_static_path, ContactSpec, FingerGeom};

fn rel(a: f64, b: f64) -> f64 {
    ((a - b) / b).abs()
}

#[test]
fn rest_pose_matches_model_md() {
    let kin = Kin::new(FingerGeom::PAPER, None);
    let rest = kin.rest().unwrap();
    assert!((rest.theta_a_rad - (-0.850_360_8)).abs() < 1e-6, "{rest:?}");
    assert!((rest.x2 - 0.631_574_0).abs() < 1e-6, "{rest:?}");
    assert!(rest.torque_nm.abs() < 1e-12);
}

#[test]
fn table2_contact_configuration() {
    let kin = Kin::new(FingerGeom::PAPER, None);
    let t2 = kin.free_theta2_at_theta1(1.2797).unwrap();
    assert!((t2 - 0.209_196).abs() < 1e-6, "θ2,c = {t2}");
    let ta = kin.theta_a(1.2797, t2).unwrap();
    assert!((ta - (-0.223_771)).abs() < 1e-6, "θa,c = {ta}");
}

#[test]
fn table2_path_acceptance() {
    let spec = ContactSpec {
        theta1_c_rad: 1.2797,
        phalanx: Phalanx::Distal,
        k_c_m: 0.02927,
        radius_m: 0.05,
    };
    let r = quasi_static_path(&FingerGeom::PAPER, &spec, 0.8).unwrap();
    assert!(rel(r.ta_c_nm, 0.340_821) < 1e-5, "{r:?}");
    assert!(
        rel(r.dtheta_a_rad, 0.080_281_4) < 1e-5,
        "Δθa = {}",
        r.dtheta_a_rad
    );
    assert!(rel(r.k_m, 0.039_414) < 1e-5, "k2 = {}", r.k_m);
    assert!(rel(0.8 / r.dtheta_a_rad, 9.9650) < 1e-4);
}

#[test]
fn table2_print() {
    let spec = ContactSpec {
        theta1_c_rad: 1.2797,
        phalanx: Phalanx::Distal,
        k_c_m: 0.02927,
        radius_m: 0.05,
    };
    let r = quasi_static_path(&FingerGeom::PAPER, &spec, 0.8).unwrap();
    println!(
        "table2: theta_a_c={:.9} ta_c={:.9} dtheta_a={:.9} k2={:.9} force={:.6}",
        r.theta_a_c_rad, r.ta_c_nm, r.dtheta_a_rad, r.k_m, r.force_n
    );
}
