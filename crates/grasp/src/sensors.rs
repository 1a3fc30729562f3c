//! Sensor conditioning, integer only: encoder counts → θa (µrad), ADC code → current (µA)
//! and actuator torque T_a (µN·m).
#![deny(clippy::float_arithmetic)]

use crate::config::Params;

/// Unwraps the 16-bit quadrature count into a 32-bit position and converts it to θa.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Encoder {
    last: u16,
    /// Counts since the rest pose (unwrapped).
    counts: i32,
}

/// A count jump larger than physically possible in one tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EncoderJump {
    /// The jump (counts, signed, wrapped to ±2¹⁵).
    pub step_counts: i32,
}

impl Encoder {
    /// Starts at the rest pose: `raw` is the reading there.
    pub fn new(raw: u16) -> Self {
        Self {
            last: raw,
            counts: 0,
        }
    }

    /// Takes one reading. The difference is taken modulo 2¹⁶ (wrap-around); a step above
    /// `max_step` counts is refused and the state is left unchanged.
    pub fn update(&mut self, raw: u16, max_step: i32) -> Result<i32, EncoderJump> {
        let step = i32::from(raw.wrapping_sub(self.last) as i16);
        if step.abs() > max_step {
            return Err(EncoderJump { step_counts: step });
        }
        self.last = raw;
        self.counts = self.counts.saturating_add(step);
        Ok(self.counts)
    }

    /// Ties the current reading to a pose: from now on it is `counts` from the rest (the
    /// rest check, once the finger is against its open stop).
    pub fn set_counts(&mut self, counts: i32) {
        self.counts = counts;
    }

    /// Counts since the rest pose.
    pub fn counts(&self) -> i32 {
        self.counts
    }

    /// θa (µrad), absolute model angle.
    pub fn theta_a_urad(&self, p: &Params) -> i32 {
        counts_to_urad(self.counts, p)
    }
}

/// θa (µrad) of an unwrapped count.
pub fn counts_to_urad(counts: i32, p: &Params) -> i32 {
    // One 32×32→64 product, exact.
    let rel = (i64::from(counts) * i64::from(p.urad_per_count_q16)) >> 16;
    sat_i32(i64::from(p.theta_a_rest_urad) + rel)
}

/// Current-sensor conditioning with an offset calibrated with the bridge off.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CurrentSense {
    /// Zero-current code ×256 (sub-code resolution from averaging).
    offset_q8: i32,
    sum: i64,
    n: u32,
}

impl CurrentSense {
    /// Uncalibrated: assumes the nominal zero code.
    pub fn new(p: &Params) -> Self {
        Self {
            offset_q8: p.adc_zero_code.saturating_mul(256),
            sum: 0,
            n: 0,
        }
    }

    /// Accumulates one calibration sample (bridge off).
    pub fn calib_add(&mut self, code: u16) {
        self.sum = self.sum.saturating_add(i64::from(code));
        self.n = self.n.saturating_add(1);
    }

    /// Ends the calibration: the offset becomes the mean code. Returns the offset ×256
    /// or `Err` with it when it is further than allowed from the nominal code.
    // Not inlined: the one division of the sampling task, once at power-up with the bridge
    // off; tests/no_float.rs checks that nothing else in the loop divides.
    #[inline(never)]
    pub fn calib_finish(&mut self, p: &Params) -> Result<i32, i32> {
        let n = i64::from(self.n.max(1));
        let q8 = sat_i32(
            self.sum
                .saturating_mul(256)
                .saturating_add(n / 2)
                .checked_div(n)
                .unwrap_or(0),
        );
        let dev = q8
            .saturating_sub(p.adc_zero_code.saturating_mul(256))
            .saturating_abs();
        if dev > p.calib_max_offset_codes.saturating_mul(256) {
            return Err(q8);
        }
        self.offset_q8 = q8;
        Ok(q8)
    }

    /// Calibrated offset ×256 (codes).
    pub fn offset_q8(&self) -> i32 {
        self.offset_q8
    }

    /// Motor current (µA) of one code.
    pub fn current_ua(&self, code: u16, p: &Params) -> i32 {
        // |Δ| < 2²¹ and an i32 factor: |result| < 2²⁸, the cast is exact.
        ((i64::from(self.delta_q8(code)) * i64::from(p.ua_per_code_q16)) >> 24) as i32
    }

    /// Actuator torque T_a (µN·m) of one code: kt × ratio × efficiency × current.
    pub fn torque_unm(&self, code: u16, p: &Params) -> i32 {
        // |Δ| < 2²¹ and an i32 factor: |result| < 2²⁸, the cast is exact.
        ((i64::from(self.delta_q8(code)) * i64::from(p.unm_per_code_q16)) >> 24) as i32
    }

    /// code·256 − offset (codes ×256), limited to ±2²¹: a 12-bit code and a plausible offset
    /// are inside; the limit bounds the products above for any offset.
    fn delta_q8(&self, code: u16) -> i32 {
        (i32::from(code) << 8)
            .saturating_sub(self.offset_q8)
            .clamp(-(1 << 21), (1 << 21) - 1)
    }
}

/// Saturating conversion to i32.
pub fn sat_i32(x: i64) -> i32 {
    x.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
}
