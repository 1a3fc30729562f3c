//! The Table 1 linkage written from its geometry alone: joint positions for a given (θ1, θ2), the
//! input-crank angle by circle intersection, and the free-motion pose found by minimising the
//! potential energy. Used only to set up bodies and place objects, never to drive the dynamics.

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};

/// Proximal phalanx length O1O2, m.
pub const L1_M: f64 = 0.100;
/// Distal phalanx length from O2 to the tip, m.
pub const L2_M: f64 = 0.075;
/// Input crank O1Oc, m.
pub const A_M: f64 = 0.071;
/// Coupler OcOb, m.
pub const B_M: f64 = 0.108;
/// Distal crank O2Ob, m.
pub const C_M: f64 = 0.044;
/// Fixed angle between the distal phalanx and its crank, rad.
pub const PHI2_RAD: f64 = FRAC_PI_2;
/// Spring stiffness at O1, N·m/rad.
pub const K1_NM_PER_RAD: f64 = 0.6895;
/// Spring stiffness at O2, N·m/rad.
pub const K2_NM_PER_RAD: f64 = 1.0274;
/// Rest angle of the O1 spring (absolute angle of the proximal phalanx), rad.
pub const THETA01_RAD: f64 = FRAC_PI_4;
/// Rest angle of the O2 spring (distal relative to proximal), rad.
pub const THETA02_RAD: f64 = 0.0;

/// Joint positions (world frame at O1, m) and the input-crank angle of one configuration.
#[derive(Clone, Copy, Debug)]
pub struct Pose {
    /// Absolute angle of the proximal phalanx O1→O2, rad.
    pub theta1_rad: f64,
    /// Distal phalanx angle relative to the proximal one, rad.
    pub theta2_rad: f64,
    /// Absolute angle of the input crank O1→Oc, rad.
    pub theta_a_rad: f64,
    /// Distal joint O2, m.
    pub o2_m: [f64; 2],
    /// Coupler/distal-crank joint Ob, m.
    pub ob_m: [f64; 2],
    /// Crank/coupler joint Oc, m.
    pub oc_m: [f64; 2],
}

impl Pose {
    /// Unit vector along the distal phalanx (O2 toward the tip).
    pub fn distal_dir(&self) -> [f64; 2] {
        let t = self.theta1_rad + self.theta2_rad;
        [t.cos(), t.sin()]
    }

    /// Unit left normal of the distal phalanx: the side flexion moves toward, where objects sit.
    pub fn distal_normal(&self) -> [f64; 2] {
        let [c, s] = self.distal_dir();
        [-s, c]
    }

    /// World point at distance `k2_m` from O2 along the distal phalanx, m.
    pub fn distal_point(&self, k2_m: f64) -> [f64; 2] {
        let u = self.distal_dir();
        [self.o2_m[0] + k2_m * u[0], self.o2_m[1] + k2_m * u[1]]
    }
}

/// The configuration at (θ1, θ2), or None where the coupler cannot close the loop.
///
/// Oc lies on the circle of radius a about O1 and at distance b from Ob; of the two intersections the
/// assembly is the one on the right of O1→Ob (the crank hangs below the finger at rest).
pub fn pose(theta1_rad: f64, theta2_rad: f64) -> Option<Pose> {
    let o2 = [L1_M * theta1_rad.cos(), L1_M * theta1_rad.sin()];
    let crank_dir = theta1_rad + theta2_rad - PHI2_RAD;
    let ob = [o2[0] + C_M * crank_dir.cos(), o2[1] + C_M * crank_dir.sin()];
    let d = (ob[0] * ob[0] + ob[1] * ob[1]).sqrt();
    if d > A_M + B_M || d < (A_M - B_M).abs() {
        return None;
    }
    // Distance from O1 along O1→Ob to the chord, and the half-chord.
    let along = (A_M * A_M - B_M * B_M + d * d) / (2.0 * d);
    let half = (A_M * A_M - along * along).max(0.0).sqrt();
    let u = [ob[0] / d, ob[1] / d];
    let right = [u[1], -u[0]];
    let oc = [
        along * u[0] + half * right[0],
        along * u[1] + half * right[1],
    ];
    Some(Pose {
        theta1_rad,
        theta2_rad,
        theta_a_rad: oc[1].atan2(oc[0]),
        o2_m: o2,
        ob_m: ob,
        oc_m: oc,
    })
}

/// The free-motion pose at proximal angle θ1: the crank torque that holds it, T_a = K1 (θ1 − θ0,1)
/// (the crank and the proximal phalanx share O1 and turn together when the distal joint is held),
/// and θ2 the minimiser of the spring energy at that crank angle.
///
/// θ2 is found as the stationary point of U(θ2) = ½K1(θ1−θ0,1)² + ½K2(θ2−θ0,2)² − T_a θa(θ1, θ2)
/// along θ1 fixed, i.e. K2 (θ2 − θ0,2) = T_a ∂θa/∂θ2, with the derivative by central differences
/// of the circle-intersection kinematics above. Returns the pose and T_a in N·m.
pub fn free_motion_pose(theta1_rad: f64) -> Option<(Pose, f64)> {
    let torque_nm = K1_NM_PER_RAD * (theta1_rad - THETA01_RAD);
    let residual = |t2: f64| -> Option<f64> {
        let h = 1e-6;
        let dp = pose(theta1_rad, t2 + h)?.theta_a_rad - pose(theta1_rad, t2 - h)?.theta_a_rad;
        Some(K2_NM_PER_RAD * (t2 - THETA02_RAD) - torque_nm * dp / (2.0 * h))
    };
    // Bisection on a bracket inside the working range (x2 > 0 there, so the residual rises).
    let (mut lo, mut hi) = (-0.5_f64, 1.5_f64);
    let (mut rlo, rhi) = (residual(lo)?, residual(hi)?);
    if rlo * rhi > 0.0 {
        return None;
    }
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        let rm = residual(mid)?;
        if rm * rlo > 0.0 {
            lo = mid;
            rlo = rm;
        } else {
            hi = mid;
        }
    }
    Some((pose(theta1_rad, 0.5 * (lo + hi))?, torque_nm))
}
