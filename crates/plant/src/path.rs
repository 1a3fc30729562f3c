//! The frictionless quasi-static path after a contact: raise T_a by ΔT_a and follow the finger.

use crate::geom::FingerGeom;
use crate::kin::{Active, Constraint, Kin, Object, Phalanx, Pose};
use crate::track::{EventKind, Tracker};
use crate::PlantError;

/// Where the contact happens on the free-motion trajectory, and the object there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactSpec {
    /// θ1 at the instant of contact (rad); the finger is in free motion up to it.
    pub theta1_c_rad: f64,
    /// Phalanx touched.
    pub phalanx: Phalanx,
    /// Contact location from the phalanx's lower joint (m).
    pub k_c_m: f64,
    /// Object radius (m); 0 for a vertex.
    pub radius_m: f64,
}

/// Places the object so that it touches the phalanx at `spec` (tangent, on its left normal),
/// returning the object and the free pose at contact.
pub fn place_object(finger: &FingerGeom, spec: &ContactSpec) -> Result<(Object, Pose), PlantError> {
    let len = match spec.phalanx {
        Phalanx::Proximal => finger.l1_m,
        Phalanx::Distal => finger.l2_m,
    };
    if !(spec.k_c_m.is_finite() && spec.k_c_m > 0.0 && spec.k_c_m <= len) {
        return Err(PlantError::Invalid("object.k_m"));
    }
    if !(spec.radius_m.is_finite() && (0.0..=1.0).contains(&spec.radius_m)) {
        return Err(PlantError::Invalid("object.radius_m"));
    }
    if !(spec.theta1_c_rad.is_finite() && spec.theta1_c_rad.abs() <= 2.0 * core::f64::consts::PI) {
        return Err(PlantError::Invalid("object.theta1_c_rad"));
    }
    let free = Kin::new(*finger, None);
    let t2 = free.free_theta2_at_theta1(spec.theta1_c_rad)?;
    let ta = free.theta_a(spec.theta1_c_rad, t2)?;
    let p = free.point_on(spec.phalanx, spec.theta1_c_rad, t2, spec.k_c_m);
    let angle = match spec.phalanx {
        Phalanx::Proximal => spec.theta1_c_rad,
        Phalanx::Distal => spec.theta1_c_rad + t2,
    };
    let n = crate::geom::V2::unit_at(angle).perp();
    let obj = Object {
        x_m: p.x + spec.radius_m * n.x,
        y_m: p.y + spec.radius_m * n.y,
        radius_m: spec.radius_m,
    };
    let pose = free.solve(ta, Active::None, t2)?;
    Ok((obj, pose))
}

/// Result of [`quasi_static_path`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathResult {
    /// θa at contact (rad).
    pub theta_a_c_rad: f64,
    /// T_a at contact (N·m) = K1(θ1,c − θ01).
    pub ta_c_nm: f64,
    /// θa after the torque step (rad).
    pub theta_a_rad: f64,
    /// T_a after the step (N·m) = T_a,c + ΔT_a.
    pub ta_nm: f64,
    /// Contact location after the step (m).
    pub k_m: f64,
    /// Δθa = θa − θa,c (rad).
    pub dtheta_a_rad: f64,
    /// θ1 after the step (rad).
    pub theta1_rad: f64,
    /// θ2 after the step (rad).
    pub theta2_rad: f64,
    /// Contact force after the step (N).
    pub force_n: f64,
    /// The object that was placed (world frame).
    pub object: Object,
}

/// One point of the path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathSample {
    /// The solved pose (θa, θ1, θ2, T_a, x2, contact force λ in N, k).
    pub pose: Pose,
}

/// θa increment of the march along the path (rad); events inside a step are bisected.
pub const PATH_STEP_RAD: f64 = 2e-3;
/// Tolerance on the final torque (N·m).
pub const PATH_TORQUE_TOL_NM: f64 = 1e-12;

/// Frictionless quasi-static path: the object is placed tangent at `spec`, then T_a is raised
/// (or lowered) by `dta_nm` (N·m). Fails with a typed error on a second contact, the contact
/// passing the tip or behind the joint, loss of contact, a joint stop or a jam (fold of the
/// contact path) before the target torque.
pub fn quasi_static_path(
    finger: &FingerGeom,
    spec: &ContactSpec,
    dta_nm: f64,
) -> Result<PathResult, PlantError> {
    quasi_static_path_with(finger, spec, dta_nm, &mut |_| {})
}

/// [`quasi_static_path`], calling `on_sample` at every march step (no allocation).
pub fn quasi_static_path_with(
    finger: &FingerGeom,
    spec: &ContactSpec,
    dta_nm: f64,
    on_sample: &mut dyn FnMut(&PathSample),
) -> Result<PathResult, PlantError> {
    finger.validate()?;
    if !(dta_nm.is_finite() && dta_nm.abs() <= 100.0) {
        return Err(PlantError::Invalid("dta"));
    }
    let (object, free) = place_object(finger, spec)?;
    let kin = Kin::new(*finger, Some(object));
    let c = Constraint::Contact(spec.phalanx);
    let mut start = kin.balance(free.theta_a_rad, free.theta2_rad, c)?;
    start.lambda = start.lambda.max(0.0);
    // A large object placed near O2 may already cut the other phalanx at the contact pose
    // (MODEL.md): that is a second contact from the start.
    let other = Constraint::Contact(spec.phalanx.other());
    if let Some(g) = kin.gap(other, start.theta1_rad, start.theta2_rad) {
        if g.gap < -1e-12 {
            return Err(PlantError::SecondContact);
        }
    }
    let ta_c = finger.k1_nm_per_rad * (start.theta1_rad - finger.theta01_rad);
    let target = ta_c + dta_nm;
    let mut tr = Tracker::at(kin, start);
    on_sample(&PathSample { pose: start });
    let dir = if dta_nm >= 0.0 { 1.0 } else { -1.0 };
    let mut prev = start;
    for _ in 0..100_000 {
        if (prev.torque_nm - target) * dir >= 0.0 {
            break;
        }
        let mut first: Option<(EventKind, f64, f64)> = None;
        let next = tr.advance(prev.theta_a_rad + dir * PATH_STEP_RAD, &mut |e| {
            if first.is_none() {
                first = Some((e.kind, e.torque_nm, e.theta_a_rad));
            }
        });
        if let Some((kind, torque_at_event, theta_at_event)) = first {
            if (torque_at_event - target) * dir >= 0.0 {
                // The target torque comes before the event inside this step.
                let at = kin.solve_one(theta_at_event, c, prev.theta2_rad, true);
                let hi = match at {
                    Ok(p) if (p.torque_nm - target) * dir >= 0.0 => p,
                    _ => return Err(PlantError::NoConvergence),
                };
                let fin = refine(&kin, prev, hi, target)?;
                on_sample(&PathSample { pose: fin });
                return Ok(result(start, ta_c, &fin, object));
            }
            return Err(match kind {
                EventKind::SecondContact { .. } => PlantError::SecondContact,
                EventKind::BeyondTip { .. } => PlantError::BeyondTip,
                EventKind::BehindJoint { .. } => PlantError::BehindJoint,
                EventKind::LossOfContact { .. } => PlantError::LossOfContact,
                EventKind::JointLimit { .. } => PlantError::JointLimit,
                EventKind::Jammed { .. } => PlantError::Jammed,
                _ => PlantError::NoConvergence,
            });
        }
        let next = next?;
        if (next.torque_nm - target) * dir >= 0.0 {
            // Refine inside [prev, next] by safeguarded secant (T_a is monotone in θa here).
            let fin = refine(&kin, prev, next, target)?;
            on_sample(&PathSample { pose: fin });
            return Ok(result(start, ta_c, &fin, object));
        }
        on_sample(&PathSample { pose: next });
        prev = next;
    }
    if dta_nm == 0.0 {
        return Ok(result(start, ta_c, &start, object));
    }
    Err(PlantError::NoConvergence)
}

fn result(start: Pose, ta_c: f64, fin: &Pose, object: Object) -> PathResult {
    PathResult {
        theta_a_c_rad: start.theta_a_rad,
        ta_c_nm: ta_c,
        theta_a_rad: fin.theta_a_rad,
        ta_nm: fin.torque_nm,
        k_m: fin.k_m,
        dtheta_a_rad: fin.theta_a_rad - start.theta_a_rad,
        theta1_rad: fin.theta1_rad,
        theta2_rad: fin.theta2_rad,
        force_n: fin.lambda,
        object,
    }
}

fn refine(kin: &Kin, a: Pose, b: Pose, target: f64) -> Result<Pose, PlantError> {
    let (mut lo, mut hi) = (a, b);
    let mut best = b;
    for _ in 0..200 {
        let (fl, fh) = (lo.torque_nm - target, hi.torque_nm - target);
        let mut x = if (fh - fl).abs() > 1e-300 {
            lo.theta_a_rad - fl * (hi.theta_a_rad - lo.theta_a_rad) / (fh - fl)
        } else {
            0.5 * (lo.theta_a_rad + hi.theta_a_rad)
        };
        let (mn, mx) = if lo.theta_a_rad < hi.theta_a_rad {
            (lo.theta_a_rad, hi.theta_a_rad)
        } else {
            (hi.theta_a_rad, lo.theta_a_rad)
        };
        let w = mx - mn;
        if !(x > mn + 0.01 * w && x < mx - 0.01 * w) {
            x = 0.5 * (mn + mx);
        }
        let p = kin.solve(x, lo.active, lo.theta2_rad)?;
        best = p;
        let f = p.torque_nm - target;
        if f.abs() <= PATH_TORQUE_TOL_NM || w < 1e-15 {
            return Ok(p);
        }
        if (f < 0.0) == (fl < 0.0) {
            lo = p;
        } else {
            hi = p;
        }
    }
    Ok(best)
}
