//! Finger geometry and the four-bar linkage, in Cartesian form.
//!
//! This is the plant's own formulation (it does not use the paper's tan(γ/2) quadratic):
//! with the proximal phalanx along +x (θ1 = 0), the distal crank end is
//! `Ob = (l1 + c cos ψ, c sin ψ)` with `ψ = θ2 − φ2`, and the input crank end `Oc` lies on the
//! circle of radius `a` about O1 at distance `b` from `Ob`. The circle–circle intersection on the
//! physical branch gives `φ(θ2) = θa − θ1 = atan2(Ob) − acos((a² + |Ob|² − b²)/(2a|Ob|))`.
//! `x2 = dφ/dθ2` follows from differentiating `|Oc − Ob|² = b²`.

use crate::PlantError;
use libm::{acos, atan2, sincos, sqrt};

/// Geometry, springs and joint limits of the two-phalanx linkage finger.
///
/// Lengths in m, angles in rad, spring rates in N·m/rad. Angles follow MODEL.md: θ1 absolute,
/// θ2 relative, flexion positive, objects touch the phalanges on their left normal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FingerGeom {
    /// Proximal phalanx length O1O2 (m).
    pub l1_m: f64,
    /// Distal phalanx length (m).
    pub l2_m: f64,
    /// Input crank O1Oc (m).
    pub a_m: f64,
    /// Coupler OcOb (m).
    pub b_m: f64,
    /// Distal crank O2Ob (m).
    pub c_m: f64,
    /// Fixed angle between the distal phalanx and its crank (rad).
    pub phi2_rad: f64,
    /// Spring rest angle at O1, absolute θ1 (rad).
    pub theta01_rad: f64,
    /// Spring rest angle at O2, relative θ2 (rad).
    pub theta02_rad: f64,
    /// Spring rate at O1 (N·m/rad).
    pub k1_nm_per_rad: f64,
    /// Spring rate at O2 (N·m/rad).
    pub k2_nm_per_rad: f64,
    /// Lower mechanical stop of θ1 (rad).
    pub theta1_min_rad: f64,
    /// Upper mechanical stop of θ1 (rad).
    pub theta1_max_rad: f64,
    /// Lower mechanical stop of θ2 (rad).
    pub theta2_min_rad: f64,
    /// Upper mechanical stop of θ2 (rad).
    pub theta2_max_rad: f64,
    /// Stiffness (N·m/rad at the base link) of the structure once the finger cannot move
    /// (two constraints active: second contact, contact + stop, both stops). A guess: the
    /// cable and the base-link compliance dominate.
    pub k_lock_nm_per_rad: f64,
}

impl FingerGeom {
    /// The paper's prototype (Table 1) with the springs of MODEL.md.
    ///
    /// Joint stops are not given in the paper; they are guesses that leave the working range
    /// free: θ1 ∈ [π/4 − 0.05, 2.4] rad (the rest pose sits 0.05 rad above the extension stop),
    /// θ2 ∈ [−0.05, 1.6] rad (well before the toggle at 2.3557 rad).
    pub const PAPER: FingerGeom = FingerGeom {
        l1_m: 0.100,
        l2_m: 0.075,
        a_m: 0.071,
        b_m: 0.108,
        c_m: 0.044,
        phi2_rad: core::f64::consts::FRAC_PI_2,
        theta01_rad: core::f64::consts::FRAC_PI_4,
        theta02_rad: 0.0,
        k1_nm_per_rad: 0.6895,
        k2_nm_per_rad: 1.0274,
        theta1_min_rad: core::f64::consts::FRAC_PI_4 - 0.05,
        theta1_max_rad: 2.4,
        theta2_min_rad: -0.05,
        theta2_max_rad: 1.6,
        k_lock_nm_per_rad: 200.0,
    };

    /// Checks that every value is finite and physical; the error names the offending key.
    pub fn validate(&self) -> Result<(), PlantError> {
        let pos = |v: f64, key: &'static str, max: f64| {
            if v.is_finite() && v > 0.0 && v <= max {
                Ok(())
            } else {
                Err(PlantError::Invalid(key))
            }
        };
        pos(self.l1_m, "finger.l1_m", 1.0)?;
        pos(self.l2_m, "finger.l2_m", 1.0)?;
        pos(self.a_m, "finger.a_m", 1.0)?;
        pos(self.b_m, "finger.b_m", 1.0)?;
        pos(self.c_m, "finger.c_m", 1.0)?;
        pos(self.k2_nm_per_rad, "finger.k2_nm_per_rad", 1e4)?;
        pos(self.k_lock_nm_per_rad, "finger.k_lock_nm_per_rad", 1e7)?;
        if !(self.k1_nm_per_rad.is_finite() && (0.0..=1e4).contains(&self.k1_nm_per_rad)) {
            return Err(PlantError::Invalid("finger.k1_nm_per_rad"));
        }
        let ang = |v: f64, key: &'static str| {
            if v.is_finite() && v.abs() <= 2.0 * core::f64::consts::PI {
                Ok(())
            } else {
                Err(PlantError::Invalid(key))
            }
        };
        ang(self.phi2_rad, "finger.phi2_rad")?;
        ang(self.theta01_rad, "finger.theta01_rad")?;
        ang(self.theta02_rad, "finger.theta02_rad")?;
        ang(self.theta1_min_rad, "finger.theta1_min_rad")?;
        ang(self.theta1_max_rad, "finger.theta1_max_rad")?;
        ang(self.theta2_min_rad, "finger.theta2_min_rad")?;
        ang(self.theta2_max_rad, "finger.theta2_max_rad")?;
        if self.theta1_min_rad >= self.theta1_max_rad {
            return Err(PlantError::Invalid("finger.theta1_max_rad"));
        }
        if self.theta2_min_rad >= self.theta2_max_rad {
            return Err(PlantError::Invalid("finger.theta2_max_rad"));
        }
        // The rest pose must lie inside the stops and must assemble.
        if !(self.theta1_min_rad..=self.theta1_max_rad).contains(&self.theta01_rad) {
            return Err(PlantError::Invalid("finger.theta01_rad"));
        }
        if !(self.theta2_min_rad..=self.theta2_max_rad).contains(&self.theta02_rad) {
            return Err(PlantError::Invalid("finger.theta02_rad"));
        }
        // Every θ2 between the stops must assemble away from a singular transmission.
        let n = 32;
        for i in 0..=n {
            let t2 = self.theta2_min_rad
                + (self.theta2_max_rad - self.theta2_min_rad) * f64::from(i) / f64::from(n);
            let l = self
                .linkage(t2)
                .map_err(|_| PlantError::Invalid("finger.b_m"))?;
            if !(l.x2 > 1e-3) {
                return Err(PlantError::Invalid("finger.theta2_max_rad"));
            }
        }
        Ok(())
    }

    /// The linkage at relative angle θ2 (rad): φ = θa − θ1 (rad) and x2 = dφ/dθ2.
    pub fn linkage(&self, theta2_rad: f64) -> Result<Linkage, PlantError> {
        if !theta2_rad.is_finite() || theta2_rad.abs() > 10.0 {
            return Err(PlantError::NonFinite);
        }
        let psi = theta2_rad - self.phi2_rad;
        let (sp, cp) = sincos(psi);
        let obx = self.l1_m + self.c_m * cp;
        let oby = self.c_m * sp;
        let d = sqrt(obx * obx + oby * oby);
        if !(d > 1e-9) {
            return Err(PlantError::NotAssemblable);
        }
        let cb = (self.a_m * self.a_m + d * d - self.b_m * self.b_m) / (2.0 * self.a_m * d);
        if !(cb.abs() <= 1.0) {
            return Err(PlantError::NotAssemblable);
        }
        // φ = α − β with α = atan2(Ob), β = acos(cb) ∈ [0, π]; sin φ and cos φ follow
        // algebraically instead of by two more trig calls (this runs soft-float on the M4).
        let phi = atan2(oby, obx) - acos(cb);
        let sb = sqrt((1.0 - cb * cb).max(0.0));
        let (ca, sa) = (obx / d, oby / d);
        let cf = ca * cb + sa * sb;
        let sf = sa * cb - ca * sb;
        let wx = self.a_m * cf - obx;
        let wy = self.a_m * sf - oby;
        // d/dφ of Oc and d/dθ2 of Ob.
        let den = wx * (-self.a_m * sf) + wy * (self.a_m * cf);
        let num = wx * (-self.c_m * sp) + wy * (self.c_m * cp);
        if !(den.abs() > 1e-12) {
            return Err(PlantError::Singular);
        }
        Ok(Linkage {
            phi_rad: phi,
            x2: num / den,
        })
    }
}

/// The linkage at one θ2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Linkage {
    /// φ(θ2) = θa − θ1 (rad).
    pub phi_rad: f64,
    /// Transmission x2 = ∂θa/∂θ2 at fixed θ1 (dimensionless).
    pub x2: f64,
}

/// A 2-vector (m).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct V2 {
    /// x (m).
    pub x: f64,
    /// y (m).
    pub y: f64,
}

impl V2 {
    /// New vector.
    pub const fn new(x: f64, y: f64) -> Self {
        Self { x, y }
    }
    pub(crate) fn dot(self, o: V2) -> f64 {
        self.x * o.x + self.y * o.y
    }
    pub(crate) fn sub(self, o: V2) -> V2 {
        V2::new(self.x - o.x, self.y - o.y)
    }
    pub(crate) fn add(self, o: V2) -> V2 {
        V2::new(self.x + o.x, self.y + o.y)
    }
    pub(crate) fn scale(self, s: f64) -> V2 {
        V2::new(self.x * s, self.y * s)
    }
    /// Rotated by +90°.
    pub(crate) fn perp(self) -> V2 {
        V2::new(-self.y, self.x)
    }
    pub(crate) fn norm(self) -> f64 {
        sqrt(self.dot(self))
    }
    pub(crate) fn unit_at(angle_rad: f64) -> V2 {
        let (s, c) = sincos(angle_rad);
        V2::new(c, s)
    }
}
