//! Quasi-static kinetostatics of the massless finger against one fixed object and its joint stops.
//!
//! Formulation (independent of the estimator's closed forms): the configuration at a given
//! actuator angle θa minimises the spring energy `½K1(θ1−θ01)² + ½K2(θ2−θ02)²` subject to the
//! linkage `θa = θ1 + φ(θ2)` and the unilateral constraints `g_c(θ1, θ2) ≥ 0` (object gap to each
//! phalanx, four joint stops). With `J_c = −∇g_c` and a multiplier `λ_c ≥ 0` the stationarity
//! conditions are the virtual-work balance
//!
//! ```text
//!   T_a · 1  = K1(θ1 − θ01) + λ J_c1
//!   T_a · x2 = K2(θ2 − θ02) + λ J_c2
//! ```
//!
//! For a contact, `J = n̂·∂p/∂θ` where `p` is the material contact point and `n̂` the normal
//! toward the object: on the phalanx interior that is `[l1 cos θ2 + k2, k2]` (distal) or
//! `[k1, 0]` (proximal). Everything reduces to one unknown θ2 (θ1 = θa − φ(θ2)):
//! free motion solves `K1(θa − φ − θ01)x2 = K2(θ2 − θ02)`, one active constraint solves
//! `g_c = 0` (Newton, `dg/dθ2 = x2 J1 − J2`), then T_a and λ follow from the 2×2 balance.
//! Two active constraints lock the finger: it then behaves as a stiff spring `k_lock`.

use crate::geom::{FingerGeom, Linkage, V2};
use crate::PlantError;

/// Which phalanx.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phalanx {
    /// O1→O2.
    Proximal,
    /// O2→tip.
    Distal,
}

impl Phalanx {
    /// 1 or 2 (as in `pts eval`).
    pub const fn index(self) -> u8 {
        match self {
            Phalanx::Proximal => 1,
            Phalanx::Distal => 2,
        }
    }
    /// The other phalanx.
    pub const fn other(self) -> Phalanx {
        match self {
            Phalanx::Proximal => Phalanx::Distal,
            Phalanx::Distal => Phalanx::Proximal,
        }
    }
    /// Lower-case name.
    pub const fn name(self) -> &'static str {
        match self {
            Phalanx::Proximal => "proximal",
            Phalanx::Distal => "distal",
        }
    }
}

/// A fixed object in the finger plane: a cylinder of radius `radius_m` centred at (x, y),
/// or a vertex (a point) when `radius_m == 0`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Object {
    /// Centre x in the world frame at O1 (m).
    pub x_m: f64,
    /// Centre y in the world frame at O1 (m).
    pub y_m: f64,
    /// Radius (m); 0 for a vertex.
    pub radius_m: f64,
}

/// One unilateral constraint of the finger.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Constraint {
    /// The object touches this phalanx.
    Contact(Phalanx),
    /// θ1 at its lower stop.
    Theta1Min,
    /// θ1 at its upper stop.
    Theta1Max,
    /// θ2 at its lower stop.
    Theta2Min,
    /// θ2 at its upper stop.
    Theta2Max,
}

impl Constraint {
    /// All constraints, in a fixed order (index = `slot()`).
    pub const ALL: [Constraint; 6] = [
        Constraint::Contact(Phalanx::Proximal),
        Constraint::Contact(Phalanx::Distal),
        Constraint::Theta1Min,
        Constraint::Theta1Max,
        Constraint::Theta2Min,
        Constraint::Theta2Max,
    ];
    /// Index in [`Constraint::ALL`].
    pub const fn slot(self) -> usize {
        match self {
            Constraint::Contact(Phalanx::Proximal) => 0,
            Constraint::Contact(Phalanx::Distal) => 1,
            Constraint::Theta1Min => 2,
            Constraint::Theta1Max => 3,
            Constraint::Theta2Min => 4,
            Constraint::Theta2Max => 5,
        }
    }
    /// Lower-case name.
    pub const fn name(self) -> &'static str {
        match self {
            Constraint::Contact(Phalanx::Proximal) => "contact_proximal",
            Constraint::Contact(Phalanx::Distal) => "contact_distal",
            Constraint::Theta1Min => "theta1_min",
            Constraint::Theta1Max => "theta1_max",
            Constraint::Theta2Min => "theta2_min",
            Constraint::Theta2Max => "theta2_max",
        }
    }
}

/// Gap and generalized direction of one constraint at one configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gap {
    /// Gap (m for contacts, rad for stops); negative means penetration.
    pub gap: f64,
    /// `J = −∇g` w.r.t. (θ1, θ2): (m, m) for contacts, dimensionless for stops.
    pub j: [f64; 2],
    /// Contact location along the phalanx from its lower joint (m), unclamped projection of the
    /// object centre; 0 for stops.
    pub k_m: f64,
    /// The object centre is on the phalanx's left (flexion) side, where contacts are modelled;
    /// always true for stops. An object behind a phalanx never starts a contact.
    pub left: bool,
}

/// Which constraints hold the finger.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Active {
    /// Free motion.
    None,
    /// One constraint active.
    One(Constraint),
    /// Two constraints active: the finger is locked and acts as a stiff spring.
    Two {
        /// The constraint that became active first.
        first: Constraint,
        /// The one that locked the finger.
        second: Constraint,
        /// θa at the lock (rad).
        theta_a_rad: f64,
        /// T_a at the lock (N·m).
        torque_nm: f64,
        /// Direction θa moved into the lock (+1 flexion, −1 extension); the lock holds while
        /// (θa − θa,lock)·dir ≥ 0.
        dir: i8,
    },
}

/// A solved quasi-static configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Actuator angle θa (rad, absolute model angle).
    pub theta_a_rad: f64,
    /// Proximal angle θ1 (rad, absolute).
    pub theta1_rad: f64,
    /// Distal angle θ2 (rad, relative).
    pub theta2_rad: f64,
    /// Torque the finger needs at the base link (N·m).
    pub torque_nm: f64,
    /// Transmission x2 at θ2.
    pub x2: f64,
    /// Multiplier of the active constraint: contact force (N) or stop torque (N·m); 0 if free.
    pub lambda: f64,
    /// Contact location (m) on the active contact's phalanx (unclamped projection), else 0.
    pub k_m: f64,
    /// Active set.
    pub active: Active,
}

/// The finger with its object: the quasi-static solver.
#[derive(Clone, Copy, Debug)]
pub struct Kin {
    /// Geometry.
    pub finger: FingerGeom,
    /// The object, if any.
    pub object: Option<Object>,
}

/// Newton iteration budget.
const MAX_ITER: usize = 60;
/// Convergence tolerance on θ2 (rad).
const TOL_THETA: f64 = 1e-12;
/// Largest Newton step (rad).
const MAX_STEP: f64 = 0.1;

impl Kin {
    /// Solver for `finger` against `object`.
    pub const fn new(finger: FingerGeom, object: Option<Object>) -> Self {
        Self { finger, object }
    }

    /// θa at (θ1, θ2) (rad).
    pub fn theta_a(&self, theta1_rad: f64, theta2_rad: f64) -> Result<f64, PlantError> {
        Ok(theta1_rad + self.finger.linkage(theta2_rad)?.phi_rad)
    }

    /// Free-motion θ2 for a given θ1 (θ1 ↦ T_a = K1(θ1 − θ01), then `T_a x2 = K2(θ2 − θ02)`).
    pub fn free_theta2_at_theta1(&self, theta1_rad: f64) -> Result<f64, PlantError> {
        let f = &self.finger;
        let ta = f.k1_nm_per_rad * (theta1_rad - f.theta01_rad);
        // G(θ2) = T x2 − K2(θ2 − θ02); the K2 term dominates dG/dθ2.
        newton(f.theta02_rad, |t2| {
            let l = f.linkage(t2)?;
            Ok((
                ta * l.x2 - f.k2_nm_per_rad * (t2 - f.theta02_rad),
                -f.k2_nm_per_rad,
            ))
        })
    }

    /// World positions: (O2, unit along proximal, unit along distal).
    fn frames(&self, theta1: f64, theta2: f64) -> (V2, V2, V2) {
        let u1 = V2::unit_at(theta1);
        let u2 = V2::unit_at(theta1 + theta2);
        (u1.scale(self.finger.l1_m), u1, u2)
    }

    /// Point on `phalanx` at distance `k_m` from its lower joint (m, world frame).
    pub fn point_on(&self, phalanx: Phalanx, theta1: f64, theta2: f64, k_m: f64) -> V2 {
        let (o2, u1, u2) = self.frames(theta1, theta2);
        match phalanx {
            Phalanx::Proximal => u1.scale(k_m),
            Phalanx::Distal => o2.add(u2.scale(k_m)),
        }
    }

    /// Gap of one constraint at (θ1, θ2); `None` for a contact when there is no object.
    pub fn gap(&self, c: Constraint, theta1: f64, theta2: f64) -> Option<Gap> {
        self.gap_ext(c, theta1, theta2, false)
    }

    /// Gaps of all constraints at one configuration (index = [`Constraint::slot`]), sharing
    /// the trigonometry of the two phalanx frames.
    pub fn gaps(&self, theta1: f64, theta2: f64) -> [Option<Gap>; 6] {
        let fr = self.frames(theta1, theta2);
        let mut out = [None; 6];
        for (slot, c) in out.iter_mut().zip(Constraint::ALL) {
            *slot = self.gap_with(c, theta1, theta2, false, fr);
        }
        out
    }

    /// [`Kin::gap`]; with `line` the contact gap is the signed distance to the phalanx's whole
    /// line (the segment extended past both ends), used to locate a contact leaving its phalanx.
    pub fn gap_ext(&self, c: Constraint, theta1: f64, theta2: f64, line: bool) -> Option<Gap> {
        let fr = match c {
            Constraint::Contact(_) => self.frames(theta1, theta2),
            _ => (V2::default(), V2::default(), V2::default()),
        };
        self.gap_with(c, theta1, theta2, line, fr)
    }

    fn gap_with(
        &self,
        c: Constraint,
        theta1: f64,
        theta2: f64,
        line: bool,
        (o2, u1, u2): (V2, V2, V2),
    ) -> Option<Gap> {
        let f = &self.finger;
        let stop = |gap: f64, j: [f64; 2]| {
            Some(Gap {
                gap,
                j,
                k_m: 0.0,
                left: true,
            })
        };
        match c {
            Constraint::Theta1Min => stop(theta1 - f.theta1_min_rad, [-1.0, 0.0]),
            Constraint::Theta1Max => stop(f.theta1_max_rad - theta1, [1.0, 0.0]),
            Constraint::Theta2Min => stop(theta2 - f.theta2_min_rad, [0.0, -1.0]),
            Constraint::Theta2Max => stop(f.theta2_max_rad - theta2, [0.0, 1.0]),
            Constraint::Contact(ph) => {
                let obj = self.object?;
                let (base, u, len) = match ph {
                    Phalanx::Proximal => (V2::new(0.0, 0.0), u1, f.l1_m),
                    Phalanx::Distal => (o2, u2, f.l2_m),
                };
                let n = u.perp();
                let centre = V2::new(obj.x_m, obj.y_m);
                let r = centre.sub(base);
                let k = r.dot(u);
                let h = r.dot(n);
                let (gap, nhat, p) = if line || (0.0..=len).contains(&k) {
                    (h - obj.radius_m, n, base.add(u.scale(k)))
                } else {
                    let kc = k.clamp(0.0, len);
                    let q = base.add(u.scale(kc));
                    let e = centre.sub(q);
                    let dist = e.norm();
                    let dir = if dist > 1e-15 { e.scale(1.0 / dist) } else { n };
                    // Past an end the object meets the phalanx's corner. Only from the left
                    // (h ≥ 0): once the centre crosses the phalanx line the corner has slid over
                    // the object and leaves it (a vertex: at once, zero radius).
                    if h >= 0.0 {
                        (dist - obj.radius_m, dir, q)
                    } else {
                        (dist, dir, q)
                    }
                };
                // Material velocities of p: rotation about O1 (θ1) and about O2 (θ2, distal only).
                let dp1 = p.perp();
                let dp2 = match ph {
                    Phalanx::Proximal => V2::new(0.0, 0.0),
                    Phalanx::Distal => p.sub(o2).perp(),
                };
                Some(Gap {
                    gap,
                    j: [nhat.dot(dp1), nhat.dot(dp2)],
                    k_m: k,
                    left: h >= 0.0,
                })
            }
        }
    }

    /// Solves the configuration at θa with the given active set, starting Newton from `theta2_guess`.
    pub fn solve(
        &self,
        theta_a_rad: f64,
        active: Active,
        theta2_guess: f64,
    ) -> Result<Pose, PlantError> {
        if !theta_a_rad.is_finite() || theta_a_rad.abs() > 10.0 {
            return Err(PlantError::NonFinite);
        }
        let f = &self.finger;
        let guess = if theta2_guess.is_finite() {
            theta2_guess
        } else {
            f.theta02_rad
        };
        match active {
            Active::None => {
                let (t2, l) = newton_eval(guess, true, |t2| {
                    let l = f.linkage(t2)?;
                    let a = f.k1_nm_per_rad * (theta_a_rad - l.phi_rad - f.theta01_rad);
                    let val = a * l.x2 - f.k2_nm_per_rad * (t2 - f.theta02_rad);
                    // dF/dθ2 without the small dx2/dθ2 term: always negative, Newton stays safe.
                    Ok((val, -(f.k1_nm_per_rad * l.x2 * l.x2 + f.k2_nm_per_rad), l))
                })?;
                let t1 = theta_a_rad - l.phi_rad;
                Ok(Pose {
                    theta_a_rad,
                    theta1_rad: t1,
                    theta2_rad: t2,
                    torque_nm: f.k1_nm_per_rad * (t1 - f.theta01_rad),
                    x2: l.x2,
                    lambda: 0.0,
                    k_m: 0.0,
                    active,
                })
            }
            Active::One(c) => self.solve_one(theta_a_rad, c, guess, false),
            Active::Two {
                first,
                theta_a_rad: ta_lock,
                torque_nm,
                ..
            } => {
                // Locked: geometry frozen at the lock; re-solve the first constraint at the lock
                // angle to report where the finger is.
                let mut p = self.balance_at_lock(ta_lock, first, guess)?;
                p.theta_a_rad = theta_a_rad;
                p.torque_nm = torque_nm + f.k_lock_nm_per_rad * (theta_a_rad - ta_lock);
                p.active = active;
                Ok(p)
            }
        }
    }

    /// One active constraint at θa; `line` as in [`Kin::gap_ext`].
    pub fn solve_one(
        &self,
        theta_a_rad: f64,
        c: Constraint,
        theta2_guess: f64,
        line: bool,
    ) -> Result<Pose, PlantError> {
        let f = &self.finger;
        let (t2, (l, g)) = newton_eval(theta2_guess, false, |t2| {
            let l = f.linkage(t2)?;
            let t1 = theta_a_rad - l.phi_rad;
            let g = self
                .gap_ext(c, t1, t2, line)
                .ok_or(PlantError::BadPlacement)?;
            Ok((g.gap, l.x2 * g.j[0] - g.j[1], (l, g)))
        })?;
        self.balance_from(theta_a_rad, t2, c, l, g)
    }

    fn balance_at_lock(&self, ta: f64, c: Constraint, guess: f64) -> Result<Pose, PlantError> {
        let f = &self.finger;
        let t2 = newton(guess, |t2| {
            let l = f.linkage(t2)?;
            let g = self
                .gap(c, ta - l.phi_rad, t2)
                .ok_or(PlantError::BadPlacement)?;
            Ok((g.gap, l.x2 * g.j[0] - g.j[1]))
        })?;
        self.balance(ta, t2, c)
    }

    /// T_a and λ from the 2×2 virtual-work balance with constraint `c` active at θ2.
    pub fn balance(
        &self,
        theta_a_rad: f64,
        theta2_rad: f64,
        c: Constraint,
    ) -> Result<Pose, PlantError> {
        self.balance_ext(theta_a_rad, theta2_rad, c, false)
    }

    fn balance_ext(
        &self,
        theta_a_rad: f64,
        theta2_rad: f64,
        c: Constraint,
        line: bool,
    ) -> Result<Pose, PlantError> {
        let l = self.finger.linkage(theta2_rad)?;
        let t1 = theta_a_rad - l.phi_rad;
        let g = self
            .gap_ext(c, t1, theta2_rad, line)
            .ok_or(PlantError::BadPlacement)?;
        self.balance_from(theta_a_rad, theta2_rad, c, l, g)
    }

    /// The balance with the linkage and gap already evaluated at θ2.
    fn balance_from(
        &self,
        theta_a_rad: f64,
        theta2_rad: f64,
        c: Constraint,
        l: Linkage,
        g: Gap,
    ) -> Result<Pose, PlantError> {
        let f = &self.finger;
        let t1 = theta_a_rad - l.phi_rad;
        let a = f.k1_nm_per_rad * (t1 - f.theta01_rad);
        let b = f.k2_nm_per_rad * (theta2_rad - f.theta02_rad);
        let d = l.x2 * g.j[0] - g.j[1];
        if !(d.abs() > 1e-12) {
            return Err(PlantError::Singular);
        }
        let torque = (g.j[0] * b - g.j[1] * a) / d;
        let lambda = (b - l.x2 * a) / d;
        if !torque.is_finite() || !lambda.is_finite() {
            return Err(PlantError::NonFinite);
        }
        Ok(Pose {
            theta_a_rad,
            theta1_rad: t1,
            theta2_rad,
            torque_nm: torque,
            x2: l.x2,
            lambda,
            k_m: if matches!(c, Constraint::Contact(_)) {
                g.k_m
            } else {
                0.0
            },
            active: Active::One(c),
        })
    }

    /// The rest pose (T_a = 0, free): θa,rest (rad).
    pub fn rest(&self) -> Result<Pose, PlantError> {
        let f = &self.finger;
        let t2 = self.free_theta2_at_theta1(f.theta01_rad)?;
        let ta = self.theta_a(f.theta01_rad, t2)?;
        self.solve(ta, Active::None, t2)
    }
}

/// Newton step size below which the evaluated point is accepted (rad). The point returned is
/// the last one evaluated (so its payload is exact there): its error is below this step.
const TOL_EVAL: f64 = 1e-11;

/// Newton that returns the last evaluated point with the payload computed there (no extra
/// evaluation to rebuild the solution). With `secant`, the given derivative is treated as an
/// approximation and replaced by the secant slope once two iterates are far enough apart.
pub(crate) fn newton_eval<P>(
    x0: f64,
    secant: bool,
    mut f: impl FnMut(f64) -> Result<(f64, f64, P), PlantError>,
) -> Result<(f64, P), PlantError> {
    let mut x = x0;
    let mut prev: Option<(f64, f64)> = None;
    for _ in 0..MAX_ITER {
        let (v, d_given, payload) = f(x)?;
        if !v.is_finite() || !d_given.is_finite() {
            return Err(PlantError::NonFinite);
        }
        let mut d = d_given;
        if let (true, Some((xp, vp))) = (secant, prev) {
            let dx = x - xp;
            if dx.abs() > 1e-9 {
                let s = (v - vp) / dx;
                if s * d_given > 0.0 && (s / d_given) > 0.2 && (s / d_given) < 5.0 {
                    d = s;
                }
            }
        }
        if !(d.abs() > 1e-300) {
            return Err(PlantError::Singular);
        }
        let step = (v / d).clamp(-MAX_STEP, MAX_STEP);
        if step.abs() < TOL_EVAL {
            return Ok((x, payload));
        }
        prev = Some((x, v));
        x -= step;
    }
    Err(PlantError::NoConvergence)
}

/// Safeguarded Newton on a scalar function returning (value, derivative).
pub(crate) fn newton(
    x0: f64,
    mut f: impl FnMut(f64) -> Result<(f64, f64), PlantError>,
) -> Result<f64, PlantError> {
    let mut x = x0;
    for _ in 0..MAX_ITER {
        let (v, d) = f(x)?;
        if !v.is_finite() || !d.is_finite() {
            return Err(PlantError::NonFinite);
        }
        if !(d.abs() > 1e-300) {
            return Err(PlantError::Singular);
        }
        let step = (v / d).clamp(-MAX_STEP, MAX_STEP);
        x -= step;
        if step.abs() < TOL_THETA {
            return Ok(x);
        }
    }
    Err(PlantError::NoConvergence)
}
