//! The finger description: linkage geometry and joint springs, SI units.

use crate::PtsError;

/// Geometry and springs of a two-phalanx linkage-driven finger (paper Table 1 / Fig. 1).
///
/// Lengths in m, angles in rad, spring rates in N·m/rad.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Finger {
    /// Proximal phalanx length O1O2 (m).
    pub l1: f64,
    /// Distal phalanx length (m).
    pub l2: f64,
    /// Input crank O1Oc (m).
    pub a: f64,
    /// Coupler OcOb (m).
    pub b: f64,
    /// Distal crank O2Ob (m).
    pub c: f64,
    /// Fixed angle between the distal phalanx and its crank (rad).
    pub phi2: f64,
    /// Rest angle of the spring at O1 (absolute θ1, rad).
    pub theta01: f64,
    /// Rest angle of the spring at O2 (relative θ2, rad).
    pub theta02: f64,
    /// Spring rate at O1 (N·m/rad); zero allowed.
    pub k1: f64,
    /// Spring rate at O2 (N·m/rad); must be positive.
    pub k2: f64,
}

impl Finger {
    /// The paper's prototype (Table 1) with the springs of `MODEL.md`.
    pub const PAPER: Finger = Finger {
        l1: 0.100,
        l2: 0.075,
        a: 0.071,
        b: 0.108,
        c: 0.044,
        phi2: core::f64::consts::FRAC_PI_2,
        theta01: core::f64::consts::FRAC_PI_4,
        theta02: 0.0,
        k1: 0.6895,
        k2: 1.0274,
    };

    /// Checks that every value is finite and physical: lengths in (0, 10] m, springs
    /// `k1 ≥ 0`, `k2 > 0`, the linkage triangle inequality satisfiable, angles in [−2π, 2π].
    pub fn validate(&self) -> Result<(), PtsError> {
        let lengths = [self.l1, self.l2, self.a, self.b, self.c];
        let angles = [self.phi2, self.theta01, self.theta02];
        if lengths
            .iter()
            .chain(angles.iter())
            .chain([self.k1, self.k2].iter())
            .any(|v| !v.is_finite())
        {
            return Err(PtsError::NonFinite);
        }
        if lengths.iter().any(|&v| !(v > 0.0 && v <= 10.0))
            || angles.iter().any(|v| v.abs() > 2.0 * core::f64::consts::PI)
            || !(self.k1 >= 0.0 && self.k1 <= 1e4)
            || !(self.k2 > 0.0 && self.k2 <= 1e4)
        {
            return Err(PtsError::InvalidFinger);
        }
        // Some configuration must close: the coupler b must fit between O2Ob and O1Oc
        // at some distance l1 apart (|O2Oc| ranges over [|l1 − a|, l1 + a]).
        let span_max = self.l1 + self.a + self.c;
        let span_min = (self.l1 - self.a).abs() - self.c;
        if self.b >= span_max || self.b <= span_min {
            return Err(PtsError::InvalidFinger);
        }
        Ok(())
    }
}

/// The finger's extension stops: where it rests against when opened, which the firmware's rest
/// check finds before it zeroes the encoder.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stops {
    /// Proximal extension stop, absolute θ1 (rad); below the rest angle θ0,1, by at most 1 rad.
    pub theta1_min_rad: f64,
    /// Distal extension stop, relative θ2 (rad); below the rest angle θ0,2, by at most 1 rad.
    pub theta2_min_rad: f64,
    /// Stiffness of a stop (N·m/rad), in (0, 1e7].
    pub stiffness_nm_per_rad: f64,
}

impl Stops {
    /// Below each rest angle by as much as the prototype's (0.05 rad), the prototype's
    /// stiffness (200 N·m/rad): the default for a file without `[stops]`.
    pub const fn below_rest(finger: &Finger) -> Stops {
        Stops {
            theta1_min_rad: finger.theta01 - Self::PAPER_BELOW_REST_RAD,
            theta2_min_rad: finger.theta02 - Self::PAPER_BELOW_REST_RAD,
            stiffness_nm_per_rad: 200.0,
        }
    }

    /// How far below its rest angle each of the prototype's stops sits (rad).
    pub const PAPER_BELOW_REST_RAD: f64 = 0.05;
}
