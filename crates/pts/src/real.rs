//! The numeric back ends: one trait, implemented for `f64` (the reference), `f32`,
//! and fixed point (see [`crate::fixed`]). The model is written once against it.

use core::ops::{Add, Div, Mul, Neg, Sub};

/// A real-number back end for the model.
///
/// Implementations must not panic on any value: fixed-point types saturate, floats
/// propagate non-finite values (the model checks [`Real::is_finite`] at its boundaries).
pub trait Real:
    Copy
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + core::fmt::Debug
{
    /// Convergence tolerance for iterative solves, in the units of the quantity solved.
    const TOL: f64;
    /// Human-readable name of the back end (for tables).
    const NAME: &'static str;
    /// Zero, as a constant: arrays of it are built from read-only data in one copy
    /// instead of element by element.
    const ZERO: Self;
    /// Converts from `f64`; `None` when the value is non-finite or outside the range.
    fn try_from_f64(x: f64) -> Option<Self>;
    /// Converts from `f64`, saturating (NaN maps to zero). For constants known to fit.
    fn from_f64(x: f64) -> Self;
    /// Converts to `f64` (exact for every back end used here).
    fn to_f64(self) -> f64;
    /// Zero.
    fn zero() -> Self {
        Self::from_f64(0.0)
    }
    /// One.
    fn one() -> Self {
        Self::from_f64(1.0)
    }
    /// True unless NaN or infinite (always true for fixed point).
    fn is_finite(self) -> bool;
    /// True when the value sits at the saturation limit of a fixed-point type
    /// (an overflow happened somewhere); always false for floats.
    fn is_saturated(self) -> bool {
        false
    }
    /// Absolute value.
    fn abs(self) -> Self;
    /// Square root; negative inputs give zero (callers check the sign first).
    fn sqrt(self) -> Self;
    /// For finite x > 0 the exponent k with x·2^-2k in [½, 2): the power-of-two Jacobi
    /// scaling of a normal matrix (exact in every back end, no square root or division);
    /// `None` for x ≤ 0 or non-finite x.
    fn half_log2(self) -> Option<i32> {
        let x = self.to_f64();
        if !(x > 0.0 && x.is_finite()) {
            return None;
        }
        // x = m·2^e with m in [½, 1): ⌊log2 x⌋ = e − 1, k = ⌈(e − 1)/2⌉.
        Some(libm::frexp(x).1.div_euclid(2))
    }
    /// x·2^k (exact while representable; fixed point saturates).
    fn ldexp(self, k: i32) -> Self {
        self * Self::from_f64(libm::ldexp(1.0, k))
    }
    /// Sine (rad).
    fn sin(self) -> Self;
    /// Cosine (rad).
    fn cos(self) -> Self;
    /// Four-quadrant arctangent of `self / x` (rad), in (−π, π].
    fn atan2(self, x: Self) -> Self;
    /// Arccosine (rad) of an argument in [−1, 1]; outside it is clamped.
    fn acos(self) -> Self;
    /// Larger of two values.
    fn max(self, other: Self) -> Self {
        if self > other {
            self
        } else {
            other
        }
    }
    /// Smaller of two values.
    fn min(self, other: Self) -> Self {
        if self < other {
            self
        } else {
            other
        }
    }
}

impl Real for f64 {
    const TOL: f64 = 1e-13;
    const NAME: &'static str = "f64";
    const ZERO: Self = 0.0;
    fn try_from_f64(x: f64) -> Option<Self> {
        x.is_finite().then_some(x)
    }
    fn from_f64(x: f64) -> Self {
        x
    }
    fn to_f64(self) -> f64 {
        self
    }
    fn is_finite(self) -> bool {
        f64::is_finite(self)
    }
    fn abs(self) -> Self {
        libm::fabs(self)
    }
    fn sqrt(self) -> Self {
        if self > 0.0 {
            libm::sqrt(self)
        } else {
            0.0
        }
    }
    fn half_log2(self) -> Option<i32> {
        (self > 0.0 && self.is_finite()).then(|| libm::frexp(self).1.div_euclid(2))
    }
    fn ldexp(self, k: i32) -> Self {
        libm::ldexp(self, k)
    }
    fn sin(self) -> Self {
        libm::sin(self)
    }
    fn cos(self) -> Self {
        libm::cos(self)
    }
    fn atan2(self, x: Self) -> Self {
        libm::atan2(self, x)
    }
    fn acos(self) -> Self {
        libm::acos(self.clamp(-1.0, 1.0))
    }
}

impl Real for f32 {
    const TOL: f64 = 2e-6;
    const NAME: &'static str = "f32";
    const ZERO: Self = 0.0;
    fn try_from_f64(x: f64) -> Option<Self> {
        let y = x as f32;
        y.is_finite().then_some(y)
    }
    fn from_f64(x: f64) -> Self {
        x as f32
    }
    fn to_f64(self) -> f64 {
        self as f64
    }
    fn is_finite(self) -> bool {
        f32::is_finite(self)
    }
    fn abs(self) -> Self {
        libm::fabsf(self)
    }
    fn sqrt(self) -> Self {
        if self > 0.0 {
            libm::sqrtf(self)
        } else {
            0.0
        }
    }
    fn half_log2(self) -> Option<i32> {
        (self > 0.0 && self.is_finite()).then(|| libm::frexpf(self).1.div_euclid(2))
    }
    fn ldexp(self, k: i32) -> Self {
        libm::ldexpf(self, k)
    }
    fn sin(self) -> Self {
        libm::sinf(self)
    }
    fn cos(self) -> Self {
        libm::cosf(self)
    }
    fn atan2(self, x: Self) -> Self {
        libm::atan2f(self, x)
    }
    fn acos(self) -> Self {
        libm::acosf(self.clamp(-1.0, 1.0))
    }
}
