//! Configuration in SI units (`f64`, evaluated once in [`Controller::new`](crate::Controller::new))
//! and its integer form [`Params`], the only thing the per-tick path reads.
//!
//! This is the one place in the crate where the drive constants live ([`DriveConfig::DEFAULT`]);
//! they mirror the plant's defaults (`plant::Drive`), and the host tests check that they agree.

use crate::DUTY_MAX;
use pts::{Finger, Model, PtsError};

/// The drive: motor, gearhead + transmission to the base link, encoder and current sensor.
/// SI units. Mirrors the simulated plant's drive constants.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriveConfig {
    /// Control period (s); `tick()` is called once per period.
    pub dt_s: f64,
    /// Motor revolutions per revolution of the input crank (gearhead × pulleys), dimensionless.
    pub gear_ratio: f64,
    /// Transmission efficiency from motor to base link, (0, 1].
    pub efficiency: f64,
    /// Motor torque constant (N·m/A).
    pub kt_nm_per_a: f64,
    /// Motor terminal resistance (Ω).
    pub resistance_ohm: f64,
    /// H-bridge supply voltage at full duty (V).
    pub bus_v: f64,
    /// Encoder counts per motor revolution, quadrature ×4 (counts/rev).
    pub encoder_counts_per_rev: f64,
    /// Current-sense gain: motor current per ADC code (A/code); positive = flexion current.
    pub amps_per_code: f64,
    /// Nominal ADC code at zero current (mid-scale for a bidirectional amplifier).
    pub adc_zero_code: f64,
    /// Absolute model angle θa at the rest pose, where the encoder reading is taken as zero (rad).
    pub theta_a_rest_rad: f64,
    /// Effective inertia of the drive at the crank as the measured torque sees it (kg·m²;
    /// η × rotor inertia × gear ratio², ≥ 0): the path fit takes J·θ̈a off every sample.
    /// Read by the path fit's table ([`crate::path_table`], which checks it) and by the torque
    /// loop's damping ([`ControllerConfig::damping_nm_s_per_rad`]).
    pub inertia_kgm2: f64,
    /// Backlash between the encoder and the crank, at the crank (rad, ≥ 0): the encoder leads
    /// the finger by half of it while the drive loads in flexion (the path fit's measurement
    /// model). Read by the path fit's table only, which checks it.
    pub backlash_rad: f64,
    /// The path fit's priors for this finger and drive (the finger file's `[estimate]`):
    /// the contact angle's and the friction offset's σ. Read by the path fit's table only.
    pub priors: pathfit::FitPriors,
}

impl DriveConfig {
    /// The share of the torque loop's damping this drive gets: its inertia over
    /// [`DriveConfig::DEFAULT`]'s, at most 1 (B/J kept on a lighter drive).
    fn damping_share(&self) -> f64 {
        (self.inertia_kgm2 / DriveConfig::DEFAULT.inertia_kgm2).min(1.0)
    }

    /// The drive of the simulated prototype (same numbers as the plant's default drive).
    pub const DEFAULT: DriveConfig = DriveConfig {
        dt_s: 100e-6,
        gear_ratio: 3072.0,
        efficiency: 0.6175,
        kt_nm_per_a: 4.5e-3,
        resistance_ohm: 20.0,
        bus_v: 6.0,
        encoder_counts_per_rev: 64.0,
        // 3.3 V / (0.5 Ω × 10 V/V × 4096 codes)
        amps_per_code: 3.3 / (0.5 * 10.0 * 4096.0),
        // 1.65 V mid-scale of a 3.3 V 12-bit ADC
        adc_zero_code: 2048.0,
        theta_a_rest_rad: -0.850_360_8,
        // η × 7.0e-9 kg·m² (RE10 rotor) × 3072², and the prototype's 3 mrad: the finger file's
        // defaults (`pts::config::FingerFile::PAPER_DRIVE`).
        inertia_kgm2: 0.6175 * 7.0e-9 * 3072.0 * 3072.0,
        backlash_rad: 3e-3,
        priors: pathfit::FitPriors::DEFAULT,
    };

    /// Actuator torque per ampere of motor current: kt × ratio × efficiency (N·m/A).
    pub fn torque_per_amp(&self) -> f64 {
        self.kt_nm_per_a * self.gear_ratio * self.efficiency
    }

    /// Actuator angle per encoder count (rad/count).
    pub const fn rad_per_count(&self) -> f64 {
        2.0 * core::f64::consts::PI / (self.encoder_counts_per_rev * self.gear_ratio)
    }

    /// The path fit's configuration for this drive: the default fit with the drive's inertia
    /// and backlash ([`pathfit::PathFitConfig::with_drive_model`]) and its priors.
    pub const fn path_fit_config(&self) -> pathfit::PathFitConfig {
        pathfit::PathFitConfig::DEFAULT
            .with_drive_model(self.inertia_kgm2, self.backlash_rad)
            .with_priors(self.priors)
    }
}

impl Default for DriveConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// How the torque is raised by ΔT_a after contact.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StepShape {
    /// The reference jumps by ΔT_a in one tick.
    Step,
    /// The reference rises at this rate (N·m/s) until ΔT_a is reached (quasi-static).
    Ramp(f64),
}

/// Which estimator [`run_estimate`](crate::run_estimate) applies to the request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Estimator {
    /// The paper's two-point method: K̂c = ΔT_a/Δθa (Eq. 1), inverted at the contact
    /// configuration.
    TwoPoint,
    /// `pathfit`: the whole contact-to-settle path fitted with the quasi-static contact
    /// model (friction offset, curvature, inertia), no ΔT_a bias.
    PathFit,
}

/// What to do once the estimate is delivered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AfterEstimate {
    /// Keep the torque T_a,c + ΔT_a (grasp holds the object).
    Hold,
    /// Ramp the torque down to zero, then switch the bridge off.
    Release,
}

/// Everything the controller is told, SI units. Converted once by [`ControllerConfig::params`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControllerConfig {
    /// The finger's geometry and springs: what both estimators invert, and what fixes the
    /// rest angle [`DriveConfig::theta_a_rest_rad`] must agree with.
    pub finger: Finger,
    /// The drive constants.
    pub drive: DriveConfig,
    /// Time with the bridge off used to calibrate the current offset (s; 16‥4096 ticks).
    pub calib_s: f64,
    /// Largest accepted |ADC offset − nominal zero code| (codes); more is a sensor fault.
    pub calib_max_offset_codes: u16,
    /// Approach: rate at which the torque reference rises from zero (N·m/s).
    pub approach_rate_nm_per_s: f64,
    /// Approach: the reference stops rising while the actuator moves faster than this (rad/s):
    /// limits the speed, and so the impact, at contact.
    pub approach_speed_max_rad_s: f64,
    /// Virtual damping added by the torque loop, T_cmd = T_ref − B·ω̂a (N·m·s/rad), for a
    /// drive of [`DriveConfig::DEFAULT`]'s inertia. The drive's reflected rotor inertia (J·N²
    /// ≈ 0.066 kg·m²) on the contact stiffness is otherwise an undamped oscillator under
    /// torque control; at rest it changes nothing. A lighter drive ([`DriveConfig::inertia_kgm2`])
    /// gets B scaled by its share of that inertia (B/J kept): the full B on a light drive holds
    /// the approach to a creep whose torque, from the quantized speed, reads as a contact.
    pub damping_nm_s_per_rad: f64,
    /// Approach: torque at which the approach gives up (no contact) (N·m).
    pub approach_max_nm: f64,
    /// Decimation: time averaged into one sample of the history / path (s; 1‥64 ticks).
    pub sample_s: f64,
    /// Contact detection window, in samples.
    pub detect_window: u32,
    /// Contact detection: consecutive stiff windows needed (samples).
    pub detect_confirm: u32,
    /// Contact detection threshold on ΔT_ref/Δθa over the window (N·m/rad). Between the
    /// free-motion stiffness (≈ 0.5‥0.7) and the proximal-contact stiffness (≈ 2.6).
    pub detect_stiffness_nm_per_rad: f64,
    /// Contact detection: smallest measured torque rise over the window that counts (N·m),
    /// above the torque quantization and noise.
    pub detect_min_rise_nm: f64,
    /// Contact detection is armed once a window moved at least this far with a free-motion
    /// stiffness (rad).
    pub detect_arm_rad: f64,
    /// After contact the reference is held at T_a,c + this while the impact dies out (its
    /// rest point is not used by the estimate); the loading points after the forward slide
    /// must span at least this (N·m). 2× must be below ΔT_a.
    pub seat_above_nm: f64,
    /// Loading points: after the impact has come to rest (held by the transmission's
    /// stiction anywhere inside its band), the reference rises at this rate (N·m/s) until
    /// the drive slides forward again; the static points of the estimate are taken after
    /// that, so that all of them (and the approach) carry the same forward-sliding friction.
    pub seat_ramp_nm_per_s: f64,
    /// θa travel beyond the impact's rest point that shows the drive slides forward again
    /// (rad); a few encoder counts above the noise.
    pub slide_min_rad: f64,
    /// Torque the reference keeps rising after the slide is seen, before it is held for the
    /// first loading point (N·m): the drive leaves the stick-slip lurch and slides steadily.
    pub slide_extra_nm: f64,
    /// Seat the contact in static stages before the step (the impact's rest, then two loading
    /// points after a forward slide: the two-point estimate's static points). `false`: the
    /// step starts from T_a,c at the detection, the path fit reading the whole loading path,
    /// and the estimate is known about a second sooner.
    pub seating: bool,
    /// The torque increase ΔT_a after contact (N·m).
    pub delta_ta_nm: f64,
    /// Shape of the increase.
    pub step_shape: StepShape,
    /// Settle: samples over which θa must stay within `settle_band_rad`.
    pub settle_window: u32,
    /// Settle: largest θa spread over the window (rad).
    pub settle_band_rad: f64,
    /// Settle: minimum time after the reference reached its target (s).
    pub settle_min_s: f64,
    /// Settle must happen within this time after contact (s), otherwise a stall fault. Four
    /// static points (impact rest, two loading points, end) take ≈ 7 s on a proximal
    /// contact (K ≈ 2.6 N·m/rad, creep time B/K ≈ 0.4 s).
    pub settle_timeout_s: f64,
    /// The estimate must be delivered within this time after the request (s).
    pub estimate_timeout_s: f64,
    /// Largest stiffness of one contact (N·m/rad): a step stiffer than this (which the
    /// estimator also finds beyond a tip contact) means the finger touched a second time and
    /// is locked. Between the tip stiffness and this, the estimate is out of range.
    pub second_contact_stiffness_nm_per_rad: f64,
    /// Least θa travel over the late half of the step (rad); less is a `NoMotion` fault
    /// (a locked finger on the plant, 200 N·m/rad, still moves 0.25 mrad for 0.05 N·m).
    pub min_step_motion_rad: f64,
    /// Second contact: the late half of the step this many times stiffer than the early one
    /// (with seating; without, the whole step is held to the absolute limit alone).
    pub second_contact_ratio: u16,
    /// Loss of contact: |ω̂a| above this in contact (rad/s); in contact the step ramp moves
    /// the finger at most ramp/K_c,prox ≈ 0.4 rad/s.
    pub loss_speed_rad_s: f64,
    /// Approach: θa beyond this (rad) without a contact ends the approach (the finger would
    /// otherwise close onto its joint stops, which read like a contact).
    pub approach_theta_a_max_rad: f64,
    /// Loss of contact: θa moving beyond what the contact stiffness allows + this margin (rad).
    pub loss_margin_rad: f64,
    /// Over-current limit on |motor current| (A).
    pub overcurrent_a: f64,
    /// Over-current must persist this long (s).
    pub overcurrent_s: f64,
    /// Stall: duty saturated for this long (s).
    pub stall_s: f64,
    /// Encoder plausibility: largest |back-EMF from V − R·I − back-EMF from the encoder speed|
    /// (V) over one sample ...
    pub emf_mismatch_v: f64,
    /// ... tolerated for this long (s); longer is a sensor fault (stuck encoder).
    pub emf_mismatch_s: f64,
    /// Largest physically possible encoder change per tick (counts); more is a sensor fault.
    pub encoder_max_counts_per_tick: u16,
    /// Current loop proportional gain, relative to the static plant inverse (dimensionless).
    pub kp_rel: f64,
    /// Current loop integral gain per tick, relative to the static plant inverse (dimensionless).
    pub ki_rel: f64,
    /// The estimator the request asks for.
    pub estimator: Estimator,
    /// After the estimate: hold or release.
    pub after_estimate: AfterEstimate,
    /// Release: ramp-down rate (N·m/s); also the rate the opening torque builds up at.
    pub release_rate_nm_per_s: f64,
    /// Release: once the torque is down, the opening torque (N·m, in [0, approach_max_nm];
    /// 0: none, the finger is left to its springs) that takes the finger back to rest
    /// through a gear its springs cannot back-drive.
    pub open_torque_nm: f64,
    /// Release: the opening ends, bridge off, once θa is within this of the rest angle
    /// (rad, ≥ 0).
    pub open_end_rad: f64,
    /// Release: the opening ends, bridge off, after this long whether or not the finger is
    /// back (s, > 0).
    pub open_timeout_s: f64,
    /// Before the first approach, find the rest pose against the open stop and zero the
    /// encoder there ([`crate::rest`]); `None`: the encoder is zeroed wherever the finger is
    /// at power-up (the host tests that start the plant at rest).
    pub rest_check: Option<crate::rest::RestCheck>,
}

/// The probe after an unseated estimate stays below this share of the torque the
/// over-current limit stands for (the current's transients on the ramp stay below the limit).
const PROBE_CURRENT_SHARE: f64 = 0.8;

impl ControllerConfig {
    /// Defaults tuned against the simulated plant (see the host tests).
    pub const DEFAULT: ControllerConfig = ControllerConfig {
        finger: Finger::PAPER,
        drive: DriveConfig::DEFAULT,
        calib_s: 0.02,
        calib_max_offset_codes: 200,
        approach_rate_nm_per_s: 0.15,
        approach_speed_max_rad_s: 0.25,
        damping_nm_s_per_rad: 1.0,
        approach_max_nm: 1.5,
        sample_s: 4e-3,
        detect_window: 10,
        detect_confirm: 2,
        detect_stiffness_nm_per_rad: 1.5,
        detect_min_rise_nm: 0.003,
        detect_arm_rad: 2e-3,
        seat_above_nm: 0.01,
        seat_ramp_nm_per_s: 0.25,
        slide_min_rad: 1e-4,
        slide_extra_nm: 0.005,
        seating: false,
        delta_ta_nm: 0.2,
        step_shape: StepShape::Ramp(4.0),
        settle_window: 25,
        settle_band_rad: 5.0e-5,
        settle_min_s: 0.05,
        settle_timeout_s: 10.0,
        estimate_timeout_s: 1.0,
        second_contact_stiffness_nm_per_rad: 80.0,
        min_step_motion_rad: 1e-4,
        second_contact_ratio: 5,
        loss_speed_rad_s: 0.6,
        approach_theta_a_max_rad: 1.0,
        loss_margin_rad: 0.01,
        overcurrent_a: 0.27,
        overcurrent_s: 2e-3,
        stall_s: 0.2,
        emf_mismatch_v: 1.0,
        emf_mismatch_s: 0.02,
        encoder_max_counts_per_tick: 64,
        kp_rel: 0.2,
        ki_rel: 0.3,
        estimator: Estimator::PathFit,
        after_estimate: AfterEstimate::Hold,
        release_rate_nm_per_s: 3.0,
        open_torque_nm: 0.3,
        open_end_rad: 0.03,
        open_timeout_s: 5.0,
        rest_check: None,
    };

    /// The default configuration with another ΔT_a (N·m).
    pub fn with_delta_ta(mut self, delta_ta_nm: f64) -> Self {
        self.delta_ta_nm = delta_ta_nm;
        self
    }

    /// The checks on the configuration's values alone (before any conversion): finite, signs
    /// and ranges, the finger's rest angle (from `rest`, which must be this finger's), and a
    /// current sensor that reads past the limit.
    fn check_values(&self, rest: &FingerRest) -> Result<(), ConfigError> {
        let d = &self.drive;
        if !d.theta_a_rest_rad.is_finite() {
            return Err(ConfigError::NonFinite);
        }
        if rest.finger != self.finger {
            return Err(ConfigError::RestAngle);
        }
        if (rest.theta_a_rest_rad - d.theta_a_rest_rad).abs() > REST_ANGLE_TOL_RAD {
            return Err(ConfigError::RestAngle);
        }
        let finite = [
            d.dt_s,
            d.gear_ratio,
            d.efficiency,
            d.kt_nm_per_a,
            d.resistance_ohm,
            d.bus_v,
            d.encoder_counts_per_rev,
            d.amps_per_code,
            d.adc_zero_code,
            d.theta_a_rest_rad,
            self.approach_rate_nm_per_s,
            self.approach_max_nm,
            self.approach_speed_max_rad_s,
            self.damping_nm_s_per_rad,
            self.calib_s,
            self.sample_s,
            self.overcurrent_s,
            self.stall_s,
            self.detect_stiffness_nm_per_rad,
            self.delta_ta_nm,
            self.seat_above_nm,
            self.seat_ramp_nm_per_s,
            self.slide_min_rad,
            self.slide_extra_nm,
            self.detect_min_rise_nm,
            self.detect_arm_rad,
            self.settle_band_rad,
            self.settle_min_s,
            self.settle_timeout_s,
            self.estimate_timeout_s,
            self.second_contact_stiffness_nm_per_rad,
            self.loss_margin_rad,
            self.loss_speed_rad_s,
            self.min_step_motion_rad,
            self.approach_theta_a_max_rad,
            self.overcurrent_a,
            self.emf_mismatch_v,
            self.emf_mismatch_s,
            self.kp_rel,
            self.ki_rel,
            self.release_rate_nm_per_s,
        ];
        if finite.iter().any(|v| !v.is_finite()) {
            return Err(ConfigError::NonFinite);
        }
        let positive = [
            d.dt_s,
            d.gear_ratio,
            d.efficiency,
            d.kt_nm_per_a,
            d.resistance_ohm,
            d.bus_v,
            d.encoder_counts_per_rev,
            self.approach_rate_nm_per_s,
            self.approach_max_nm,
            self.detect_stiffness_nm_per_rad,
            self.delta_ta_nm,
            self.settle_band_rad,
            self.settle_timeout_s,
            self.estimate_timeout_s,
            self.second_contact_stiffness_nm_per_rad,
            self.overcurrent_a,
            self.release_rate_nm_per_s,
            self.seat_ramp_nm_per_s,
        ];
        if positive.iter().any(|&v| v <= 0.0)
            || d.efficiency > 1.0
            || d.amps_per_code == 0.0
            || !(0.0..4096.0).contains(&d.adc_zero_code)
            || self.kp_rel < 0.0
            || self.seat_above_nm < 0.0
            || self.slide_min_rad < 0.0
            || self.slide_extra_nm < 0.0
            || 2.0 * self.seat_above_nm >= self.delta_ta_nm
            || self.damping_nm_s_per_rad < 0.0
            || self.approach_speed_max_rad_s <= 0.0
            || !(self.ki_rel > 0.0 && self.ki_rel <= 1.0)
            || self.settle_min_s < 0.0
            || self.loss_margin_rad < 0.0
            || self.emf_mismatch_v <= 0.0
            || self.emf_mismatch_s < 0.0
            || !(0.0..=self.approach_max_nm).contains(&self.open_torque_nm)
            || !(self.open_end_rad >= 0.0 && self.open_end_rad.is_finite())
            || !(self.open_timeout_s > 0.0 && self.open_timeout_s <= 600.0)
        {
            return Err(ConfigError::OutOfRange);
        }
        // The sensor must read past the limit: full scale from the zero code to the nearer
        // rail, 5 % kept for offset and gain error (else the ADC sits at its rail below the
        // limit, and over-current detection is blind).
        let full_scale_a = d.adc_zero_code.min(4095.0 - d.adc_zero_code) * d.amps_per_code.abs();
        if self.overcurrent_a > 0.95 * full_scale_a {
            return Err(ConfigError::OverCurrentBeyondSensor);
        }
        Ok(())
    }

    /// Checks the configuration and converts it to the integer parameters of the tick path.
    ///
    /// The finger is checked here too (valid linkage, and a rest angle that agrees with
    /// [`DriveConfig::theta_a_rest_rad`] within [`REST_ANGLE_TOL_RAD`]), so the same verdict is
    /// given on the host (`pts finger`, build.rs) and on the board.
    pub fn params(&self) -> Result<Params, ConfigError> {
        self.params_for(&FingerRest::new(&self.finger)?)
    }

    /// [`ControllerConfig::params`] with the finger's part of the check already done: `rest`
    /// (this configuration's finger, else [`ConfigError::RestAngle`]) carries its rest angle, so
    /// the model is not solved again. For a firmware whose finger is fixed at build time and
    /// checked there ([`FingerRest::checked_at_build`]): it links no model for the check.
    pub fn params_for(&self, rest: &FingerRest) -> Result<Params, ConfigError> {
        self.check_values(rest)?;
        let d = &self.drive;
        let secs = |s: f64| to_u32(s / d.dt_s);
        let calib_ticks = secs(self.calib_s);
        let sample_ticks = secs(self.sample_s);
        if !(16..=4096).contains(&calib_ticks)
            || !(1..=64).contains(&sample_ticks)
            || !(2..=(HISTORY as u32 / 2)).contains(&self.detect_window)
            || !(1..=16).contains(&self.detect_confirm)
            || !(2..=(HISTORY as u32)).contains(&self.settle_window)
            || secs(self.overcurrent_s) == 0
            || secs(self.stall_s) == 0
            || self.encoder_max_counts_per_tick == 0
        {
            return Err(ConfigError::OutOfRange);
        }
        let unm = |nm: f64| to_i32(nm * 1e6);
        // Static inverse of the drive: duty (DUTY_MAX units) per µN·m of actuator torque,
        // at standstill: V = R I, I = T/(kt N η).
        let duty_per_unm =
            d.resistance_ohm / (d.torque_per_amp() * d.bus_v) * 1e-6 * DUTY_MAX as f64;
        let q16 = |x: f64| to_i64(x * 65536.0);
        // The per-tick factors are i32 (one 32×32→64 multiply each in the control loop);
        // a value that does not fit is a configuration error, not a wrap.
        let q16_i32 = |x: f64| i32::try_from(q16(x)).map_err(|_| ConfigError::OutOfRange);
        let ramp = |nm_per_s: f64| to_i64(nm_per_s * 1e6 * d.dt_s * 65536.0);
        let step_ramp_q16 = match self.step_shape {
            StepShape::Step => 0,
            StepShape::Ramp(r) if r.is_finite() && r > 0.0 => ramp(r),
            StepShape::Ramp(_) => return Err(ConfigError::OutOfRange),
        };
        let p = Params {
            calib_ticks,
            adc_zero_code: to_i32(d.adc_zero_code),
            calib_max_offset_codes: i32::from(self.calib_max_offset_codes),
            // θa_µrad = rest + counts × urad_per_count (Q16).
            urad_per_count_q16: q16_i32(d.rad_per_count() * 1e6)?,
            theta_a_rest_urad: to_i32(d.theta_a_rest_rad * 1e6),
            // T_µN·m = (code·256 − offset_q8) × unm_per_code (Q16) >> 8.
            unm_per_code_q16: q16_i32(d.amps_per_code * d.torque_per_amp() * 1e6)?,
            ua_per_code_q16: q16_i32(d.amps_per_code * 1e6)?,
            approach_ramp_q16: ramp(self.approach_rate_nm_per_s),
            approach_max_unm: unm(self.approach_max_nm),
            // µrad per sample.
            approach_vmax_urad: to_i32(self.approach_speed_max_rad_s * 1e6 * self.sample_s),
            // µN·m per (µrad per sample), Q16: B [N·m·s/rad] / sample_s.
            damping_q16: q16(self.damping_nm_s_per_rad * d.damping_share() / self.sample_s),
            sample_ticks,
            detect_window: self.detect_window as usize,
            detect_confirm: self.detect_confirm,
            detect_k_unm_per_rad: to_i64(self.detect_stiffness_nm_per_rad * 1e6),
            detect_min_rise_unm: unm(self.detect_min_rise_nm),
            detect_arm_urad: to_i32(self.detect_arm_rad * 1e6),
            seat_above_unm: unm(self.seat_above_nm),
            seat_ramp_q16: ramp(self.seat_ramp_nm_per_s),
            slide_min_urad: to_i32(self.slide_min_rad * 1e6),
            slide_extra_unm: unm(self.slide_extra_nm),
            seating: self.seating,
            delta_ta_unm: unm(self.delta_ta_nm),
            probe_max_unm: unm((self.approach_max_nm + self.delta_ta_nm)
                .min(PROBE_CURRENT_SHARE * self.overcurrent_a * d.torque_per_amp())),
            step_ramp_q16,
            settle_window: self.settle_window as usize,
            settle_band_urad: to_i32(self.settle_band_rad * 1e6),
            settle_min_ticks: secs(self.settle_min_s),
            settle_timeout_ticks: secs(self.settle_timeout_s),
            estimate_timeout_ticks: secs(self.estimate_timeout_s),
            second_k_unm_per_rad: to_i64(self.second_contact_stiffness_nm_per_rad * 1e6),
            loss_margin_urad: to_i32(self.loss_margin_rad * 1e6),
            second_ratio: u32::from(self.second_contact_ratio.max(1)),
            min_motion_urad: to_i32(self.min_step_motion_rad * 1e6),
            loss_speed_urad: to_i32(self.loss_speed_rad_s * 1e6 * self.sample_s),
            approach_theta_max_urad: to_i32(self.approach_theta_a_max_rad * 1e6),
            overcurrent_ua: to_i32(self.overcurrent_a * 1e6),
            overcurrent_ticks: secs(self.overcurrent_s),
            stall_ticks: secs(self.stall_s),
            encoder_max_step: i32::from(self.encoder_max_counts_per_tick),
            bus_uv: to_i64(d.bus_v * 1e6),
            r_mohm: to_i64(d.resistance_ohm * 1e3),
            // ke = kt (SI): µV of back-EMF per encoder count per sample.
            emf_uv_per_count_q16: q16(d.kt_nm_per_a * 2.0 * core::f64::consts::PI
                / d.encoder_counts_per_rev
                / self.sample_s
                * 1e6),
            emf_mismatch_uv: to_i64(self.emf_mismatch_v * 1e6),
            emf_mismatch_samples: to_u32(self.emf_mismatch_s / self.sample_s).max(1),
            ff_duty_per_unm_q16: q16_i32(duty_per_unm)?,
            kp_duty_per_unm_q16: q16_i32(duty_per_unm * self.kp_rel)?,
            ki_duty_per_unm_q16: q16_i32(duty_per_unm * self.ki_rel)?,
            after_estimate: self.after_estimate,
            estimator: self.estimator,
            dt_ns: to_u32(d.dt_s * 1e9),
            release_ramp_q16: ramp(self.release_rate_nm_per_s),
            open_unm: unm(self.open_torque_nm),
            open_end_urad: to_i32(self.open_end_rad * 1e6),
            open_timeout_ticks: secs(self.open_timeout_s),
            rest: match &self.rest_check {
                Some(r) => Some(r.params(d)?),
                None => None,
            },
        };
        if p.urad_per_count_q16 == 0
            || p.unm_per_code_q16 == 0
            || p.ff_duty_per_unm_q16 == 0
            || p.approach_ramp_q16 == 0
            || p.release_ramp_q16 == 0
            || p.seat_ramp_q16 == 0
        {
            return Err(ConfigError::OutOfRange);
        }
        Ok(p)
    }
}

#[cfg(feature = "std")]
impl ControllerConfig {
    /// The controller for a finger file, on a control period `dt_s` (s): the file's geometry and
    /// springs, drive, motor, encoder and current sense; the over-current limit from
    /// `motor.max_current_a`; the encoder zeroed at the finger's own rest angle; everything else
    /// from `self`. Checked by [`ControllerConfig::params`], so a file accepted here is accepted
    /// by the firmware built from it, and both estimators' tables are built for the finger, so
    /// that firmware can estimate. Errors name the file's key and what is allowed.
    pub fn with_finger_file(
        self,
        file: &pts::config::FingerFile,
        dt_s: f64,
    ) -> Result<ControllerConfig, pts::config::ConfigError> {
        use pts::config::ConfigError as E;
        use std::format;
        use std::string::ToString;
        let invalid = |key: &str, message: std::string::String| E::Invalid {
            key: key.to_string(),
            message,
        };
        let cs = &file.current_sense;
        if cs.adc_bits != ADC_BITS {
            return Err(invalid(
                "current_sense.adc_bits",
                format!(
                    "{} bits: the controller reads {ADC_BITS}-bit ADC codes",
                    cs.adc_bits
                ),
            ));
        }
        // The current the sensor can still tell apart from the rail, whichever the sign.
        let codes_to_rail = f64::from(
            cs.zero_count
                .min(ADC_MAX_CODE.saturating_sub(cs.zero_count)),
        );
        let sense_range_a = cs.amps_per_count.abs() * codes_to_rail;
        // The same rule as `params` (5 % kept for offset and gain error), said with the key.
        if file.motor.max_current_a > 0.95 * sense_range_a {
            return Err(invalid(
                "motor.max_current_a",
                format!(
                    "{} A is beyond the current sensor's range of ±{:.4} A (current_sense): an \
                     over-current could not be seen; allowed: up to {:.4} A (95 % of the range)",
                    file.motor.max_current_a,
                    sense_range_a,
                    0.95 * sense_range_a
                ),
            ));
        }
        // Both estimators run on tables built from the finger (the board's with its firmware):
        // a file whose tables cannot be built would give a controller that never estimates.
        let max_k = pathfit::q::MAX_SPRING_NM_PER_RAD;
        for (key, k) in [
            ("springs.k1_nm_per_rad", file.finger.k1),
            ("springs.k2_nm_per_rad", file.finger.k2),
        ] {
            if !(k > 0.0 && k < max_k) {
                return Err(invalid(
                    key,
                    format!(
                        "{k} N·m/rad: the estimators' tables hold springs in (0, {max_k}) N·m/rad"
                    ),
                ));
            }
        }
        let theta_a_rest_rad = finger_rest_theta_a_rad(&file.finger).map_err(|e| {
            invalid(
                "geometry",
                format!("the linkage has no rest pose the model can solve: {e:?}"),
            )
        })?;
        let cfg = ControllerConfig {
            finger: file.finger,
            drive: DriveConfig {
                dt_s,
                gear_ratio: file.drive.gear_ratio,
                efficiency: file.drive.efficiency,
                kt_nm_per_a: file.motor.kt_nm_per_a,
                resistance_ohm: file.motor.resistance_ohm,
                bus_v: file.motor.supply_v,
                encoder_counts_per_rev: f64::from(file.encoder.counts_per_rev),
                amps_per_code: cs.amps_per_count,
                adc_zero_code: f64::from(cs.zero_count),
                theta_a_rest_rad,
                inertia_kgm2: file.drive.inertia_kgm2,
                backlash_rad: file.drive.backlash_rad,
                priors: fit_priors(&file.estimate),
            },
            overcurrent_a: file.motor.max_current_a,
            ..self
        };
        match cfg.params() {
            Ok(_) => {}
            Err(ConfigError::Finger(e)) => {
                return Err(invalid(
                    "geometry",
                    format!("not a valid linkage for the model: {e:?}"),
                ))
            }
            Err(e) => {
                return Err(invalid(
                    "drive",
                    format!(
                        "the drive, motor, encoder and current-sense values together are \
                         outside what the controller's integer parameters can hold ({e:?}): e.g. \
                         a gear ratio or counts per turn so large that one count is below 1 µrad"
                    ),
                ))
            }
        }
        let table = |which: &str, r: Result<(), PtsError>| {
            r.map_err(|e| {
                invalid(
                    "geometry",
                    format!(
                        "the {which} table cannot be built for this finger ({e}): its formats \
                         hold the linkage's free motion over T_a {} … {} N·m, l2 plus a \
                         {} m object within 4·l1 and |x2|, |dx2/dθ2| ≤ 4",
                        pts::table::TABLE_TA_MIN_NM,
                        pts::table::TABLE_TA_MAX_NM,
                        pathfit::PathFitConfig::DEFAULT.max_radius_m,
                    ),
                )
            })
        };
        table(
            "two-point estimate's free-motion",
            crate::two_point_table(&file.finger).map(|_| ()),
        )?;
        table(
            "path fit's",
            crate::path_table(&file.finger, &cfg.drive, (dt_s * 1e9) as u32).map(|_| ()),
        )?;
        cfg.detection_separates(&file.finger)
            .map_err(|m| invalid("springs", m))?;
        Ok(cfg)
    }
}

impl ControllerConfig {
    /// The contact detection must take this finger's free motion for free and its softest
    /// contact for a contact: over the approach (T_a from 0 to
    /// [`ControllerConfig::approach_max_nm`]) the free-motion stiffness stays at or below half
    /// [`ControllerConfig::detect_stiffness_nm_per_rad`] (the detection reads it through the
    /// drive's friction and the approach's dynamics), and every contact (proximal, and distal
    /// from 2 % of l2 to the tip) is at least as stiff as the threshold, else it is missed.
    /// `Err` says which side fails, with the finger's stiffnesses.
    #[cfg(feature = "std")]
    pub fn detection_separates(&self, finger: &Finger) -> Result<(), std::string::String> {
        use std::format;
        let DetectionStiffness {
            free_max_nm_per_rad: free_max,
            contact_min_nm_per_rad: contact_min,
            softest,
        } = self.detection_stiffness(finger)?;
        let thr = self.detect_stiffness_nm_per_rad;
        if 2.0 * free_max > thr {
            return Err(format!(
                "the free motion is up to {free_max:.3} N·m/rad stiff over the approach: the \
                 contact detection's threshold of {thr} N·m/rad would take it for a contact \
                 (allowed: free motion up to half the threshold, {:.3} N·m/rad)",
                0.5 * thr
            ));
        }
        if contact_min < thr {
            return Err(format!(
                "{softest} is only {contact_min:.3} N·m/rad stiff: below the contact detection's \
                 threshold of {thr} N·m/rad, the detection would miss it"
            ));
        }
        Ok(())
    }

    /// The stiffnesses [`ControllerConfig::detection_separates`] compares with the threshold:
    /// the free motion's largest over the approach and the softest contact's.
    #[cfg(feature = "std")]
    pub fn detection_stiffness(
        &self,
        finger: &Finger,
    ) -> Result<DetectionStiffness, std::string::String> {
        use std::format;
        let model = pts::Model::<f64>::new(finger).map_err(|e| format!("{e:?}"))?;
        let (mut free_max, mut contact_min) = (0.0f64, (f64::INFINITY, ""));
        const STEPS: u32 = 16;
        for i in 0..=STEPS {
            let ta = self.approach_max_nm * f64::from(i) / f64::from(STEPS);
            let c = model.free_from_torque(ta).map_err(|e| {
                format!("the free motion at T_a = {ta:.3} N·m cannot be solved ({e:?})")
            })?;
            if let Ok(k) = model.kc_free(c.theta2, ta) {
                free_max = free_max.max(k);
            }
            if let Ok(k) = model.kc_proximal(c.theta2, ta) {
                if k < contact_min.0 {
                    contact_min = (k, "a proximal contact");
                }
            }
            for j in 0..10 {
                let k2 = finger.l2 * (0.02 + 0.98 * f64::from(j) / 9.0);
                if let Ok(k) = model.kc_distal(c.theta2, ta, k2) {
                    if k < contact_min.0 {
                        contact_min = (k, "a distal contact");
                    }
                }
            }
        }
        Ok(DetectionStiffness {
            free_max_nm_per_rad: free_max,
            contact_min_nm_per_rad: contact_min.0,
            softest: contact_min.1,
        })
    }
}

/// What the contact detection has to tell apart on a finger
/// (`ControllerConfig::detection_stiffness`, with `std`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DetectionStiffness {
    /// Largest free-motion stiffness over the approach (N·m/rad).
    pub free_max_nm_per_rad: f64,
    /// Smallest contact stiffness (N·m/rad).
    pub contact_min_nm_per_rad: f64,
    /// Which contact that is ("a proximal contact" or "a distal contact").
    pub softest: &'static str,
}

/// Resolution of the ADC the controller reads (bits): the STM32F411's, and the simulated board's.
pub const ADC_BITS: u32 = 12;
/// Largest ADC code.
pub const ADC_MAX_CODE: u32 = (1 << ADC_BITS) - 1;

impl Default for ControllerConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Why a configuration was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ConfigError {
    /// A value was NaN or infinite.
    NonFinite,
    /// A value was outside its documented range (or rounds to zero in integer form).
    OutOfRange,
    /// The over-current limit is beyond what the current sensor can read (its full scale,
    /// from the zero code to the nearer ADC rail, less 5 %): the trip could never fire.
    OverCurrentBeyondSensor,
    /// The finger's geometry or springs are not a valid linkage (the model's reason).
    Finger(PtsError),
    /// [`DriveConfig::theta_a_rest_rad`] is not the finger's rest angle (beyond
    /// [`REST_ANGLE_TOL_RAD`]): the encoder would be zeroed at a pose the model does not have.
    RestAngle,
}

/// Largest accepted difference between the drive's rest angle and the finger's (rad).
pub const REST_ANGLE_TOL_RAD: f64 = 1e-3;

/// A finger with its rest angle from the model: the finger's part of the controller's check
/// ([`ControllerConfig::params`]), done once.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FingerRest {
    finger: Finger,
    theta_a_rest_rad: f64,
}

impl FingerRest {
    /// Checks the finger (a valid linkage whose rest pose the model solves) and keeps its
    /// rest angle ([`finger_rest_theta_a_rad`]).
    pub fn new(finger: &Finger) -> Result<Self, ConfigError> {
        Ok(Self {
            finger: *finger,
            theta_a_rest_rad: finger_rest_theta_a_rad(finger)?,
        })
    }

    /// The result of [`FingerRest::new`] computed at build time (a build script's constant,
    /// from the same finger): not checked again. Anything else goes through `new`.
    pub const fn checked_at_build(finger: Finger, theta_a_rest_rad: f64) -> Self {
        Self {
            finger,
            theta_a_rest_rad,
        }
    }
}

/// The path fit's priors of a finger file's `[estimate]` section, to the µrad and µN·m (the
/// file's ranges keep them within 50,000 µrad and 500,000 µN·m).
#[cfg(feature = "std")]
pub fn fit_priors(p: &pts::config::EstimatePriors) -> pathfit::FitPriors {
    let micro = |v: f64| (v * 1e6).round().clamp(0.0, f64::from(u32::MAX)) as u32;
    pathfit::FitPriors {
        contact_angle_sigma_urad: micro(p.contact_angle_sigma_rad),
        friction_offset_sigma_unm: micro(p.friction_offset_sigma_nm),
    }
}

/// The input-crank angle θa at the finger's rest pose (θ1 = θ0,1, θ2 = θ0,2), in rad: where the
/// firmware zeroes its encoder.
pub fn finger_rest_theta_a_rad(finger: &Finger) -> Result<f64, ConfigError> {
    use pts::Real;
    let model = Model::<crate::EstReal>::new(finger).map_err(ConfigError::Finger)?;
    let conv = |v: f64| crate::EstReal::try_from_f64(v).ok_or(ConfigError::OutOfRange);
    let th = model
        .theta_a(conv(finger.theta01)?, conv(finger.theta02)?)
        .map_err(ConfigError::Finger)?;
    Ok(th.to_f64())
}

/// Samples kept in the pre-contact history ring (decimated samples).
pub const HISTORY: usize = 64;

/// The integer form of [`ControllerConfig`]: what the tick path reads. Q16 = ×2¹⁶.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Params {
    /// Calibration length (ticks).
    pub calib_ticks: u32,
    /// Nominal zero-current ADC code.
    pub adc_zero_code: i32,
    /// Largest accepted offset deviation (codes).
    pub calib_max_offset_codes: i32,
    /// µrad of θa per encoder count, Q16.
    pub urad_per_count_q16: i32,
    /// θa at the rest pose (µrad).
    pub theta_a_rest_urad: i32,
    /// µN·m of T_a per ADC code, Q16.
    pub unm_per_code_q16: i32,
    /// µA per ADC code, Q16.
    pub ua_per_code_q16: i32,
    /// Approach torque ramp, µN·m per tick, Q16.
    pub approach_ramp_q16: i64,
    /// Approach speed limit (µrad per sample).
    pub approach_vmax_urad: i32,
    /// Damping, µN·m per (µrad per sample), Q16.
    pub damping_q16: i64,
    /// Approach torque ceiling (µN·m).
    pub approach_max_unm: i32,
    /// Ticks per sample.
    pub sample_ticks: u32,
    /// Detection window (samples).
    pub detect_window: usize,
    /// Consecutive stiff windows (samples).
    pub detect_confirm: u32,
    /// Detection stiffness (µN·m/rad).
    pub detect_k_unm_per_rad: i64,
    /// Smallest torque rise for a stiff window (µN·m).
    pub detect_min_rise_unm: i32,
    /// Arming displacement (µrad).
    pub detect_arm_urad: i32,
    /// Seating: press above T_a,c (µN·m).
    pub seat_above_unm: i32,
    /// Seating: reference ramp until the drive slides forward, µN·m per tick, Q16.
    pub seat_ramp_q16: i64,
    /// Seating: θa travel that shows the slide (µrad).
    pub slide_min_urad: i32,
    /// Seating: torque added after the slide is seen (µN·m).
    pub slide_extra_unm: i32,
    /// Seat in static stages before the step (else the step starts at the detection).
    pub seating: bool,
    /// ΔT_a (µN·m).
    pub delta_ta_unm: i32,
    /// Step ramp, µN·m per tick, Q16; 0 = a step.
    pub step_ramp_q16: i64,
    /// Settle window (samples).
    pub settle_window: usize,
    /// Settle band (µrad).
    pub settle_band_urad: i32,
    /// Minimum settle time (ticks).
    pub settle_min_ticks: u32,
    /// Settle timeout after contact (ticks).
    pub settle_timeout_ticks: u32,
    /// Estimate delivery timeout (ticks).
    pub estimate_timeout_ticks: u32,
    /// Highest reference of the probe after an unseated estimate (µN·m): no more than a step
    /// from the approach's ceiling would reach, and a margin below the over-current limit.
    pub probe_max_unm: i32,
    /// Second-contact stiffness (µN·m/rad).
    pub second_k_unm_per_rad: i64,
    /// Least late-half travel (µrad).
    pub min_motion_urad: i32,
    /// Second-contact stiffness ratio late/early.
    pub second_ratio: u32,
    /// Loss-of-contact speed (µrad per sample).
    pub loss_speed_urad: i32,
    /// Approach θa limit (µrad).
    pub approach_theta_max_urad: i32,
    /// Loss-of-contact margin (µrad).
    pub loss_margin_urad: i32,
    /// Over-current limit (µA).
    pub overcurrent_ua: i32,
    /// Over-current persistence (ticks).
    pub overcurrent_ticks: u32,
    /// Stall persistence (ticks).
    pub stall_ticks: u32,
    /// Largest encoder step per tick (counts).
    pub encoder_max_step: i32,
    /// Bus voltage (µV).
    pub bus_uv: i64,
    /// Winding resistance (mΩ).
    pub r_mohm: i64,
    /// Back-EMF per encoder count per sample (µV), Q16.
    pub emf_uv_per_count_q16: i64,
    /// Back-EMF mismatch threshold (µV).
    pub emf_mismatch_uv: i64,
    /// Back-EMF mismatch persistence (samples).
    pub emf_mismatch_samples: u32,
    /// Feed-forward duty per µN·m, Q16.
    pub ff_duty_per_unm_q16: i32,
    /// Proportional duty per µN·m of error, Q16.
    pub kp_duty_per_unm_q16: i32,
    /// Integral duty per µN·m of error per tick, Q16.
    pub ki_duty_per_unm_q16: i32,
    /// Hold or release after the estimate.
    pub after_estimate: AfterEstimate,
    /// Estimator for the request.
    pub estimator: Estimator,
    /// Control period (ns).
    pub dt_ns: u32,
    /// Release ramp, µN·m per tick, Q16.
    pub release_ramp_q16: i64,
    /// Opening torque after a release (µN·m, ≥ 0).
    pub open_unm: i32,
    /// The opening ends within this of θa,rest (µrad).
    pub open_end_urad: i32,
    /// The opening ends after this long (ticks).
    pub open_timeout_ticks: u32,
    /// The rest check before the first approach (`None`: zeroed at power-up).
    pub rest: Option<crate::rest::RestParams>,
}

// The conversions of `params`, out of line: called from a dozen places once per grasp, one
// copy of the soft-float rounding is enough (inlined, each call site carried its own).
#[inline(never)]
fn to_i64(x: f64) -> i64 {
    // `as` saturates and maps NaN to 0: no panic; ranges are checked by the callers.
    libm_round(x) as i64
}

#[inline(never)]
fn to_i32(x: f64) -> i32 {
    libm_round(x) as i32
}

#[inline(never)]
fn to_u32(x: f64) -> u32 {
    libm_round(x) as u32
}

fn libm_round(x: f64) -> f64 {
    // Round half away from zero without std.
    if x >= 0.0 {
        (x + 0.5) as i64 as f64
    } else {
        (x - 0.5) as i64 as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The finger file's default priors are the path fit's defaults: a file that leaves
    /// `[estimate]` out builds the same table as before.
    #[cfg(feature = "std")]
    #[test]
    fn the_finger_file_s_default_priors_are_the_path_fit_s() {
        let p = fit_priors(&pts::config::FingerFile::PAPER_ESTIMATE);
        assert_eq!(p, pathfit::FitPriors::DEFAULT);
        assert_eq!(
            pathfit::PathFitConfig::DEFAULT.with_priors(p),
            pathfit::PathFitConfig::DEFAULT,
            "the default priors give the default fit, bit for bit"
        );
        assert_eq!(
            DriveConfig::DEFAULT.path_fit_config(),
            pathfit::PathFitConfig::DEFAULT.with_drive_model(
                DriveConfig::DEFAULT.inertia_kgm2,
                DriveConfig::DEFAULT.backlash_rad
            )
        );
    }

    /// The rest angle from the model agrees with the reference value of the model document
    /// (θa = −0.8503608 rad at θ1 = π/4, θ2 = 0 for the paper's finger).
    #[test]
    fn rest_angle_of_the_paper_finger_is_the_reference_value() {
        let rest = finger_rest_theta_a_rad(&Finger::PAPER).unwrap();
        assert!((rest - -0.850_360_8).abs() < 2e-6, "{rest}");
        assert!(ControllerConfig::DEFAULT.params().is_ok());
    }

    #[test]
    fn a_drive_zeroed_at_another_pose_than_the_fingers_rest_is_refused() {
        let mut c = ControllerConfig::DEFAULT;
        c.finger.l2 = 0.09;
        c.finger.k2 = 2.0;
        // l2 and K2 do not move the rest pose; θ0,1 does.
        assert!(c.params().is_ok());
        c.finger.theta01 += 0.05;
        assert_eq!(c.params().err(), Some(ConfigError::RestAngle));
        c.drive.theta_a_rest_rad = finger_rest_theta_a_rad(&c.finger).unwrap();
        assert!(c.params().is_ok());
    }

    /// The finger's part of the check done once (a firmware's build-time constant) gives the
    /// same parameters, and is refused for another finger or another rest angle.
    #[test]
    fn a_finger_checked_once_gives_the_same_parameters_and_only_for_that_finger() {
        let c = ControllerConfig::DEFAULT;
        let rest = FingerRest::new(&c.finger).unwrap();
        assert_eq!(c.params_for(&rest), c.params());
        let built = FingerRest::checked_at_build(c.finger, c.drive.theta_a_rest_rad);
        assert_eq!(c.params_for(&built), c.params());
        let mut other = c;
        other.finger.l2 = 0.09;
        assert_eq!(other.params_for(&rest).err(), Some(ConfigError::RestAngle));
        let off = FingerRest::checked_at_build(c.finger, c.drive.theta_a_rest_rad + 0.01);
        assert_eq!(c.params_for(&off).err(), Some(ConfigError::RestAngle));
        let mut bad = Finger::PAPER;
        bad.b = 0.5;
        assert!(matches!(FingerRest::new(&bad), Err(ConfigError::Finger(_))));
    }

    #[test]
    fn an_impossible_linkage_is_refused_with_the_models_reason() {
        let mut c = ControllerConfig::DEFAULT;
        c.finger.b = 0.5; // the coupler cannot close the four-bar
        assert!(
            matches!(c.params(), Err(ConfigError::Finger(_))),
            "{:?}",
            c.params()
        );
        c.finger = Finger::PAPER;
        c.finger.k1 = f64::NAN;
        assert!(matches!(c.params(), Err(ConfigError::Finger(_))));
    }
}

#[cfg(all(test, feature = "std"))]
mod file_tests {
    use super::*;
    use pts::config::{ConfigError as E, FingerFile};
    use std::string::ToString;

    fn key_of(e: E) -> std::string::String {
        match e {
            E::Invalid { key, .. } | E::Parse { key, .. } => key,
        }
    }

    #[test]
    fn every_drive_field_of_the_file_reaches_the_controller() {
        let mut f = FingerFile::paper();
        f.finger.l2 = 0.09;
        f.finger.k1 = 0.8;
        f.drive.gear_ratio = 2560.0;
        f.drive.efficiency = 0.7;
        f.motor.kt_nm_per_a = 5e-3;
        f.motor.resistance_ohm = 15.0;
        f.motor.supply_v = 5.0;
        f.motor.max_current_a = 0.28; // the sensor sees ±0.30 A (2000 codes × 0.15 mA)
        f.encoder.counts_per_rev = 128;
        f.current_sense.amps_per_count = 1.5e-4;
        f.current_sense.zero_count = 2000;
        f.estimate.contact_angle_sigma_rad = 1.5e-3;
        f.estimate.friction_offset_sigma_nm = 0.02;
        let c = ControllerConfig::DEFAULT
            .with_finger_file(&f, 1e-4)
            .unwrap();
        assert_eq!(c.finger, f.finger);
        let d = c.drive;
        // The priors reach the path fit's configuration (and with it the table's constants).
        let pf = d.path_fit_config();
        assert_eq!(
            (pf.contact_angle_sigma_rad, pf.friction_prior_sigma_nm),
            (1.5e-3, 0.02)
        );
        assert_eq!(
            (
                d.gear_ratio,
                d.efficiency,
                d.kt_nm_per_a,
                d.resistance_ohm,
                d.bus_v
            ),
            (2560.0, 0.7, 5e-3, 15.0, 5.0)
        );
        assert_eq!(
            (d.encoder_counts_per_rev, d.amps_per_code, d.adc_zero_code),
            (128.0, 1.5e-4, 2000.0)
        );
        assert_eq!(c.overcurrent_a, 0.28);
        assert_eq!(
            d.theta_a_rest_rad,
            finger_rest_theta_a_rad(&f.finger).unwrap()
        );
    }

    #[test]
    fn a_current_limit_the_sensor_cannot_see_is_refused_by_name() {
        let mut f = FingerFile::paper();
        // ±0.3298 A of sensor range (2047 codes to the upper rail × 0.161 mA).
        f.motor.max_current_a = 0.5;
        let e = ControllerConfig::DEFAULT
            .with_finger_file(&f, 1e-4)
            .unwrap_err();
        assert!(e.to_string().contains("0.3298"), "{e}");
        assert_eq!(key_of(e), "motor.max_current_a");
        // An off-centre zero narrows the range on one side.
        f.motor.max_current_a = 0.28;
        f.current_sense.zero_count = 4000;
        let e = ControllerConfig::DEFAULT
            .with_finger_file(&f, 1e-4)
            .unwrap_err();
        assert_eq!(key_of(e), "motor.max_current_a");
    }

    /// The detection's threshold (1.5 N·m/rad) between the free motion and the softest
    /// contact: the paper's finger (free ≤ 0.58, proximal 2.59 N·m/rad) passes; springs three
    /// times stiffer make the free motion up to 1.65 N·m/rad (above the threshold itself: a
    /// contact for the detection), and a distal spring a third as stiff leaves a proximal
    /// contact at 0.86 N·m/rad (missed by the detection): both refused under `springs`, with the
    /// stiffness named. The free motion's stiffness is checked by finite differences of the
    /// free-motion solution, independently of the model's closed form.
    #[test]
    fn a_finger_the_contact_detection_cannot_see_is_refused() {
        let cfg = ControllerConfig::DEFAULT;
        assert!(cfg.detection_separates(&Finger::PAPER).is_ok());
        let mut f = FingerFile::paper();
        f.finger.k1 *= 3.0;
        f.finger.k2 *= 3.0;
        let e = cfg.with_finger_file(&f, 1e-4).unwrap_err();
        assert_eq!(key_of(e.clone()), "springs", "{e}");
        assert!(e.to_string().contains("would take it for a contact"), "{e}");
        // The free motion's stiffness as the detection sees it: ΔT_a/Δθa along free motion.
        let m = Model::<f64>::new(&f.finger).unwrap();
        let th = |t: f64| m.free_from_torque(t).unwrap().theta_a;
        let k_fd = 0.2 / (th(1.5) - th(1.3));
        std::println!("{e}; finite differences: {k_fd:.3} N·m/rad");
        assert!(k_fd > 1.5, "free stiffness {k_fd}");
        let mut f = FingerFile::paper();
        f.finger.k2 /= 3.0;
        let e = cfg.with_finger_file(&f, 1e-4).unwrap_err();
        assert_eq!(key_of(e.clone()), "springs", "{e}");
        std::println!("{e}");
        assert!(e.to_string().contains("a proximal contact is only"), "{e}");
    }

    #[test]
    fn another_adc_resolution_is_refused_by_name() {
        let mut f = FingerFile::paper();
        f.current_sense.adc_bits = 16;
        let e = ControllerConfig::DEFAULT
            .with_finger_file(&f, 1e-4)
            .unwrap_err();
        assert_eq!(key_of(e), "current_sense.adc_bits");
    }

    #[test]
    fn a_drive_the_integer_parameters_cannot_hold_is_refused() {
        let mut f = FingerFile::paper();
        f.drive.gear_ratio = 1e6; // one encoder count < 0.1 µrad: rounds to zero in Q16 µrad
        f.encoder.counts_per_rev = 100_000;
        let e = ControllerConfig::DEFAULT
            .with_finger_file(&f, 1e-4)
            .unwrap_err();
        assert_eq!(key_of(e), "drive");
    }
}
