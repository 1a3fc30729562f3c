//! Fixed-point back ends implementing [`Real`]: [`Fx32`] (I32F32), the firmware's, and with
//! the `bench-variants` feature the narrow comparison types `Fx24` (I8F24) and `Fx16` (I16F16).
//!
//! Every operation saturates instead of overflowing or panicking: `+ − × ÷` and negation
//! clamp to the type's limits, division by zero saturates to the limit of the dividend's
//! sign, and [`Real::is_saturated`] reports a value sitting at a limit, which the model
//! turns into [`crate::PtsError::Overflow`].
//!
//! The elementary functions are our own, integer-only, `no_std`:
//! - `sin`/`cos`: reduction by π/2 with a 62-bit π/2 in 128-bit arithmetic, then the
//!   Taylor polynomials to degree 13/14 in Q62 (|r| ≤ π/4, truncation error < 1e-12);
//! - `atan2`: octant reduction, a second reduction by the nearest multiple of π/16
//!   (`tan(a − b)` in the ratio, one division), then the Taylor series of atan to u¹¹
//!   on |u| ≤ tan(π/32) (truncation error < 2e-14);
//! - `sqrt`: normalisation to [¼, 1), a 96-entry seed table, two division-free Newton
//!   steps on 1/√f and one Heron correction (relative error < 1e-13);
//! - `acos(x) = atan2(√((1 − x)(1 + x)), x)` with the product kept exact in Q64.
//!
//! [`Fx32`] evaluates them to about one unit in the last place (2⁻³² ≈ 2.3e-10 rad);
//! `Fx24` and `Fx16` evaluate them in Q32 and round to Q24/Q16 (6e-8 / 1.5e-5).

use crate::Real;
use core::ops::{Add, Div, Mul, Neg, Sub};
use fixed::types::I32F32;

/// The Q31 reciprocal of the integer kernel, for other integer kernels (the path fit's).
pub use kernel::recip_q31;

/// Integer kernels in Q62/Q32 shared by both widths.
pub(crate) mod kernel {
    /// 1.0 in Q62.
    const ONE: i64 = 1 << 62;
    /// π/2 in Q62 (and π in Q61: the same integer).
    const PIO2_Q62: i64 = 7_244_019_458_077_122_842;
    /// π in Q61.
    const PI_Q61: i64 = 7_244_019_458_077_122_842;
    /// π/2 in Q61.
    const PIO2_Q61: i64 = 3_622_009_729_038_561_421;
    /// 2/π in Q62.
    const TWO_OVER_PI_Q62: i64 = 2_935_890_503_282_001_226;
    /// sin(kπ/16), k = 0..=4, Q62.
    const SIN16: [i64; 5] = [
        0,
        899_695_310_372_275_547,
        1_764_815_834_521_887_442,
        2_562_115_475_870_945_497,
        3_260_954_456_333_195_553,
    ];
    /// cos(kπ/16), k = 0..=4, Q62.
    const COS16: [i64; 5] = [
        4_611_686_018_427_387_904,
        4_523_073_764_714_963_030,
        4_260_642_322_793_532_497,
        3_834_476_785_802_888_710,
        3_260_954_456_333_195_553,
    ];
    /// kπ/16, k = 0..=4, Q61.
    const PI16_Q61: [i64; 5] = [
        0,
        452_751_216_129_820_178,
        905_502_432_259_640_355,
        1_358_253_648_389_460_533,
        1_811_004_864_519_280_711,
    ];
    /// Sector bounds tan((2k+1)π/32), k = 0..=3, Q62.
    const BOUND: [i64; 4] = [
        454_211_427_797_526_680,
        1_398_939_659_528_297_413,
        2_464_997_532_358_006_541,
        3_784_712_905_284_427_670,
    ];
    /// 1/√f at the midpoints of [i/128, (i+1)/128), i = 32..=127, Q30 (relative error of
    /// the seed < 2^-7): ⌊2^30·√(256/(2i + 1))⌋ = ⌊√(2^68/(2i + 1))⌋.
    const RSQRT: [u32; 96] = {
        let mut t = [0u32; 96];
        let mut i = 0;
        while i < 96 {
            t[i] = ((1u128 << 68) / (2 * (i as u128 + 32) + 1)).isqrt() as u32;
            i += 1;
        }
        t
    };

    /// 32×32→64 unsigned product. Armv6-M has no long multiply and LLVM would call the
    /// generic 64×64 `__aeabi_lmul` (≈ 45 instructions); there it is four 16×16 products
    /// (ARMv6-M is recognised by its lack of 32-bit compare-and-swap). Elsewhere: UMULL.
    #[inline(always)]
    pub(super) fn mul_u32(a: u32, b: u32) -> u64 {
        #[cfg(all(target_arch = "arm", not(target_has_atomic = "32")))]
        {
            mul_u32_pieces(a, b)
        }
        #[cfg(not(all(target_arch = "arm", not(target_has_atomic = "32"))))]
        {
            a as u64 * b as u64
        }
    }

    /// `a·b` for the integer word `a` of a Q32.32 value: most model quantities are below
    /// 2^16 in magnitude, and there Armv6-M needs two 32-bit products instead of four.
    #[inline(always)]
    pub(super) fn mul_int_word(a: u32, b: u32) -> u64 {
        #[cfg(all(target_arch = "arm", not(target_has_atomic = "32")))]
        if a >> 16 == 0 {
            let lo = a * (b & 0xFFFF);
            let mid = (a * (b >> 16)) as u64;
            return (mid << 16) + lo as u64;
        }
        mul_u32(a, b)
    }

    /// [`mul_u32`] from 16-bit halves with 32-bit multiplies only (used on Armv6-M; tested
    /// everywhere).
    #[inline(always)]
    #[allow(dead_code)]
    pub(super) fn mul_u32_pieces(a: u32, b: u32) -> u64 {
        let (a1, a0) = (a >> 16, a & 0xFFFF);
        let (b1, b0) = (b >> 16, b & 0xFFFF);
        let (mid, carry) = (a0 * b1).overflowing_add(a1 * b0);
        let (lo, c2) = (a0 * b0).overflowing_add(mid << 16);
        let hi = a1 * b1 + (mid >> 16) + ((carry as u32) << 16) + c2 as u32;
        ((hi as u64) << 32) | lo as u64
    }

    /// Leading zeros of a u64. Armv6-M has no CLZ instruction and the library call costs
    /// ≈ 35 instructions; there a five-step binary search on the non-zero word.
    #[inline(always)]
    pub(super) fn clz64(x: u64) -> u32 {
        #[cfg(all(target_arch = "arm", not(target_has_atomic = "32")))]
        {
            clz64_search(x)
        }
        #[cfg(not(all(target_arch = "arm", not(target_has_atomic = "32"))))]
        {
            x.leading_zeros()
        }
    }

    /// Leading zeros of a non-zero u32 (CLZ, or the binary search on Armv6-M).
    #[inline(always)]
    pub(super) fn clz32(x: u32) -> u32 {
        #[cfg(all(target_arch = "arm", not(target_has_atomic = "32")))]
        {
            clz64_search(x as u64) - 32
        }
        #[cfg(not(all(target_arch = "arm", not(target_has_atomic = "32"))))]
        {
            x.leading_zeros()
        }
    }

    /// [`clz64`] by binary search (used on Armv6-M; tested everywhere).
    #[inline(always)]
    #[allow(dead_code)]
    pub(super) fn clz64_search(x: u64) -> u32 {
        let (mut w, mut n) = if x >> 32 == 0 {
            (x as u32, 32)
        } else {
            ((x >> 32) as u32, 0)
        };
        if w == 0 {
            return 64;
        }
        if w >> 16 == 0 {
            n += 16;
            w <<= 16;
        }
        if w >> 24 == 0 {
            n += 8;
            w <<= 8;
        }
        if w >> 28 == 0 {
            n += 4;
            w <<= 4;
        }
        if w >> 30 == 0 {
            n += 2;
            w <<= 2;
        }
        if w >> 31 == 0 {
            n += 1;
        }
        n
    }

    /// Product of two Q62 numbers of magnitude ≤ 1 (result ≤ 1 in magnitude).
    #[inline]
    fn mul62(a: i64, b: i64) -> i64 {
        ((a as i128 * b as i128) >> 62) as i64
    }

    /// Rounds a Q62 value to Q32.
    #[inline]
    fn q62_to_q32(v: i64) -> i64 {
        (v >> 30) + ((v >> 29) & 1)
    }

    /// (sin x, cos x) for x in Q32 (any magnitude), results in Q32.
    pub(super) fn sin_cos_q32(x: i64) -> (i64, i64) {
        // k = round(x·2/π); |x·2/π| < 2^63·2^62 in Q94: fits i128.
        let q = x as i128 * TWO_OVER_PI_Q62 as i128;
        let k = (q + (1i128 << 93)) >> 94;
        // r = x − kπ/2 in Q62; |x << 30| < 2^93, |k·π/2| < 2^32·2^63.
        let r = (((x as i128) << 30) - k * PIO2_Q62 as i128) as i64;
        let r2 = mul62(r, r);
        // sin r = r(1 − r²/3! + r⁴/5! − … + r¹²/13!)
        let mut p = ONE / 6_227_020_800;
        p = -(ONE / 39_916_800) + mul62(r2, p);
        p = ONE / 362_880 + mul62(r2, p);
        p = -(ONE / 5_040) + mul62(r2, p);
        p = ONE / 120 + mul62(r2, p);
        p = -(ONE / 6) + mul62(r2, p);
        let s = r + mul62(r, mul62(r2, p));
        // cos r = 1 − r²/2! + … + r¹⁴/14!
        let mut c = -(ONE / 87_178_291_200);
        c = ONE / 479_001_600 + mul62(r2, c);
        c = -(ONE / 3_628_800) + mul62(r2, c);
        c = ONE / 40_320 + mul62(r2, c);
        c = -(ONE / 720) + mul62(r2, c);
        c = ONE / 24 + mul62(r2, c);
        c = -(ONE / 2) + mul62(r2, c);
        let c = ONE + mul62(r2, c);
        let (s, c) = (q62_to_q32(s), q62_to_q32(c));
        match (k as i64) & 3 {
            0 => (s, c),
            1 => (c, -s),
            2 => (-s, -c),
            _ => (-c, s),
        }
    }

    /// num·2^62/den for |num| ≤ den/8 and den ∈ [2^59, 2^63): a reciprocal of den's top
    /// word (relative error < 2^-30) and one exact-remainder correction in 128-bit
    /// products, within a unit of the truncated quotient; a 128-bit division is a
    /// software loop of thousands of instructions on the Cortex-M.
    pub(super) fn div_q62(num: i64, den: u64) -> i64 {
        let nu = num.unsigned_abs();
        let lz = den.leading_zeros(); // 1..=4
        let dh = ((den << lz) >> 32) as u32; // [2^31, 2^32)
        let y = recip_q31(dh) as u128; // ≈ 2^63/dh; 1/den ≈ y/2^(95 − lz)
        let u0 = ((nu as u128 * y) >> (33 - lz)) as u64;
        // |r| < den·2^30: the remainder against the exact quotient, then r/den.
        let r = ((nu as u128) << 62) as i128 - (u0 as u128 * den as u128) as i128;
        let corr = if r >= 0 {
            ((r as u128 * y) >> (95 - lz)) as i64
        } else {
            -((((-r) as u128 * y) >> (95 - lz)) as i64)
        };
        let u = (u0 as i64).wrapping_add(corr);
        if num < 0 {
            -u
        } else {
            u
        }
    }

    /// atan2(y, x) in Q32 for y, x in any common scale; (0, 0) gives 0. Range (−π, π].
    pub(super) fn atan2_q32(y: i64, x: i64) -> i64 {
        if y == 0 && x == 0 {
            return 0;
        }
        let (ax, ay) = (x.unsigned_abs(), y.unsigned_abs());
        let (n, d, swapped) = if ay > ax {
            (ax, ay, true)
        } else {
            (ay, ax, false)
        };
        // Normalise d into [2^61, 2^62); n ≤ d follows.
        let lz = d.leading_zeros();
        let (n, d) = if lz >= 2 {
            (n << (lz - 2), d << (lz - 2))
        } else {
            (n >> (2 - lz), d >> (2 - lz))
        };
        let (n, d) = (n as i128, d as i128);
        // Sector k: |atan(n/d) − kπ/16| ≤ π/32.
        let k = BOUND.iter().filter(|&&b| (n << 62) > d * b as i128).count();
        let (s, c, base) = match (SIN16.get(k), COS16.get(k), PI16_Q61.get(k)) {
            (Some(&s), Some(&c), Some(&b)) => (s as i128, c as i128, b),
            _ => (0, ONE as i128, 0),
        };
        // tan(θ − kπ/16) = (n cos − d sin)/(d cos + n sin)
        let num = (n * c - d * s) >> 62;
        let den = (d * c + n * s) >> 62;
        if den <= 0 {
            return 0;
        }
        let u = div_q62(num as i64, den as u64);
        let u2 = mul62(u, u);
        let mut p = -(ONE / 11);
        p = ONE / 9 + mul62(u2, p);
        p = -(ONE / 7) + mul62(u2, p);
        p = ONE / 5 + mul62(u2, p);
        p = -(ONE / 3) + mul62(u2, p);
        let at = u + mul62(u, mul62(u2, p));
        let mut a = base + (at >> 1);
        if swapped {
            a = PIO2_Q61 - a;
        }
        if x < 0 {
            a = PI_Q61 - a;
        }
        if y < 0 {
            a = -a;
        }
        (a >> 29) + ((a >> 28) & 1)
    }

    /// Seeds ⌊2^63/d_max⌋ >> 16 for the 256 intervals of d's top byte, d_max the top of
    /// the interval: never above 2^63/d, relative error < 2^-8 (used without a divider).
    #[allow(dead_code)]
    const RECIP_SEED: [u16; 256] = {
        let mut t = [0u16; 256];
        let mut i = 0;
        while i < 256 {
            t[i] = (((1u64 << 63) / ((1u64 << 31) + ((i as u64 + 1) << 23))) >> 16) as u16;
            i += 1;
        }
        t
    };

    /// ≈ 2^63/d for d in [2^31, 2^32) (1/f in Q31, f = d/2^32; exact for d = 2^31),
    /// never above it, relative error < 2^-30: a seed from below and two Newton steps
    /// y += y(1 − f·y), which stay below 1/f, so every term is unsigned.
    ///
    /// The seed comes from the hardware divider where there is one (one UDIV, 2–12
    /// cycles on the Cortex-M4, relative error < 2^-14) and from a 256-entry table on
    /// Armv6-M, which has no divide instruction (relative error < 2^-8).
    #[inline(always)]
    pub fn recip_q31(d: u32) -> u64 {
        #[cfg(all(target_arch = "arm", not(target_has_atomic = "32")))]
        {
            recip_q31_from(d, recip_seed_table(d))
        }
        #[cfg(not(all(target_arch = "arm", not(target_has_atomic = "32"))))]
        {
            recip_q31_from(d, recip_seed_div(d))
        }
    }

    /// The divider's seed: ⌊(2^32 − 1)/(⌊d/2^16⌋ + 1)⌋·2^15 ≤ 2^63/d.
    #[inline(always)]
    #[allow(dead_code)]
    pub(super) fn recip_seed_div(d: u32) -> u32 {
        (u32::MAX / ((d >> 16) + 1)) << 15
    }

    /// The table's seed (≤ 2^63/d).
    #[inline(always)]
    #[allow(dead_code)]
    pub(super) fn recip_seed_table(d: u32) -> u32 {
        let idx = ((d >> 23) & 0xFF) as usize;
        (RECIP_SEED.get(idx).copied().unwrap_or(0x8000) as u32) << 16
    }

    /// [`recip_q31`] from a seed y0 ≤ 2^63/d with relative error below 2^-8.
    #[inline(always)]
    pub(super) fn recip_q31_from(d: u32, y0: u32) -> u64 {
        if d == 1 << 31 {
            return 1 << 32; // exact for powers of two
        }
        let mut y = y0;
        for _ in 0..2 {
            // 1 − f·y in Q63: ≥ 0 because y ≤ 1/f, ≈ 2^55 at most (error ≈ 2^-8).
            let e = (1u64 << 63).wrapping_sub(mul_u32(d, y));
            // y·e truncated: y stays at or below 2^63/d < 2^32.
            y = y.wrapping_add((mul_u32(y, (e >> 31) as u32) >> 32) as u32);
        }
        y as u64
    }

    /// √(x / 2^frac) in Q32 (rounded), for even `frac` in 4..=62.
    ///
    /// Normalises to f ∈ [¼, 1), seeds 1/√f from a 96-entry table (2^-7), two Newton
    /// steps y ← y(3 − f y²)/2 in Q30 (32×32 products; from below after the first, so y
    /// stays under 2 and no intermediate overflows), r = f·y, then one Heron correction
    /// r += (f − r²)·y/2 against the exact 64-bit f (relative error < 1e-13).
    pub(super) fn sqrt_q32(x: u64, frac: u32) -> u64 {
        if x == 0 {
            return 0;
        }
        let lz = clz64(x);
        // m = x·2^e in [2^62, 2^64) with e + frac even.
        let odd = (lz + frac) & 1;
        let (m, e) = if lz == 0 && odd == 1 {
            (x >> 1, -1i32)
        } else {
            (x << (lz - odd), (lz - odd) as i32)
        };
        let f = (m >> 32) as u32; // f in Q32 (≥ 2^30)
        let idx = ((m >> 57) as usize).wrapping_sub(32);
        let mut y = RSQRT.get(idx).copied().unwrap_or(1 << 30); // Q30, < 2^31
        for _ in 0..2 {
            // y < 2 (Q30: < 2^31), so y² < 4 and f·y² < 4; the step keeps y below 1/√f ≤ 2.
            let y2 = (mul_u32(y, y) >> 30) as u32; // Q30
            let fy2 = (mul_u32(f, y2) >> 32) as u32; // Q30, ≈ 2^30
            let t = (3u32 << 30).wrapping_sub(fy2);
            y = (mul_u32(y, t) >> 31) as u32;
        }
        // r = √f in Q32, then the correction with the full-precision m.
        let r = (mul_u32(f, y) >> 30).min(u32::MAX as u64) as u32;
        let delta = m.wrapping_sub(mul_u32(r, r)) as i64; // Q64, |δ| < 2^42
                                                          // r + δ·y/2 in Q48 (the correction is good to ≈ 2^-50 relative).
        let d16 = (delta >> 16).unsigned_abs().min(u32::MAX as u64) as u32;
        let corr = (mul_u32(d16, y) >> 31) as i64;
        let corr = if delta < 0 { -corr } else { corr };
        let r48 = ((r as i64) << 16) + corr;
        let r48 = r48.max(0) as u64;
        // √(x/2^frac) = √f·2^k, k = (64 − e − frac)/2; in Q32 that is r48·2^(k − 16).
        let k = (64 - e - frac as i32) / 2 - 16;
        if k >= 0 {
            r48 << k.min(15)
        } else {
            let sh = (-k).min(63) as u32;
            (r48 + (1u64 << (sh - 1))) >> sh
        }
    }

    /// acos(x) in Q32 for x in Q32, clamped to [−1, 1].
    pub(super) fn acos_q32(x: i64) -> i64 {
        let one = 1i64 << 32;
        let x = x.clamp(-one, one);
        // (1 − x)(1 + x) exactly in Q64 (≤ 2^64), then Q62.
        let p = ((one - x) as u128 * (one + x) as u128) >> 2;
        let s = sqrt_q32(p as u64, 62) as i64;
        atan2_q32(s, x)
    }
}

macro_rules! common_impls {
    ($name:ident, $inner:ty, $raw:ty) => {
        impl $name {
            /// The largest value (the positive saturation limit).
            pub const MAX: Self = Self(<$inner>::MAX);
            /// The smallest value (the negative saturation limit).
            pub const MIN: Self = Self(<$inner>::MIN);
            /// Builds from the raw two's-complement bits.
            pub const fn from_bits(bits: $raw) -> Self {
                Self(<$inner>::from_bits(bits))
            }
            /// The raw two's-complement bits.
            pub const fn to_bits(self) -> $raw {
                self.0.to_bits()
            }
            /// The wrapped `fixed` value.
            pub const fn inner(self) -> $inner {
                self.0
            }
        }
        impl From<$inner> for $name {
            fn from(v: $inner) -> Self {
                Self(v)
            }
        }
        impl From<$name> for $inner {
            fn from(v: $name) -> Self {
                v.0
            }
        }
        impl Add for $name {
            type Output = Self;
            #[inline]
            fn add(self, rhs: Self) -> Self {
                Self(self.0.saturating_add(rhs.0))
            }
        }
        impl Sub for $name {
            type Output = Self;
            #[inline]
            fn sub(self, rhs: Self) -> Self {
                Self(self.0.saturating_sub(rhs.0))
            }
        }
        impl Neg for $name {
            type Output = Self;
            #[inline]
            fn neg(self) -> Self {
                Self(self.0.saturating_neg())
            }
        }
        impl core::fmt::Display for $name {
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                core::fmt::Display::fmt(&self.0, f)
            }
        }
    };
}

/// Q32.32 fixed point (`fixed::types::I32F32`): range ±2.1e9, resolution 2.3e-10.
/// Saturating; the firmware's estimator type (see [`crate::FirmwareReal`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Fx32(pub I32F32);

common_impls!(Fx32, I32F32, i64);

// The narrow types: the bench's comparison variants, never the firmware's.
#[cfg(feature = "bench-variants")]
mod narrow;
#[cfg(feature = "bench-variants")]
pub use narrow::{Fx16, Fx24};

/// ⌊p·u/2^32⌋ for the raw bits `p` of a Q32.32 value and a fraction `u` in Q32 (u < 1):
/// the product of a value and a fraction, never larger than |p|, so it cannot overflow.
/// Two 32×32 products (on Armv6-M: four 16×16 and, for |p| < 2^48, two more).
#[inline(always)]
pub(crate) fn mul_frac(p: i64, u: u32) -> i64 {
    let (ph, pl) = ((p >> 32) as i32, p as u32);
    let lo = (kernel::mul_u32(pl, u) >> 32) as i64;
    // |ph·u| < 2^63.
    #[cfg(all(target_arch = "arm", not(target_has_atomic = "32")))]
    let hi = mul_i32_u32_pieces(ph, u);
    #[cfg(not(all(target_arch = "arm", not(target_has_atomic = "32"))))]
    let hi = ph as i64 * u as i64;
    hi + lo
}

/// a·u exactly without a long multiply (used on Armv6-M; tested everywhere).
#[inline(always)]
#[allow(dead_code)]
fn mul_i32_u32_pieces(a: i32, u: u32) -> i64 {
    let m = kernel::mul_int_word(a.unsigned_abs(), u) as i64; // < 2^63
    if a < 0 {
        -m
    } else {
        m
    }
}

/// ⌊p·u/2^32⌋ for a Q32 value `p` (raw i32 bits) and a fraction `u` in Q32: one 32×32
/// product (on Armv6-M, four 16×16 on the magnitude).
#[inline(always)]
pub(crate) fn mul_frac32(p: i32, u: u32) -> i32 {
    #[cfg(all(target_arch = "arm", not(target_has_atomic = "32")))]
    {
        mul_frac32_pieces(p, u)
    }
    #[cfg(not(all(target_arch = "arm", not(target_has_atomic = "32"))))]
    {
        ((p as i64 * u as i64) >> 32) as i32
    }
}

/// [`mul_frac32`] on the magnitude (used on Armv6-M; tested everywhere).
#[inline(always)]
#[allow(dead_code)]
fn mul_frac32_pieces(p: i32, u: u32) -> i32 {
    let m = kernel::mul_u32(p.unsigned_abs(), u);
    if p < 0 {
        // ⌊−m/2^32⌋ = −⌈m/2^32⌉
        (((m + 0xFFFF_FFFF) >> 32) as i32).wrapping_neg()
    } else {
        (m >> 32) as i32
    }
}

impl Mul for Fx32 {
    type Output = Self;
    // With a long multiply, what is left here is the short common case and a tail call:
    // inlined, it saves the call (≈ 1 KiB of flash in the firmware for ≈ 10 % of an
    // estimate). On Armv6-M the whole product is long, and stays a call.
    #[cfg_attr(
        not(all(target_arch = "arm", not(target_has_atomic = "32"))),
        inline(always)
    )]
    #[cfg_attr(all(target_arch = "arm", not(target_has_atomic = "32")), inline)]
    fn mul(self, rhs: Self) -> Self {
        let (a, b) = (self.to_bits(), rhs.to_bits());
        // Where there is a long multiply, the common case (both integer words in
        // [−2^15, 2^15): every model quantity) is signed and cannot saturate.
        #[cfg(not(all(target_arch = "arm", not(target_has_atomic = "32"))))]
        if (((a >> 32) as i32).wrapping_add(1 << 15) | ((b >> 32) as i32).wrapping_add(1 << 15))
            >> 16
            == 0
        {
            return Self::from_bits(mul_small(a, b));
        }
        Self::from_bits(mul_magnitudes(a, b))
    }
}

/// a·b/2^32 rounded to nearest (ties up) for raw Q32.32 values whose integer words lie in
/// [−2^15, 2^15): |a·b| < 2^94, so the result fits in 62 bits. Signed partial products:
/// ⌊a·b/2^32⌉ = ah·bh·2^32 + ah·bl + al·bh + ⌊al·bl/2^32⌉ (al, bl unsigned).
#[inline(always)]
#[allow(dead_code)] // not used on Armv6-M
fn mul_small(a: i64, b: i64) -> i64 {
    let (ah, al) = ((a >> 32) as i32, a as u32);
    let (bh, bl) = ((b >> 32) as i32, b as u32);
    let ll = kernel::mul_u32(al, bl);
    let r = ((ll >> 32) + ((ll >> 31) & 1)) as i64;
    r + ah as i64 * bl as i64 + bh as i64 * al as i64 + (((ah * bh) as i64) << 32)
}

/// a·b/2^32 for any raw Q32.32 values, on magnitudes: up to four 32×32→64 partial
/// products (fewer when an operand is below 1 in magnitude), rounded to nearest, saturated.
/// Out of line where [`mul_small`] handles the common case, so that what is left of a
/// multiply is small enough to inline.
#[cfg_attr(
    not(all(target_arch = "arm", not(target_has_atomic = "32"))),
    inline(never)
)]
#[cfg_attr(all(target_arch = "arm", not(target_has_atomic = "32")), inline)]
fn mul_magnitudes(a: i64, b: i64) -> i64 {
    use kernel::mul_u32;
    let neg = (a ^ b) < 0;
    let (ua, ub) = (a.unsigned_abs(), b.unsigned_abs());
    let (ah, al) = ((ua >> 32) as u32, ua as u32);
    let (bh, bl) = ((ub >> 32) as u32, ub as u32);
    let ll = mul_u32(al, bl);
    let mut m = (ll >> 32) + ((ll >> 31) & 1);
    if ah != 0 {
        m += kernel::mul_int_word(ah, bl); // < 2^63
    }
    if bh != 0 {
        m = m.saturating_add(kernel::mul_int_word(bh, al));
        if ah != 0 {
            let hh = mul_u32(ah, bh);
            m = if hh >= 1 << 31 {
                u64::MAX
            } else {
                m.saturating_add(hh << 32)
            };
        }
    }
    let lim = if neg { 1u64 << 63 } else { i64::MAX as u64 };
    if m > lim {
        return if neg { i64::MIN } else { i64::MAX };
    }
    let m = m as i64; // 2^63 wraps to i64::MIN, which negates to itself
    if neg {
        m.wrapping_neg()
    } else {
        m
    }
}

impl Div for Fx32 {
    type Output = Self;
    #[inline]
    fn div(self, rhs: Self) -> Self {
        // Reciprocal of the divisor's top 32 bits (relative error < 2^-30), one 64×32
        // product: quotient to ≈ 1e-9 relative, truncated, saturated; x/0 saturates by
        // the sign of x. All shifts by variable amounts are below 32 (no 64-bit shift
        // routine on Armv6-M).
        let (a, b) = (self.to_bits(), rhs.to_bits());
        if b == 0 {
            return if a < 0 { Self::MIN } else { Self::MAX };
        }
        let neg = (a ^ b) < 0;
        let (ua, ub) = (a.unsigned_abs(), b.unsigned_abs());
        let (bh, bl) = ((ub >> 32) as u32, ub as u32);
        // d = ub·2^k/2^32 in [2^31, 2^32) with k = s + 32·[bh = 0], s < 32.
        let (big, s) = if bh != 0 {
            (true, kernel::clz32(bh))
        } else {
            (false, kernel::clz32(bl))
        };
        let d = if big {
            (bh << s) | ((bl >> 1) >> (31 - s))
        } else {
            bl << s
        };
        // q = ua·2^32/ub ≈ ua·y/2^(63 − k) = P/2^(95 − k), P = ua·y = hi·2^32 + lo (96 bits).
        let y = kernel::recip_q31(d);
        let (hi, lo) = if y >> 32 != 0 {
            (ua, 0u32) // y = 2^32 exactly: a power-of-two divisor
        } else {
            let l = kernel::mul_u32(ua as u32, y as u32);
            let h = kernel::mul_u32((ua >> 32) as u32, y as u32) + (l >> 32);
            (h, l as u32)
        };
        let n = 31 - s;
        let (hh, hl) = ((hi >> 32) as u32, hi as u32);
        let q = if big {
            // |b| ≥ 1: q = hi/2^n ≤ ua.
            (((hh >> n) as u64) << 32) | ((hl >> n) | ((hh << 1) << (31 - n))) as u64
        } else if hh >> n != 0 {
            return if neg { Self::MIN } else { Self::MAX };
        } else {
            // |b| < 1: q = P/2^n, which fits in 64 bits.
            let q_hi = (hl >> n) | ((hh << 1) << (31 - n));
            let q_lo = (lo >> n) | ((hl << 1) << (31 - n));
            ((q_hi as u64) << 32) | q_lo as u64
        };
        let lim = if neg { 1u64 << 63 } else { i64::MAX as u64 };
        if q > lim {
            return if neg { Self::MIN } else { Self::MAX };
        }
        let q = q as i64; // 2^63 wraps to i64::MIN, which negates to itself
        Self::from_bits(if neg { q.wrapping_neg() } else { q })
    }
}

impl Real for Fx32 {
    const TOL: f64 = 2e-8;
    const NAME: &'static str = "Fx32 (I32F32)";
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
        let y = x * 4294967296.0;
        Self::from_bits((if y < 0.0 { y - 0.5 } else { y + 0.5 }) as i64)
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
        Self::from_bits(kernel::sqrt_q32(b as u64, 32) as i64)
    }
    #[inline]
    fn half_log2(self) -> Option<i32> {
        // 2^e ≤ x < 2^(e+1) with e = 31 − clz(bits); k = ⌈e/2⌉.
        let b = self.to_bits();
        if b <= 0 || self.is_saturated() {
            return None;
        }
        Some((32 - b.leading_zeros() as i32).div_euclid(2))
    }
    #[inline]
    fn ldexp(self, k: i32) -> Self {
        let b = self.to_bits();
        if k <= 0 {
            Self::from_bits(b >> (-k).min(63))
        } else if k < 63 && (b.unsigned_abs() >> (62 - k)) == 0 {
            Self::from_bits(b << k)
        } else if b == 0 {
            self
        } else if b > 0 {
            Self::MAX
        } else {
            Self::MIN
        }
    }
    fn sin(self) -> Self {
        Self::from_bits(kernel::sin_cos_q32(self.to_bits()).0)
    }
    fn cos(self) -> Self {
        Self::from_bits(kernel::sin_cos_q32(self.to_bits()).1)
    }
    fn atan2(self, x: Self) -> Self {
        Self::from_bits(kernel::atan2_q32(self.to_bits(), x.to_bits()))
    }
    fn acos(self) -> Self {
        Self::from_bits(kernel::acos_q32(self.to_bits()))
    }
}

/// Rounds a Q32 value to Q`F`, saturating to i32.
#[cfg(test)]
mod tests {
    use super::kernel::{
        clz32, clz64, clz64_search, mul_int_word, mul_u32, mul_u32_pieces, recip_q31,
        recip_q31_from, recip_seed_div, recip_seed_table,
    };
    use super::{
        mul_frac, mul_frac32, mul_frac32_pieces, mul_i32_u32_pieces, mul_magnitudes, mul_small,
    };

    fn xorshift(x: &mut u64) -> u64 {
        *x ^= *x << 13;
        *x ^= *x >> 7;
        *x ^= *x << 17;
        *x
    }

    /// The atan2 kernel's quotient without a 128-bit division: within one unit of the exact
    /// truncated num·2^62/den over its whole domain (|num| ≤ den/8, den ∈ [2^59, 2^63)).
    #[test]
    fn q62_quotient_within_a_unit_of_the_exact_one() {
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        let check = |num: i64, den: u64| {
            let exact = ((num as i128) << 62) / den as i128;
            let got = super::kernel::div_q62(num, den) as i128;
            assert!((got - exact).abs() <= 1, "{num} / {den}: {got} vs {exact}");
        };
        for den in [1u64 << 59, (1 << 63) - 1, 3 << 60, (1 << 62) + 1] {
            for num in [0i64, 1, -1, (den / 8) as i64, -((den / 8) as i64)] {
                check(num, den);
            }
        }
        for _ in 0..200_000 {
            let den = (1u64 << 59) + xorshift(&mut x) % ((1u64 << 63) - (1 << 59));
            let num = (xorshift(&mut x) % (den / 8 + 1)) as i64;
            check(if xorshift(&mut x) & 1 == 0 { num } else { -num }, den);
        }
    }

    /// Both reciprocal seeds (divider and table) and the two Newton steps: never above
    /// 2^63/d, relative error below 2^-30, exact at d = 2^31.
    #[test]
    fn reciprocal_from_below_to_2_pow_minus_30() {
        let check = |d: u32| {
            let exact = (1u128 << 63) as f64 / d as f64;
            for (name, y0) in [("div", recip_seed_div(d)), ("table", recip_seed_table(d))] {
                assert!(y0 as f64 <= exact, "{name} seed above 1/f at {d:#x}");
                assert!(
                    y0 as f64 >= exact * (1.0 - 1.0 / 256.0),
                    "{name} seed at {d:#x}"
                );
                let y = recip_q31_from(d, y0) as f64;
                assert!(
                    y <= exact && y >= exact * (1.0 - 2f64.powi(-30)),
                    "{name} {d:#x}"
                );
            }
            assert_eq!(recip_q31(d), recip_q31_from(d, recip_seed_div(d)));
        };
        assert_eq!(recip_q31(1 << 31), 1 << 32);
        for d in [
            (1u32 << 31) + 1,
            0x8080_0000,
            0xBFFF_FFFF,
            0xFFFF_FFFF,
            0xFF80_0000,
        ] {
            check(d);
        }
        let mut x: u64 = 0x2545_F491_4F6C_DD1D;
        for _ in 0..200_000 {
            check((xorshift(&mut x) as u32) | 1 << 31);
        }
    }

    /// The signed small-operand product against the saturating one on magnitudes (equal
    /// but for ties, which round up instead of away from zero), and the fraction product.
    #[test]
    fn small_product_and_fraction_product() {
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        for _ in 0..200_000 {
            let r = xorshift(&mut x);
            // Integer words anywhere in [−2^15, 2^15).
            let a = (r as i64) >> (16 + (r >> 59) as u32 % 16);
            let b = (xorshift(&mut x) as i64) >> (16 + (r >> 54) as u32 % 16);
            let exact = a as i128 * b as i128;
            let want = (exact + (1 << 31)) >> 32;
            assert_eq!(mul_small(a, b) as i128, want, "{a} {b}");
            let m = mul_magnitudes(a, b) as i128;
            assert!((m - want).abs() <= 1);
            if exact & 0xFFFF_FFFF != 1 << 31 {
                assert_eq!(m, want, "{a} {b}");
            }
            let p = xorshift(&mut x) as i64;
            let u = xorshift(&mut x) as u32;
            assert_eq!(mul_frac(p, u) as i128, (p as i128 * u as i128) >> 32);
            let w = xorshift(&mut x) as u32 | 1;
            assert_eq!(clz32(w), w.leading_zeros());
            let (q, v) = (p as i32 >> (p as u32 % 32), (p >> 32) as i32);
            let want = ((q as i128 * u as i128) >> 32) as i32;
            assert_eq!(mul_frac32(q, u), want);
            assert_eq!(mul_frac32_pieces(q, u), want);
            assert_eq!(mul_i32_u32_pieces(v, u), v as i64 * u as i64);
        }
        for (q, u) in [
            (i32::MIN, u32::MAX),
            (i32::MAX, u32::MAX),
            (-1, 1),
            (-1, 0),
            (0, 7),
        ] {
            let want = ((q as i128 * u as i128) >> 32) as i32;
            assert_eq!(mul_frac32_pieces(q, u), want);
            assert_eq!(mul_i32_u32_pieces(q, u), q as i64 * u as i64);
        }
        assert_eq!(mul_small(-(1 << 47), -(1 << 47)), 1 << 62);
        assert_eq!(
            mul_small((1 << 47) - 1, -(1 << 47)) as i128,
            (((1i128 << 47) - 1) * -(1i128 << 47) + (1 << 31)) >> 32
        );
    }

    #[test]
    fn armv6m_long_multiply_is_exact() {
        let edge = [
            0u32,
            1,
            2,
            0xFFFF,
            0x1_0000,
            0x8000_0000,
            0xFFFF_FFFF,
            0x1234_5678,
        ];
        for &a in &edge {
            for &b in &edge {
                assert_eq!(mul_u32_pieces(a, b), a as u64 * b as u64, "{a} {b}");
            }
        }
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        for _ in 0..100_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let (a, b) = (x as u32, (x >> 32) as u32);
            assert_eq!(mul_u32_pieces(a, b), a as u64 * b as u64);
            assert_eq!(mul_u32(a, b), a as u64 * b as u64);
            let small = a >> (x % 32) as u32;
            assert_eq!(mul_int_word(small, b), small as u64 * b as u64);
            let y = x >> (x % 64);
            assert_eq!(clz64_search(y), y.leading_zeros());
            assert_eq!(clz64(y), y.leading_zeros());
        }
        for k in 0..64 {
            assert_eq!(clz64_search(1u64 << k), 63 - k);
        }
        assert_eq!(clz64_search(0), 64);
    }
}
