//! `pts eval` op "path": the plant's frictionless quasi-static path after contact
//! ([`plant::quasi_static_path`]), an independent solver (it does not use the pts model).

use crate::eval::{num, Fail};
use pts::Finger;
use serde_json::{Map, Value};

/// The plant's finger with this geometry and these springs (joint stops and lock stiffness
/// stay the plant's defaults).
pub fn plant_finger(f: &Finger) -> plant::FingerGeom {
    plant::FingerGeom {
        l1_m: f.l1,
        l2_m: f.l2,
        a_m: f.a,
        b_m: f.b,
        c_m: f.c,
        phi2_rad: f.phi2,
        theta01_rad: f.theta01,
        theta02_rad: f.theta02,
        k1_nm_per_rad: f.k1,
        k2_nm_per_rad: f.k2,
        ..plant::FingerGeom::PAPER
    }
}

/// Maps a plant error to the eval error kinds.
pub fn fail(e: plant::PlantError) -> Fail {
    use plant::PlantError as P;
    let (kind, message) = match e {
        P::Invalid("object.k_m") => (
            "contact_outside_phalanx",
            "k_c is outside the phalanx".to_string(),
        ),
        P::Invalid(key) => ("out_of_range", format!("{key} is out of range")),
        P::BadPlacement => (
            "second_contact",
            "the object cannot be placed there without touching the other phalanx".to_string(),
        ),
        P::SecondContact => (
            "second_contact",
            "the object touches the other phalanx before the torque is reached".to_string(),
        ),
        P::BeyondTip => (
            "beyond_tip",
            "the contact point slides past the tip of the phalanx".to_string(),
        ),
        P::BehindJoint => (
            "behind_joint",
            "the contact point slides behind the joint of the phalanx".to_string(),
        ),
        P::LossOfContact => (
            "loss_of_contact",
            "the contact force fell to zero: the finger left the object".to_string(),
        ),
        P::JointLimit => (
            "joint_limit",
            "a joint reached its mechanical stop".to_string(),
        ),
        other => (other.kind(), format!("plant: {other}")),
    };
    Fail {
        kind: kind.into(),
        message,
    }
}

/// Answers a path request: `values` = [theta1_c, k_c, radius, dta], `phalanx` 1 or 2.
pub fn answer(finger: &Finger, phalanx: u8, values: &[f64]) -> Result<Map<String, Value>, Fail> {
    let &[theta1_c, k_c, radius, dta] = values else {
        return Err(Fail::bad(
            "op \"path\" takes theta1_c, phalanx, k_c, radius, dta",
        ));
    };
    if radius < 0.0 {
        return Err(Fail::bad(format!(
            "field \"radius\" = {radius} m must be ≥ 0 (0 is a vertex)"
        )));
    }
    // Same physical checks as the model for the overrides.
    finger.validate()?;
    let spec = plant::ContactSpec {
        theta1_c_rad: theta1_c,
        phalanx: if phalanx == 1 {
            plant::Phalanx::Proximal
        } else {
            plant::Phalanx::Distal
        },
        k_c_m: k_c,
        radius_m: radius,
    };
    let r = plant::quasi_static_path(&plant_finger(finger), &spec, dta).map_err(fail)?;
    let mut out = Map::new();
    for (k, v) in [
        ("theta_a_c", r.theta_a_c_rad),
        ("ta_c", r.ta_c_nm),
        ("theta_a", r.theta_a_rad),
        ("k", r.k_m),
        ("dtheta_a", r.dtheta_a_rad),
    ] {
        if !v.is_finite() {
            return Err(Fail {
                kind: "non_finite".into(),
                message: format!("result \"{k}\" is not finite"),
            });
        }
        out.insert(k.into(), num(v));
    }
    Ok(out)
}
