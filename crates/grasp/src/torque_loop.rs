//! The torque (current) loop: feed-forward of the static drive inverse plus a PI on the
//! measured actuator torque, with output limits and anti-windup. Integer only.
#![deny(clippy::float_arithmetic)]

use crate::config::Params;
use crate::DUTY_MAX;

/// PI torque controller state.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct TorqueLoop {
    /// Integrator, duty units ×2¹⁶.
    integ_q16: i64,
    /// Whether the last output was clamped at ±DUTY_MAX.
    saturated: bool,
}

impl TorqueLoop {
    /// A loop with an empty integrator.
    pub fn new() -> Self {
        Self::default()
    }

    /// Clears the integrator (bridge off / restart).
    pub fn reset(&mut self) {
        *self = Self::default();
    }

    /// Whether the last output hit the duty limit.
    pub fn saturated(&self) -> bool {
        self.saturated
    }

    /// One update: reference and measurement in µN·m → duty in ±[`DUTY_MAX`].
    ///
    /// Anti-windup: the integrator is itself limited to ±DUTY_MAX and is not advanced
    /// while the output is clamped in the direction the error pushes (conditional integration).
    #[inline(always)]
    pub fn update(&mut self, ref_unm: i32, meas_unm: i32, p: &Params) -> i16 {
        // Every product is 25 × 32 bits at most (gains and signals limited where they enter,
        // one instruction each on Cortex-M4): exact, and the sums of three cannot overflow,
        // whatever a hand-made `Params` holds. A configuration's gains are ~10³.
        let g = |k: i32| i64::from(k.clamp(-(1 << 24), (1 << 24) - 1));
        let e = i64::from(ref_unm.saturating_sub(meas_unm));
        let lim = i64::from(DUTY_MAX) << 16;
        let ff = i64::from(ref_unm) * g(p.ff_duty_per_unm_q16);
        let pe = e * g(p.kp_duty_per_unm_q16);
        let di = e * g(p.ki_duty_per_unm_q16);
        let trial = ff + pe + self.integ_q16 + di;
        let pushing_out = (trial > lim && di > 0) || (trial < -lim && di < 0);
        if !pushing_out {
            self.integ_q16 = (self.integ_q16 + di).clamp(-lim, lim);
        }
        let u = (ff + pe + self.integ_q16).clamp(-lim, lim);
        self.saturated = u == lim || u == -lim;
        // Round to nearest duty unit; |u| ≤ DUTY_MAX·2¹⁶ so the result fits i16.
        let duty = (u + (1 << 15)) >> 16;
        duty.clamp(-i64::from(DUTY_MAX), i64::from(DUTY_MAX)) as i16
    }
}
