//! The narrow fixed-point types (one 32-bit word): comparison variants for `cargo xtask
//! bench`, behind the `bench-variants` feature; the firmware runs [`Fx32`].

use core::ops::{Add, Div, Mul, Neg, Sub};

use fixed::types::{I16F16, I32F32, I8F24};

use super::{kernel, Fx32};
use crate::Real;

/// Q16.16 fixed point (`fixed::types::I16F16`): range ±32768, resolution 1.5e-5.
/// Saturating.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Fx16(pub I16F16);

/// Q8.24 fixed point (`fixed::types::I8F24`): range ±128, resolution 6.0e-8. Saturating.
/// One 32-bit word like [`Fx16`], with f32-like resolution on the model's O(1) quantities:
/// cheap on cores without a long multiply or an FPU (Cortex-M0).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Fx24(pub I8F24);

common_impls!(Fx16, I16F16, i32);
common_impls!(Fx24, I8F24, i32);

impl From<Fx24> for Fx32 {
    fn from(v: Fx24) -> Self {
        Fx32(I32F32::from_bits((v.to_bits() as i64) << 8))
    }
}

impl From<Fx16> for Fx32 {
    fn from(v: Fx16) -> Self {
        Fx32(I32F32::from_bits((v.to_bits() as i64) << 16))
    }
}

#[inline]
fn sat_i32(v: i64) -> i32 {
    v.clamp(i32::MIN as i64, i32::MAX as i64) as i32
}

#[inline]
fn q32_to<const F: u32>(v: i64) -> i32 {
    sat_i32((v >> (32 - F)) + ((v >> (31 - F)) & 1))
}

/// Arithmetic and [`Real`] for the 32-bit fixed-point types (Q`frac`): one 32×32→64
/// product per multiply, a reciprocal with an exact remainder correction per divide, the
/// elementary functions through the Q32 kernels.
macro_rules! narrow_fixed {
    ($name:ident, $frac:literal, $tol:expr, $label:expr) => {
        impl Mul for $name {
            type Output = Self;
            #[inline]
            fn mul(self, rhs: Self) -> Self {
                let (a, b) = (self.to_bits(), rhs.to_bits());
                let neg = (a ^ b) < 0;
                let p = kernel::mul_u32(a.unsigned_abs(), b.unsigned_abs());
                let m = ((p >> $frac) + ((p >> ($frac - 1)) & 1)) as i64;
                Self::from_bits(sat_i32(if neg { -m } else { m }))
            }
        }

        impl Div for $name {
            type Output = Self;
            #[inline]
            fn div(self, rhs: Self) -> Self {
                // Reciprocal (32-bit Newton), one product, then an exact remainder correction:
                // the truncated quotient, saturated; x/0 saturates by the sign of x.
                let (a, b) = (self.to_bits(), rhs.to_bits());
                if b == 0 {
                    return if a < 0 { Self::MIN } else { Self::MAX };
                }
                let neg = (a < 0) != (b < 0);
                let (ua, ub) = (a.unsigned_abs(), b.unsigned_abs());
                let s = kernel::clz64(ub as u64) - 32;
                let y = kernel::recip_q31(ub << s);
                // q = ua·2^F/ub ≈ ua·y / 2^(63 − F − s)
                let p = if y >> 32 != 0 {
                    (ua as u64) << 32
                } else {
                    kernel::mul_u32(ua, y as u32)
                };
                let mut q = p >> (63 - $frac - s);
                if q > i32::MAX as u64 + 1 {
                    return if neg { Self::MIN } else { Self::MAX };
                }
                let num = ((ua as u64) << $frac) as i64;
                let mut rem = num - kernel::mul_u32(q as u32, ub) as i64;
                for _ in 0..3 {
                    if rem < 0 {
                        q -= 1;
                        rem += ub as i64;
                    } else if rem >= ub as i64 {
                        q += 1;
                        rem -= ub as i64;
                    }
                }
                let q = q as i64;
                Self::from_bits(sat_i32(if neg { -q } else { q }))
            }
        }

        impl Real for $name {
            const TOL: f64 = $tol;
            const NAME: &'static str = $label;
            const ZERO: Self = Self::from_bits(0);
            fn try_from_f64(x: f64) -> Option<Self> {
                if !x.is_finite() {
                    return None;
                }
                let v = Self::from_f64(x);
                (!v.is_saturated()).then_some(v)
            }
            #[inline(always)]
            fn from_f64(x: f64) -> Self {
                // Round to nearest, saturating, NaN → 0 (`as` saturates): folds to a constant
                // for literal arguments, so model constants cost nothing at run time.
                let y = x * (1u64 << $frac) as f64;
                Self::from_bits((if y < 0.0 { y - 0.5 } else { y + 0.5 }) as i32)
            }
            fn to_f64(self) -> f64 {
                self.0.to_num::<f64>()
            }
            fn is_finite(self) -> bool {
                true
            }
            fn is_saturated(self) -> bool {
                self == Self::MAX || self == Self::MIN
            }
            fn abs(self) -> Self {
                Self(self.0.saturating_abs())
            }
            fn sqrt(self) -> Self {
                let b = self.to_bits();
                if b <= 0 {
                    return Self::default();
                }
                Self::from_bits(q32_to::<$frac>(kernel::sqrt_q32(b as u64, $frac) as i64))
            }
            fn sin(self) -> Self {
                Self::from_bits(q32_to::<$frac>(
                    kernel::sin_cos_q32((self.to_bits() as i64) << (32 - $frac)).0,
                ))
            }
            fn cos(self) -> Self {
                Self::from_bits(q32_to::<$frac>(
                    kernel::sin_cos_q32((self.to_bits() as i64) << (32 - $frac)).1,
                ))
            }
            fn atan2(self, x: Self) -> Self {
                Self::from_bits(q32_to::<$frac>(kernel::atan2_q32(
                    self.to_bits() as i64,
                    x.to_bits() as i64,
                )))
            }
            fn acos(self) -> Self {
                Self::from_bits(q32_to::<$frac>(kernel::acos_q32(
                    (self.to_bits() as i64) << (32 - $frac),
                )))
            }
        }
    };
}

narrow_fixed!(Fx16, 16, 4e-4, "Fx16 (I16F16)");
narrow_fixed!(Fx24, 24, 2e-6, "Fx24 (I8F24)");
