//! The kinetostatic model of the finger, generic over the numeric back end.
//!
//! Conventions and corrections: `docs/MODEL.md`. Flexion positive, SI units,
//! θ1 absolute, θ2 relative, θa the absolute angle of the input crank O1Oc.

use crate::{Finger, PtsError, Real};

/// |x2| below this is treated as the toggle (the actuator loses control of θ2).
pub const TOGGLE_X2: f64 = 1e-2;
/// Smallest actuator displacement (rad) accepted for a stiffness measurement.
pub const MIN_DTHETA_A: f64 = 1e-6;
/// Largest |angle| (rad) accepted as input.
pub const MAX_ANGLE: f64 = 4.0 * core::f64::consts::PI;
/// Largest |torque| (N·m) accepted as input.
pub const MAX_TORQUE: f64 = 1e3;
/// Largest stiffness (N·m/rad) accepted as input.
pub const MAX_STIFFNESS: f64 = 1e4;
/// Newton iteration budget for the free-motion solves.
pub const MAX_NEWTON: usize = 40;
/// Relative band below the free-motion stiffness still read as "no contact"
/// (measurement noise); below it the stiffness is an error.
pub const FREE_BAND: f64 = 0.05;
/// Largest accepted condition number of the distal inversion, κ = (K_c/l2)/(dK_c/dk2):
/// the shift of k2, as a fraction of l2, per unit relative error in K̂c. Over the monotone
/// range of the paper's finger κ ≤ 0.43 (a 1 % error in K̂c moves k2 by ≤ 0.43 % of l2);
/// it grows without bound where K1 s x2 + K2′ → 0 (dK_c/dk2 → 0). Above this the
/// inversion is refused with [`PtsError::IllConditioned`].
pub const MAX_CONDITION: f64 = 2.0;
/// Stiffness (N·m/rad) above K_c,tip still read as a contact at the tip: rounding-level
/// (far below any measurement), so that K_c computed at k2 = l2 by another formula
/// ([`Model::kc_distal`]) is not refused as beyond the tip.
pub const TIP_TOLERANCE: f64 = 1e-9;
/// Reference uncertainty of a measured θa (rad) for refusing noisy estimates: one count of
/// the default drive, 2π/(64 counts·3072) ≈ 3.2e-5 rad, rounded up.
pub const THETA_A_NOISE_RAD: f64 = 3.2e-5;
/// Largest accepted shift of k2 (fraction of l2) caused by a θa error of
/// [`THETA_A_NOISE_RAD`] in the two-point estimate: κ·δθa/Δθa. Above it the estimate is
/// refused with [`PtsError::IllConditioned`] (the step was too small for this stiffness).
pub const MAX_K2_NOISE: f64 = 0.05;

/// The four-bar closure at one θ2: the input-crank angle γ and the transmission.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Closure<R> {
    /// λ = π + θ2 − φ2 (rad).
    pub lambda: R,
    /// γ on the physical assembly branch (rad), angle of O1Oc in the O2Ob frame.
    pub gamma: R,
    /// Transmission factor x2 = ∂θa/∂θ2 (dimensionless).
    pub x2: R,
    /// dx2/dθ2 (1/rad).
    pub dx2: R,
}

/// A configuration of the finger with the torque that holds it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Config<R> {
    /// Absolute proximal angle θ1 (rad).
    pub theta1: R,
    /// Relative distal angle θ2 (rad).
    pub theta2: R,
    /// Actuator angle θa (rad), absolute model angle.
    pub theta_a: R,
    /// Actuator torque T_a (N·m).
    pub ta: R,
    /// Transmission x2 at θ2.
    pub x2: R,
    /// dx2/dθ2 at θ2 (1/rad).
    pub dx2: R,
}

/// Which phalanx a stiffness points to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Phalanx {
    /// No contact: the stiffness is the free-motion one.
    None,
    /// A contact on the proximal phalanx (detectable, not locatable).
    Proximal,
    /// A contact on the distal phalanx, located by k2.
    Distal,
}

impl Phalanx {
    /// Lower-case name for logs and JSON.
    pub const fn name(&self) -> &'static str {
        match self {
            Phalanx::None => "none",
            Phalanx::Proximal => "proximal",
            Phalanx::Distal => "distal",
        }
    }
}

/// The result of inverting a stiffness at a contact configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Contact<R> {
    /// Classification.
    pub phalanx: Phalanx,
    /// Distal contact location from O2 (m); `Some` only for [`Phalanx::Distal`].
    pub k2: Option<R>,
    /// Free-motion stiffness at the configuration (N·m/rad).
    pub kc_free: R,
    /// Stiffness of a proximal contact (= distal contact at O2) (N·m/rad).
    pub kc_proximal: R,
    /// Stiffness of a contact at the distal tip (N·m/rad).
    pub kc_tip: R,
}

/// The paper's two-point estimate (Eq. 1 and inversion at the contact configuration).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate<R> {
    /// K̂c = ΔT_a/Δθa (N·m/rad).
    pub kc_hat: R,
    /// Torque step ΔT_a (N·m).
    pub dta: R,
    /// Actuator displacement Δθa (rad).
    pub dtheta_a: R,
    /// Configuration at contact, rebuilt from θa,c (torque T_a,c as measured).
    pub contact_config: Config<R>,
    /// Classification and location.
    pub contact: Contact<R>,
}

/// The model of one finger on one numeric back end. Build once, call many times.
#[derive(Clone, Copy, Debug)]
pub struct Model<R> {
    /// The description this model was built from.
    pub finger: Finger,
    l1: R,
    l2: R,
    phi2_minus_pi: R,
    theta01: R,
    theta02: R,
    k1: R,
    k2: R,
    z1: R,
    z2: R,
    z3: R,
    /// l1/(2 l2): the inversion works with lengths in units of 2 l2, where l1 cos θ2 is
    /// this times cos θ2, l2 is ½ and the condition number loses its factor 2 l2.
    cos_scale: R,
    /// 2 l2 (m), back to metres.
    two_l2: R,
    /// K1/2 and K1/4 (N·m/rad).
    k1_half: R,
    k1_quarter: R,
}

/// Quantities of the monotonicity test that the inversion reuses (lengths in units of 2 l2).
struct Mono<R> {
    /// L = (l1 cos θ2 + l2)/(2 l2) = c + ½.
    big_l: R,
    /// (s_tip − x2)·L = ½ − x2 L (negative).
    dt: R,
    /// K2′ = K2 − T_a dx2/dθ2.
    k2p: R,
    /// K2′ L.
    k2p_l: R,
}

fn check<R: Real>(x: R, limit: f64) -> Result<R, PtsError> {
    if !x.is_finite() {
        return Err(PtsError::NonFinite);
    }
    // A value at a fixed-point limit may stand for anything beyond it (and the limit itself
    // may be below `limit` in a narrow type). Where the limit is representable, the range
    // test already excludes the saturation values (`lim` is a constant: this folds).
    let lim = R::from_f64(limit);
    if x > lim || x < -lim || (lim.is_saturated() && x.is_saturated()) {
        return Err(PtsError::OutOfRange);
    }
    Ok(x)
}

fn ok_value<R: Real>(x: R) -> Result<R, PtsError> {
    if !x.is_finite() {
        Err(PtsError::NonFinite)
    } else if x.is_saturated() {
        Err(PtsError::Overflow)
    } else {
        Ok(x)
    }
}

impl<R: Real> Model<R> {
    /// Builds the model; fails on a non-physical finger or one the back end cannot represent.
    pub fn new(finger: &Finger) -> Result<Self, PtsError> {
        finger.validate()?;
        let f = finger;
        let conv = |v: f64| R::try_from_f64(v).ok_or(PtsError::OutOfRange);
        let z1 = (f.l1 * f.l1 + f.c * f.c + f.a * f.a - f.b * f.b) / (2.0 * f.a * f.l1);
        Ok(Self {
            finger: *finger,
            l1: conv(f.l1)?,
            l2: conv(f.l2)?,
            phi2_minus_pi: conv(f.phi2 - core::f64::consts::PI)?,
            theta01: conv(f.theta01)?,
            theta02: conv(f.theta02)?,
            k1: conv(f.k1)?,
            k2: conv(f.k2)?,
            z1: conv(z1)?,
            z2: conv(f.c / f.l1)?,
            z3: conv(f.c / f.a)?,
            cos_scale: conv(f.l1 / (2.0 * f.l2))?,
            two_l2: conv(2.0 * f.l2)?,
            k1_half: conv(0.5 * f.k1)?,
            k1_quarter: conv(0.25 * f.k1)?,
        })
    }

    /// The paper's prototype on this back end.
    pub fn paper() -> Result<Self, PtsError> {
        Self::new(&Finger::PAPER)
    }

    /// Distal phalanx length l2 (m), in the back end's type.
    pub fn l2(&self) -> R {
        self.l2
    }

    /// Four-bar closure at θ2 (rad) on the physical branch, with x2 and dx2/dθ2 (analytic).
    ///
    /// γ = atan2(Q, P) − acos(R/√(P²+Q²)): no tan(γ/2) pole.
    pub fn closure(&self, theta2: R) -> Result<Closure<R>, PtsError> {
        let theta2 = check(theta2, MAX_ANGLE)?;
        let lambda = theta2 - self.phi2_minus_pi;
        let (sl, cl) = (lambda.sin(), lambda.cos());
        let p = cl - self.z2;
        let q = sl;
        let r = self.z3 * cl - self.z1;
        let rho = (p * p + q * q).sqrt();
        if !(rho > R::from_f64(1e-6)) {
            return Err(PtsError::NotAssemblable);
        }
        let ratio = r / rho;
        if ratio.abs() > R::one() {
            return Err(PtsError::NotAssemblable);
        }
        let gamma = q.atan2(p) - ratio.acos();
        let lg = lambda - gamma;
        let (slg, clg) = (lg.sin(), lg.cos());
        let (sg, cg) = (gamma.sin(), gamma.cos());
        // Implicit derivative of P cos γ + Q sin γ − R = 0 with respect to λ.
        let n = slg - self.z3 * sl;
        let m = slg + self.z2 * sg;
        if m.abs() < R::from_f64(1e-4) {
            return Err(PtsError::Singular);
        }
        let gp = n / m;
        let x2 = R::one() - gp;
        if x2.abs() < R::from_f64(TOGGLE_X2) {
            return Err(PtsError::Toggle);
        }
        let np = clg * x2 - self.z3 * cl;
        let mp = clg * x2 + self.z2 * cg * gp;
        let gpp = (np - gp * mp) / m;
        Ok(Closure {
            lambda,
            gamma: ok_value(gamma)?,
            x2: ok_value(x2)?,
            dx2: ok_value(-gpp)?,
        })
    }

    /// Actuator angle θa = θ1 + θ2 − φ2 − γ (rad) (corrected Eq. 18).
    pub fn theta_a(&self, theta1: R, theta2: R) -> Result<R, PtsError> {
        let theta1 = check(theta1, MAX_ANGLE)?;
        let cl = self.closure(theta2)?;
        ok_value(self.theta_a_from(theta1, theta2, &cl))
    }

    fn theta_a_from(&self, theta1: R, theta2: R, cl: &Closure<R>) -> R {
        // θ1 + θ2 − φ2 − γ = θ1 + λ − π − γ
        theta1 + theta2 - (self.phi2_minus_pi + R::from_f64(core::f64::consts::PI)) - cl.gamma
    }

    /// K2′ = K2 − T_a dx2/dθ2 (N·m/rad): the distal spring stiffened by the G term.
    fn k2_prime(&self, ta: R, cl: &Closure<R>) -> R {
        self.k2 - ta * cl.dx2
    }

    /// Stiffness (N·m/rad) at the actuator for a proximal contact: K2′/x2², independent of k1.
    pub fn kc_proximal(&self, theta2: R, ta: R) -> Result<R, PtsError> {
        let ta = check(ta, MAX_TORQUE)?;
        let cl = self.closure(theta2)?;
        ok_value(self.k2_prime(ta, &cl) / (cl.x2 * cl.x2))
    }

    /// Stiffness (N·m/rad) for a distal contact at k2 (m from O2):
    /// (K1 s² + K2′)/(s − x2)², s = k2/(l1 cos θ2 + k2).
    pub fn kc_distal(&self, theta2: R, ta: R, k2: R) -> Result<R, PtsError> {
        let ta = check(ta, MAX_TORQUE)?;
        let k2 = check(k2, 1e3)?;
        if !(k2 > R::zero()) || k2 > self.l2 {
            return Err(PtsError::ContactOutsidePhalanx);
        }
        let cl = self.closure(theta2)?;
        let den = self.l1 * theta2.cos() + k2;
        if den.abs() < R::from_f64(1e-9) {
            return Err(PtsError::Singular);
        }
        let s = k2 / den;
        let d = s - cl.x2;
        if d.abs() < R::from_f64(1e-6) {
            // The locking point: infinite stiffness.
            return Err(PtsError::NotMonotone);
        }
        ok_value((self.k1 * s * s + self.k2_prime(ta, &cl)) / (d * d))
    }

    /// Free-motion stiffness (N·m/rad): 1/(1/K1 + x2²/K2′); zero when K1 = 0.
    pub fn kc_free(&self, theta2: R, ta: R) -> Result<R, PtsError> {
        let ta = check(ta, MAX_TORQUE)?;
        let cl = self.closure(theta2)?;
        ok_value(self.kc_free_from(ta, &cl))
    }

    fn kc_free_from(&self, ta: R, cl: &Closure<R>) -> R {
        // K1 K2′ / (K2′ + K1 x2²): the series form without dividing by K1.
        let k2p = self.k2_prime(ta, cl);
        let den = k2p + self.k1 * cl.x2 * cl.x2;
        // `<=`: the threshold rounds to zero in fixed point, where den can be exactly 0.
        if !(den.abs() > R::from_f64(1e-12)) {
            return R::zero();
        }
        self.k1 * k2p / den
    }

    /// Free-motion configuration holding torque T_a (N·m). Needs K1 > 0 unless T_a = 0.
    pub fn free_from_torque(&self, ta: R) -> Result<Config<R>, PtsError> {
        let ta = check(ta, MAX_TORQUE)?;
        let theta1 = if self.k1 > R::zero() {
            self.theta01 + ta / self.k1
        } else if ta == R::zero() {
            return self.free_from_theta_a_k1_zero(None);
        } else {
            // With K1 = 0 only T_a = 0 is an equilibrium of free motion.
            return Err(PtsError::OutOfRange);
        };
        let theta1 = check(theta1, MAX_ANGLE)?;
        // Solve g(θ2) = K2(θ2 − θ02) − T_a x2(θ2) = 0; g′ = K2′.
        let mut theta2 = self.theta02;
        for _ in 0..MAX_NEWTON {
            let cl = self.closure(theta2)?;
            let g = self.k2 * (theta2 - self.theta02) - ta * cl.x2;
            let dg = self.k2_prime(ta, &cl);
            if !(dg > R::from_f64(1e-9)) {
                return Err(PtsError::NoConvergence);
            }
            let step = clamp_step(g / dg);
            theta2 = theta2 - step;
            if step.abs() <= R::from_f64(R::TOL) {
                let cl = self.closure(theta2)?;
                let theta_a = self.theta_a_from(theta1, theta2, &cl);
                return Ok(Config {
                    theta1,
                    theta2,
                    theta_a: ok_value(theta_a)?,
                    ta,
                    x2: cl.x2,
                    dx2: cl.dx2,
                });
            }
        }
        Err(PtsError::NoConvergence)
    }

    /// Free-motion configuration at a measured actuator angle θa (rad).
    ///
    /// Solves g(θ2) = K2(θ2 − θ02) − K1(θ1(θ2) − θ01) x2 = 0 with θ1 = θa − θ2 + φ2 + γ;
    /// g′ = K2′ + K1 x2² > 0 on the working range. With K1 = 0 the answer is θ2 = θ02, T_a = 0.
    pub fn free_from_theta_a(&self, theta_a: R) -> Result<Config<R>, PtsError> {
        let theta_a = check(theta_a, MAX_ANGLE)?;
        if !(self.k1 > R::zero()) {
            return self.free_from_theta_a_k1_zero(Some(theta_a));
        }
        let offset = self.phi2_minus_pi + R::from_f64(core::f64::consts::PI);
        let mut theta2 = self.theta02;
        // θ1 of the previous iterate: γ comes from atan2 and jumps by 2π where the linkage's
        // angle crosses ±π, which θ1 (the proximal phalanx) does not. θ1 is kept continuous
        // along the iterates, starting on γ's branch at θ02.
        let mut theta1_prev = R::zero();
        // The converged θ2's configuration is built at the top of the pass after the last step.
        let mut converged = false;
        for i in 0..=MAX_NEWTON {
            if !converged && i == MAX_NEWTON {
                break;
            }
            let cl = self.closure(theta2)?;
            let mut theta1 = theta_a - theta2 + offset + cl.gamma;
            if i > 0 {
                theta1 = continuous(theta1, theta1_prev);
            }
            theta1_prev = theta1;
            let ta = self.k1 * (theta1 - self.theta01);
            if converged {
                return Ok(Config {
                    theta1: ok_value(theta1)?,
                    theta2,
                    theta_a,
                    ta: ok_value(ta)?,
                    x2: cl.x2,
                    dx2: cl.dx2,
                });
            }
            let g = self.k2 * (theta2 - self.theta02) - ta * cl.x2;
            let dg = self.k2_prime(ta, &cl) + self.k1 * cl.x2 * cl.x2;
            if !(dg > R::from_f64(1e-9)) {
                return Err(PtsError::NoConvergence);
            }
            let step = clamp_step(g / dg);
            theta2 = theta2 - step;
            converged = step.abs() <= R::from_f64(R::TOL);
        }
        Err(PtsError::NoConvergence)
    }

    fn free_from_theta_a_k1_zero(&self, theta_a: Option<R>) -> Result<Config<R>, PtsError> {
        // K1 = 0: the finger turns as one body at T_a = 0, θ2 = θ02.
        let theta2 = self.theta02;
        let cl = self.closure(theta2)?;
        let offset = self.phi2_minus_pi + R::from_f64(core::f64::consts::PI);
        let (theta1, theta_a) = match theta_a {
            Some(ta_angle) => (ta_angle - theta2 + offset + cl.gamma, ta_angle),
            None => (self.theta01, self.theta_a_from(self.theta01, theta2, &cl)),
        };
        Ok(Config {
            theta1: ok_value(theta1)?,
            theta2,
            theta_a: ok_value(theta_a)?,
            ta: R::zero(),
            x2: cl.x2,
            dx2: cl.dx2,
        })
    }

    /// Checks that K_c(k2) is strictly increasing on (0, l2] at this configuration
    /// (MODEL.md, "Monotonicity"), so the inversion is unique.
    pub fn check_monotone(&self, cfg: &Config<R>) -> Result<(), PtsError> {
        self.check_monotone_cos(cfg, cfg.theta2.cos())
    }

    /// [`Model::check_monotone`] with cos θ2 supplied by the caller (a table, say).
    pub fn check_monotone_cos(&self, cfg: &Config<R>, cos_theta2: R) -> Result<(), PtsError> {
        let c2 = check(cos_theta2, 1.0 + 1e-3)?;
        self.monotone(cfg, c2 * self.cos_scale).map(|_| ())
    }

    /// cos θ2 → c = l1 cos θ2/(2 l2), the scaled value the inversion takes, checked.
    pub(crate) fn scaled_cos(&self, cos_theta2: R) -> Result<R, PtsError> {
        Ok(check(cos_theta2, 1.0 + 1e-3)? * self.cos_scale)
    }

    /// The monotonicity conditions, division-free, with lengths in units of 2 l2
    /// (c = l1 cos θ2/(2 l2), L = c + ½), and the quantities the inversion shares.
    #[inline(always)]
    fn monotone(&self, cfg: &Config<R>, c: R) -> Result<Mono<R>, PtsError> {
        let x2 = cfg.x2;
        if !(c > R::zero()) || !(x2 < R::one()) || !(x2 > R::zero()) {
            return Err(PtsError::NotMonotone);
        }
        let half = R::from_f64(0.5);
        let big_l = c + half;
        // (s_tip − x2)·L with s_tip = ½/L: negative exactly when the locking point
        // k2* = x2 l1 cos θ2/(1 − x2) lies beyond the tip (x2 L > ½).
        let dt = half - x2 * big_l;
        if !(dt < R::zero()) {
            return Err(PtsError::NotMonotone);
        }
        let k2p = self.k2 - cfg.ta * cfg.dx2;
        let k2p_l = k2p * big_l;
        // (K1 s_tip x2 + K2′)·L = K1 x2/2 + K2′ L > 0, L > 0: division-free.
        if !(k2p > R::zero()) || !(self.k1_half * x2 + k2p_l > R::zero()) {
            return Err(PtsError::NotMonotone);
        }
        Ok(Mono {
            big_l,
            dt,
            k2p,
            k2p_l,
        })
    }

    /// Classifies a measured stiffness K_c (N·m/rad) at the contact configuration and,
    /// for a distal contact, inverts the closed form for k2 (m) as a quadratic in s.
    pub fn invert(&self, cfg: &Config<R>, kc: R) -> Result<Contact<R>, PtsError> {
        self.invert_cos(cfg, cfg.theta2.cos(), kc)
    }

    /// [`Model::invert`] with cos θ2 supplied by the caller, so that a back end without
    /// cheap trigonometry (fixed point with a free-motion table) needs none here.
    pub fn invert_cos(
        &self,
        cfg: &Config<R>,
        cos_theta2: R,
        kc: R,
    ) -> Result<Contact<R>, PtsError> {
        let kc = check(kc, MAX_STIFFNESS)?;
        let c = self.scaled_cos(cos_theta2)?;
        self.invert_shared(cfg, c, kc, None)
    }

    /// [`Model::invert_inner`] as one function: the path fit's initial guess and the
    /// two-point estimate beside it share one copy in a firmware that runs both.
    #[inline(never)]
    fn invert_shared(
        &self,
        cfg: &Config<R>,
        c: R,
        kc: R,
        dtheta_a: Option<R>,
    ) -> Result<Contact<R>, PtsError> {
        self.invert_inner(cfg, c, kc, dtheta_a)
    }

    /// The inversion at a checked K_c and c = l1 cos θ2/(2 l2) ([`Model::scaled_cos`]);
    /// with `dtheta_a` also refuses when θa noise would move k2 too far.
    ///
    /// Written for few operations: lengths in units of 2 l2, every shared product computed
    /// once, divisions only for the five values that are quotients (K_c free, proximal,
    /// tip, the root s, k2), the comparisons cross-multiplied.
    #[inline(always)]
    fn invert_inner(
        &self,
        cfg: &Config<R>,
        c: R,
        kc: R,
        dtheta_a: Option<R>,
    ) -> Result<Contact<R>, PtsError> {
        let Mono {
            big_l,
            dt,
            k2p,
            k2p_l,
        } = self.monotone(cfg, c)?;
        let x2 = cfg.x2;
        let x2sq = x2 * x2;
        // Free motion: K1 K2′/(K2′ + K1 x2²) (as `kc_free_from`, K2′ > 0 here).
        let den_free = k2p + self.k1 * x2sq;
        let k1k2p = self.k1 * k2p;
        let kc_free = if den_free > R::from_f64(1e-12) {
            k1k2p / den_free
        } else {
            R::zero()
        };
        let kc_free = ok_value(kc_free)?;
        let kc_prox = ok_value(k2p / x2sq)?;
        // (K1 s_tip² + K2′)/(s_tip − x2)², numerator and denominator multiplied by L².
        let kc_tip = ok_value((self.k1_quarter + k2p_l * big_l) / (dt * dt))?;
        let mut contact = Contact {
            phalanx: Phalanx::None,
            k2: None,
            kc_free,
            kc_proximal: kc_prox,
            kc_tip,
        };
        if kc < kc_free * R::from_f64(1.0 - FREE_BAND) {
            return Err(PtsError::StiffnessBelowFree);
        }
        // Between free motion and a proximal contact, read the nearer one (geometric midpoint).
        if kc * kc < kc_free * kc_prox {
            return Ok(contact);
        }
        if kc <= kc_prox {
            contact.phalanx = Phalanx::Proximal;
            return Ok(contact);
        }
        // A hair above K_c,tip is the tip: the closed form above and `kc_distal` at k2 = l2
        // round differently.
        if kc > kc_tip + R::from_f64(TIP_TOLERANCE) {
            return Err(PtsError::BeyondTip);
        }
        // (Kc − K1) s² − 2 Kc x2 s + Kc x2² − K2′ = 0; the root below x2, in the form
        // that neither cancels nor divides by Kc − K1.
        let disc = kc * den_free - k1k2p;
        if disc < R::zero() {
            return Err(PtsError::NotMonotone);
        }
        let kc_x2 = kc * x2;
        let s = (kc_x2 * x2 - k2p) / (kc_x2 + disc.sqrt());
        // s ≤ s_tip follows from K_c ≤ K_c,tip (k2 is clamped to l2 below).
        let s = ok_value(s)?.max(R::zero());
        // Conditioning, division-free: κ = l1c (x2 − s)(K1 s² + K2′) / (2 l2 (1 − s)² (K1 s x2 + K2′)).
        // At the root K1 s² + K2′ = Kc e² and K1 s x2 + K2′ = e (Kc e + K1 s), e = x2 − s, so
        // in units of 2 l2, κ = c Kc e² / ((1 − s)² (Kc e + K1 s)).
        let e = x2 - s;
        let kc_e = kc * e;
        let slope = kc_e + self.k1 * s;
        let one_s = R::one() - s;
        let lhs = c * (kc_e * e);
        // κ ≤ MAX_CONDITION and, with Δθa, κ·δθ/Δθa ≤ MAX_K2_NOISE: the smaller bound,
        // min(MAX_CONDITION, C·Δθa) with C = MAX_K2_NOISE/δθ, ordered so that no product
        // underflows in Q16.16. C·Δθa is the smaller only for Δθa below MAX_CONDITION/C (C
        // as the back end holds it: Q8.24 saturates it); a constant unless C saturates (no
        // floating point at run time).
        let q = one_s * one_s * slope;
        let c_noise = R::from_f64(MAX_K2_NOISE / THETA_A_NOISE_RAD);
        let dth_max = if c_noise.is_saturated() {
            R::from_f64(MAX_CONDITION) / c_noise
        } else {
            R::from_f64(MAX_CONDITION * THETA_A_NOISE_RAD / MAX_K2_NOISE)
        };
        let rhs = match dtheta_a {
            Some(dth) if dth < dth_max => c_noise * dth * q,
            _ => times_const(q, MAX_CONDITION),
        };
        if !(slope > R::zero()) || !(lhs <= rhs) || lhs.is_saturated() || rhs.is_saturated() {
            return Err(PtsError::IllConditioned);
        }
        // k2 = l1 cos θ2 s/(1 − s) = 2 l2 c s/(1 − s).
        let k2 = self.two_l2 * (s * c / one_s);
        let k2 = ok_value(k2)?.min(self.l2);
        if !(k2 > R::zero()) {
            // s rounded to 0 (K̂c a hair above K_c,proximal in a coarse back end): O2.
            contact.phalanx = Phalanx::Proximal;
            return Ok(contact);
        }
        contact.phalanx = Phalanx::Distal;
        contact.k2 = Some(k2);
        Ok(contact)
    }

    /// The paper's two-point estimate: K̂c = ΔT_a/Δθa from the contact instant
    /// (θa,c, T_a,c) and the end of the step (θa, T_a), inverted at the contact configuration.
    ///
    /// Refused with [`PtsError::IllConditioned`] where the inversion is ill-conditioned
    /// (κ > [`MAX_CONDITION`]) or where a θa error of [`THETA_A_NOISE_RAD`] would move k2
    /// by more than [`MAX_K2_NOISE`]·l2.
    pub fn estimate_two_point(
        &self,
        theta_a_c: R,
        ta_c: R,
        theta_a: R,
        ta: R,
    ) -> Result<Estimate<R>, PtsError> {
        self.estimate_two_point_with(theta_a_c, ta_c, theta_a, ta, |t| {
            let cfg = self.free_from_theta_a(t)?;
            Ok((cfg, cfg.theta2.cos()))
        })
    }

    /// [`Model::estimate_two_point`] with the free-motion configuration at θa,c (and its
    /// cos θ2) supplied by `contact_config`, e.g. from a table instead of the Newton solve.
    pub fn estimate_two_point_with<F>(
        &self,
        theta_a_c: R,
        ta_c: R,
        theta_a: R,
        ta: R,
        contact_config: F,
    ) -> Result<Estimate<R>, PtsError>
    where
        F: FnOnce(R) -> Result<(Config<R>, R), PtsError>,
    {
        self.estimate_scaled(theta_a_c, ta_c, theta_a, ta, |t| {
            let (cfg, cos_theta2) = contact_config(t)?;
            Ok((cfg, self.scaled_cos(cos_theta2)?))
        })
    }

    /// [`Model::estimate_two_point_with`] through the one out-of-line copy of the inversion
    /// that [`Model::invert_cos`] (the path fit's initial guess) also calls, instead of a copy
    /// inlined here: the same result, for a firmware that runs both and is short of flash
    /// rather than of the call's instructions.
    pub fn estimate_two_point_shared<F>(
        &self,
        theta_a_c: R,
        ta_c: R,
        theta_a: R,
        ta: R,
        contact_config: F,
    ) -> Result<Estimate<R>, PtsError>
    where
        F: FnOnce(R) -> Result<(Config<R>, R), PtsError>,
    {
        self.estimate_scaled_by::<_, true>(theta_a_c, ta_c, theta_a, ta, |t| {
            let (cfg, cos_theta2) = contact_config(t)?;
            Ok((cfg, self.scaled_cos(cos_theta2)?))
        })
    }

    /// l1/(2 l2), the factor from cos θ2 to the inversion's c (for tables that store c).
    pub(crate) fn cos_scale(&self) -> R {
        self.cos_scale
    }

    /// [`Model::estimate_two_point_with`] where `contact_config` gives the configuration
    /// with c = l1 cos θ2/(2 l2) (checked) instead of cos θ2; its torque is not used.
    #[inline(always)]
    pub(crate) fn estimate_scaled<F>(
        &self,
        theta_a_c: R,
        ta_c: R,
        theta_a: R,
        ta: R,
        contact_config: F,
    ) -> Result<Estimate<R>, PtsError>
    where
        F: FnOnce(R) -> Result<(Config<R>, R), PtsError>,
    {
        self.estimate_scaled_by::<_, false>(theta_a_c, ta_c, theta_a, ta, contact_config)
    }

    /// [`Model::estimate_scaled`] with the inversion inlined here, or (`SHARED`) through its
    /// one out-of-line copy ([`Model::invert_shared`]).
    #[inline(always)]
    fn estimate_scaled_by<F, const SHARED: bool>(
        &self,
        theta_a_c: R,
        ta_c: R,
        theta_a: R,
        ta: R,
        contact_config: F,
    ) -> Result<Estimate<R>, PtsError>
    where
        F: FnOnce(R) -> Result<(Config<R>, R), PtsError>,
    {
        let theta_a_c = check(theta_a_c, MAX_ANGLE)?;
        let theta_a = check(theta_a, MAX_ANGLE)?;
        let ta_c = check(ta_c, MAX_TORQUE)?;
        let ta = check(ta, MAX_TORQUE)?;
        let dta = ok_value(ta - ta_c)?;
        if !(dta > R::zero()) {
            return Err(PtsError::DeltaTorqueNotPositive);
        }
        let dtheta_a = ok_value(theta_a - theta_a_c)?;
        if !(dtheta_a > R::from_f64(MIN_DTHETA_A)) {
            return Err(PtsError::DeltaThetaTooSmall);
        }
        let kc_hat = dta / dtheta_a;
        if kc_hat > R::from_f64(MAX_STIFFNESS) {
            return Err(PtsError::BeyondTip);
        }
        let (mut cfg, c) = contact_config(theta_a_c)?;
        let kc_hat = check(kc_hat, MAX_STIFFNESS)?;
        // The G term carries the torque actually applied at contact.
        cfg.ta = ta_c;
        let contact = if SHARED {
            self.invert_shared(&cfg, c, kc_hat, Some(dtheta_a))
        } else {
            self.invert_inner(&cfg, c, kc_hat, Some(dtheta_a))
        }?;
        Ok(Estimate {
            kc_hat,
            dta,
            dtheta_a,
            contact_config: cfg,
            contact,
        })
    }
}

/// Number of Q32.32 words in [`Model::to_raw`].
pub const MODEL_RAW_WORDS: usize = 14;

impl Model<crate::fixed::Fx32> {
    /// The model's precomputed constants as raw Q32.32 bits (with the finger, everything
    /// [`Model::from_raw`] needs): for generating a model at build time.
    pub fn to_raw(&self) -> [i64; MODEL_RAW_WORDS] {
        [
            self.l1,
            self.l2,
            self.phi2_minus_pi,
            self.theta01,
            self.theta02,
            self.k1,
            self.k2,
            self.z1,
            self.z2,
            self.z3,
            self.cos_scale,
            self.two_l2,
            self.k1_half,
            self.k1_quarter,
        ]
        .map(|v| v.to_bits())
    }

    /// The model from the finger and the words of [`Model::to_raw`] (a build-time constant:
    /// no floating point).
    pub const fn from_raw(finger: Finger, w: &[i64; MODEL_RAW_WORDS]) -> Self {
        use crate::fixed::Fx32;
        Self {
            finger,
            l1: Fx32::from_bits(w[0]),
            l2: Fx32::from_bits(w[1]),
            phi2_minus_pi: Fx32::from_bits(w[2]),
            theta01: Fx32::from_bits(w[3]),
            theta02: Fx32::from_bits(w[4]),
            k1: Fx32::from_bits(w[5]),
            k2: Fx32::from_bits(w[6]),
            z1: Fx32::from_bits(w[7]),
            z2: Fx32::from_bits(w[8]),
            z3: Fx32::from_bits(w[9]),
            cos_scale: Fx32::from_bits(w[10]),
            two_l2: Fx32::from_bits(w[11]),
            k1_half: Fx32::from_bits(w[12]),
            k1_quarter: Fx32::from_bits(w[13]),
        }
    }
}

/// k·x for a constant k, as an addition when k = 2.
#[inline(always)]
fn times_const<R: Real>(x: R, k: f64) -> R {
    if k == 2.0 {
        x + x
    } else {
        R::from_f64(k) * x
    }
}

/// `angle` (rad) shifted by a whole turn to lie within π of `prev`.
fn continuous<R: Real>(angle: R, prev: R) -> R {
    let (pi, turn) = (
        R::from_f64(core::f64::consts::PI),
        R::from_f64(2.0 * core::f64::consts::PI),
    );
    let d = angle - prev;
    if d > pi {
        angle - turn
    } else if d < -pi {
        angle + turn
    } else {
        angle
    }
}

fn clamp_step<R: Real>(step: R) -> R {
    // Newton steps larger than 0.5 rad leave the basin; limit them.
    let lim = R::from_f64(0.5);
    step.max(-lim).min(lim)
}
