//! A free-motion table: the contact configuration from θa without a Newton solve.
//!
//! The two-point estimate spends almost all its work finding the free-motion configuration
//! at θa,c (a Newton solve, each step a four-bar closure with five trigonometric calls).
//! [`FreeTable`] replaces it by a lookup: θ2, θ1, x2, dx2/dθ2 and cos θ2 as piecewise cubic
//! (Hermite) functions of θa on a uniform grid, built once at init from the **f64** model
//! (values and central-difference slopes), then evaluated in the back end's arithmetic:
//! one multiply for the index and three per field (for Q32.32, 32-bit products where the
//! cubic's slope terms are small, as they are for the paper's finger). With cos θ2 in the
//! table (and l1 cos θ2/(2 l2), the form the inversion takes) the inversion
//! ([`Model::invert_cos`], the closed-form quadratic) needs no trigonometry at all.
//!
//! The grid spans the free motion for T_a from [`TABLE_TA_MIN_NM`] to [`TABLE_TA_MAX_NM`]
//! (θa ≈ −1.40 … 1.98 rad for the paper's finger; lower at the top for a finger so soft that
//! the free motion at that torque turns the crank off the model's branch, past π); outside it
//! the lookup falls back to the model's Newton solve, so the answers are the same function of
//! the inputs everywhere.

use crate::fixed::Fx32;
use crate::model::{Config, Estimate, Model, MODEL_RAW_WORDS};
use crate::real::Real;
use crate::{Finger, PtsError};

/// Intervals of the uniform θa grid.
pub const TABLE_INTERVALS: usize = 32;
/// Lowest free-motion torque covered by the table (N·m).
pub const TABLE_TA_MIN_NM: f64 = -0.3;
/// Highest free-motion torque covered by the table (N·m).
pub const TABLE_TA_MAX_NM: f64 = 1.6;
/// Fields per knot: θ2, θ1, x2, dx2/dθ2, cos θ2 and c = l1 cos θ2/(2 l2) (the scaled cosine
/// the inversion takes, so the estimate needs no multiply for it).
pub const FIELDS: usize = 6;

/// A back end the table can index: splits a non-negative grid coordinate into the
/// interval number and the fraction within it.
pub trait TableReal: Real {
    /// `(floor(t), t − floor(t))` for finite `t ≥ 0` below 2³¹; `None` otherwise.
    fn split_index(self) -> Option<(usize, Self)>;

    /// The cubic c0 + u(c1 + u(c2 + u·c3)) at a fraction u ∈ [0, 1) from
    /// [`TableReal::split_index`], for coefficients with Σ|c_i| ≤ [`MAX_COEFFICIENT_SUM`]
    /// (what [`FreeTable::new`] accepts): no partial sum can then overflow, so a back end
    /// may skip saturation (the result for other arguments is unspecified, never a panic).
    #[inline(always)]
    fn cubic(c: &[Self; 4], u: Self) -> Self {
        c[0] + u * (c[1] + u * (c[2] + u * c[3]))
    }

    /// [`TableReal::cubic`] for coefficients that also have |c1| + |c2| + |c3| ≤
    /// [`SMALL_SLOPE_SUM`] (every partial sum but the last below ½ in magnitude), which a
    /// back end may evaluate in narrower arithmetic. [`FreeTable`] uses it when every
    /// interval of every field qualifies (the paper's finger: ≤ 0.06).
    #[inline(always)]
    fn cubic_small(c: &[Self; 4], u: Self) -> Self {
        Self::cubic(c, u)
    }
}

/// Largest Σ|c_i| of one field's cubic on one interval that a table accepts.
pub const MAX_COEFFICIENT_SUM: f64 = 1e6;
/// Largest |c1| + |c2| + |c3| for [`TableReal::cubic_small`] (margin below ½).
pub const SMALL_SLOPE_SUM: f64 = 0.25;

impl TableReal for f64 {
    fn split_index(self) -> Option<(usize, Self)> {
        if !(0.0..2147483648.0).contains(&self) {
            return None;
        }
        let i = libm::floor(self);
        Some((i as usize, self - i))
    }
}

impl TableReal for f32 {
    fn split_index(self) -> Option<(usize, Self)> {
        if !(0.0..2147483648.0).contains(&self) {
            return None;
        }
        let i = libm::floorf(self);
        Some((i as usize, self - i))
    }
}

impl TableReal for crate::fixed::Fx32 {
    fn split_index(self) -> Option<(usize, Self)> {
        let b = self.to_bits();
        if b < 0 || self.is_saturated() {
            return None;
        }
        Some(((b >> 32) as usize, Self::from_bits(b & 0xFFFF_FFFF)))
    }

    #[inline(always)]
    fn cubic(c: &[Self; 4], u: Self) -> Self {
        // u < 1 and Σ|c_i| ≤ 1e6 bound every partial sum: one 64×32 product and a plain
        // add per step, truncated (≤ 3 units of 2^-32 in all).
        let u = u.to_bits() as u32;
        let mut p = c[3].to_bits();
        for c in [c[2], c[1], c[0]] {
            p = c.to_bits().wrapping_add(crate::fixed::mul_frac(p, u));
        }
        Self::from_bits(p)
    }

    #[inline(always)]
    fn cubic_small(c: &[Self; 4], u: Self) -> Self {
        // The partial sums c3, c2 + u·c3, c1 + u(…) are below ½: their raw bits fit in an
        // i32 and each step is one 32×32 product.
        use crate::fixed::mul_frac32;
        let u = u.to_bits() as u32;
        let mut p = c[3].to_bits() as i32;
        p = (c[2].to_bits() as i32).wrapping_add(mul_frac32(p, u));
        p = (c[1].to_bits() as i32).wrapping_add(mul_frac32(p, u));
        Self::from_bits(c[0].to_bits().wrapping_add(mul_frac32(p, u) as i64))
    }
}

#[cfg(feature = "bench-variants")]
impl TableReal for crate::fixed::Fx16 {
    fn split_index(self) -> Option<(usize, Self)> {
        let b = self.to_bits();
        if b < 0 || self.is_saturated() {
            return None;
        }
        Some(((b >> 16) as usize, Self::from_bits(b & 0xFFFF)))
    }
}

#[cfg(feature = "bench-variants")]
impl TableReal for crate::fixed::Fx24 {
    fn split_index(self) -> Option<(usize, Self)> {
        let b = self.to_bits();
        if b < 0 || self.is_saturated() {
            return None;
        }
        Some(((b >> 24) as usize, Self::from_bits(b & 0xFF_FFFF)))
    }
}

/// One interval: per field the cubic a0 + u(a1 + u(a2 + u·a3)), u ∈ [0, 1).
#[derive(Clone, Copy, Debug)]
struct Segment<R> {
    c: [[R; 4]; FIELDS],
}

/// The free-motion curve of one finger as a table over θa, with the model it came from.
#[derive(Clone, Debug)]
pub struct FreeTable<R> {
    model: Model<R>,
    theta_a0: R,
    inv_h: R,
    k1: R,
    theta01: R,
    /// Every cubic qualifies for [`TableReal::cubic_small`].
    small: bool,
    seg: [Segment<R>; TABLE_INTERVALS],
}

/// Free-motion fields at θa from the f64 model: θ2, θ1, x2, dx2, cos θ2, l1 cos θ2/(2 l2).
fn fields(m: &Model<f64>, theta_a: f64) -> Result<[f64; FIELDS], PtsError> {
    let c = m.free_from_theta_a(theta_a)?;
    let cos2 = libm::cos(c.theta2);
    Ok([c.theta2, c.theta1, c.x2, c.dx2, cos2, cos2 * m.cos_scale()])
}

/// Torque step (N·m) by which the table's top comes down for a finger that has no free
/// motion up to [`TABLE_TA_MAX_NM`].
const TOP_STEP_NM: f64 = 0.05;

/// The θa (rad) of the table's top: the free motion at [`TABLE_TA_MAX_NM`]. Soft springs let
/// the free motion at that torque turn the crank past π, where the model's solution leaves
/// its branch (θa jumps by 2π, or the solve fails): such a finger's table ends at the highest
/// torque [`TOP_STEP_NM`] lower whose free motion is on the branch (θa below π and rising with
/// the torque), far above any contact it grasps; lookups above it fall back to the model.
/// No such torque 0.3 N·m above [`TABLE_TA_MIN_NM`]: refused as the model refuses.
fn top_theta_a(m64: &Model<f64>, lo: f64) -> Result<f64, PtsError> {
    let mut ta = TABLE_TA_MAX_NM;
    loop {
        let top = m64.free_from_torque(ta).and_then(|c| {
            let below = m64.free_from_torque(ta - TOP_STEP_NM)?.theta_a;
            let on_branch = c.theta_a < core::f64::consts::PI && c.theta_a > below && below > lo;
            if on_branch {
                Ok(c.theta_a)
            } else {
                Err(PtsError::NoConvergence)
            }
        });
        match top {
            Ok(t) => return Ok(t),
            Err(e) if ta - TOP_STEP_NM < TABLE_TA_MIN_NM + 0.3 => return Err(e),
            Err(_) => ta -= TOP_STEP_NM,
        }
    }
}

impl<R: TableReal> FreeTable<R> {
    /// Builds the table from the f64 model of `finger` (about 100 free-motion solves).
    ///
    /// Fails like [`Model::new`], with [`PtsError::OutOfRange`] when the finger has no
    /// free motion over the table's torque range (K1 = 0) or a value does not fit `R`.
    pub fn new(finger: &Finger) -> Result<Self, PtsError> {
        let m64 = Model::<f64>::new(finger)?;
        let model = Model::<R>::new(finger)?;
        if !(finger.k1 > 0.0) {
            return Err(PtsError::OutOfRange);
        }
        let lo = m64.free_from_torque(TABLE_TA_MIN_NM)?.theta_a;
        let hi = top_theta_a(&m64, lo)?;
        if !(hi > lo) {
            return Err(PtsError::OutOfRange);
        }
        let h = (hi - lo) / TABLE_INTERVALS as f64;
        let conv = |v: f64| R::try_from_f64(v).ok_or(PtsError::OutOfRange);
        // Values and slopes (per interval, i.e. ×h) at the knots.
        let delta = 1e-5;
        let knot = |i: usize| -> Result<([f64; FIELDS], [f64; FIELDS]), PtsError> {
            let t = lo + h * i as f64;
            let (v, a, b) = (
                fields(&m64, t)?,
                fields(&m64, t - delta)?,
                fields(&m64, t + delta)?,
            );
            let mut d = [0.0; FIELDS];
            for ((d, a), b) in d.iter_mut().zip(a).zip(b) {
                *d = (b - a) / (2.0 * delta) * h;
            }
            Ok((v, d))
        };
        let zero = R::zero();
        let mut seg = [Segment {
            c: [[zero; 4]; FIELDS],
        }; TABLE_INTERVALS];
        let mut small = true;
        let mut prev = knot(0)?;
        for (i, s) in seg.iter_mut().enumerate() {
            let next = knot(i + 1)?;
            let ((p0, m0), (p1, m1)) = (prev, next);
            for (f, c) in s.c.iter_mut().enumerate() {
                let v = [
                    p0[f],
                    m0[f],
                    3.0 * (p1[f] - p0[f]) - 2.0 * m0[f] - m1[f],
                    2.0 * (p0[f] - p1[f]) + m0[f] + m1[f],
                ];
                if !(v.iter().map(|x| x.abs()).sum::<f64>() <= MAX_COEFFICIENT_SUM) {
                    return Err(PtsError::OutOfRange);
                }
                small &= v[1].abs() + v[2].abs() + v[3].abs() <= SMALL_SLOPE_SUM;
                *c = [conv(v[0])?, conv(v[1])?, conv(v[2])?, conv(v[3])?];
            }
            prev = next;
        }
        Ok(Self {
            model,
            theta_a0: conv(lo)?,
            inv_h: conv(1.0 / h)?,
            k1: conv(finger.k1)?,
            theta01: conv(finger.theta01)?,
            small,
            seg,
        })
    }

    /// The model the table was built for, on the same back end.
    pub fn model(&self) -> &Model<R> {
        &self.model
    }

    /// The θa range (rad) the table covers; outside it lookups fall back to Newton.
    pub fn theta_a_range(&self) -> (f64, f64) {
        let lo = self.theta_a0.to_f64();
        (lo, lo + TABLE_INTERVALS as f64 / self.inv_h.to_f64())
    }

    /// The interval holding θa and the fraction within it; `None` outside the table.
    #[inline(always)]
    fn locate(&self, theta_a: R) -> Option<(&Segment<R>, R)> {
        let t = (theta_a - self.theta_a0) * self.inv_h;
        let (i, u) = t.split_index()?;
        Some((self.seg.get(i)?, u))
    }

    /// Field `f` of segment `s` at the fraction `u`.
    #[inline(always)]
    fn field(&self, s: &Segment<R>, f: usize, u: R) -> R {
        let c = &s.c[f];
        if self.small {
            R::cubic_small(c, u)
        } else {
            R::cubic(c, u)
        }
    }

    /// Free-motion configuration at θa (rad) and its cos θ2, interpolated (no trigonometry,
    /// no division) inside the table, by the model's Newton solve outside it.
    pub fn free_from_theta_a(&self, theta_a: R) -> Result<(Config<R>, R), PtsError> {
        if !theta_a.is_finite() || theta_a.is_saturated() {
            return Err(PtsError::NonFinite);
        }
        let Some((s, u)) = self.locate(theta_a) else {
            let c = self.model.free_from_theta_a(theta_a)?;
            return Ok((c, c.theta2.cos()));
        };
        let theta1 = self.field(s, 1, u);
        let cfg = Config {
            theta1,
            theta2: self.field(s, 0, u),
            theta_a,
            ta: self.k1 * (theta1 - self.theta01),
            x2: self.field(s, 2, u),
            dx2: self.field(s, 3, u),
        };
        Ok((cfg, self.field(s, 4, u)))
    }

    /// The free-motion torque T_a = K1(θ1 − θ01) (N·m) at θa (rad): one cubic inside the
    /// table, the model's Newton solve outside it.
    pub fn free_torque(&self, theta_a: R) -> Result<R, PtsError> {
        match self.free_torque_in_table(theta_a) {
            Err(PtsError::OutOfRange) => Ok(self.model.free_from_theta_a(theta_a)?.ta),
            r => r,
        }
    }

    /// [`FreeTable::free_torque`] inside the table only: [`PtsError::OutOfRange`] outside it
    /// (a caller that needs no Newton solve links none).
    pub fn free_torque_in_table(&self, theta_a: R) -> Result<R, PtsError> {
        if !theta_a.is_finite() || theta_a.is_saturated() {
            return Err(PtsError::NonFinite);
        }
        let (s, u) = self.locate(theta_a).ok_or(PtsError::OutOfRange)?;
        let ta = self.k1 * (self.field(s, 1, u) - self.theta01);
        if ta.is_saturated() {
            return Err(PtsError::Overflow);
        }
        Ok(ta)
    }

    /// The paper's two-point estimate ([`Model::estimate_two_point`]) with the contact
    /// configuration from the table (the model's Newton solve outside it).
    pub fn estimate_two_point(
        &self,
        theta_a_c: R,
        ta_c: R,
        theta_a: R,
        ta: R,
    ) -> Result<Estimate<R>, PtsError> {
        self.estimate_with(theta_a_c, ta_c, theta_a, ta, |t| {
            let (cfg, cos2) = self.free_from_theta_a(t)?;
            Ok((cfg, self.model.scaled_cos(cos2)?))
        })
    }

    /// [`FreeTable::estimate_two_point`] with θa,c inside the table only:
    /// [`PtsError::OutOfRange`] outside it (a caller that needs no Newton solve links none).
    pub fn estimate_two_point_in_table(
        &self,
        theta_a_c: R,
        ta_c: R,
        theta_a: R,
        ta: R,
    ) -> Result<Estimate<R>, PtsError> {
        self.estimate_with(theta_a_c, ta_c, theta_a, ta, |_| Err(PtsError::OutOfRange))
    }

    /// The estimate with the table's contact configuration, `outside` where θa,c is not in it.
    #[inline(always)]
    fn estimate_with(
        &self,
        theta_a_c: R,
        ta_c: R,
        theta_a: R,
        ta: R,
        outside: impl FnOnce(R) -> Result<(Config<R>, R), PtsError>,
    ) -> Result<Estimate<R>, PtsError> {
        self.model
            .estimate_scaled(theta_a_c, ta_c, theta_a, ta, |t| {
                // θa,c has passed the estimate's input checks. The free-motion torque is not
                // computed: the estimate replaces it by the measured T_a,c.
                match self.locate(t) {
                    Some((s, u)) => Ok((
                        Config {
                            theta1: self.field(s, 1, u),
                            theta2: self.field(s, 0, u),
                            theta_a: t,
                            ta: R::zero(),
                            x2: self.field(s, 2, u),
                            dx2: self.field(s, 3, u),
                        },
                        self.field(s, 5, u),
                    )),
                    None => outside(t),
                }
            })
    }
}

/// A Q32.32 table as raw bits ([`FreeTable::to_raw`], [`FreeTable::from_raw`]): what a build
/// script writes out so that the firmware holds the table as a constant in flash.
#[derive(Clone, Debug, PartialEq)]
pub struct FreeTableRaw {
    /// The finger.
    pub finger: Finger,
    /// The model's constants ([`Model::to_raw`]).
    pub model: [i64; MODEL_RAW_WORDS],
    /// θa at the first knot, 1/h, K1 and θ01.
    pub scalars: [i64; 4],
    /// Every cubic qualifies for [`TableReal::cubic_small`].
    pub small: bool,
    /// Per interval and field, the cubic's coefficients.
    pub seg: [[[i64; 4]; FIELDS]; TABLE_INTERVALS],
}

impl FreeTable<Fx32> {
    /// The table as raw bits.
    pub fn to_raw(&self) -> FreeTableRaw {
        FreeTableRaw {
            finger: self.model.finger,
            model: self.model.to_raw(),
            scalars: [self.theta_a0, self.inv_h, self.k1, self.theta01].map(|v| v.to_bits()),
            small: self.small,
            seg: self.seg.map(|s| s.c.map(|f| f.map(|v| v.to_bits()))),
        }
    }

    /// The table from [`FreeTable::to_raw`]'s bits: a constant expression (no floating
    /// point), so a build-time table lives in flash.
    pub const fn from_raw(raw: &FreeTableRaw) -> Self {
        let zero = Fx32::from_bits(0);
        let mut seg = [Segment {
            c: [[zero; 4]; FIELDS],
        }; TABLE_INTERVALS];
        let mut i = 0;
        while i < TABLE_INTERVALS {
            let mut f = 0;
            while f < FIELDS {
                let mut k = 0;
                while k < 4 {
                    seg[i].c[f][k] = Fx32::from_bits(raw.seg[i][f][k]);
                    k += 1;
                }
                f += 1;
            }
            i += 1;
        }
        Self {
            model: Model::from_raw(raw.finger, &raw.model),
            theta_a0: Fx32::from_bits(raw.scalars[0]),
            inv_h: Fx32::from_bits(raw.scalars[1]),
            k1: Fx32::from_bits(raw.scalars[2]),
            theta01: Fx32::from_bits(raw.scalars[3]),
            small: raw.small,
            seg,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A table rebuilt from its raw bits is the same table: same bits, same answers, and the
    /// answers those of the f64 model.
    #[test]
    fn raw_round_trip_keeps_the_table() {
        let t = FreeTable::<Fx32>::new(&Finger::PAPER).unwrap();
        let raw = t.to_raw();
        let back = FreeTable::from_raw(&raw);
        assert_eq!(back.to_raw(), raw);
        let m64 = Model::<f64>::new(&Finger::PAPER).unwrap();
        for i in 0..20 {
            let th = -1.2 + 0.15 * f64::from(i);
            let x = Fx32::from_f64(th);
            assert_eq!(back.free_torque(x), t.free_torque(x));
            let want = m64.free_from_theta_a(th).unwrap().ta;
            let got = back.free_torque(x).unwrap().to_f64();
            assert!((got - want).abs() < 1e-5, "θa {th}: {got} vs {want}");
            let e = |tb: &FreeTable<Fx32>| {
                tb.estimate_two_point(
                    x,
                    Fx32::from_f64(0.4),
                    x + Fx32::from_f64(0.08),
                    Fx32::from_f64(1.2),
                )
            };
            assert_eq!(e(&back), e(&t));
        }
    }
}
