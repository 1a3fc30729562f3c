//! The estimator's own model of the quasi-static contact path (used by [`crate`]).
//!
//! After contact on the distal phalanx at k2,c the object is fixed: a vertex (R = 0) or a
//! cylinder of radius R tangent to the phalanx at the contact point, on its flexion side.
//! Written in the frame of the distal phalanx at contact (unit vectors u along the phalanx,
//! n its left normal), with O1 at the origin, the contact constraint has a closed form in the
//! rotation δφ of the distal phalanx and the change δ2 of θ2:
//!
//! ```text
//! E1 = sin(θ2c+δ2) − sin(θ2c+δφ) − (k2c sin δφ + R (1 − cos δφ))/l1 = 0   (tangency)
//! E2 = δφ − (γ(θ2c+δ2) − γc) − Δθa = 0                                   (θa = θ1+θ2−φ2−γ)
//! k2 = l1 (cos(θ2c+δφ) − cos θ2) + k2c cos δφ + R sin δφ                  (contact point)
//! ```
//!
//! and the equilibrium with the contact force f eliminated
//! (`T_a = K1 Δ1 + f L`, `T_a x2 = K2 Δ2 + f k2`, `L = l1 cos θ2 + k2`) gives
//! `T_a = (K1 Δ1 k2 − K2 Δ2 L) / (k2 − x2 L)`.
//!
//! Only small angles (|δ| ≤ [`MAX_DELTA`]) enter the trigonometry, through polynomials; the
//! four-bar closure γ(θ2), x2(θ2) comes from a lazily filled table of exact closures with
//! cubic Hermite interpolation between nodes [`NODE_STEP`] apart. So a path evaluation costs
//! multiplications and a few divisions, no library trigonometry.

use pts::{Config, Model, PtsError, Real};

/// Spacing of the closure table nodes in θ2 (rad). A power of two: exact in fixed point.
pub const NODE_STEP: f64 = 0.125;
/// Nodes below θ2,c in the table.
const NODES_BELOW: usize = 2;
/// Total nodes: θ2 ∈ [θ2,c − 0.25, θ2,c + 1.375] rad.
pub const NODES: usize = 14;
/// Largest |δφ|, |δ2| (rad) the polynomials and the table accept along a path.
pub const MAX_DELTA: f64 = 1.25;
/// Newton iterations per path point (a warm-started solve needs 1–2).
pub const MAX_PATH_NEWTON: usize = 8;
/// A Newton step below this (rad) ends the solve; it is applied to the outputs to first order
/// (remainder ~step² < 4e-6 rad, an eighth of an encoder count). 5e-4 → 1e-3 → 2e-3 left the
/// plant grid's accuracy unchanged at its printed precision and took the integer kernel's
/// worst realistic request from 109k to 102k instructions.
pub const ACCEPT_STEP: f64 = 2e-3;
/// Newton step (rad) below which a free-motion solve (the contact configuration) ends.
pub const FREE_TOL: f64 = 5e-6;

/// sin and cos of a small angle |x| ≤ [`MAX_DELTA`] by Taylor polynomials in Horner form
/// in x² (error < 3e-7 at 1.25 rad, < 6e-9 below 0.5 rad).
pub fn sin_cos_small<R: Real>(x: R, c: &PolyConsts<R>) -> (R, R) {
    let x2 = x * x;
    if x2 < c.quarter {
        // |x| < 0.5 (every step of a path point): two terms fewer, error < 6e-9
        // (x⁹/9! at 0.5), below f32's resolution.
        let s = x + x * (x2 * (c.s[0] + x2 * (c.s[1] + x2 * c.s[2])));
        let k = R::one() + x2 * (c.c[0] + x2 * (c.c[1] + x2 * (c.c[2] + x2 * c.c[3])));
        return (s, k);
    }
    let s = x + x * (x2 * (c.s[0] + x2 * (c.s[1] + x2 * (c.s[2] + x2 * c.s[3]))));
    let k = R::one() + x2 * (c.c[0] + x2 * (c.c[1] + x2 * (c.c[2] + x2 * (c.c[3] + x2 * c.c[4]))));
    (s, k)
}

/// Polynomial coefficients, converted once per back end.
#[derive(Clone, Copy, Debug)]
pub struct PolyConsts<R> {
    quarter: R,
    /// −1/3!, 1/5!, −1/7!, 1/9!.
    s: [R; 4],
    /// −1/2!, 1/4!, −1/6!, 1/8!, −1/10!.
    c: [R; 5],
}

impl<R: Real> PolyConsts<R> {
    /// Converts the coefficients.
    pub fn new() -> Self {
        let f = |d: f64| R::from_f64(1.0 / d);
        Self {
            quarter: f(4.0),
            s: [f(-6.0), f(120.0), f(-5040.0), f(362_880.0)],
            c: [f(-2.0), f(24.0), f(-720.0), f(40_320.0), f(-3_628_800.0)],
        }
    }
}

impl<R: Real> Default for PolyConsts<R> {
    fn default() -> Self {
        Self::new()
    }
}

/// γ, x2 and dx2/dθ2 at one θ2 node.
#[derive(Clone, Copy, Debug)]
struct Node<R> {
    gamma: R,
    x2: R,
    dx2: R,
}

/// The contact configuration and everything a path evaluation needs, built once per contact.
#[derive(Clone, Copy, Debug)]
pub struct PathModel<R> {
    /// The free-motion configuration at θa,c (the contact configuration).
    pub contact: Config<R>,
    /// θa,c of that configuration (rad).
    pub theta_a_c: R,
    /// Free-motion stiffness at contact (N·m/rad).
    pub kfree: R,
    /// θ2 of the closure table's reference node (rad).
    theta2b: R,
    /// θ2,c − θ2b (rad).
    off: R,
    phi2: R,
    theta01: R,
    theta02: R,
    /// θ1 at contact (rad).
    pub theta1c: R,
    /// θ2 at contact (rad).
    pub theta2c: R,
    /// T_a of the free-motion equilibrium at contact (N·m).
    pub tac: R,
    s2c: R,
    c2c: R,
    s2b: R,
    c2b: R,
    gamma_c: R,
    d1c: R,
    d2c: R,
    l1: R,
    inv_l1: R,
    /// Coulomb friction coefficient at the object contact (see `PathFitConfig::contact_mu`).
    mu: R,
    l2: R,
    k1: R,
    k2: R,
    h: R,
    inv_h: R,
    max_delta: R,
    accept: R,
    eps_det: R,
    eps_den: R,
    eps_force: R,
    two: R,
    three: R,
    nodes: [Option<Node<R>>; NODES],
    /// Index of the table segment last interpolated and its cubics' coefficients (γ then x2).
    seg_index: usize,
    seg: [R; 8],
    /// sin, cos of λ = θ2 − φ2 + π at the reference node (the closure's angle).
    slb: R,
    clb: R,
    /// sin, cos of the node step h.
    sh: R,
    ch: R,
    /// Loop constants ζ1, ζ2, ζ3 of the closure (MODEL.md "Assembly branch").
    z1: R,
    z2: R,
    z3: R,
    /// Closure evaluations done so far (cost accounting).
    pub closures: u16,
    /// Newton iterations done so far (cost accounting).
    pub newton_iters: u32,
    pc: PolyConsts<R>,
}

/// One solved point of the path with its first-order sensitivities.
#[derive(Clone, Copy, Debug)]
pub struct PathPoint<R> {
    /// Rotation of the distal phalanx since contact (rad).
    pub dphi: R,
    /// Change of θ2 since contact (rad).
    pub d2: R,
    /// Contact location from O2 (m).
    pub k2: R,
    /// Actuator torque of the equilibrium (N·m).
    pub ta: R,
    /// Contact force times k2 (N·m): negative means the contact would open.
    pub fk2: R,
    /// ∂T_a/∂k2,c at fixed θa (N·m per m).
    pub dta_dk2c: R,
    /// ∂T_a/∂R at fixed θa (N·m per m).
    pub dta_dr: R,
    /// dT_a/dθa along the path (N·m/rad).
    pub stiffness: R,
    /// dδφ/dθa, dδ2/dθa along the path.
    pub tangent: (R, R),
    /// ∂(δφ, δ2)/∂k2,c at fixed θa (rad/m).
    pub sens_k: (R, R),
    /// ∂(δφ, δ2)/∂R at fixed θa (rad/m).
    pub sens_r: (R, R),
}

/// Why a path point cannot be computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PathFail {
    /// The model failed (closure, toggle, overflow).
    Model(PtsError),
    /// The contact point left the distal phalanx past the tip.
    PastTip,
    /// The contact point reached O2 (k2 ≤ 0).
    PastJoint,
    /// The contact force would be negative: the object does not hold the finger.
    ContactOpens,
    /// The angles left the range of the polynomials/table, or the locking point was reached.
    OutOfRange,
    /// The Newton solve did not converge in its budget.
    NoConvergence,
}

impl From<PtsError> for PathFail {
    fn from(e: PtsError) -> Self {
        PathFail::Model(e)
    }
}

impl<R: Real> PathModel<R> {
    /// Builds the path model at the contact configuration found by free motion from θa,c.
    pub fn new(model: &Model<R>, theta_a_c: R) -> Result<Self, PtsError> {
        let f = model.finger;
        let conv = |v: f64| R::try_from_f64(v).ok_or(PtsError::OutOfRange);
        let pc = PolyConsts::new();
        let z1 = (f.l1 * f.l1 + f.c * f.c + f.a * f.a - f.b * f.b) / (2.0 * f.a * f.l1);
        let z = [conv(z1)?, conv(f.c / f.l1)?, conv(f.c / f.a)?];
        // The contact configuration (free motion at θa,c) and sin, cos of its θ2 and λ without
        // library trigonometry (libm's sinf/cosf run in soft double on a Cortex-M4F: ~25 k
        // instructions for `Model::free_from_theta_a`'s four closures).
        let (cfg, (s2, c2), (slb, clb)) = if f.k1 > 0.0 {
            free_trig_free(model, &z, &pc, theta_a_c)?
        } else {
            let cfg = model.free_from_theta_a(theta_a_c)?;
            let lambda_b = cfg.theta2 - conv(f.phi2 - core::f64::consts::PI)?;
            (
                cfg,
                (cfg.theta2.sin(), cfg.theta2.cos()),
                (lambda_b.sin(), lambda_b.cos()),
            )
        };
        // γ at contact from θa = θ1 + θ2 − φ2 − γ: no closure needed.
        let gamma_c = cfg.theta1 + cfg.theta2 - conv(f.phi2)? - theta_a_c;
        let mut nodes = [None; NODES];
        if let Some(slot) = nodes.get_mut(NODES_BELOW) {
            *slot = Some(Node {
                gamma: gamma_c,
                x2: cfg.x2,
                dx2: cfg.dx2,
            });
        }
        let k2p = conv(f.k2)? - cfg.ta * cfg.dx2;
        let k1 = conv(f.k1)?;
        let kfree = k1 * k2p / (k2p + k1 * cfg.x2 * cfg.x2);
        let (sh, ch) = sin_cos_small(conv(NODE_STEP)?, &pc);
        Ok(Self {
            contact: cfg,
            theta_a_c,
            kfree,
            theta2b: cfg.theta2,
            off: R::zero(),
            phi2: conv(f.phi2)?,
            theta01: conv(f.theta01)?,
            theta02: conv(f.theta02)?,
            theta1c: cfg.theta1,
            theta2c: cfg.theta2,
            tac: cfg.ta,
            s2c: s2,
            c2c: c2,
            s2b: s2,
            c2b: c2,
            gamma_c,
            d1c: cfg.theta1 - conv(f.theta01)?,
            d2c: cfg.theta2 - conv(f.theta02)?,
            l1: conv(f.l1)?,
            inv_l1: conv(1.0 / f.l1)?,
            mu: R::zero(),
            l2: conv(f.l2)?,
            k1: conv(f.k1)?,
            k2: conv(f.k2)?,
            h: conv(NODE_STEP)?,
            inv_h: conv(1.0 / NODE_STEP)?,
            max_delta: conv(MAX_DELTA)?,
            accept: conv(ACCEPT_STEP)?,
            eps_det: conv(1e-6)?,
            eps_den: conv(1e-9)?,
            eps_force: conv(1e-6)?,
            two: conv(2.0)?,
            three: conv(3.0)?,
            nodes,
            seg_index: usize::MAX,
            seg: [R::zero(); 8],
            slb,
            clb,
            sh,
            ch,
            z1: z[0],
            z2: z[1],
            z3: z[2],
            closures: 0,
            newton_iters: 0,
            pc,
        })
    }

    /// Sets the Coulomb friction coefficient µ at the object contact (0 at construction):
    /// the path's moment arm at O1 becomes L = l1 (cos θ2 − µ sin θ2) + k2.
    pub fn set_contact_mu(&mut self, mu: R) {
        self.mu = mu;
    }

    /// Moves the contact to another θa,c (the closure table is kept: it is indexed by θ2).
    pub fn set_contact(&mut self, model: &Model<R>, theta_a_c: R) -> Result<(), PtsError> {
        let cfg = if self.k1 > R::zero() {
            self.free_near(model, theta_a_c)?
        } else {
            model.free_from_theta_a(theta_a_c)?
        };
        self.gamma_c = cfg.theta1 + cfg.theta2 - self.phi2 - theta_a_c;
        let k2p = self.k2 - cfg.ta * cfg.dx2;
        self.kfree = self.k1 * k2p / (k2p + self.k1 * cfg.x2 * cfg.x2);
        self.contact = cfg;
        self.theta_a_c = theta_a_c;
        self.off = cfg.theta2 - self.theta2b;
        self.theta1c = cfg.theta1;
        self.theta2c = cfg.theta2;
        self.tac = cfg.ta;
        // sin/cos θ2c from the reference node by angle addition (no library trigonometry).
        let (so, co) = sin_cos_small(self.off, &self.pc);
        self.s2c = self.s2b * co + self.c2b * so;
        self.c2c = self.c2b * co - self.s2b * so;
        self.d1c = cfg.theta1 - self.theta01;
        self.d2c = cfg.theta2 - self.theta02;
        Ok(())
    }

    /// Free motion at θa (the same equilibrium as [`Model::free_from_theta_a`]: g(θ2) =
    /// K2(θ2 − θ02) − K1(θ1 − θ01) x2 = 0, θ1 = θa − θ2 + φ2 + γ), by Newton from the current
    /// contact's θ2 on the closure table: no trigonometry, 1–2 steps for a nearby θa.
    fn free_near(&mut self, model: &Model<R>, theta_a: R) -> Result<Config<R>, PtsError> {
        let to_pts = |e: PathFail| match e {
            PathFail::Model(p) => p,
            _ => PtsError::OutOfRange,
        };
        let mut th2 = self.theta2c;
        let tol = R::from_f64(FREE_TOL);
        let mut it = 0usize;
        while it < MAX_PATH_NEWTON {
            it += 1;
            let (gamma, x2, dx2) = self.interp(model, th2 - self.theta2b).map_err(to_pts)?;
            let th1 = theta_a - th2 + self.phi2 + gamma;
            let ta = self.k1 * (th1 - self.theta01);
            let g = self.k2 * (th2 - self.theta02) - ta * x2;
            let dg = self.k2 - ta * dx2 + self.k1 * x2 * x2;
            if !(dg > self.eps_det) {
                return Err(PtsError::NoConvergence);
            }
            let step = g / dg;
            if step.abs() <= tol {
                return Ok(Config {
                    theta1: th1,
                    theta2: th2,
                    theta_a,
                    ta,
                    x2,
                    dx2,
                });
            }
            th2 = th2 - step;
        }
        Err(PtsError::NoConvergence)
    }

    /// Distal phalanx length (m).
    pub fn l2(&self) -> R {
        self.l2
    }

    fn node(&mut self, _model: &Model<R>, i: usize) -> Result<Node<R>, PathFail> {
        match self.nodes.get(i) {
            Some(Some(n)) => return Ok(*n),
            Some(None) => {}
            None => return Err(PathFail::OutOfRange),
        }
        // sin, cos of λ at node i: the reference node's rotated by (i − NODES_BELOW) h
        // (≤ 13 exact rotations; no library trigonometry).
        let (mut sl, mut cl) = (self.slb, self.clb);
        let mut k = 0usize;
        while k < NODES_BELOW {
            (sl, cl) = (sl * self.ch - cl * self.sh, cl * self.ch + sl * self.sh);
            k += 1;
        }
        let mut k = 0usize;
        while k < i {
            (sl, cl) = (sl * self.ch + cl * self.sh, cl * self.ch - sl * self.sh);
            k += 1;
        }
        let n = closure_sc(&[self.z1, self.z2, self.z3], sl, cl)?;
        self.closures = self.closures.saturating_add(1);
        if let Some(slot) = self.nodes.get_mut(i) {
            *slot = Some(n);
        }
        Ok(n)
    }

    /// γ(θ2c+δ2) − γc, x2 and dx2/dθ2 by cubic Hermite interpolation of the table.
    fn closure_at(&mut self, model: &Model<R>, d2: R) -> Result<(R, R, R), PathFail> {
        let (gamma, x2, dx2) = self.interp(model, d2 + self.off)?;
        Ok((gamma - self.gamma_c, x2, dx2))
    }

    /// γ, x2, dx2/dθ2 at θ2 = θ2b + `d2` from the table (cubic Hermite).
    fn interp(&mut self, model: &Model<R>, d2: R) -> Result<(R, R, R), PathFail> {
        let mut lo = -(self.h + self.h);
        if !d2.is_finite() || d2 > self.max_delta || d2 < lo {
            return Err(PathFail::OutOfRange);
        }
        // Segment index: the first i with (i+1−NODES_BELOW) h > δ2.
        let mut i = 0usize;
        while i + 2 < NODES && d2 >= lo + self.h {
            lo = lo + self.h;
            i += 1;
        }
        if self.seg_index != i {
            let a = self.node(model, i)?;
            let b = self.node(model, i + 1)?;
            // Power-basis coefficients of the segment's two Hermite cubics in t = (θ2 − θ2,i)/h,
            // once per segment: γ with slopes 1 − x2, x2 with slopes dx2/dθ2.
            let (ma, mb) = ((R::one() - a.x2) * self.h, (R::one() - b.x2) * self.h);
            let dg = b.gamma - a.gamma;
            let (xa, xb) = (a.dx2 * self.h, b.dx2 * self.h);
            let dx = b.x2 - a.x2;
            self.seg = [
                a.gamma,
                ma,
                self.three * dg - self.two * ma - mb,
                ma + mb - self.two * dg,
                a.x2,
                xa,
                self.three * dx - self.two * xa - xb,
                xa + xb - self.two * dx,
            ];
            self.seg_index = i;
        }
        let t = (d2 - lo) * self.inv_h;
        let c = &self.seg;
        let gamma = c[0] + t * (c[1] + t * (c[2] + t * c[3]));
        let x2 = c[4] + t * (c[5] + t * (c[6] + t * c[7]));
        let dx2 = (c[5] + t * (self.two * c[6] + t * self.three * c[7])) * self.inv_h;
        Ok((gamma, x2, dx2))
    }

    /// The tangent of the path at (δφ, δ2) for (k2,c, R): dδ/dθa (rad/rad).
    pub fn tangent(
        &mut self,
        model: &Model<R>,
        k2c: R,
        radius: R,
        dphi: R,
        d2: R,
    ) -> Result<(R, R), PathFail> {
        let mut st = EvalState::zero();
        self.eval(model, k2c, radius, dphi, d2, &mut st)?;
        if !(st.det.abs() > self.eps_det) {
            return Err(PathFail::OutOfRange);
        }
        let inv = R::one() / st.det;
        Ok((-st.a12 * inv, st.a11 * inv))
    }

    /// Solves the path point at actuator displacement Δθa = `dta` (rad) since contact for the
    /// hypothesis (k2,c, R) (m), by Newton from the guess (δφ, δ2). The last Newton step, once
    /// below [`ACCEPT_STEP`] rad, is applied to the outputs to first order instead of paying
    /// one more evaluation (its second-order remainder, ~step², is below 3e-7 rad: a hundredth of
    /// an encoder count).
    pub fn point(
        &mut self,
        model: &Model<R>,
        k2c: R,
        radius: R,
        dta: R,
        guess: (R, R),
    ) -> Result<PathPoint<R>, PathFail> {
        let (mut dphi, mut d2) = guess;
        let mut it = 0usize;
        // Filled in place: a returned 14-value state is copied twice per step (memcpy).
        let mut st = EvalState::zero();
        while it < MAX_PATH_NEWTON {
            it += 1;
            self.newton_iters = self.newton_iters.saturating_add(1);
            self.eval(model, k2c, radius, dphi, d2, &mut st)?;
            let e1 = st.s2 - st.s2p - (k2c * st.sp + radius * (R::one() - st.cp)) * self.inv_l1;
            let e2 = dphi - st.dgamma - dta;
            if !(st.det.abs() > self.eps_det) {
                return Err(PathFail::OutOfRange);
            }
            // [a11 a12; a21 a22] [dδφ; dδ2] = −[e1; e2]
            let inv = R::one() / st.det;
            let sphi = -(st.a22 * e1 - st.a12 * e2) * inv;
            let s2 = -(st.a11 * e2 - st.a21 * e1) * inv;
            if sphi.abs() <= self.accept && s2.abs() <= self.accept {
                return self.outputs(k2c, radius, dphi, d2, &st, inv, (sphi, s2));
            }
            dphi = dphi + sphi;
            d2 = d2 + s2;
            if !dphi.is_finite() || dphi.abs() > self.max_delta {
                return Err(PathFail::OutOfRange);
            }
        }
        Err(PathFail::NoConvergence)
    }

    /// Outputs at the evaluated point (δφ, δ2) moved by the final Newton step `fin` to first
    /// order.
    #[allow(clippy::too_many_arguments)]
    fn outputs(
        &self,
        k2c: R,
        radius: R,
        dphi: R,
        d2: R,
        st: &EvalState<R>,
        inv: R,
        fin: (R, R),
    ) -> Result<PathPoint<R>, PathFail> {
        let lc = self.l1 * st.c2;
        let dk2_dphi = -self.l1 * st.s2p - k2c * st.sp + radius * st.cp;
        let dk2_d2 = self.l1 * st.s2;
        let k2 = self.l1 * (st.c2p - st.c2) + k2c * st.cp + radius * st.sp;
        let k2_fin = k2 + dk2_dphi * fin.0 + dk2_d2 * fin.1;
        if k2_fin > self.l2 {
            return Err(PathFail::PastTip);
        }
        if !(k2_fin > R::zero()) {
            return Err(PathFail::PastJoint);
        }
        // Friction µ f on the sliding contact acts at O1 through the material point's motion
        // along the phalanx, l1 sin θ2 per unit of θ1: L = l1 (cos θ2 − µ sin θ2) + k2.
        let l = lc - self.mu * self.l1 * st.s2 + k2;
        let dl_d2 = -self.mu * self.l1 * st.c2;
        let d1 = self.d1c + dphi - d2;
        let dd2 = self.d2c + d2;
        let num = self.k1 * d1 * k2 - self.k2 * dd2 * l;
        let den = k2 - st.x2 * l;
        if !(den.abs() > self.eps_den) {
            return Err(PathFail::OutOfRange);
        }
        let inv_den = R::one() / den;
        let ta = num * inv_den;
        // T_a is linear in a direction (dδφ, dδ2, dk2c, dR) to first order: its four partial
        // derivatives once, then a dot product per use (stiffness, sensitivities, last step).
        // dT = (dn − T·dden)/den with n = K1 Δ1 k2 − K2 Δ2 L, den = k2 − x2 L, L = l1 cos θ2 + k2.
        let t_phi = {
            let (dk2, dl) = (dk2_dphi, dk2_dphi);
            let dn = self.k1 * (k2 + d1 * dk2) - self.k2 * dd2 * dl;
            let dden = dk2 - st.x2 * dl;
            (dn - ta * dden) * inv_den
        };
        // Along δ2, k2 gains l1 sin θ2 and l1 cos θ2 + k2 stays put: ∂L/∂δ2 is the friction
        // arm's −µ l1 cos θ2.
        let t_2 = {
            let dk2 = dk2_d2;
            let dn = self.k1 * (d1 * dk2 - k2) - self.k2 * (l + dd2 * dl_d2);
            let dden = dk2 - l * st.dx2 - st.x2 * dl_d2;
            (dn - ta * dden) * inv_den
        };
        // ∂k2 = ∂L = cos δφ per k2c and sin δφ per R: both share one factor.
        let q = (self.k1 * d1 - self.k2 * dd2 - ta * (R::one() - st.x2)) * inv_den;
        let (t_k, t_r) = (q * st.cp, q * st.sp);
        let ta_fin = ta + t_phi * fin.0 + t_2 * fin.1;
        let fk2 = ta * st.x2 - self.k2 * dd2;
        if fk2 < -self.eps_force {
            return Err(PathFail::ContactOpens);
        }
        // Tangent along the path: J t = (0, 1).
        let tphi = -st.a12 * inv;
        let t2 = st.a11 * inv;
        let stiffness = t_phi * tphi + t_2 * t2;
        // Sensitivities at fixed θa: J dδ = −(∂E1/∂p, 0).
        let e1k = -st.sp * self.inv_l1;
        let e1r = -(R::one() - st.cp) * self.inv_l1;
        let dphi_k = -(st.a22 * e1k) * inv;
        let d2_k = (st.a21 * e1k) * inv;
        let dphi_r = -(st.a22 * e1r) * inv;
        let d2_r = (st.a21 * e1r) * inv;
        let dta_dk2c = t_phi * dphi_k + t_2 * d2_k + t_k;
        let dta_dr = t_phi * dphi_r + t_2 * d2_r + t_r;
        let out = PathPoint {
            dphi: dphi + fin.0,
            d2: d2 + fin.1,
            k2: k2_fin,
            ta: ta_fin,
            fk2,
            dta_dk2c,
            dta_dr,
            stiffness,
            tangent: (tphi, t2),
            sens_k: (dphi_k, d2_k),
            sens_r: (dphi_r, d2_r),
        };
        if !out.ta.is_finite() || out.ta.is_saturated() || out.dta_dk2c.is_saturated() {
            return Err(PathFail::Model(PtsError::Overflow));
        }
        Ok(out)
    }

    fn eval(
        &mut self,
        model: &Model<R>,
        k2c: R,
        radius: R,
        dphi: R,
        d2: R,
        out: &mut EvalState<R>,
    ) -> Result<(), PathFail> {
        if !dphi.is_finite() || dphi.abs() > self.max_delta || d2.abs() > self.max_delta {
            return Err(PathFail::OutOfRange);
        }
        let (sp, cp) = sin_cos_small(dphi, &self.pc);
        let (sd, cd) = sin_cos_small(d2, &self.pc);
        // θ2c + δφ and θ2 = θ2c + δ2 by angle addition.
        let s2p = self.s2c * cp + self.c2c * sp;
        let c2p = self.c2c * cp - self.s2c * sp;
        let s2 = self.s2c * cd + self.c2c * sd;
        let c2 = self.c2c * cd - self.s2c * sd;
        let (dgamma, x2, dx2) = self.closure_at(model, d2)?;
        let a11 = -c2p - (k2c * cp + radius * sp) * self.inv_l1;
        let a12 = c2;
        let a21 = R::one();
        let a22 = x2 - R::one();
        let det = a11 * a22 - a12 * a21;
        *out = EvalState {
            s2,
            c2,
            s2p,
            c2p,
            sp,
            cp,
            dgamma,
            x2,
            dx2,
            a11,
            a12,
            a21,
            a22,
            det,
        };
        Ok(())
    }

    /// Signed clearance (m) between a cylinder of radius R tangent at k2,c and the proximal
    /// phalanx after it rotated by δ1 = δφ − δ2 since contact: negative means the object cuts
    /// the proximal phalanx (a second contact). `None` when the closest point of the proximal
    /// line lies outside the phalanx (no second contact possible there).
    pub fn proximal_clearance(&self, k2c: R, radius: R, dphi: R, d2: R) -> Option<R> {
        // C − O1 in the contact frame (u, n): (l1 cos θ2c + k2c, R − l1 sin θ2c).
        let cx = self.l1 * self.c2c + k2c;
        let cy = radius - self.l1 * self.s2c;
        // The proximal phalanx points at angle δ1 − θ2c from u.
        let (sd, cd) = sin_cos_small(dphi - d2, &self.pc);
        let ce = cd * self.c2c + sd * self.s2c; // cos(δ1 − θ2c)
        let se = sd * self.c2c - cd * self.s2c; // sin(δ1 − θ2c)
        let along = cx * ce + cy * se;
        let normal = -cx * se + cy * ce;
        if along > R::zero() && along < self.l1 {
            Some(normal - radius)
        } else {
            None
        }
    }
}

#[derive(Clone, Copy, Debug)]
struct EvalState<R> {
    s2: R,
    c2: R,
    s2p: R,
    c2p: R,
    sp: R,
    cp: R,
    dgamma: R,
    x2: R,
    dx2: R,
    a11: R,
    a12: R,
    a21: R,
    a22: R,
    det: R,
}

impl<R: Real> EvalState<R> {
    fn zero() -> Self {
        let z = R::zero();
        Self {
            s2: z,
            c2: z,
            s2p: z,
            c2p: z,
            sp: z,
            cp: z,
            dgamma: z,
            x2: z,
            dx2: z,
            a11: z,
            a12: z,
            a21: z,
            a22: z,
            det: z,
        }
    }
}

/// The four-bar closure (`Model::closure`) from sin λ, cos λ: γ = atan2(Q, P) −
/// acos(R/ρ) needs one atan2 and one acos; sin γ, cos γ and those of λ − γ follow by
/// angle addition (cos of atan2(Q, P) is P/ρ, sin of acos(r) is √(1 − r²)).
fn closure_sc<R: Real>(z: &[R; 3], sl: R, cl: R) -> Result<Node<R>, PathFail> {
    let [z1, z2, z3] = *z;
    let p = cl - z2;
    let q = sl;
    let r = z3 * cl - z1;
    let rho = (p * p + q * q).sqrt();
    if !(rho > R::from_f64(1e-6)) {
        return Err(PathFail::Model(PtsError::NotAssemblable));
    }
    let inv_rho = R::one() / rho;
    let ratio = r * inv_rho;
    if ratio.abs() > R::one() {
        return Err(PathFail::Model(PtsError::NotAssemblable));
    }
    let gamma = q.atan2(p) - ratio.acos();
    let (cb, sb) = (p * inv_rho, q * inv_rho);
    let (ca, sa) = (ratio, (R::one() - ratio * ratio).max(R::zero()).sqrt());
    let sg = sb * ca - cb * sa;
    let cg = cb * ca + sb * sa;
    let slg = sl * cg - cl * sg;
    let clg = cl * cg + sl * sg;
    let n = slg - z3 * sl;
    let m = slg + z2 * sg;
    if m.abs() < R::from_f64(1e-4) {
        return Err(PathFail::Model(PtsError::Singular));
    }
    let inv_m = R::one() / m;
    let gp = n * inv_m;
    let x2 = R::one() - gp;
    if x2.abs() < R::from_f64(pts::model::TOGGLE_X2) {
        return Err(PathFail::Model(PtsError::Toggle));
    }
    let np = clg * x2 - z3 * cl;
    let mp = clg * x2 + z2 * cg * gp;
    let dx2 = (gp * mp - np) * inv_m;
    if !(gamma.is_finite() && x2.is_finite() && dx2.is_finite()) {
        return Err(PathFail::Model(PtsError::NonFinite));
    }
    Ok(Node { gamma, x2, dx2 })
}

/// sin, cos of any angle |x| ≤ 2·[`MAX_DELTA`] by the small-angle polynomials (halved and
/// doubled beyond [`MAX_DELTA`]); library trigonometry only further out.
fn sin_cos_any<R: Real>(x: R, pc: &PolyConsts<R>) -> (R, R) {
    let lim = R::from_f64(MAX_DELTA);
    if x.abs() <= lim {
        sin_cos_small(x, pc)
    } else if x.abs() <= lim + lim {
        let (s, c) = sin_cos_small(x * R::from_f64(0.5), pc);
        (R::from_f64(2.0) * s * c, c * c - s * s)
    } else {
        (x.sin(), x.cos())
    }
}

/// Free motion at θa (`Model::free_from_theta_a`: K2(θ2 − θ02) = K1(θ1 − θ01) x2, θ1 = θa −
/// θ2 + φ2 + γ), Newton from θ02 with sin, cos of λ = θ2 + π − φ2 carried along by exact
/// rotations (no library trigonometry). Returns the configuration and sin, cos of θ2 and λ.
#[allow(clippy::type_complexity)]
fn free_trig_free<R: Real>(
    model: &Model<R>,
    z: &[R; 3],
    pc: &PolyConsts<R>,
    theta_a: R,
) -> Result<(Config<R>, (R, R), (R, R)), PtsError> {
    let f = model.finger;
    let conv = |v: f64| R::try_from_f64(v).ok_or(PtsError::OutOfRange);
    if !theta_a.is_finite() || theta_a.abs() > R::from_f64(10.0) {
        return Err(PtsError::OutOfRange);
    }
    let (k1, k2) = (conv(f.k1)?, conv(f.k2)?);
    let (phi2, th01, th02) = (conv(f.phi2)?, conv(f.theta01)?, conv(f.theta02)?);
    let c = conv(core::f64::consts::PI - f.phi2)?;
    let (sc, cc) = sin_cos_any(c, pc);
    let mut th2 = th02;
    let (s0, c0) = sin_cos_any(th02, pc);
    let (mut sl, mut cl) = (s0 * cc + c0 * sc, c0 * cc - s0 * sc);
    let lim = R::from_f64(0.5);
    let tol = R::from_f64(FREE_TOL);
    let mut it = 0usize;
    while it < 2 * MAX_PATH_NEWTON {
        it += 1;
        let n = closure_sc(z, sl, cl).map_err(|e| match e {
            PathFail::Model(p) => p,
            _ => PtsError::OutOfRange,
        })?;
        let th1 = theta_a - th2 + phi2 + n.gamma;
        let ta = k1 * (th1 - th01);
        if !(ta.is_finite() && th1.is_finite()) {
            return Err(PtsError::NonFinite);
        }
        let g = k2 * (th2 - th02) - ta * n.x2;
        let dg = k2 - ta * n.dx2 + k1 * n.x2 * n.x2;
        if !(dg > R::from_f64(1e-9)) {
            return Err(PtsError::NoConvergence);
        }
        let step = (g / dg).max(-lim).min(lim);
        if step.abs() <= tol {
            // Renormalise the rotated pair once (rounding of the rotations).
            let inv = R::one() / (sl * sl + cl * cl).sqrt();
            let (sl, cl) = (sl * inv, cl * inv);
            let s2 = sl * cc - cl * sc;
            let c2 = cl * cc + sl * sc;
            let cfg = Config {
                theta1: th1,
                theta2: th2,
                theta_a,
                ta,
                x2: n.x2,
                dx2: n.dx2,
            };
            return Ok((cfg, (s2, c2), (sl, cl)));
        }
        th2 = th2 - step;
        let (ss, cs) = sin_cos_small(step, pc);
        (sl, cl) = (sl * cs - cl * ss, cl * cs + sl * ss);
    }
    Err(PtsError::NoConvergence)
}
