//! Validation of the engine-based finger before it judges anything: statics in free motion, the
//! Table 2 contact and step, and convergence in time step and contact stiffness.
//!
//! The reference numbers are MODEL.md's (the model document's Table 1/Table 2 reference values),
//! copied here; each tolerance says what limits it.

use dynsim::grasp::{self, GraspSpec, Target};
use dynsim::linkage;
use dynsim::sim::{DriveFriction, EngineSettings, Finger, FingerParams, Object};

// The model document's reference values (rest pose and Table 2 scenario).
const THETA_A_REST_RAD: f64 = -0.8503608;
const TABLE2_THETA1_C_RAD: f64 = 1.2797;
const TABLE2_THETA2_C_RAD: f64 = 0.209196;
const TABLE2_TA_C_NM: f64 = 0.340821;
const TABLE2_THETA_A_C_RAD: f64 = -0.223771;
const TABLE2_RADIUS_M: f64 = 0.05;
const TABLE2_K2_C_M: f64 = 0.02927;
const TABLE2_KC_NM_PER_RAD: f64 = 6.7249;
const TABLE2_DELTA_TA_NM: f64 = 0.8;
const TABLE2_DELTA_THETA_A_RAD: f64 = 0.08028;
const TABLE2_K2_END_M: f64 = 0.039414;

/// A frictionless drive with enough viscous damping to settle quickly: for statics.
fn quiet_finger() -> FingerParams {
    FingerParams {
        drive_inertia_kgm2: 1.0e-3,
        friction: DriveFriction {
            viscous_nm_s_per_rad: 0.02,
            ..DriveFriction::OFF
        },
        contact_mu: 0.0,
        torque_lag_s: 0.0,
    }
}

/// Runs `f` for `seconds` with the torque `torque(t)` (t from the call's start).
fn hold(f: &mut Finger, seconds: f64, torque: impl Fn(f64) -> f64) {
    let dt = EngineSettings::default().dt_s;
    let n = (seconds / dt).round() as usize;
    for i in 0..n {
        f.step(torque(i as f64 * dt));
    }
}

#[test]
fn placement_kinematics_reproduce_the_model_numbers() {
    // The setup code's own geometry (used only to place objects) against the model document.
    let rest = linkage::pose(linkage::THETA01_RAD, 0.0).unwrap();
    assert!(
        (rest.theta_a_rad - THETA_A_REST_RAD).abs() < 1e-7,
        "{}",
        rest.theta_a_rad
    );
    let (p, ta) = linkage::free_motion_pose(TABLE2_THETA1_C_RAD).unwrap();
    assert!(
        (p.theta2_rad - TABLE2_THETA2_C_RAD).abs() < 2e-6,
        "{}",
        p.theta2_rad
    );
    assert!((ta - TABLE2_TA_C_NM).abs() < 2e-6, "{ta}");
    assert!(
        (p.theta_a_rad - TABLE2_THETA_A_C_RAD).abs() < 2e-6,
        "{}",
        p.theta_a_rad
    );
}

#[test]
fn free_motion_statics_match_the_model() {
    // Springs balance a constant crank torque through the linkage: the engine's settled pose at
    // T_a,c must be the model's free-motion pose at θ1,c. Tolerance 2e-5 rad (a twentieth of an
    // encoder count; the reference values carry 6 decimals).
    let mut f = Finger::new(quiet_finger(), Object::None, EngineSettings::default());
    assert!((f.theta_a_rad() - THETA_A_REST_RAD).abs() < 1e-6);
    hold(&mut f, 3.0, |t| TABLE2_TA_C_NM * t.min(1.0));
    let (ta, t1, t2) = (f.theta_a_rad(), f.theta1_rad(), f.theta2_rad());
    println!(
        "settled at T_a,c: theta_a {ta:.7} (model {TABLE2_THETA_A_C_RAD}), theta1 {t1:.7} \
         (model {TABLE2_THETA1_C_RAD}), theta2 {t2:.7} (model {TABLE2_THETA2_C_RAD}), loop gap {:.2e} m",
        f.loop_gap_m()
    );
    assert!((ta - TABLE2_THETA_A_C_RAD).abs() < 2e-5);
    assert!((t1 - TABLE2_THETA1_C_RAD).abs() < 2e-5);
    assert!((t2 - TABLE2_THETA2_C_RAD).abs() < 2e-5);
    // And back to rest when the torque is removed (no drift, no hysteresis without friction).
    hold(&mut f, 2.0, |t| TABLE2_TA_C_NM * (1.0 - t).max(0.0));
    println!("back at rest: theta_a {:.7}", f.theta_a_rad());
    assert!((f.theta_a_rad() - THETA_A_REST_RAD).abs() < 2e-5);
}

/// The Table 2 grasp, quasi-static: approach, contact, then a slow torque rise of `delta_nm`.
/// Returns (θa at contact, T_a at contact, k2 at contact, Δθa, k2 after the rise).
fn table2(delta_nm: f64) -> (f64, f64, f64, f64, f64) {
    let object = grasp::place(Target::Object {
        radius_m: TABLE2_RADIUS_M,
        k_m: TABLE2_K2_C_M,
        distal: true,
        theta1_c_rad: TABLE2_THETA1_C_RAD,
    })
    .unwrap();
    let mut f = Finger::new(quiet_finger(), object, EngineSettings::default());
    // Settle just short of contact, then creep at 0.02 N·m/s so viscous lag stays below 1e-3 N·m.
    let near = TABLE2_TA_C_NM - 0.02;
    hold(&mut f, 1.5, |t| near * (t / 0.8).min(1.0));
    let mut torque = near;
    let dt = EngineSettings::default().dt_s;
    while f.contacts().is_empty() {
        torque += 0.02 * dt;
        f.step(torque);
        assert!(torque < TABLE2_TA_C_NM + 0.02, "no contact");
    }
    let (theta_c, k2_c) = (f.theta_a_rad(), f.contacts()[0].k_m);
    let ta_c = torque;
    hold(&mut f, 0.3, |_| ta_c);
    let theta0 = f.theta_a_rad();
    hold(&mut f, 2.5, |t| ta_c + delta_nm * (t / 1.5).min(1.0));
    let c = f.contacts();
    let k2_end = c.iter().map(|c| c.k_m).sum::<f64>() / c.len() as f64;
    (theta_c, ta_c, k2_c, f.theta_a_rad() - theta0, k2_end)
}

#[test]
fn table2_contact_and_step_match_the_model() {
    let (theta_c, ta_c, k2_c, dtheta, k2_end) = table2(TABLE2_DELTA_TA_NM);
    println!(
        "contact: theta_a {theta_c:.6} (model {TABLE2_THETA_A_C_RAD}), T_a {ta_c:.6} (model \
         {TABLE2_TA_C_NM}), k2 {k2_c:.6} m (model {TABLE2_K2_C_M}); step 0.8: dtheta_a {dtheta:.6} \
         (model {TABLE2_DELTA_THETA_A_RAD}), k2 end {k2_end:.6} (model {TABLE2_K2_END_M})"
    );
    // Contact where it was placed: within 5e-5 rad, 20 µm, and 1e-3 N·m (the viscous lag of the
    // 0.02 N·m/s creep is 8e-4 N·m).
    assert!((theta_c - TABLE2_THETA_A_C_RAD).abs() < 5e-5);
    assert!((ta_c - TABLE2_TA_C_NM).abs() < 1e-3);
    assert!((k2_c - TABLE2_K2_C_M).abs() < 2e-5);
    // The step along the frictionless contact path: Δθa within 0.2 % (the reference has 4 digits),
    // the final location within 50 µm (the contact's µm penetration and the 5-digit reference).
    assert!((dtheta / TABLE2_DELTA_THETA_A_RAD - 1.0).abs() < 0.002);
    assert!((k2_end - TABLE2_K2_END_M).abs() < 5e-5);
}

#[test]
fn table2_stiffness_at_contact_matches_eq2() {
    // A small step reads the stiffness at contact; over 0.01 N·m the secant differs from the
    // tangent by well under 1 % (K grows from 6.72 to 9.97 over 0.8 N·m), so 1 % bounds it.
    let delta = 0.01;
    let (_, _, _, dtheta, _) = table2(delta);
    let kc = delta / dtheta;
    println!("K_c from a 0.01 N·m step: {kc:.4} (model {TABLE2_KC_NM_PER_RAD})");
    assert!((kc / TABLE2_KC_NM_PER_RAD - 1.0).abs() < 0.01);
}

fn dynamic_grasp(engine: EngineSettings) -> grasp::Recording {
    let spec = GraspSpec {
        target: Target::Object {
            radius_m: 0.01,
            k_m: 0.5 * linkage::L2_M,
            distal: true,
            theta1_c_rad: TABLE2_THETA1_C_RAD,
        },
        delta_ta_nm: 0.5,
        rise_s: 0.2,
        detection_delay_s: 0.01,
        hold_s: 0.3,
        ramp_nm_per_s: 0.5,
        finger: FingerParams {
            drive_inertia_kgm2: 5e-4,
            friction: DriveFriction::REALISTIC,
            contact_mu: 0.3,
            torque_lag_s: 5e-4,
        },
        engine,
    };
    grasp::run(&spec).unwrap()
}

fn compare(a: &grasp::Recording, b: &grasp::Recording) -> (f64, f64, f64, f64) {
    let n = a.samples.len().min(b.samples.len());
    let max_dtheta = (0..n)
        .map(|i| (a.samples[i].theta_a_rad - b.samples[i].theta_a_rad).abs())
        .fold(0.0, f64::max);
    let last = |r: &grasp::Recording| r.samples.last().unwrap().theta_a_rad;
    (
        (a.truth.k_c_m.unwrap() - b.truth.k_c_m.unwrap()).abs(),
        (a.truth.k_end_m.unwrap() - b.truth.k_end_m.unwrap()).abs(),
        (last(a) - last(b)).abs(),
        max_dtheta,
    )
}

#[test]
fn converges_in_time_step_and_contact_stiffness() {
    let base = EngineSettings::default();
    let r0 = dynamic_grasp(base);
    let r_dt = dynamic_grasp(EngineSettings {
        dt_s: base.dt_s / 2.0,
        ..base
    });
    let r_k = dynamic_grasp(EngineSettings {
        contact_hz: base.contact_hz * 2.0,
        ..base
    });
    let (dk, dke, dth, dmax) = compare(&r0, &r_dt);
    println!("dt/2: dk2_c {dk:.2e} m, dk2_end {dke:.2e} m, dtheta_end {dth:.2e} rad, max dtheta {dmax:.2e} rad");
    let (sk, ske, sth, smax) = compare(&r0, &r_k);
    println!("stiffer contact: dk2_c {sk:.2e} m, dk2_end {ske:.2e} m, dtheta_end {sth:.2e} rad, max dtheta {smax:.2e} rad");
    println!("max loop gap {:.2e} m", r0.max_loop_gap_m);
    // Halving dt: the trace moves by < 0.5 mrad anywhere (an encoder count is 0.38 mrad), the
    // contact locations by < 10 µm. Doubling the contact's stiffness: the same bounds.
    for (dk, dke, dmax) in [(dk, dke, dmax), (sk, ske, smax)] {
        assert!(dk < 1e-5 && dke < 1e-5 && dmax < 5e-4);
    }
    // The loop stays closed to a micrometre.
    assert!(r0.max_loop_gap_m < 1e-6);
}
