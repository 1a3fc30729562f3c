//! The firmware's path fit: the samples, the closure table and the path points in 32-bit
//! integers with a fixed binary point per quantity; only the 4×4 normal equations, the
//! Levenberg–Marquardt steps and σ (a few hundred operations per fit) stay in [`Fx32`].
//!
//! Why a kernel of its own: in Q32.32 every add saturates and every product takes three to
//! four long multiplies, which puts the generic fit ([`super::fit_path`] on [`Fx32`]) over the
//! firmware's instruction budget. Here a product is one `SMULL` and a shift, sums of products
//! accumulate in 64 bits (`SMLAL`), a quotient is a reciprocal seeded by the hardware divider,
//! and the samples never leave the integers the
//! controller measured (µrad, µN·m, ticks). The formats (value = raw · 2^-Q):
//!
//! | quantity | Q | range | resolution |
//! |---|---|---|---|
//! | angles (rad), sin/cos, x2, dx2/dθ2, lengths in units of l1 | 28 | ±8 | 3.7e-9 |
//! | torques (N·m), K1, K2 (N·m/rad); tangents and sensitivities of δφ, δ2 | 24 | ±128 | 6.0e-8 |
//! | torque derivatives (N·m/rad, N·m per l1 or l2) | 16 | ±32768 | 1.5e-5 |
//!
//! The closure γ(θ2), x2(θ2) and sin θ2, cos θ2 come from a table of cubic Hermite
//! segments [`SEG_STEP`] apart in θ2, built once from the fixed-point model ([`PathTable::new`]),
//! so a fit runs no closure, no trigonometry and no library call; the same table solves free
//! motion ([`PathTable::free_torque`]). Bounds: the angles the Newton solves reach are
//! limited to ±[`MAX_DELTA`] about the contact and to the table, the hypothesis (k2,c, R) by
//! the fit's bounds, and the finger by [`PathTable::new`] (lengths, stiffnesses and
//! transmission within the formats): every product and sum is then in range, and every
//! quotient and narrowing is checked ([`PathFail::OutOfRange`] otherwise).
//!
//! Memory: the table lives in RAM, built at init; a fit allocates nothing. Its instruction
//! count on thumbv7em is gated by `cargo xtask bench --check` (`benches/icount`).
//!
//! Tested against an exact f64 solve of the contact equations (path points, unit tests
//! below), the f64 model (free motion), the generic fit in f64 (`tests/q.rs`:
//! recorded-style requests, synthesized paths, arbitrary samples without a panic) and the
//! plant (`tests/pathfit_grid.rs`).

use super::path::{PathFail, ACCEPT_STEP, FREE_TOL, MAX_DELTA, MAX_PATH_NEWTON};
use super::{
    run_fit, Eval, FitConsts, Kernel, ObjectModel, PathFit, PathFitConfig, PathFitError, Work,
    MAX_BINS, MIN_BINS, NP, RAD, TC, TF,
};
use core::num::NonZeroU32;
use pts::fixed::{recip_q31, Fx32};
use pts::model::MODEL_RAW_WORDS;
use pts::table::{TABLE_TA_MAX_NM, TABLE_TA_MIN_NM};
use pts::{Config, Finger, Model, PtsError, Real};

/// Binary point of angles, sin/cos, x2, dx2/dθ2 and lengths in units of l1.
const QA: u32 = 28;
/// Binary point of torques (N·m) and the spring constants (N·m/rad).
const QT: u32 = 24;
/// Binary point of torque derivatives.
const QD: u32 = 16;
/// Binary point of the torque's derivative in the radius (N·m per l1 or l2), small near the
/// contact.
const QR: u32 = 24;
/// 1.0 in Q28.
const ONE: i32 = 1 << QA;

/// log2 of the table's segments per radian of θ2.
const SEG_SHIFT: u32 = 4;
/// Spacing of the closure table in θ2 (rad): 1/16 (cubic Hermite error of sin θ2 < 4e-8).
pub const SEG_STEP: f64 = 1.0 / (1u32 << SEG_SHIFT) as f64;
/// Most table segments (3 rad of θ2; the paper finger needs 43; a wider range is cut at the
/// top, far above any contact).
pub const MAX_SEGMENTS: usize = 48;
/// θ2 covered below the free motion at [`TABLE_TA_MIN_NM`] and above it at
/// [`TABLE_TA_MAX_NM`] (rad): the path's excursions.
const BELOW: f64 = 0.25;
const ABOVE: f64 = MAX_DELTA + 0.125;

/// Springs the table holds: K1 and K2 below this (N·m/rad), and above 0.
pub const MAX_SPRING_NM_PER_RAD: f64 = 100.0;

/// Rounded conversion to a Q format, `None` outside i32.
fn to_q(v: f64, q: u32) -> Option<i32> {
    let y = v * (1u64 << q) as f64;
    let r = if y < 0.0 { y - 0.5 } else { y + 0.5 };
    (v.is_finite() && r > i32::MIN as f64 && r < i32::MAX as f64).then_some(r as i32)
}

/// a·b / 2^S. The callers keep |a·b| / 2^S within i32 (see the module bounds).
#[inline(always)]
fn mul<const S: u32>(a: i32, b: i32) -> i32 {
    ((a as i64 * b as i64) >> S) as i32
}

/// The full product a·b.
#[inline(always)]
fn wide(a: i32, b: i32) -> i64 {
    a as i64 * b as i64
}

/// `v` when it fits in i32.
#[inline(always)]
fn narrow(v: i64) -> Result<i32, PathFail> {
    i32::try_from(v).map_err(|_| PathFail::OutOfRange)
}

/// `v` clamped to i32.
#[inline(always)]
fn clamp32(v: i64) -> i32 {
    // The low word when it is the value (one compare of the high word with its sign
    // extension), else the limit on v's side: two 64-bit compares fewer than `clamp`.
    let lo = v as i32;
    if lo as i64 == v {
        lo
    } else if v < 0 {
        i32::MIN
    } else {
        i32::MAX
    }
}

/// A reciprocal 1/d (d ≠ 0) to divide several numerators by one denominator: one
/// normalisation, a hardware-divider seed and two Newton steps ([`recip_q31`]), then one
/// product and a shift per quotient (relative error < 2^-29).
#[derive(Clone, Copy, Debug)]
struct Recip {
    /// ≈ 2^62 / (|d| · 2^lz), in [2^30, 2^31).
    y: i32,
    /// 62 − lz: 1/|d| = y · 2^-sh.
    sh: i32,
    neg: bool,
}

impl Recip {
    #[inline(always)]
    fn new(d: i32) -> Option<Recip> {
        if d == 0 {
            return None;
        }
        let a = d.unsigned_abs();
        let lz = a.leading_zeros();
        let y = (recip_q31(a << lz) >> 1).min(i32::MAX as u64) as i32;
        Some(Recip {
            y,
            sh: 62 - lz as i32,
            neg: d < 0,
        })
    }

    /// x / d scaled by 2^K: for x in Q(a), d in Q(b) and the quotient in Q(c), K = c − a + b.
    #[inline(always)]
    fn div<const K: i32>(self, x: i32) -> Result<i32, PathFail> {
        let s = self.sh - K;
        if s <= 0 {
            // A quotient ≥ 2^31 unless x is 0.
            return if x == 0 {
                Ok(0)
            } else {
                Err(PathFail::OutOfRange)
            };
        }
        let q = wide(x, self.y) >> s.min(63);
        narrow(if self.neg { -q } else { q })
    }
}

impl Recip {
    /// x / d scaled by 2^K for an i64 x (see [`Recip::div`]); `None` beyond ±2^62.
    #[inline(always)]
    fn div64<const K: i32>(self, x: i64) -> Option<i64> {
        let s = self.sh - K;
        if !(1..=62).contains(&s) {
            return None;
        }
        let p = mul_shr(x, self.y, s as u32)?;
        Some(if self.neg { -p } else { p })
    }
}

/// x·m / 2^s (floor) for x in i64, m in i32, 1 ≤ s ≤ 62, from two 32×32 products:
/// `None` when the result leaves ±2^62.
#[inline(always)]
fn mul_shr(x: i64, m: i32, s: u32) -> Option<i64> {
    let hi = wide((x >> 32) as i32, m); // the top word of an i64 fits i32
    let lo = (x as u32 as i64) * m as i64; // below 2^63 in magnitude
    let hi_part = if s <= 32 {
        let sh = 32 - s;
        if hi.unsigned_abs() >> (62 - sh) != 0 {
            return None;
        }
        hi << sh
    } else {
        hi >> (s - 32)
    };
    let v = hi_part.checked_add(lo >> s)?;
    (v.unsigned_abs() < 1 << 62).then_some(v)
}

/// sin and cos in Q28 of x (Q28 rad), |x| ≤ 1.25 (the Taylor polynomials of
/// [`super::path::sin_cos_small`], error < 3e-7 at 1.25 rad, < 6e-9 below 0.5 rad).
#[inline(always)]
fn sin_cos(x: i32) -> (i32, i32) {
    // 1/3!, 1/5!, 1/7!, 1/9! and 1/2!, …, 1/10! in Q28.
    const S: [i32; 4] = [44_739_243, 2_236_962, 53_261, 740];
    const C: [i32; 5] = [134_217_728, 11_184_811, 372_827, 6_658, 74];
    let x2 = mul::<QA>(x, x);
    if x2 < ONE / 4 {
        let s = x - mul::<QA>(
            x,
            mul::<QA>(x2, S[0] - mul::<QA>(x2, S[1] - mul::<QA>(x2, S[2]))),
        );
        let c = ONE
            - mul::<QA>(
                x2,
                C[0] - mul::<QA>(x2, C[1] - mul::<QA>(x2, C[2] - mul::<QA>(x2, C[3]))),
            );
        return (s, c);
    }
    let s = x - mul::<QA>(
        x,
        mul::<QA>(
            x2,
            S[0] - mul::<QA>(x2, S[1] - mul::<QA>(x2, S[2] - mul::<QA>(x2, S[3]))),
        ),
    );
    let c = ONE
        - mul::<QA>(
            x2,
            C[0] - mul::<QA>(
                x2,
                C[1] - mul::<QA>(x2, C[2] - mul::<QA>(x2, C[3] - mul::<QA>(x2, C[4]))),
            ),
        );
    (s, c)
}

/// sin and cos of |x| ≤ 2.5 rad (Q28): halved and doubled above 1.25.
fn sin_cos_wide(x: i32) -> (i32, i32) {
    let lim = to_q(MAX_DELTA, QA).unwrap_or(i32::MAX);
    if x.unsigned_abs() <= lim as u32 {
        return sin_cos(x);
    }
    let (s, c) = sin_cos(x / 2);
    (2 * mul::<QA>(s, c), mul::<QA>(c, c) - mul::<QA>(s, s))
}

/// Fields of one table segment: cubics in t ∈ [0, 1) for γ, x2, sin θ2, cos θ2
/// (4 coefficients each, Q28).
pub const FIELDS: usize = 16;

/// A free-motion equilibrium (Q28 angles, Q24 torque) with its closure.
#[derive(Clone, Copy, Debug)]
struct FreeState {
    theta1: i32,
    theta2: i32,
    ta: i32,
    closure: Closure,
}

/// The closure at one θ2 from the table.
#[derive(Clone, Copy, Debug)]
struct Closure {
    gamma: i32,
    x2: i32,
    dx2: i32,
    s2: i32,
    c2: i32,
}

/// Everything the integer fit needs that does not depend on the samples: the closure
/// table, the finger's constants in their Q formats, the fit configuration converted once,
/// and the [`Model<Fx32>`] the fit's initial guess inverts with. Built once (at init: f64
/// arithmetic, ~40 exact closures); about 4.8 KB.
#[derive(Clone, Debug)]
pub struct PathTable {
    model: Model<Fx32>,
    consts: FitConsts<Fx32>,
    /// θ2 of the first node (Q28 rad) and the number of segments.
    theta2_0: i32,
    segs: usize,
    seg: [[i32; FIELDS]; MAX_SEGMENTS],
    /// Free-motion θa at each node (Q28 rad), increasing: the start of the contact solve.
    theta_a_free: [i32; MAX_SEGMENTS + 1],
    k1: i32,
    k2: i32,
    phi2: i32,
    theta01: i32,
    theta02: i32,
    /// l2/l1 (Q28) and l1 (Q28 m).
    l2_l1: i32,
    l1: i32,
    /// Coulomb friction coefficient at the object contact (Q28; `PathFitConfig::contact_mu`).
    mu: i32,
    /// 1/l1 (Q24 per m).
    inv_l1: i32,
    /// The sample pass, in the controller's units.
    samples: SampleConsts,
    /// The controller's tick period the table was built for (s), and in ns (rounded).
    tick_s: f64,
    tick_ns: u32,
}

/// [`PathFitConfig`]'s sample-pass settings in integers (µrad, µN·m, ticks).
#[derive(Clone, Copy, Debug)]
struct SampleConsts {
    nbins: u32,
    dead_urad_q16: i64,
    min_travel_urad_q16: i64,
    /// Fraction of the travel skipped (Q16).
    skip_q16: i64,
    /// Approach span (µrad, Q16) when the approach samples are used, else `None`.
    approach_urad_q16: Option<i64>,
    /// J/dt² (µN·m per µrad of second difference per tick², Q16): the inertial correction.
    inertia_q16: i64,
    envelope_urad: i32,
    drop_plateaus: bool,
}

/// A [`PathTable`] as plain data ([`PathTable::to_raw`], [`PathTable::from_raw`]): what a
/// build script writes out so that the firmware holds the table as a constant in flash.
#[derive(Clone, Debug, PartialEq)]
pub struct PathTableRaw {
    /// The finger.
    pub finger: Finger,
    /// The model's constants ([`Model::to_raw`]).
    pub model: [i64; MODEL_RAW_WORDS],
    /// The fit configuration's Q32.32 constants (bits), in the order of [`PathTable::to_raw`].
    pub consts: [i64; 11],
    /// The fit configuration's contact-angle switch.
    pub fit_contact_angle: bool,
    /// The fit configuration's object model.
    pub object: ObjectModel,
    /// θ2 of the first node (Q28 rad).
    pub theta2_0: i32,
    /// Segments in use.
    pub segs: usize,
    /// Per segment, the cubics' coefficients (Q28).
    pub seg: [[i32; FIELDS]; MAX_SEGMENTS],
    /// Free-motion θa at each node (Q28 rad).
    pub theta_a_free: [i32; MAX_SEGMENTS + 1],
    /// K1, K2 (Q24), φ2, θ01, θ02, l2/l1, l1 (Q28), μ (Q28), 1/l1 (Q24).
    pub q: [i32; 9],
    /// The sample pass: bins, dead band, minimum travel, skip, inertia (Q16), envelope (µrad).
    pub samples: [i64; 6],
    /// The approach span (µrad, Q16) when the approach samples are used.
    pub approach_urad_q16: Option<i64>,
    /// The sample pass drops plateaus.
    pub drop_plateaus: bool,
    /// The tick period (s) as f64 bits.
    pub tick_s_bits: u64,
    /// The tick period (ns).
    pub tick_ns: u32,
}

impl PathTable {
    /// Builds the table for a finger, the fit configuration and the controller's tick period
    /// `tick_s` (s; sample times are ticks). Refuses ([`PtsError::OutOfRange`]) a finger or a
    /// configuration outside the formats: K1 or K2 not in (0, 100) N·m/rad, l2 + R_max above
    /// 4 l1, |x2| or |dx2/dθ2| above 4 on the table, more bins than [`MAX_BINS`].
    pub fn new(finger: &Finger, cfg: &PathFitConfig, tick_s: f64) -> Result<Self, PtsError> {
        // The closure at the nodes from the fixed-point model (its own trigonometry, ≈ 1e-9
        // rad, below the table's Q28 step): the firmware links no f64 trigonometry for it.
        let model = Model::<Fx32>::new(finger)?;
        let consts = FitConsts::new(cfg).map_err(|e| match e {
            PathFitError::Model(p) => p,
            _ => PtsError::OutOfRange,
        })?;
        let f = finger;
        let oor = PtsError::OutOfRange;
        let spring_ok = |k: f64| k > 0.0 && k < MAX_SPRING_NM_PER_RAD;
        if !(spring_ok(f.k1) && spring_ok(f.k2)) {
            return Err(oor);
        }
        if !((f.l2 + cfg.max_radius_m) <= 4.0 * f.l1 && f.l1 > 1e-3 && f.l1 < 4.0) {
            return Err(oor);
        }
        let sane = cfg.skip_fraction >= 0.0
            && cfg.skip_fraction < 1.0
            && tick_s > 0.0
            && tick_s < 1.0
            && cfg.inertia_kgm2 >= 0.0
            && (0.0..2.0).contains(&cfg.contact_mu);
        if !sane {
            return Err(oor);
        }
        // The θ2 range: free motion over the torque table's range, plus the path's excursions.
        let theta2_free = |ta: f64| -> Result<f64, PtsError> {
            let ta = Fx32::try_from_f64(ta).ok_or(oor)?;
            Ok(model.free_from_torque(ta)?.theta2.to_f64())
        };
        let lo = theta2_free(TABLE_TA_MIN_NM)? - BELOW;
        let top_free = theta2_free(TABLE_TA_MAX_NM)?;
        let hi = top_free + ABOVE;
        let mut segs = (libm::ceil((hi - lo) / SEG_STEP) as usize).min(MAX_SEGMENTS);
        if !(lo > -7.0 && lo + segs as f64 * SEG_STEP < 7.0) || segs < 2 {
            return Err(oor);
        }
        let mut seg = [[0i32; FIELDS]; MAX_SEGMENTS];
        let mut theta_a_free = [0i32; MAX_SEGMENTS + 1];
        // γ from atan2 − acos jumps by 2π somewhere on the circle: unwrapped node to node.
        let mut gamma_prev: Option<f64> = None;
        let mut node = |i: usize| -> Result<[f64; 9], PtsError> {
            let th2 = lo + i as f64 * SEG_STEP;
            let th2_q = Fx32::try_from_f64(th2).ok_or(oor)?;
            let c = model.closure(th2_q)?;
            let (gamma, x2, dx2) = (c.gamma.to_f64(), c.x2.to_f64(), c.dx2.to_f64());
            let tau = 2.0 * core::f64::consts::PI;
            let mut gamma = gamma;
            if let Some(g) = gamma_prev {
                gamma -= tau * libm::round((gamma - g) / tau);
            }
            gamma_prev = Some(gamma);
            // Free motion through this θ2: K1(θ1 − θ01) x2 = K2(θ2 − θ02).
            let th1 = f.theta01 + f.k2 * (th2 - f.theta02) / (f.k1 * x2);
            let ta_free = th1 + th2 - f.phi2 - gamma;
            let (s, co) = (th2_q.sin().to_f64(), th2_q.cos().to_f64());
            // Values and slopes per radian: γ′ = 1 − x2.
            Ok([gamma, 1.0 - x2, x2, dx2, s, co, co, -s, ta_free])
        };
        // The free-motion θa at the nodes only starts the contact solve: clipped to the
        // format (the table's top lies far beyond any contact).
        let free_q = |v: f64| to_q(v.clamp(-7.5, 7.5), QA).ok_or(oor);
        let mut a = node(0)?;
        theta_a_free[0] = free_q(a[8])?;
        for i in 0..segs {
            let b = node(i + 1).and_then(|b| {
                let fits =
                    b[8] > a[8] && b[0].abs() <= 7.5 && b[2].abs() <= 4.0 && b[3].abs() <= 4.0;
                // Free motion must be monotone in θ2 for the contact solve's start.
                if fits {
                    Ok(b)
                } else {
                    Err(oor)
                }
            });
            let b = match b {
                Ok(b) => b,
                // A soft distal spring takes the path's excursion band past the toggle, where
                // the actuator no longer drives θ2 and no contact path can go: the table ends
                // at the last node before it, above the whole free motion it must cover.
                Err(_) if lo + i as f64 * SEG_STEP > top_free + SEG_STEP && i >= 2 => {
                    segs = i;
                    break;
                }
                Err(e) => return Err(e),
            };
            theta_a_free[i + 1] = free_q(b[8])?;
            let s = seg.get_mut(i).ok_or(oor)?;
            for (fld, out) in s.chunks_exact_mut(4).enumerate() {
                let (f0, m0, f1, m1) = (a[2 * fld], a[2 * fld + 1], b[2 * fld], b[2 * fld + 1]);
                let (m0, m1) = (m0 * SEG_STEP, m1 * SEG_STEP);
                let d = f1 - f0;
                let c = [f0, m0, 3.0 * d - 2.0 * m0 - m1, m0 + m1 - 2.0 * d];
                for (o, v) in out.iter_mut().zip(c) {
                    *o = to_q(v, QA).ok_or(oor)?;
                }
            }
            a = b;
        }
        let q16 = |v: f64| -> Result<i64, PtsError> {
            let y = v * 65536.0;
            if !(y.is_finite() && y.abs() < 9e18) {
                return Err(oor);
            }
            Ok(libm::round(y) as i64)
        };
        if !(cfg.dead_band_rad >= 0.0 && cfg.min_travel_rad >= 0.0 && cfg.envelope_tol_rad >= 0.0) {
            return Err(oor);
        }
        let approach = cfg.fit_contact_angle
            && cfg.contact_angle_sigma_rad > 0.0
            && cfg.approach_span_rad > 0.0;
        let samples = SampleConsts {
            nbins: (cfg.bins as usize).clamp(MIN_BINS, MAX_BINS) as u32,
            dead_urad_q16: q16(cfg.dead_band_rad * 1e6)?,
            min_travel_urad_q16: q16(cfg.min_travel_rad * 1e6)?,
            skip_q16: q16(cfg.skip_fraction)?,
            approach_urad_q16: if approach {
                Some(q16(cfg.approach_span_rad * 1e6)?)
            } else {
                None
            },
            inertia_q16: q16(cfg.inertia_kgm2 / (tick_s * tick_s))?,
            envelope_urad: libm::round(cfg.envelope_tol_rad * 1e6).min(1e9) as i32,
            drop_plateaus: cfg.drop_plateaus,
        };
        Ok(PathTable {
            model,
            consts,
            theta2_0: to_q(lo, QA).ok_or(oor)?,
            segs,
            seg,
            theta_a_free,
            k1: to_q(f.k1, QT).ok_or(oor)?,
            k2: to_q(f.k2, QT).ok_or(oor)?,
            phi2: to_q(f.phi2, QA).ok_or(oor)?,
            theta01: to_q(f.theta01, QA).ok_or(oor)?,
            theta02: to_q(f.theta02, QA).ok_or(oor)?,
            l2_l1: to_q(f.l2 / f.l1, QA).ok_or(oor)?,
            mu: to_q(cfg.contact_mu, QA).ok_or(oor)?,
            l1: to_q(f.l1, QA).ok_or(oor)?,
            inv_l1: to_q(1.0 / f.l1, QT).ok_or(oor)?,
            samples,
            tick_s,
            tick_ns: libm::round(tick_s * 1e9) as u32,
        })
    }

    /// The table as plain data ([`PathTable::from_raw`] rebuilds it bit for bit).
    pub fn to_raw(&self) -> PathTableRaw {
        let c = &self.consts;
        let sm = &self.samples;
        PathTableRaw {
            finger: self.model.finger,
            model: self.model.to_raw(),
            consts: [
                c.lead,
                c.noise_floor,
                c.friction_prior_sigma,
                c.contact_angle_sigma,
                c.max_radius,
                c.inflation,
                c.sigma_floor,
                c.max_chi2,
                c.max_sigma_frac,
                c.tip_margin,
                c.radius_rel_sigma,
            ]
            .map(|v| v.to_bits()),
            fit_contact_angle: c.fit_contact_angle,
            object: c.object,
            theta2_0: self.theta2_0,
            segs: self.segs,
            seg: self.seg,
            theta_a_free: self.theta_a_free,
            q: [
                self.k1,
                self.k2,
                self.phi2,
                self.theta01,
                self.theta02,
                self.l2_l1,
                self.l1,
                self.mu,
                self.inv_l1,
            ],
            samples: [
                i64::from(sm.nbins),
                sm.dead_urad_q16,
                sm.min_travel_urad_q16,
                sm.skip_q16,
                sm.inertia_q16,
                i64::from(sm.envelope_urad),
            ],
            approach_urad_q16: sm.approach_urad_q16,
            drop_plateaus: sm.drop_plateaus,
            tick_s_bits: self.tick_s.to_bits(),
            tick_ns: self.tick_ns,
        }
    }

    /// The table from [`PathTable::to_raw`]'s data: a constant expression (no floating-point
    /// arithmetic), so a table generated at build time lives in flash and the firmware links
    /// no table builder.
    pub const fn from_raw(r: &PathTableRaw) -> Self {
        const fn fx(r: &PathTableRaw, i: usize) -> Fx32 {
            Fx32::from_bits(r.consts[i])
        }
        PathTable {
            model: Model::from_raw(r.finger, &r.model),
            consts: FitConsts {
                lead: fx(r, 0),
                noise_floor: fx(r, 1),
                friction_prior_sigma: fx(r, 2),
                contact_angle_sigma: fx(r, 3),
                fit_contact_angle: r.fit_contact_angle,
                object: r.object,
                max_radius: fx(r, 4),
                inflation: fx(r, 5),
                sigma_floor: fx(r, 6),
                max_chi2: fx(r, 7),
                max_sigma_frac: fx(r, 8),
                tip_margin: fx(r, 9),
                radius_rel_sigma: fx(r, 10),
            },
            theta2_0: r.theta2_0,
            segs: r.segs,
            seg: r.seg,
            theta_a_free: r.theta_a_free,
            k1: r.q[0],
            k2: r.q[1],
            phi2: r.q[2],
            theta01: r.q[3],
            theta02: r.q[4],
            l2_l1: r.q[5],
            l1: r.q[6],
            mu: r.q[7],
            inv_l1: r.q[8],
            samples: SampleConsts {
                nbins: r.samples[0] as u32,
                dead_urad_q16: r.samples[1],
                min_travel_urad_q16: r.samples[2],
                skip_q16: r.samples[3],
                approach_urad_q16: r.approach_urad_q16,
                inertia_q16: r.samples[4],
                envelope_urad: r.samples[5] as i32,
                drop_plateaus: r.drop_plateaus,
            },
            tick_s: f64::from_bits(r.tick_s_bits),
            tick_ns: r.tick_ns,
        }
    }

    /// The model the fit inverts its initial guess with.
    pub fn model(&self) -> &Model<Fx32> {
        &self.model
    }

    /// The controller tick period (s) the sample times are in.
    pub fn tick_s(&self) -> f64 {
        self.tick_s
    }

    /// The controller tick period (ns, rounded), for checking a request without floats.
    pub fn tick_ns(&self) -> u32 {
        self.tick_ns
    }

    /// T_a (N·m) of the free-motion equilibrium at θa (rad, the finger's frame): the
    /// table's Newton solve (no trigonometry), for the estimator's contact-point search.
    pub fn free_torque(&self, theta_a: Fx32) -> Result<Fx32, PtsError> {
        let tha = i32::try_from(fx_to_q28(theta_a)).map_err(|_| PtsError::OutOfRange)?;
        let f = self.free_motion(tha, None)?;
        Ok(Fx32::from_bits((f.ta as i64) << (32 - QT)))
    }

    /// The free-motion configuration at θa (rad, the finger's frame) and its cos θ2, from the
    /// table (its Newton solve, no trigonometry): the contact configuration a two-point
    /// estimate inverts at (`Model::estimate_two_point_shared` on [`PathTable::model`]).
    pub fn free_config(&self, theta_a: Fx32) -> Result<(Config<Fx32>, Fx32), PtsError> {
        let tha = i32::try_from(fx_to_q28(theta_a)).map_err(|_| PtsError::OutOfRange)?;
        let f = self.free_motion(tha, None)?;
        let angle = |v: i32| Fx32::from_bits(i64::from(v) << (32 - QA));
        let cfg = Config {
            theta1: angle(f.theta1),
            theta2: angle(f.theta2),
            theta_a,
            ta: Fx32::from_bits(i64::from(f.ta) << (32 - QT)),
            x2: angle(f.closure.x2),
            dx2: angle(f.closure.dx2),
        };
        Ok((cfg, angle(f.closure.c2)))
    }

    /// Free motion at θa (Q28): K2(θ2 − θ02) = K1(θ1 − θ01)·x2 with θ1 = θa − θ2 + φ2 + γ,
    /// Newton on θ2 from `start` or from the node table, the last step applied.
    fn free_motion(&self, tha: i32, start: Option<i32>) -> Result<FreeState, PtsError> {
        let oor = PtsError::OutOfRange;
        let mut th2 = match start {
            Some(t) => t,
            None => {
                // The node interval holding θa, then linear interpolation in it.
                let free = self.theta_a_free.get(..=self.segs).ok_or(oor)?;
                let i = free.iter().position(|&v| v > tha).ok_or(oor)?;
                if i == 0 {
                    return Err(oor);
                }
                let (a, b) = (free[i - 1], free[i]);
                let x0 = self.theta2_0 as i64 + (((i - 1) as i64) << (QA - SEG_SHIFT));
                narrow(x0 + node_fraction(tha - a, b - a)).map_err(|_| oor)?
            }
        };
        let tol = to_q(FREE_TOL, QA).unwrap_or(1);
        let lim = ONE / 2;
        let mut done = false;
        for _ in 0..2 * MAX_PATH_NEWTON {
            let c = self.closure(th2).map_err(|_| oor)?;
            // θ1 = θa − θ2 + φ2 + γ; g = K2(θ2 − θ02) − K1(θ1 − θ01)·x2; g′ = K2 − T dx2 + K1 x2².
            let th1 = (tha as i64 - th2 as i64 + self.phi2 as i64 + c.gamma as i64) as i32;
            let ta = mul::<QA>(self.k1, th1.wrapping_sub(self.theta01));
            if done {
                return Ok(FreeState {
                    theta1: th1,
                    theta2: th2,
                    ta,
                    closure: c,
                });
            }
            let g = mul::<QA>(self.k2, th2 - self.theta02) - mul::<QA>(ta, c.x2);
            let dg = self.k2 - mul::<QA>(ta, c.dx2) + mul::<QA>(self.k1, mul::<QA>(c.x2, c.x2));
            if dg < (1 << 8) {
                return Err(PtsError::NoConvergence);
            }
            let r = Recip::new(dg).ok_or(PtsError::NoConvergence)?;
            let step = r.div::<{ QA as i32 }>(g).map_err(|_| oor)?.clamp(-lim, lim);
            done = step.abs() <= tol;
            th2 -= step;
        }
        Err(PtsError::NoConvergence)
    }

    /// The closure at θ2 (Q28 rad) from the table.
    #[inline(always)]
    fn closure(&self, theta2: i32) -> Result<Closure, PathFail> {
        let x = theta2.wrapping_sub(self.theta2_0);
        let i = (x >> (QA - SEG_SHIFT)) as usize;
        let c = match (x >= 0).then(|| self.seg.get(i)).flatten() {
            Some(c) if i < self.segs => c,
            _ => return Err(PathFail::OutOfRange),
        };
        let t = (x << SEG_SHIFT) & (ONE - 1);
        let cubic = |k: usize| {
            c[k] + mul::<QA>(
                t,
                c[k + 1] + mul::<QA>(t, c[k + 2] + mul::<QA>(t, c[k + 3])),
            )
        };
        let dx2 = (c[5] + mul::<QA>(t, 2 * c[6] + mul::<QA>(t, 3 * c[7]))) << SEG_SHIFT;
        Ok(Closure {
            gamma: cubic(0),
            x2: cubic(4),
            dx2,
            s2: cubic(8),
            c2: cubic(12),
        })
    }
}

/// ⌊x·2^(QA − SEG_SHIFT) / d⌋ for 0 ≤ x < d, d > 0 (θa into a node interval as a fraction of
/// the segment's θ2, Q28): long division by the 32-bit divider, six 4-bit digits, when
/// d < 2^28 (node intervals of the paper finger are ≈ 2^25, and the 64-bit division is a
/// library routine on the target), else the 64-bit division: the same quotient either way.
/// Other x (not reached from the node search) are clamped.
#[inline(always)]
fn node_fraction(x: i32, d: i32) -> i64 {
    const _: () = assert!(QA - SEG_SHIFT == 24);
    let d = d.max(1);
    let x = x.clamp(0, d - 1);
    if d < 1 << 28 {
        let d = d as u32;
        let (mut q, mut r) = (0u32, x as u32);
        for _ in 0..6 {
            // r < d < 2^28: r·2^4 < 2^32.
            let n = r << 4;
            q = (q << 4) | (n / d);
            r = n % d;
        }
        q as i64
    } else {
        ((x as i64) << 24) / d as i64
    }
}

/// One sample as the controller records it (C layout: three 32-bit words).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(C)]
pub struct RawSample {
    /// Controller tick of the sample (the period given to [`PathTable::new`]).
    pub tick: u32,
    /// θa, absolute model angle (µrad).
    pub theta_a_urad: i32,
    /// T_a at the actuator (µN·m).
    pub torque_unm: i32,
}

/// One θa bin in the kernel's formats.
#[derive(Clone, Copy, Debug, Default)]
struct QBin {
    n: u32,
    /// Mean θa − θa,c (given, the finger's frame) (Q28 rad).
    dta: i32,
    /// Mean measured T_a (Q24 N·m).
    t: i32,
    /// n / N (Q16).
    w: i32,
    /// √(n / N) (Q16).
    sqrt_w: i32,
}

/// A solved point kept for warm starts (angles Q28; sensitivities per unit of k2,c/l1 and
/// R/l1, Q24).
#[derive(Clone, Copy, Debug)]
struct QPrev {
    kap: i32,
    rho: i32,
    dphi: i32,
    d2: i32,
    sens_k: (i32, i32),
    sens_r: (i32, i32),
}

/// The kernel's empty bins and warm starts, as constants: cleared in one block each, not
/// element by element through a temporary.
const NO_BINS: [QBin; MAX_BINS] = [QBin {
    n: 0,
    dta: 0,
    t: 0,
    w: 0,
    sqrt_w: 0,
}; MAX_BINS];
const NO_PREV: [Option<QPrev>; MAX_BINS] = [None; MAX_BINS];

/// A solved path point (see [`super::path::PathPoint`]), in the kernel's formats.
#[derive(Clone, Copy, Debug)]
struct QPoint {
    dphi: i32,
    d2: i32,
    /// k2/l1 (Q28).
    k2: i32,
    /// T_a (Q24 N·m).
    ta: i32,
    /// ∂T_a/∂(k2,c/l1) (Q16 N·m), ∂T_a/∂(R/l1) (Q24 N·m).
    dta_dk: i32,
    dta_dr: i32,
    /// dT_a/dθa along the path (Q16 N·m/rad).
    stiffness: i32,
    /// dδ/dθa along the path and ∂δ/∂(k2,c/l1), ∂δ/∂(R/l1) (Q24).
    tangent: (i32, i32),
    sens_k: (i32, i32),
    sens_r: (i32, i32),
}

/// The state of one Newton step (see `super::path::EvalState`).
#[derive(Clone, Copy, Debug, Default)]
struct St {
    sp: i32,
    cp: i32,
    s2p: i32,
    c2p: i32,
    s2: i32,
    c2: i32,
    dgamma: i32,
    x2: i32,
    dx2: i32,
    a11: i32,
    a22: i32,
    det: i32,
}

/// The integer kernel of one fit: the contact configuration, the bins, the warm starts.
struct QKernel<'t> {
    tb: &'t PathTable,
    bins: [QBin; MAX_BINS],
    prev: [Option<QPrev>; MAX_BINS],
    /// θa,c as given to the model (Fx32 rad) and its configuration.
    theta_a_c: Fx32,
    contact: Config<Fx32>,
    theta2c: i32,
    s2c: i32,
    c2c: i32,
    gamma_c: i32,
    d1c: i32,
    d2c: i32,
    /// T_a at contact (Q24) and the free-motion stiffness there (Q16).
    tac: i32,
    kfree: i32,
    newton: u32,
}

/// Fx32 (Q32) to Q28, rounded.
#[inline(always)]
fn fx_to_q28(v: Fx32) -> i64 {
    (v.to_bits() + 8) >> 4
}

impl<'t> QKernel<'t> {
    fn new(tb: &'t PathTable) -> Self {
        let z = Fx32::zero();
        QKernel {
            tb,
            bins: NO_BINS,
            prev: NO_PREV,
            theta_a_c: z,
            contact: Config {
                theta1: z,
                theta2: z,
                theta_a: z,
                ta: z,
                x2: z,
                dx2: z,
            },
            theta2c: 0,
            s2c: 0,
            c2c: ONE,
            gamma_c: 0,
            d1c: 0,
            d2c: 0,
            tac: 0,
            kfree: 0,
            newton: 0,
        }
    }

    /// The free-motion configuration at θa,c (see [`PathTable::free_motion`]; warm-started
    /// from the current contact when there is one).
    fn solve_contact(&mut self, theta_a_c: Fx32, warm: bool) -> Result<(), PtsError> {
        let tb = self.tb;
        let tha = i32::try_from(fx_to_q28(theta_a_c)).map_err(|_| PtsError::OutOfRange)?;
        let f = tb.free_motion(tha, warm.then_some(self.theta2c))?;
        let c = f.closure;
        let k2p = tb.k2 - mul::<QA>(f.ta, c.dx2);
        let den = k2p + mul::<QA>(tb.k1, mul::<QA>(c.x2, c.x2));
        let kfree = Recip::new(den)
            .ok_or(PtsError::NoConvergence)?
            .div::<{ QD as i32 }>(mul::<QT>(tb.k1, k2p))
            .map_err(|_| PtsError::OutOfRange)?;
        let fx = |v: i32, q: u32| Fx32::from_bits((v as i64) << (32 - q));
        self.contact = Config {
            theta1: fx(f.theta1, QA),
            theta2: fx(f.theta2, QA),
            theta_a: theta_a_c,
            ta: fx(f.ta, QT),
            x2: fx(c.x2, QA),
            dx2: fx(c.dx2, QA),
        };
        self.theta_a_c = theta_a_c;
        self.theta2c = f.theta2;
        self.s2c = c.s2;
        self.c2c = c.c2;
        self.gamma_c = c.gamma;
        self.d1c = f.theta1.wrapping_sub(tb.theta01);
        self.d2c = f.theta2 - tb.theta02;
        self.tac = f.ta;
        self.kfree = kfree;
        self.prev = [None; MAX_BINS];
        Ok(())
    }

    /// One Newton state at (δφ, δ2) for k2,c/l1 = `kap`, R/l1 = `rho`.
    #[inline(always)]
    fn eval(&self, kap: i32, rho: i32, dphi: i32, d2: i32, st: &mut St) -> Result<(), PathFail> {
        let (sp, cp) = sin_cos(dphi);
        let s2p = ((wide(self.s2c, cp) + wide(self.c2c, sp)) >> QA) as i32;
        let c2p = ((wide(self.c2c, cp) - wide(self.s2c, sp)) >> QA) as i32;
        let c = self.tb.closure(self.theta2c + d2)?;
        let a11 = -c2p - ((wide(kap, cp) + wide(rho, sp)) >> QA) as i32;
        let a22 = c.x2 - ONE;
        // det = a11 a22 − a12 a21 with a12 = cos θ2, a21 = 1.
        let det = narrow((wide(a11, a22) >> QA) - c.c2 as i64)?;
        *st = St {
            sp,
            cp,
            s2p,
            c2p,
            s2: c.s2,
            c2: c.c2,
            dgamma: c.gamma - self.gamma_c,
            x2: c.x2,
            dx2: c.dx2,
            a11,
            a22,
            det,
        };
        Ok(())
    }

    /// The path point at Δθa = `dta` (Q28) from the guess (Newton, warm-started; the last
    /// step below [`ACCEPT_STEP`] applied to first order, as [`super::path::PathModel::point`]).
    #[inline(never)]
    fn point(
        &mut self,
        kap: i32,
        rho: i32,
        dta: i32,
        guess: (i32, i32),
    ) -> Result<QPoint, PathFail> {
        const MAXD: i32 = (MAX_DELTA * (1u64 << QA) as f64) as i32;
        const ACCEPT: i32 = (ACCEPT_STEP * (1u64 << QA) as f64) as i32;
        const EPS_DET: i32 = (1e-6 * (1u64 << QA) as f64) as i32;
        let (mut dphi, mut d2) = guess;
        let mut st = St::default();
        for _ in 0..MAX_PATH_NEWTON {
            self.newton = self.newton.saturating_add(1);
            if dphi.abs() > MAXD || d2.abs() > MAXD {
                return Err(PathFail::OutOfRange);
            }
            self.eval(kap, rho, dphi, d2, &mut st)?;
            let e1 = st.s2 - st.s2p - ((wide(kap, st.sp) + wide(rho, ONE - st.cp)) >> QA) as i32;
            let e2 = dphi - st.dgamma - dta;
            if st.det.abs() <= EPS_DET {
                return Err(PathFail::OutOfRange);
            }
            let r = Recip::new(st.det).ok_or(PathFail::OutOfRange)?;
            // [a11 c2; 1 a22] [dδφ; dδ2] = −[e1; e2]
            let n1 = clamp32((wide(st.a22, e1) - wide(st.c2, e2)) >> QA);
            let n2 = clamp32((wide(st.a11, e2) - e1 as i64 * ONE as i64) >> QA);
            let sphi = -r.div::<{ QA as i32 }>(n1)?;
            let s2 = -r.div::<{ QA as i32 }>(n2)?;
            if sphi.abs() <= ACCEPT && s2.abs() <= ACCEPT {
                return self.outputs(kap, rho, dphi, d2, &st, r, (sphi, s2));
            }
            dphi = dphi.saturating_add(sphi);
            d2 = d2.saturating_add(s2);
        }
        Err(PathFail::NoConvergence)
    }

    /// The outputs at (δφ, δ2) moved by the last Newton step `fin` to first order (see
    /// `super::path::PathModel::outputs` for the equations; lengths here in units of l1).
    #[allow(clippy::too_many_arguments)]
    fn outputs(
        &self,
        kap: i32,
        rho: i32,
        dphi: i32,
        d2: i32,
        st: &St,
        rdet: Recip,
        fin: (i32, i32),
    ) -> Result<QPoint, PathFail> {
        const EPS_DEN: i32 = 1 << 4;
        const EPS_FORCE: i32 = (1e-6 * (1u64 << QT) as f64) as i32;
        let tb = self.tb;
        let sh = |v: i64| (v >> QA) as i32;
        let dk2_dphi = -st.s2p + sh(wide(rho, st.cp) - wide(kap, st.sp));
        let dk2_d2 = st.s2;
        let k2 = st.c2p - st.c2 + sh(wide(kap, st.cp) + wide(rho, st.sp));
        let k2_fin = k2 + sh(wide(dk2_dphi, fin.0) + wide(dk2_d2, fin.1));
        if k2_fin > tb.l2_l1 {
            return Err(PathFail::PastTip);
        }
        if k2_fin <= 0 {
            return Err(PathFail::PastJoint);
        }
        // Contact friction: L = l1 (cos θ2 − µ sin θ2) + k2, ∂L/∂δ2 = −µ l1 cos θ2 (skipped
        // at µ = 0, the firmware's default: its instruction budget is counted without them).
        let (l, dl_d2) = if tb.mu == 0 {
            (st.c2 + k2, 0)
        } else {
            (
                st.c2 - mul::<QA>(tb.mu, st.s2) + k2,
                -mul::<QA>(tb.mu, st.c2),
            )
        };
        let d1 = self.d1c + dphi - d2;
        let dd2 = self.d2c + d2;
        let k1d1 = mul::<QA>(tb.k1, d1);
        let k2dd2 = mul::<QA>(tb.k2, dd2);
        // T_a = (K1 Δ1 k2 − K2 Δ2 L)/(k2 − x2 L): numerator Q24, denominator Q28.
        let num = narrow((wide(k1d1, k2) - wide(k2dd2, l)) >> QA)?;
        let den = k2 - mul::<QA>(st.x2, l);
        if den.abs() <= EPS_DEN {
            return Err(PathFail::OutOfRange);
        }
        let rden = Recip::new(den).ok_or(PathFail::OutOfRange)?;
        // Q24 / Q28 → Q24 and Q24 / Q28 → Q16.
        const KT: i32 = QA as i32;
        const KD: i32 = QD as i32 - QT as i32 + QA as i32;
        let ta = rden.div::<KT>(num)?;
        // dT = (dn − T dden)/den along δφ (dk2 = dL = dk2_dphi) and along δ2 (dL = dl_d2).
        let dn_phi =
            sh(wide(tb.k1, k2 + mul::<QA>(d1, dk2_dphi)) - wide(tb.k2, mul::<QA>(dd2, dk2_dphi)));
        let dden_phi = dk2_dphi - mul::<QA>(st.x2, dk2_dphi);
        let t_phi = rden.div::<KD>(narrow(dn_phi as i64 - (wide(ta, dden_phi) >> QA))?)?;
        let (l_2, x2dl) = if dl_d2 == 0 {
            (l, 0)
        } else {
            (l + mul::<QA>(dd2, dl_d2), mul::<QA>(st.x2, dl_d2))
        };
        let dn_2 = sh(wide(tb.k1, mul::<QA>(d1, dk2_d2) - k2) - wide(tb.k2, l_2));
        let dden_2 = dk2_d2 - mul::<QA>(l, st.dx2) - x2dl;
        let t_2 = rden.div::<KD>(narrow(dn_2 as i64 - (wide(ta, dden_2) >> QA))?)?;
        // ∂k2 = ∂L = cos δφ per k2,c and sin δφ per R.
        let qn = narrow(k1d1 as i64 - k2dd2 as i64 - (wide(ta, ONE - st.x2) >> QA))?;
        let q = rden.div::<KD>(qn)?;
        let t_k = mul::<QA>(q, st.cp);
        // Corrections by the last step: Q16 · Q28 → Q24.
        let ta_fin =
            narrow(ta as i64 + ((wide(t_phi, fin.0) + wide(t_2, fin.1)) >> (QD + QA - QT)))?;
        let fk2 = mul::<QA>(ta, st.x2) - k2dd2;
        if fk2 < -EPS_FORCE {
            return Err(PathFail::ContactOpens);
        }
        // Tangent: J t = (0, 1); sensitivities: J dδ = −(∂E1/∂p, 0), ∂E1/∂κ = −sin δφ,
        // ∂E1/∂ρ = −(1 − cos δφ).
        // Both in Q24 (they pass 8 on stiff paths): Q28/Q28 → Q24.
        const K0: i32 = QT as i32;
        let tphi = rdet.div::<K0>(-st.c2)?;
        let t2 = rdet.div::<K0>(st.a11)?;
        let stiffness = narrow((wide(t_phi, tphi) + wide(t_2, t2)) >> QT)?;
        let e1k = -st.sp;
        let e1r = st.cp - ONE;
        // dδ2 = ∂E1/det per parameter, dδφ = −a22·dδ2.
        let d2_k = rdet.div::<K0>(e1k)?;
        let d2_r = rdet.div::<K0>(e1r)?;
        let dphi_k = -mul::<QA>(st.a22, d2_k);
        let dphi_r = -mul::<QA>(st.a22, d2_r);
        let dta_dk = narrow(((wide(t_phi, dphi_k) + wide(t_2, d2_k)) >> QT) + t_k as i64)?;
        // ∂T/∂R in Q24: near the contact it grows from zero (with δφ²), where Q16 would leave
        // the radius column of the first bins a per cent off.
        let dta_dr = narrow(
            ((wide(t_phi, dphi_r) + wide(t_2, d2_r)) >> (QD + QT - QR))
                + (wide(q, st.sp) >> (QD + QA - QR)),
        )?;
        Ok(QPoint {
            dphi: dphi + fin.0,
            d2: d2 + fin.1,
            k2: k2_fin,
            ta: ta_fin,
            dta_dk,
            dta_dr,
            stiffness,
            tangent: (tphi, t2),
            sens_k: (dphi_k, d2_k),
            sens_r: (dphi_r, d2_r),
        })
    }

    /// The path's tangent dδ/dθa at contact (Q24).
    fn tangent0(&self, kap: i32, rho: i32) -> Result<(i32, i32), PathFail> {
        let mut st = St::default();
        self.eval(kap, rho, 0, 0, &mut st)?;
        let r = Recip::new(st.det).ok_or(PathFail::OutOfRange)?;
        Ok((
            r.div::<{ QT as i32 }>(-st.c2)?,
            r.div::<{ QT as i32 }>(st.a11)?,
        ))
    }

    /// Hypothesis (k2,c, R) in m (Fx32) → units of l1 (Q28).
    fn to_l1(&self, v: Fx32) -> Result<i32, PathFail> {
        // Q32 m · Q24 /m → Q56 → Q28; |v| < 8 m keeps the product in i64.
        let b = v.to_bits();
        if b.unsigned_abs() >= 1 << 35 {
            return Err(PathFail::OutOfRange);
        }
        narrow((b * self.tb.inv_l1 as i64) >> 28)
    }
}

/// √x for x in Q16 within [0, 1] (the result in Q16, within one unit of the rounded root):
/// Newton's iteration from a power of two above the root, which it approaches from above.
fn sqrt_q16(x: i32) -> i32 {
    if x >= 1 << 16 {
        return 1 << 16;
    }
    let v = (x.max(0) as u32) << 16;
    if v == 0 {
        return 0;
    }
    let mut r = 1u32 << (32 - v.leading_zeros()).div_ceil(2);
    for _ in 0..5 {
        // r stays at or above √v ≥ 1: the division is never by zero (and has no panic path).
        r = (r + v.checked_div(r).unwrap_or(v)) / 2;
    }
    r as i32
}

/// Fx32 bits from a sum in Q`q` of N·m-based products, times 10^6 (the fit's statistics
/// are in (mN·m)²), saturating: value·1e6 in Q32 = sum·15625·2^(38 − q).
#[inline(always)]
fn stat_bits(sum: i64, q: u32) -> Fx32 {
    const LIM: i64 = i64::MAX / 15625;
    let v = if q >= 38 {
        (sum.clamp(-LIM, LIM) * 15625) >> (q - 38)
    } else {
        let lim = LIM >> (38 - q);
        if sum.abs() <= lim {
            (sum * 15625) << (38 - q)
        } else if sum > 0 {
            i64::MAX
        } else {
            -i64::MAX
        }
    };
    Fx32::from_bits(v)
}

impl Kernel<Fx32> for QKernel<'_> {
    fn l2(&self) -> Fx32 {
        self.tb.model.l2()
    }
    fn theta_a_c(&self) -> Fx32 {
        self.theta_a_c
    }
    fn tac(&self) -> Fx32 {
        self.contact.ta
    }
    fn contact(&self) -> Config<Fx32> {
        self.contact
    }
    fn set_contact(&mut self, theta_a_c: Fx32) -> Result<(), PtsError> {
        if theta_a_c != self.theta_a_c {
            self.solve_contact(theta_a_c, true)?;
        }
        Ok(())
    }

    fn evaluate(
        &mut self,
        w: &mut Work<Fx32>,
        p: &[Fx32; NP],
        out: &mut Eval<Fx32>,
    ) -> Result<(), PathFail> {
        w.evals += 1;
        self.set_contact(p[TC])?;
        let tb = self.tb;
        let kap = self.to_l1(p[super::K])?;
        let rho = self.to_l1(p[RAD])?;
        let shift = narrow(fx_to_q28(p[TC] - w.theta_a_c0))?;
        const FREE: i32 = (1e-6 * (1u64 << QA) as f64) as i32;
        const COL_MAX: i32 = 1 << 28;
        let nb = w.nb.min(MAX_BINS);
        let mut res = [0i32; MAX_BINS];
        let mut cols = [[0i32; NP]; MAX_BINS];
        let mut prev_pt: Option<(i32, i32, i32, (i32, i32))> = None;
        let mut k_first: Option<i32> = None;
        let (mut k2_last, mut last) = (0i32, (0i32, 0i32));
        let mut sum_r = 0i64;
        for i in 0..nb {
            let b = self.bins[i];
            let dta = narrow(b.dta as i64 - shift as i64)?;
            let (r, col) = if dta <= FREE {
                // Free motion below the contact, linearised about θa,c.
                let r = b.t as i64 - self.tac as i64 - (wide(self.kfree, dta) >> (QD + QA - QT));
                (narrow(r)?, [0, 0, 1 << QD, 0])
            } else {
                let guess = match (self.prev[i], prev_pt) {
                    (Some(q), _) => {
                        let (dk, dr) = (kap - q.kap, rho - q.rho);
                        (
                            q.dphi + mul::<QT>(q.sens_k.0, dk) + mul::<QT>(q.sens_r.0, dr),
                            q.d2 + mul::<QT>(q.sens_k.1, dk) + mul::<QT>(q.sens_r.1, dr),
                        )
                    }
                    (None, Some((dta0, dphi0, d20, t))) => {
                        let step = dta - dta0;
                        (dphi0 + mul::<QT>(t.0, step), d20 + mul::<QT>(t.1, step))
                    }
                    (None, None) => {
                        let t = self.tangent0(kap, rho)?;
                        (mul::<QT>(t.0, dta), mul::<QT>(t.1, dta))
                    }
                };
                let pt = self.point(kap, rho, dta, guess)?;
                prev_pt = Some((dta, pt.dphi, pt.d2, pt.tangent));
                self.prev[i] = Some(QPrev {
                    kap,
                    rho,
                    dphi: pt.dphi,
                    d2: pt.d2,
                    sens_k: pt.sens_k,
                    sens_r: pt.sens_r,
                });
                k_first.get_or_insert(pt.stiffness);
                k2_last = pt.k2;
                last = (pt.dphi, pt.d2);
                // ∂T/∂p per (l2, l2, N·m, rad): Q16, the radius Q24.
                let col = [
                    mul::<QA>(pt.dta_dk, tb.l2_l1),
                    mul::<QA>(pt.dta_dr, tb.l2_l1),
                    1 << QD,
                    self.kfree - pt.stiffness,
                ];
                (narrow(b.t as i64 - pt.ta as i64)?, col)
            };
            // Every column below 2^28 in magnitude exactly when the OR of the magnitudes is
            // (one test, not four).
            let mag = col.iter().fold(0u32, |m, c| m | c.unsigned_abs());
            if mag >= COL_MAX as u32 || r.unsigned_abs() > 1 << 29 {
                // (|∂T/∂R| within 2^28 in Q24 too: 16 N·m per l2.)
                return Err(PathFail::OutOfRange);
            }
            sum_r += wide(b.w, r);
            res[i] = r;
            cols[i] = col;
        }
        // Optimal offset with the approach prior: (Σ w r + w_p T_f,prior)/(Σ w + w_p), with
        // the weights' own sum (n/N in Q16 sums to a little below 1): the T_f gradient is
        // then zero to the rounding of T_f, as it is for the exact weights. A residual of
        // that sum would leak, through T_f's strong coupling, into the other steps.
        let z = Fx32::zero();
        let ks = w.ks;
        let wp = w.prior_w[TF];
        let sw: i64 = self.bins.iter().take(nb).map(|b| b.w as i64).sum();
        let tf_data = Fx32::from_bits(sum_r >> (QT + QD - 32));
        let tf = (tf_data + wp * w.prior[TF]) / (Fx32::from_bits(sw << (32 - QD)) + wp);
        let tf_q = narrow((tf.to_bits() + (1 << (31 - QT))) >> (32 - QT))?;
        // The normal equations in integers: columns K, R, θa,c in Q16; the T_f column is 1
        // for every bin, so its products are sums of the weights.
        let (mut skk, mut skr, mut skt, mut srr, mut srt, mut stt) =
            (0i64, 0i64, 0i64, 0i64, 0i64, 0i64);
        let (mut swk, mut swr, mut swt, mut sw) = (0i64, 0i64, 0i64, 0i64);
        let (mut sgk, mut sgr, mut sgt, mut sgf, mut ss) = (0i64, 0i64, 0i64, 0i64, 0i64);
        for (b, (&r, c)) in self.bins.iter().zip(res.iter().zip(cols.iter())).take(nb) {
            let r = r - tf_q;
            // w·r rounded (not floored: a floor's bias adds up over the bins), and exact for
            // the T_f gradient, which the optimal T_f makes zero.
            let wr_full = wide(b.w, r);
            let wr = ((wr_full + (1 << (QD - 1))) >> QD) as i32;
            ss += wide(wr, r);
            let [ck, cr, _, ct] = *c;
            sgk += wide(wr, ck);
            sgr += wide(wr, cr);
            sgt += wide(wr, ct);
            sgf += wr_full;
            // The normal matrix as the exact Gram matrix of the √w-scaled columns: positive
            // semidefinite whatever their rounding. Rounding w·c on one side only (12 bits
            // at 8 bins) made it indefinite where θa,c and T_f are nearly collinear.
            let s = b.sqrt_w;
            let (uk, ur, ut) = (mul::<QD>(s, ck), mul::<QD>(s, cr), mul::<QD>(s, ct));
            skk += wide(uk, uk);
            skr += wide(uk, ur);
            skt += wide(uk, ut);
            srr += wide(ur, ur);
            srt += wide(ur, ut);
            stt += wide(ut, ut);
            swk += wide(s, uk);
            swr += wide(s, ur);
            swt += wide(s, ut);
            sw += wide(s, s);
        }
        let q2 = 2 * QD;
        let (ak, ar, at, af) = (
            [
                stat_bits(skk, q2),
                stat_bits(skr, QD + QR),
                stat_bits(swk, q2),
                stat_bits(skt, q2),
            ],
            stat_bits(srr, 2 * QR),
            [
                stat_bits(srt, QR + QD),
                stat_bits(swt, q2),
                stat_bits(stt, q2),
            ],
            [stat_bits(swr, QR + QD), stat_bits(sw, q2)],
        );
        // Rows (K, RAD, TF, TC), symmetric.
        let mut a = [
            ak,
            [ak[1], ar, af[0], at[0]],
            [ak[2], af[0], af[1], at[1]],
            [ak[3], at[0], at[1], at[2]],
        ];
        let gq = QT + QD;
        let mut g = [
            -stat_bits(sgk, gq),
            -stat_bits(sgr, QT + QR),
            -stat_bits(sgf, QT + QD),
            -stat_bits(sgt, gq),
        ];
        let dp = (w.prior[TF] - tf) * ks;
        let mut sse = stat_bits(ss, 2 * QT) + wp * dp * dp;
        let _ = z;
        a[TF][TF] = a[TF][TF] + wp * ks * ks;
        g[TF] = g[TF] - wp * ks * dp;
        let wc = w.prior_w[TC];
        let dc = w.prior[TC] - p[TC];
        sse = sse + wc * dc * dc;
        a[TC][TC] = a[TC][TC] + wc;
        g[TC] = g[TC] - wc * dc;
        let fx = |v: i32, q: u32| Fx32::from_bits((v as i64) << (32 - q));
        *out = Eval {
            a,
            g,
            sse,
            tf,
            k2_last: Fx32::from_bits(wide(k2_last, tb.l1) >> (2 * QA - 32)),
            k_first: fx(k_first.unwrap_or(0), QD),
            last: (fx(last.0, QA), fx(last.1, QA)),
        };
        Ok(())
    }

    fn chord_stiffness(&self, nb: usize) -> Option<Fx32> {
        let bins = self.bins.get(..nb)?;
        let i0 = bins.iter().position(|b| b.dta > 0).unwrap_or(0);
        let a = bins.get(i0)?;
        let b = bins.get(i0 + (bins.len().saturating_sub(i0)) / 2)?;
        let dth = b.dta as i64 - a.dta as i64;
        if dth <= (1e-6 * (1u64 << QA) as f64) as i64 {
            return None;
        }
        // Q24 / Q28 → N·m/rad, in Fx32.
        let num = (b.t as i64 - a.t as i64) << (32 - QT);
        Some(Fx32::from_bits(num) / Fx32::from_bits(dth << (32 - QA)))
    }

    fn proximal_clearance(&self, k2c: Fx32, radius: Fx32, dphi: Fx32, d2: Fx32) -> Option<Fx32> {
        let kap = self.to_l1(k2c).ok()?;
        let rho = self.to_l1(radius).ok()?;
        let d1 = i32::try_from(fx_to_q28(dphi - d2)).ok()?;
        if d1.unsigned_abs() > (2.0 * MAX_DELTA * (1u64 << QA) as f64) as u32 {
            return None;
        }
        // C − O1 in the contact frame, in units of l1; the proximal phalanx at δ1 − θ2c.
        let cx = self.c2c + kap;
        let cy = rho - self.s2c;
        let (sd, cd) = sin_cos_wide(d1);
        let ce = mul::<QA>(cd, self.c2c) + mul::<QA>(sd, self.s2c);
        let se = mul::<QA>(sd, self.c2c) - mul::<QA>(cd, self.s2c);
        let along = mul::<QA>(cx, ce) + mul::<QA>(cy, se);
        let normal = mul::<QA>(cy, ce) - mul::<QA>(cx, se);
        (along > 0 && along < ONE)
            .then(|| Fx32::from_bits(wide(normal - rho, self.tb.l1) >> (2 * QA - 32)))
    }

    fn counters(&self) -> (u32, u16) {
        (self.newton, 0)
    }
}

/// The backwards sample pass in the controller's integers (the same cleaning as
/// `super::bin_samples`: inertia removed, stiction plateaus dropped, lower envelope in time,
/// θa bins with their within-bin scatter), filling the kernel's bins and `w`.
#[inline(never)]
fn bin_raw<I>(
    k: &mut QKernel<'_>,
    w: &mut Work<Fx32>,
    theta_meas_c: Fx32,
    samples: I,
) -> Result<(), PathFitError>
where
    I: DoubleEndedIterator<Item = RawSample>,
{
    let sc = k.tb.samples;
    let nbins = sc.nbins as usize;
    // θa,c (measured frame) in µrad, Q16.
    let thc_q16 = ((theta_meas_c.to_bits() as i128 * 1_000_000) >> 16) as i64;
    // (period in ticks, J/h²) of the last uniform pair; period 0: none yet.
    let mut k_uniform = (0u32, 0i32);
    // Backwards: the latest sample as it is, every inner one corrected with its neighbours
    // (or dropped on a plateau), the earliest as it is. The latest is always kept by the
    // envelope and fixes the bins: from θa,c (+ dead band + skip, or − the approach span)
    // to its θa.
    let mut it = samples.rev();
    let Some(mut n) = it.next() else {
        return Err(PathFitError::NoMotion);
    };
    let hi = n.theta_a_urad;
    let travel = ((hi as i64) << 16) - thc_q16 - sc.dead_urad_q16;
    if travel <= sc.min_travel_urad_q16 {
        return Err(PathFitError::NoMotion);
    }
    let lo_q16 = match sc.approach_urad_q16 {
        Some(span) => thc_q16 - span,
        None => thc_q16 + sc.dead_urad_q16 + ((travel as i128 * sc.skip_q16 as i128) >> 16) as i64,
    };
    // Below hi and within i32 (min, then max: `clamp` would check that hi − 1 ≥ i32::MIN,
    // with a panic path; for hi = i32::MIN this gives i32::MIN, and a span of 1).
    let lo = ((lo_q16 + 0xFFFF) >> 16)
        .min(hi as i64 - 1)
        .max(i32::MIN as i64) as i32;
    // The bins live apart from the binner (which borrows them): zeroed once in place, not
    // built in a temporary and copied (672 bytes on the Cortex-M4).
    let mut bins = BinAcc::ZEROS;
    let mut acc = Binner {
        lo,
        // At least 1: a nonzero divisor by type (no division-by-zero path).
        span: NonZeroU32::new((hi as i64 - lo as i64).clamp(1, u32::MAX as i64) as u32)
            .unwrap_or(NonZeroU32::MIN),
        nbins: sc.nbins,
        envelope: sc.envelope_urad,
        min_th: hi,
        limit: hi.saturating_add(sc.envelope_urad),
        last_kept: hi,
        bins: &mut bins,
    };
    acc.push(hi, n.torque_unm);
    if let Some(mut c) = it.next() {
        for p in it.by_ref() {
            let th = c.theta_a_urad;
            let plateau = sc.drop_plateaus && (th == p.theta_a_urad || th == n.theta_a_urad);
            if !plateau && acc.keep(th) {
                acc.push(th, correct(&sc, &mut k_uniform, p, c, n).torque_unm);
            }
            n = c;
            c = p;
        }
        if acc.keep(c.theta_a_urad) {
            acc.push(c.theta_a_urad, c.torque_unm);
        }
    }
    let mut nb = 0usize;
    let mut total = 0u32;
    // Centred moments of each used bin (µrad², µN·m², µrad·µN·m) and the means in µ units Q16.
    const NO_MOM: [[i64; 3]; MAX_BINS] = [[0; 3]; MAX_BINS];
    const NO_MEAN: [(i64, i64); MAX_BINS] = [(0, 0); MAX_BINS];
    let mut mom = NO_MOM;
    let mut mean = NO_MEAN;
    for bin in acc.bins.iter().take(nbins) {
        let c = bin.n;
        if c == 0 {
            continue;
        }
        // The nb-th used bin's slots (nb counts the used bins before this one, so it is below
        // MAX_BINS: never the `else`, which only spares a bounds check's panic path).
        let (Some(me), Some(mo), Some(kb)) =
            (mean.get_mut(nb), mom.get_mut(nb), k.bins.get_mut(nb))
        else {
            break;
        };
        let a = bin.s;
        // Means (Q16) by the reciprocal of the count: one hardware division.
        let (mth_q16, mt_q16) = if c == 1 {
            (a[0] << 16, a[1] << 16)
        } else {
            let inv = (u32::MAX / c) as i32; // ≈ 2^32/c, c ≥ 2
            (
                mul_shr(a[0], inv, 16).unwrap_or(0),
                mul_shr(a[1], inv, 16).unwrap_or(0),
            )
        };
        *me = (
            ((bin.th0 as i64) << 16) + mth_q16,
            ((bin.t0 as i64) << 16) + mt_q16,
        );
        *mo = [
            a[2].saturating_sub(mul_sat(a[0], mth_q16) >> 16),
            a[3].saturating_sub(mul_sat(a[1], mt_q16) >> 16),
            a[4].saturating_sub(mul_sat(a[0], mt_q16) >> 16),
        ];
        *kb = QBin {
            n: c,
            // µrad Q16 → rad Q28: · 2^12 / 10^6; µN·m Q16 → N·m Q24: · 2^8 / 10^6 (both
            // 4.096e-3 · 2^34 / 2^32 on a quarter: constant to 1e-9, products within i64).
            dta: clamp32((((me.0 - thc_q16).clamp(-(1 << 37), 1 << 37) >> 2) * MICRO_Q34) >> 32),
            t: clamp32(((me.1.clamp(-(1 << 37), 1 << 37) >> 2) * MICRO_Q34) >> 36),
            w: 0,
            sqrt_w: 0,
        };
        nb += 1;
        total = total.saturating_add(c);
    }
    if nb < MIN_BINS {
        return Err(PathFitError::TooFewSamples);
    }
    // Within-bin scatter about the local trend (slope from the neighbouring bins' means).
    let mut ss = 0i64;
    // The used bins (nb ≤ MAX_BINS, see above); each with its neighbours' means, the first
    // and last standing for their own missing neighbour.
    let used = mean.get(..nb).unwrap_or(&[]);
    for (i, m) in mom.iter().take(used.len()).enumerate() {
        let (Some(&a), Some(&b)) = (
            used.get(i.saturating_sub(1)),
            used.get(i + 1).or(used.last()),
        ) else {
            break;
        };
        let dth = b.0 - a.0;
        // Slope in µN·m per µrad (= N·m/rad), Q16.
        // Δt (µN·m, Q16) / Δθ (µrad, Q8): Q16 − 16 + 8 → K = 8.
        let sl = match Recip::new(clamp32(dth >> 8)) {
            Some(r) if dth > (1 << 16) / 10 => r.div64::<8>(b.1 - a.1).unwrap_or(0),
            _ => 0,
        };
        let v = m[1]
            .saturating_sub(mul_sat(sl.saturating_mul(2), m[2]) >> 16)
            .saturating_add(mul_sat(sl, mul_sat(sl, m[0]) >> 16) >> 16);
        ss = ss.saturating_add(v.max(0));
    }
    let dof = total.saturating_sub(nb as u32).max(1) as i64;
    // Per sample, µN·m² → (mN·m)² in Q32: · 2^32 / 10^6 = · (4295 − 0.032704), the second
    // term as 34292 / 2^20 (to 1e-9 relative); ss ≥ 0, and below 2^47 (the torque deviations
    // are clamped to 8 N·m) so that both products stay in i64.
    let per = (ss / dof).min(1 << 47);
    w.var_sample = Fx32::from_bits(per * 4295 - ((per * 34_292) >> 20));
    w.inv_n = Fx32::one() / Fx32::from_bits((total as i64) << 32);
    for b in k.bins.iter_mut().take(nb) {
        // n ≤ 2^15 per bin: n·2^16 within u32.
        b.w = ((b.n << QD) / total.max(1)) as i32;
        b.sqrt_w = sqrt_q16(b.w);
    }
    w.nb = nb;
    w.n_total = total;
    Ok(())
}

/// One θa bin of the sample pass: count, the first sample (θ µrad, T µN·m) and the sums
/// Σdθ, Σdt, Σdθ², Σdt², Σdθ·dt about it.
#[derive(Clone, Copy, Debug, Default)]
struct BinAcc {
    n: u32,
    th0: i32,
    t0: i32,
    s: [i64; 5],
}

impl BinAcc {
    const ZERO: Self = BinAcc {
        n: 0,
        th0: 0,
        t0: 0,
        s: [0; 5],
    };
    /// All bins empty: one block clear (an array repeat expression clears element by
    /// element).
    const ZEROS: [Self; MAX_BINS] = [Self::ZERO; MAX_BINS];
}

/// The binning state of the sample pass.
struct Binner<'a> {
    /// Bins from `lo` over `span` (µrad) in `nbins` equal parts.
    lo: i32,
    span: NonZeroU32,
    nbins: u32,
    envelope: i32,
    /// The lowest θ so far, and it plus the envelope tolerance (saturating).
    min_th: i32,
    limit: i32,
    /// θ of the sample kept last: from the start the latest sample's, which opens the pass
    /// (a later test compares it only with a θ below `limit`, so below it).
    last_kept: i32,
    bins: &'a mut [BinAcc; MAX_BINS],
}

impl Binner<'_> {
    /// Most samples a bin takes (keeps its sums within i64 with the clamps below, and
    /// its weight's numerator n·2^16 within u32).
    const MAX_COUNT: u32 = 1 << 15;

    /// The lower envelope in time, latest sample first: θa within the envelope tolerance
    /// of every later sample and not the θa kept last (one sample per plateau). It needs
    /// θa only, so the inertial correction is computed for the kept samples alone.
    #[inline(always)]
    fn keep(&mut self, th: i32) -> bool {
        let below = th < self.limit;
        let moved = self.last_kept != th;
        if th < self.min_th {
            self.min_th = th;
            self.limit = th.saturating_add(self.envelope);
        }
        if below && moved {
            self.last_kept = th;
        }
        below && moved
    }

    /// A kept sample into its bin.
    #[inline(always)]
    fn push(&mut self, th: i32, t: i32) {
        if th < self.lo {
            return;
        }
        // floor(off·nbins/span) by the 32-bit divider (off within 2^28 µrad).
        let off = th.saturating_sub(self.lo).min(1 << 28) as u32;
        let i = ((off * self.nbins) / self.span).min(self.nbins - 1) as usize;
        let Some(b) = self.bins.get_mut(i) else {
            return;
        };
        if b.n >= Self::MAX_COUNT {
            return;
        }
        if b.n == 0 {
            (b.th0, b.t0) = (th, t);
        }
        // Clamped to ±1 rad and ±8 N·m about the bin's first sample (to the signed 21- and
        // 24-bit ranges: one SSAT each).
        let dth = th.saturating_sub(b.th0).clamp(-(1 << 20), (1 << 20) - 1);
        let dt = t.saturating_sub(b.t0).clamp(-(1 << 23), (1 << 23) - 1);
        b.s[0] += dth as i64;
        b.s[1] += dt as i64;
        b.s[2] += wide(dth, dth);
        b.s[3] += wide(dt, dt);
        b.s[4] += wide(dth, dt);
        b.n += 1;
    }
}

/// 4.096e-3 · 2^34: µ-units in Q16 to Q28 (·2^12/10^6) after a quarter, with a shift of 32.
const MICRO_Q34: i64 = 70_368_744;

/// a·b, saturating, with the full multiply only when an operand is large.
#[inline(always)]
fn mul_sat(a: i64, b: i64) -> i64 {
    if a.unsigned_abs() < 1 << 31 && b.unsigned_abs() < 1 << 31 {
        a * b
    } else {
        a.saturating_mul(b)
    }
}

/// `c` with the inertial torque J θ̈a removed (θ̈a from the second difference over its
/// neighbours; J/h² once per uniform period).
fn correct(
    sc: &SampleConsts,
    cache: &mut (u32, i32),
    p: RawSample,
    c: RawSample,
    n: RawSample,
) -> RawSample {
    let (dt1, dt2) = (c.tick.wrapping_sub(p.tick), n.tick.wrapping_sub(c.tick));
    if dt1 == dt2 && dt1 == cache.0 {
        // The controller's uniform period: J/h² cached (Q16 µN·m per µrad, within i32);
        // the second difference in saturating 32-bit arithmetic (QSUB).
        let dd = n
            .theta_a_urad
            .saturating_sub(c.theta_a_urad)
            .saturating_sub(c.theta_a_urad.saturating_sub(p.theta_a_urad));
        let corr = clamp32(wide(cache.1, dd) >> 16);
        return RawSample {
            torque_unm: c.torque_unm.saturating_sub(corr),
            ..c
        };
    }
    let d1 = c.theta_a_urad as i64 - p.theta_a_urad as i64;
    let d2 = n.theta_a_urad as i64 - c.theta_a_urad as i64;
    let corr = {
        if dt1 == 0 || dt2 == 0 || dt1 > 1 << 30 || dt2 > 1 << 30 || sc.inertia_q16 == 0 {
            return c;
        }
        if dt1 == dt2 {
            let k = sc.inertia_q16 / (dt1 as i64 * dt1 as i64);
            if let Ok(k) = i32::try_from(k) {
                *cache = (dt1, k);
            }
            ((k as i128 * (d2 - d1) as i128) >> 16).clamp(-(1 << 62), 1 << 62) as i64
        } else {
            // θ̈ = 2(d2/dt2 − d1/dt1)/span in µrad/tick² (Q16), then J/τ² θ̈. Gaps above 2^12
            // ticks or steps above 2^24 µrad are not a continuous record: left uncorrected.
            if dt1 > 1 << 12 || dt2 > 1 << 12 || d1.abs() > 1 << 24 || d2.abs() > 1 << 24 {
                return c;
            }
            let (t1, t2) = (dt1 as i64, dt2 as i64);
            let num = 2 * (d2 * t1 - d1 * t2);
            let acc_q16 = (num << 16) / (t1 * t2 * (t1 + t2));
            ((sc.inertia_q16 as i128 * acc_q16 as i128) >> 32).clamp(-(1 << 62), 1 << 62) as i64
        }
    };
    RawSample {
        torque_unm: clamp32(c.torque_unm as i64 - corr),
        ..c
    }
}

/// [`super::fit_path`] on the firmware's integer kernel: the same fit (model, cleaning,
/// priors, Levenberg–Marquardt, radius decision, σ, refusals), fixed point throughout, for
/// the finger and configuration of `table`.
///
/// `theta_a_c_rad` and `approach_torque_nm` as for [`super::fit_path`]; `samples` are the
/// controller's own (ticks of the period given to [`PathTable::new`], µrad, µN·m), in time
/// order, traversed backwards once. Cost on a Cortex-M4: see `crates/pathfit/benches/icount`.
pub fn fit_path_q<I>(
    table: &PathTable,
    theta_a_c_rad: Fx32,
    approach_torque_nm: Option<Fx32>,
    samples: I,
) -> Result<PathFit<Fx32>, PathFitError>
where
    I: IntoIterator<Item = RawSample>,
    I::IntoIter: DoubleEndedIterator,
{
    if theta_a_c_rad.is_saturated() {
        return Err(PathFitError::Model(PtsError::OutOfRange));
    }
    let c = table.consts;
    let theta_a_c = theta_a_c_rad - c.lead;
    let mut k = QKernel::new(table);
    k.solve_contact(theta_a_c, false)?;
    let mut w = Work::new(theta_a_c);
    bin_raw(&mut k, &mut w, theta_a_c_rad, samples.into_iter())?;
    run_fit(&mut k, &table.model, &c, &mut w, approach_torque_nm)
}

#[cfg(test)]
mod tests {
    //! The integer path points against an exact f64 solve of the same contact equations
    //! (library trigonometry, the model's exact closure, Newton to 1e-13) and its finite
    //! differences; the generic path model's interpolated points are printed beside it.
    use super::*;
    use crate::path::PathModel;
    extern crate std;

    fn q28(v: f64) -> i32 {
        to_q(v, QA).unwrap()
    }

    /// (δφ, δ2, k2, T_a) of the path point at Δθa for (k2,c, R) from the contact `c`,
    /// exactly: E1 = sin(θ2c+δ2) − sin(θ2c+δφ) − (k2c sin δφ + R(1 − cos δφ))/l1,
    /// E2 = δφ − (γ(θ2c+δ2) − γc) − Δθa, Newton with a central-difference Jacobian. T_a and
    /// the normal force f from the two joint balances with the sliding friction −µ f along
    /// the phalanx at the material point (moment arm l1 sin θ2 at O1, none at O2), solved as
    /// a 2×2 linear system (not the path model's closed form).
    #[allow(clippy::too_many_arguments)]
    fn exact(
        m: &Model<f64>,
        c: &Config<f64>,
        k2c: f64,
        r: f64,
        dta: f64,
        g: (f64, f64),
        mu: f64,
    ) -> [f64; 4] {
        let f = Finger::PAPER;
        let gc = m.closure(c.theta2).unwrap().gamma;
        let e = |x: (f64, f64)| {
            let (dphi, d2) = x;
            let gm = m.closure(c.theta2 + d2).unwrap().gamma;
            let mut dg = gm - gc;
            dg -= 2.0 * core::f64::consts::PI * libm::round(dg / (2.0 * core::f64::consts::PI));
            (
                libm::sin(c.theta2 + d2)
                    - libm::sin(c.theta2 + dphi)
                    - (k2c * libm::sin(dphi) + r * (1.0 - libm::cos(dphi))) / f.l1,
                dphi - dg - dta,
            )
        };
        let mut x = g;
        for _ in 0..60 {
            let h = 1e-7;
            let f0 = e(x);
            let fa = e((x.0 + h, x.1));
            let fb = e((x.0, x.1 + h));
            let j = [
                [(fa.0 - f0.0) / h, (fb.0 - f0.0) / h],
                [(fa.1 - f0.1) / h, (fb.1 - f0.1) / h],
            ];
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            let s0 = -(j[1][1] * f0.0 - j[0][1] * f0.1) / det;
            let s1 = -(j[0][0] * f0.1 - j[1][0] * f0.0) / det;
            x = (x.0 + s0, x.1 + s1);
            if s0.abs() + s1.abs() < 1e-13 {
                break;
            }
        }
        let (dphi, d2) = x;
        let th2 = c.theta2 + d2;
        let cl = m.closure(th2).unwrap();
        let k2 = f.l1 * (libm::cos(c.theta2 + dphi) - libm::cos(th2))
            + k2c * libm::cos(dphi)
            + r * libm::sin(dphi);
        let (d1, dd2) = (c.theta1 - f.theta01 + dphi - d2, th2 - f.theta02);
        // T·1 = K1 Δ1 + f (l1 cos θ2 + k2) − µ f l1 sin θ2;  T·x2 = K2 Δ2 + f k2.
        let arm = f.l1 * libm::cos(th2) + k2 - mu * f.l1 * libm::sin(th2);
        let (a11, a12, b1) = (1.0, -arm, f.k1 * d1);
        let (a21, a22, b2) = (cl.x2, -k2, f.k2 * dd2);
        let ta = (b1 * a22 - a12 * b2) / (a11 * a22 - a12 * a21);
        [dphi, d2, k2, ta]
    }

    /// The bin weights' root against f64 over every Q16 weight: within one unit.
    #[test]
    fn sqrt_q16_is_the_root_to_one_unit() {
        for x in 0..=(1 << 16) {
            let exact = (f64::from(x) / 65_536.0).sqrt() * 65_536.0;
            let got = f64::from(sqrt_q16(x));
            assert!((got - exact).abs() <= 1.0, "√{x}: {got} vs {exact}");
        }
        assert_eq!(sqrt_q16(-5), 0);
        assert_eq!(sqrt_q16(1 << 20), 1 << 16);
    }

    #[test]
    fn node_fraction_is_the_64_bit_quotient() {
        let reference = |x: i32, d: i32| ((x as i64) << 24) / d as i64;
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for _ in 0..200_000 {
            // Divisors on both sides of the digit path's 2^28 and at its ends.
            let d = match next() % 4 {
                0 => (next() % (1 << 28)) as i32 + 1,
                1 => (1 << 28) - 1 - (next() % 64) as i32,
                2 => (1 << 28) + (next() % (1 << 30)) as i32,
                _ => (next() % 4096) as i32 + 1,
            };
            let x = match next() % 3 {
                0 => (next() % d as u64) as i32,
                1 => d - 1,
                _ => 0,
            };
            assert_eq!(node_fraction(x, d), reference(x, d), "x {x} d {d}");
        }
    }

    /// A table rebuilt from its raw data is the same table: the same data and the same
    /// answers (a build-time table in flash is the one init would build).
    #[test]
    fn raw_round_trip_keeps_the_table() {
        let t = PathTable::new(&Finger::PAPER, &PathFitConfig::DEFAULT, 1e-4).unwrap();
        let raw = t.to_raw();
        let back = PathTable::from_raw(&raw);
        assert_eq!(back.to_raw(), raw);
        assert_eq!(back.tick_s().to_bits(), t.tick_s().to_bits());
        for i in 0..40 {
            let x = Fx32::from_f64(-1.2 + 0.08 * f64::from(i));
            assert_eq!(back.free_torque(x), t.free_torque(x));
        }
    }

    #[test]
    fn free_torque_matches_the_model() {
        free_torque_matches_the_model_for(&Finger::PAPER);
    }

    /// A soft distal spring (K2 × 0.75, K1 × 1.25): the excursion band above the free motion
    /// reaches the toggle (θ2 = 2.3557 rad), so the table is cut below it; the free motion it
    /// must cover is still whole.
    #[test]
    fn a_soft_distal_spring_cuts_the_table_at_the_toggle() {
        let f = soft_distal_finger();
        let table = PathTable::new(&f, &PathFitConfig::DEFAULT, 1e-4).unwrap();
        let raw = table.to_raw();
        let m64 = Model::<f64>::new(&f).unwrap();
        let top = m64.free_from_torque(TABLE_TA_MAX_NM).unwrap().theta2;
        let uncut = libm::ceil((top + ABOVE - raw.theta2_0 as f64 / ONE as f64) / SEG_STEP);
        assert!(
            (raw.segs as f64) < uncut,
            "table not cut: {} segments",
            raw.segs
        );
        let end = raw.theta2_0 as f64 / ONE as f64 + raw.segs as f64 * SEG_STEP;
        assert!(end > top && end < 2.3557, "table ends at θ2 = {end} rad");
        free_torque_matches_the_model_for(&f);
    }

    fn soft_distal_finger() -> Finger {
        Finger {
            k1: Finger::PAPER.k1 * 1.25,
            k2: Finger::PAPER.k2 * 0.75,
            ..Finger::PAPER
        }
    }

    /// The table's free motion against the f64 model's solve over the table's range
    /// (T_a ≈ −0.3 … 1.6 N·m): the torque the contact-point search reads, and the
    /// configuration the two-point estimate inverts at (angles, torque, transmission and its
    /// slope, cos θ2).
    fn free_torque_matches_the_model_for(f: &Finger) {
        let f = *f;
        let table = PathTable::new(&f, &PathFitConfig::DEFAULT, 1e-4).unwrap();
        let m64 = Model::<f64>::new(&f).unwrap();
        let mut worst = 0.0f64;
        let mut checked = 0;
        for i in 0..=60 {
            let tha = -1.3 + 0.05 * i as f64;
            let Ok(c) = m64.free_from_theta_a(tha) else {
                continue;
            };
            if !(-0.3..=1.6).contains(&c.ta) {
                continue;
            }
            let t = table.free_torque(Fx32::from_f64(tha)).unwrap().to_f64();
            worst = worst.max((t - c.ta).abs());
            let (q, cos2) = table.free_config(Fx32::from_f64(tha)).unwrap();
            let d = |a: Fx32, b: f64| (a.to_f64() - b).abs();
            assert!(d(q.theta_a, tha) < 1e-9, "θa at {tha}");
            assert!(d(q.theta1, c.theta1) < 1e-6, "θ1 at {tha}: {q:?} vs {c:?}");
            assert!(d(q.theta2, c.theta2) < 1e-6, "θ2 at {tha}: {q:?} vs {c:?}");
            assert!(d(q.ta, c.ta) < 2e-7, "T_a at {tha}: {q:?} vs {c:?}");
            assert!(d(q.x2, c.x2) < 1e-6, "x2 at {tha}: {q:?} vs {c:?}");
            assert!(d(q.dx2, c.dx2) < 1e-5, "dx2 at {tha}: {q:?} vs {c:?}");
            assert!(d(cos2, c.theta2.cos()) < 1e-6, "cos θ2 at {tha}");
            checked += 1;
        }
        assert!(checked >= 20, "only {checked} points in the table's range");
        assert!(worst < 2e-7, "free-motion torque off by {worst} N·m");
        // Outside the table: a typed error, no panic.
        assert!(table.free_torque(Fx32::from_f64(7.9)).is_err());
        assert!(table.free_torque(Fx32::from_f64(-7.9)).is_err());
        assert!(table.free_config(Fx32::from_f64(7.9)).is_err());
    }

    #[test]
    fn points_match_an_exact_f64_solve() {
        points_match_an_exact_f64_solve_at(0.0);
    }

    /// The same with sliding friction at the object contact (µ of a rubber-free rough pad).
    #[test]
    fn points_with_contact_friction_match_an_exact_f64_solve() {
        points_match_an_exact_f64_solve_at(0.4);
    }

    fn points_match_an_exact_f64_solve_at(mu: f64) {
        let f = Finger::PAPER;
        let cfg = PathFitConfig {
            contact_mu: mu,
            ..PathFitConfig::DEFAULT
        };
        let table = PathTable::new(&f, &cfg, 1e-4).unwrap();
        let m64 = Model::<f64>::new(&f).unwrap();
        let (mut worst, mut worst_generic) = ([0.0f64; 6], [0.0f64; 6]);
        let mut n = 0;
        for &tha in &[-0.35, -0.2236, -0.05, 0.2] {
            let mut pm = PathModel::<f64>::new(&m64, tha).unwrap();
            pm.set_contact_mu(mu);
            let mut k = QKernel::new(&table);
            k.solve_contact(Fx32::from_f64(tha), false).unwrap();
            // The contact configuration against the model's own free-motion solve.
            let c64 = m64.free_from_theta_a(tha).unwrap();
            assert!(
                (k.contact.theta2.to_f64() - c64.theta2).abs() < 2e-7,
                "θ2c at {tha}"
            );
            assert!(
                (k.contact.ta.to_f64() - c64.ta).abs() < 2e-7,
                "T_a,c at {tha}"
            );
            assert!((k.contact.x2.to_f64() - c64.x2).abs() < 2e-7, "x2 at {tha}");
            for &(kf, r) in &[
                (0.1, 0.0),
                (0.4, 0.0),
                (0.8, 0.0),
                (0.3, 0.01),
                (0.5, 0.05),
                (0.2, 0.0975),
            ] {
                let (k2c, radius) = (kf * f.l2, r);
                for &dta in &[0.002, 0.02, 0.08] {
                    let t = pm.tangent(&m64, k2c, radius, 0.0, 0.0).unwrap();
                    let Ok(p) = pm.point(&m64, k2c, radius, dta, (t.0 * dta, t.1 * dta)) else {
                        continue;
                    };
                    // Re-solved from its own answer: the last step (and so the point the
                    // derivatives are taken at) is then negligible.
                    let p = pm.point(&m64, k2c, radius, dta, (p.dphi, p.d2)).unwrap();
                    let (kap, rho) = (q28(k2c / f.l1), q28(radius / f.l1));
                    let t0 = k.tangent0(kap, rho).unwrap();
                    let d = q28(dta);
                    let q = match k.point(kap, rho, d, (mul::<QT>(t0.0, d), mul::<QT>(t0.1, d))) {
                        Ok(q) => q,
                        // Friction moves the locking point inward (self-locking): past the
                        // integer formats (T_a in Q24: ±128 N·m) a typed refusal is right.
                        Err(PathFail::OutOfRange) if p.ta.abs() > 100.0 => continue,
                        Err(e) => panic!("{e:?} at θa,c {tha}, k2,c {kf} l2, R {r}: {p:?}"),
                    };
                    let q = k.point(kap, rho, d, (q.dphi, q.d2)).unwrap();
                    let x = exact(&m64, &c64, k2c, radius, dta, (p.dphi, p.d2), mu);
                    let hk = 1e-6;
                    let fd = |dk: f64, dr: f64| {
                        let a = exact(&m64, &c64, k2c + dk, radius + dr, dta, (x[0], x[1]), mu)[3];
                        let b = exact(&m64, &c64, k2c - dk, radius - dr, dta, (x[0], x[1]), mu)[3];
                        (a - b) / (2.0 * (dk + dr))
                    };
                    let (dk_ex, dr_ex) = (fd(hk, 0.0), fd(0.0, hk));
                    let ds = 1e-6;
                    let st_ex = (exact(&m64, &c64, k2c, radius, dta + ds, (x[0], x[1]), mu)[3]
                        - exact(&m64, &c64, k2c, radius, dta - ds, (x[0], x[1]), mu)[3])
                        / (2.0 * ds);
                    let a = |v: i32| v as f64 / (1u64 << QA) as f64;
                    let tq = |v: i32| v as f64 / (1u64 << QT) as f64;
                    let dq = |v: i32| v as f64 / (1u64 << QD) as f64;
                    let rel = |v: f64, r: f64| (v - r).abs() / r.abs().max(1.0);
                    let eq = [
                        (tq(q.ta) - x[3]).abs(),
                        (a(q.dphi) - x[0]).abs(),
                        (a(q.k2) * f.l1 - x[2]).abs(),
                        rel(dq(q.dta_dk) / f.l1, dk_ex),
                        rel(tq(q.dta_dr) / f.l1, dr_ex),
                        rel(dq(q.stiffness), st_ex),
                    ];
                    let eg = [
                        (p.ta - x[3]).abs(),
                        (p.dphi - x[0]).abs(),
                        (p.k2 - x[2]).abs(),
                        rel(p.dta_dk2c, dk_ex),
                        rel(p.dta_dr, dr_ex),
                        rel(p.stiffness, st_ex),
                    ];
                    for i in 0..6 {
                        worst[i] = worst[i].max(eq[i]);
                        worst_generic[i] = worst_generic[i].max(eg[i]);
                    }
                    n += 1;
                }
            }
        }
        // T_a (N·m), δφ (rad), k2 (m), then ∂T/∂k2c, ∂T/∂R, dT/dθa (relative).
        std::println!(
            "{n} points; integer kernel worst {worst:?}; generic f64 path model {worst_generic:?}"
        );
        assert!(n > 50);
        // T_a within 1e-5 N·m (the worst point is the stiffest, 371 N·m/rad at 5.5 N·m,
        // where the 7e-8 rad of δφ become 7e-6 N·m), δφ within 1e-6 rad, k2 within 0.1 µm.
        assert!(
            worst[0] < 1e-5 && worst[1] < 1e-6 && worst[2] < 1e-7,
            "{worst:?}"
        );
        assert!(
            worst[3] < 1e-3 && worst[4] < 1e-3 && worst[5] < 1e-3,
            "{worst:?}"
        );
    }
}
