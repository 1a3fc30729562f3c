//! Sensors as the board sees them: a quadrature encoder on the motor shaft and a shunt current
//! amplifier into a 12-bit ADC, with deterministic seeded noise.
//!
//! | constant | default | source / reasoning |
//! |---|---|---|
//! | encoder | 16 CPT, ×4 = 64 counts/motor turn | small magnetic encoder class for a Ø10 mm motor: **guess**; 32 µrad at the base link with N = 3072 |
//! | shunt | 0.5 Ω | keeps the drop < 0.2 V at the 0.3 A stall current (choice) |
//! | amplifier | 10 V/V, bidirectional, 1.65 V mid-scale | 5 V/A ⇒ ±0.33 A over a 3.3 V ADC (choice) |
//! | ADC | 12 bit, 3.3 V reference | typical Cortex-M4 ADC (STM32F4 class) |
//! | offset error | +4 mV | amplifier input offset × gain, ≈ 5 LSB: **guess** |
//! | gain error | +1 % | 1 % shunt + amplifier gain tolerance: **guess** |
//! | noise | 1.2 mV rms (≈ 1.5 LSB) | PWM ripple residue + ADC noise: **guess** |

use libm::{floor, round};

/// Encoder and current-sensor parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorParams {
    /// Encoder lines per motor turn (CPT); the board counts ×4 edges.
    pub encoder_cpt: u32,
    /// Shunt resistance (Ω).
    pub shunt_ohm: f64,
    /// Current amplifier gain (V/V).
    pub amp_gain: f64,
    /// Amplifier output at zero current, nominal (V).
    pub offset_v: f64,
    /// Offset error added to the nominal offset (V).
    pub offset_error_v: f64,
    /// Relative gain error (e.g. 0.01 = +1 %).
    pub gain_error: f64,
    /// Noise at the ADC input, rms (V).
    pub noise_v_rms: f64,
    /// ADC reference (V).
    pub adc_vref_v: f64,
    /// ADC resolution (bits, 8..=16).
    pub adc_bits: u8,
    /// Seed of the noise generator.
    pub seed: u64,
}

impl SensorParams {
    /// Realistic defaults (see the module table).
    pub const DEFAULT: SensorParams = SensorParams {
        encoder_cpt: 16,
        shunt_ohm: 0.5,
        amp_gain: 10.0,
        offset_v: 1.65,
        offset_error_v: 0.004,
        gain_error: 0.01,
        noise_v_rms: 0.0012,
        adc_vref_v: 3.3,
        adc_bits: 12,
        seed: 0x5EED_F1A6_0000_0001,
    };

    /// Same hardware with no offset error, no gain error and no noise (quantisation stays).
    pub const fn ideal(self) -> SensorParams {
        SensorParams {
            offset_error_v: 0.0,
            gain_error: 0.0,
            noise_v_rms: 0.0,
            ..self
        }
    }

    /// Encoder counts per motor turn (×4).
    pub const fn counts_per_turn(&self) -> u32 {
        self.encoder_cpt.saturating_mul(4)
    }

    /// Nominal ADC codes per ampere (what a controller would use, no error terms).
    pub fn codes_per_amp(&self) -> f64 {
        self.shunt_ohm * self.amp_gain * self.full_scale() / self.adc_vref_v
    }

    /// Nominal ADC code at zero current.
    pub fn zero_code(&self) -> f64 {
        self.offset_v * self.full_scale() / self.adc_vref_v
    }

    fn full_scale(&self) -> f64 {
        f64::from(1u32 << self.adc_bits.clamp(1, 16))
    }

    /// Checks the values; the error names the key.
    pub fn validate(&self) -> Result<(), crate::PlantError> {
        use crate::PlantError::Invalid;
        if self.encoder_cpt == 0 || self.encoder_cpt > 1_000_000 {
            return Err(Invalid("sensors.encoder_cpt"));
        }
        let chk = |v: f64, lo: f64, hi: f64, key: &'static str| {
            if v.is_finite() && v >= lo && v <= hi {
                Ok(())
            } else {
                Err(Invalid(key))
            }
        };
        chk(self.shunt_ohm, 1e-6, 1e3, "sensors.shunt_ohm")?;
        chk(self.amp_gain, 1e-3, 1e4, "sensors.amp_gain")?;
        chk(self.adc_vref_v, 0.1, 10.0, "sensors.adc_vref_v")?;
        chk(self.offset_v, 0.0, self.adc_vref_v, "sensors.offset_v")?;
        chk(self.offset_error_v, -1.0, 1.0, "sensors.offset_error_v")?;
        chk(self.gain_error, -0.5, 0.5, "sensors.gain_error")?;
        chk(self.noise_v_rms, 0.0, 1.0, "sensors.noise_v_rms")?;
        if !(8..=16).contains(&self.adc_bits) {
            return Err(Invalid("sensors.adc_bits"));
        }
        Ok(())
    }

    /// Unwrapped encoder count for a motor angle (rad).
    pub fn encoder_count_unwrapped(&self, motor_angle_rad: f64) -> i64 {
        let c = floor(motor_angle_rad * f64::from(self.counts_per_turn()) / core::f64::consts::TAU);
        if c.is_finite() {
            // Saturating float→int cast: no panic.
            c as i64
        } else {
            0
        }
    }

    /// ADC code for a true current (A) and a standard-normal noise sample.
    pub fn adc_code(&self, current_a: f64, noise_std: f64) -> u16 {
        let v = self.offset_v
            + self.offset_error_v
            + current_a * self.shunt_ohm * self.amp_gain * (1.0 + self.gain_error)
            + self.noise_v_rms * noise_std;
        let fs = self.full_scale();
        let code = round(v / self.adc_vref_v * fs);
        let code = if code.is_finite() {
            code.clamp(0.0, fs - 1.0)
        } else {
            0.0
        };
        code as u16
    }
}

/// Small deterministic PRNG (SplitMix64) with an approximately normal sampler
/// (Irwin–Hall sum of four uniforms, scaled to unit variance; tails bounded at ±3.46σ).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rng(u64);

impl Rng {
    /// Seeded generator.
    pub const fn new(seed: u64) -> Self {
        Rng(seed)
    }
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / 9_007_199_254_740_992.0)
    }
    /// Approximately standard normal.
    pub fn normal(&mut self) -> f64 {
        let s = self.uniform() + self.uniform() + self.uniform() + self.uniform();
        // Sum of 4 U(0,1): mean 2, variance 1/3.
        (s - 2.0) * 1.732_050_807_568_877_2
    }
}
