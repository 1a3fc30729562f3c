//! The finger description file (TOML), host side only (`std` feature).
//!
//! One file describes one finger: linkage geometry, joint springs and their rest angles, the
//! drive (gear ratio, efficiency), the motor constants and the sensors (encoder counts, current
//! sense scaling). The host tool reads it at run time; the firmware's `build.rs` reads the same
//! file with [`FingerFile::from_toml_str`] and emits `const` data, so the target does no parsing.
//!
//! Every section and every key is optional: what a file leaves out keeps the value of
//! [`FingerFile::paper`] (the paper's prototype, Table 1, with the springs of `MODEL.md`).
//! Unknown keys, wrong types and non-physical values are rejected with the key's dotted name.
//!
//! ```toml
//! name = "paper prototype"
//! [geometry]            # m, rad
//! l1_m = 0.100
//! l2_m = 0.075
//! a_m = 0.071
//! b_m = 0.108
//! c_m = 0.044
//! phi2_rad = 1.5707963267948966
//! [springs]             # N·m/rad, rad
//! k1_nm_per_rad = 0.6895
//! k2_nm_per_rad = 1.0274
//! theta01_rad = 0.7853981633974483
//! theta02_rad = 0.0
//! [drive]
//! gear_ratio = 3072.0   # motor turns per turn of the input crank θa
//! efficiency = 0.6175     # output torque = efficiency · gear_ratio · motor torque
//! [motor]
//! kt_nm_per_a = 0.0045
//! resistance_ohm = 20.0
//! supply_v = 6.0
//! max_current_a = 0.28
//! [encoder]
//! counts_per_rev = 64   # quadrature ×4 counts per motor revolution
//! [current_sense]
//! amps_per_count = 0.00016113281
//! zero_count = 2048
//! adc_bits = 12
//! [contact]
//! mu_max = 0.4          # largest friction coefficient at the object the estimate allows for
//! [estimate]            # the path fit's priors
//! contact_angle_sigma_rad = 0.003   # how far the contact angle found may lie from the true one
//! friction_offset_sigma_nm = 0.003  # how far the drive's friction while loading may differ
//!                                   # from the approach's
//! ```

extern crate std;

use crate::{Finger, Model, Stops};
use serde::Deserialize;
use std::fmt;
use std::format;
use std::string::{String, ToString};

/// Why a finger description was rejected.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ConfigError {
    /// Not valid TOML, an unknown key, or a value of the wrong type. The message from the
    /// parser names the key (and the line).
    Parse {
        /// Dotted key name when it could be recovered (`"drive.gear_ratio"`), else empty.
        key: String,
        /// The parser's message.
        message: String,
    },
    /// A value of the right type that is not physical.
    Invalid {
        /// Dotted key name, e.g. `"geometry.l1_m"`.
        key: String,
        /// What is wrong and what is accepted.
        message: String,
    },
}

impl ConfigError {
    /// The dotted name of the offending key (may be empty for a syntax error).
    pub fn key(&self) -> &str {
        match self {
            ConfigError::Parse { key, .. } | ConfigError::Invalid { key, .. } => key,
        }
    }

    fn invalid(key: &str, message: String) -> Self {
        ConfigError::Invalid {
            key: key.to_string(),
            message,
        }
    }
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ConfigError::Parse { key, message } if key.is_empty() => {
                write!(f, "finger file: {}", message.trim_end())
            }
            ConfigError::Parse { key, message } => {
                write!(f, "finger file: key `{key}`: {}", message.trim_end())
            }
            ConfigError::Invalid { key, message } => {
                write!(f, "finger file: key `{key}`: {message}")
            }
        }
    }
}

impl std::error::Error for ConfigError {}

/// The drive between the motor and the input crank O1Oc.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Drive {
    /// Motor revolutions per revolution of the input crank (θa); > 0.
    pub gear_ratio: f64,
    /// Transmission efficiency in (0, 1]: T_a = efficiency · gear_ratio · kt · i.
    pub efficiency: f64,
    /// Prior of the effective inertia the measured torque carries at the crank (kg·m²),
    /// η·J_rotor·N² for a geared motor; ≥ 0. Host estimators identify the inertia per
    /// recording from its approach and fall back on this where the approach never
    /// accelerated.
    pub inertia_kgm2: f64,
    /// Backlash between the encoder and the crank (rad, at the crank); ≥ 0. The encoder
    /// leads the finger by half of it while the drive loads in flexion.
    pub backlash_rad: f64,
}

/// The DC motor (paper: Maxon RE10).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Motor {
    /// Torque constant (N·m/A).
    pub kt_nm_per_a: f64,
    /// Terminal resistance (Ω).
    pub resistance_ohm: f64,
    /// H-bridge supply voltage (V).
    pub supply_v: f64,
    /// Largest current the controller may command (A).
    pub max_current_a: f64,
}

/// The incremental encoder on the motor shaft.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Encoder {
    /// Quadrature ×4 counts per motor revolution.
    pub counts_per_rev: u32,
}

/// The current sensor: a shunt amplifier read by an ADC.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentSense {
    /// Motor current per ADC count (A/count), signed: i = (code − zero_count) · amps_per_count.
    pub amps_per_count: f64,
    /// ADC code at zero current.
    pub zero_count: u32,
    /// ADC resolution (bits), 8..=16.
    pub adc_bits: u32,
}

/// The finger's contact with objects: priors an estimate needs and a recording cannot show.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Contact {
    /// Largest Coulomb friction coefficient between the distal phalanx and an object that the
    /// estimate allows for; in [0, 1.5]. Friction at the object resists the contact point's
    /// slide under the step and reads as a contact further out, and one loading path cannot
    /// tell µ from k2,c: `pts estimate` fits a recording at µ = 0 and at this µ, and σ(k2,c)
    /// spans the two. Hard pads on everyday objects: 0.2–0.4; rubber: higher; 0 when the pads
    /// cannot hold friction.
    pub mu_max: f64,
}

/// The priors of the path fit that belong to the finger and its drive (`[estimate]`). The
/// firmware's path fit takes them from its build's finger file, `pts estimate` from the file
/// it is given.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstimatePriors {
    /// How far the contact angle θa,c that the contact detection finds may lie from the true
    /// one (rad at the crank; standard deviation), 0 or in [1e-4, 0.05]: the prior of the
    /// fitted θa,c, which also enters σ(k2,c). The finger's inertia carries it past the
    /// contact and the detection sees the kink a few mrad late. 0 takes the angle found as
    /// exact.
    pub contact_angle_sigma_rad: f64,
    /// How far the transmission's friction offset while the contact loads may differ from the
    /// one read on the approach (N·m at the base link; standard deviation), 0 or in
    /// [1e-4, 0.5]: the prior that anchors the fitted path at the contact. A drive with
    /// stick-slip or a friction that changes with load sets more. 0 leaves the offset free.
    pub friction_offset_sigma_nm: f64,
}

/// A validated finger description: what [`FingerFile::from_toml_str`] returns.
#[derive(Clone, Debug, PartialEq)]
pub struct FingerFile {
    /// Free-text name of the finger.
    pub name: String,
    /// Geometry and springs, in the form the model takes.
    pub finger: Finger,
    /// Gear ratio and efficiency.
    pub drive: Drive,
    /// Motor constants.
    pub motor: Motor,
    /// Encoder resolution.
    pub encoder: Encoder,
    /// Current-sense scaling.
    pub current_sense: CurrentSense,
    /// Extension stops.
    pub stops: Stops,
    /// Contact priors of the estimate.
    pub contact: Contact,
    /// The path fit's priors.
    pub estimate: EstimatePriors,
}

impl Default for FingerFile {
    fn default() -> Self {
        Self::paper()
    }
}

impl FingerFile {
    /// Drive defaults of the prototype. The paper gives none; these are the simulated plant's
    /// (`plant::drive::DriveParams::RE10_GP10A`, `plant::sensors::SensorParams::DEFAULT`): a
    /// Maxon RE10 6 V (4.5 mN·m/A, 20 Ω) behind a 256:1 gearhead and a 12:1 cable stage
    /// (N = 3072, η = 0.6175 driving), a 16-line encoder (64 counts ×4 per motor turn) and a
    /// 0.5 Ω shunt × 10 V/V into a 12-bit 3.3 V ADC (6206 codes/A, zero at code 2048).
    pub const PAPER_DRIVE: Drive = Drive {
        gear_ratio: 3072.0,
        efficiency: 0.6175,
        // η · 7.0e-9 kg·m² (RE10 rotor) · 3072², and the plant's 3 mrad.
        inertia_kgm2: 0.6175 * 7.0e-9 * 3072.0 * 3072.0,
        backlash_rad: 3e-3,
    };
    /// Motor defaults of the prototype (see [`FingerFile::PAPER_DRIVE`]).
    pub const PAPER_MOTOR: Motor = Motor {
        kt_nm_per_a: 4.5e-3,
        resistance_ohm: 20.0,
        supply_v: 6.0,
        max_current_a: 0.28,
    };
    /// Encoder defaults of the prototype.
    pub const PAPER_ENCODER: Encoder = Encoder { counts_per_rev: 64 };
    /// Contact defaults of the prototype: hard pads, dry friction up to 0.4.
    pub const PAPER_CONTACT: Contact = Contact { mu_max: 0.4 };
    /// The path fit's priors for the prototype: 3 mrad and 3 mN·m (`pathfit::FitPriors`
    /// holds the same numbers; a test checks that they agree).
    pub const PAPER_ESTIMATE: EstimatePriors = EstimatePriors {
        contact_angle_sigma_rad: 0.003,
        friction_offset_sigma_nm: 0.003,
    };
    /// Current-sense defaults of the prototype: ±0.33 A over a 12-bit ADC.
    pub const PAPER_CURRENT_SENSE: CurrentSense = CurrentSense {
        amps_per_count: 1.0 / (0.5 * 10.0 * 4096.0 / 3.3),
        zero_count: 2048,
        adc_bits: 12,
    };

    /// The paper's prototype (Table 1) with the springs of `MODEL.md` and the drive
    /// constants above.
    pub fn paper() -> Self {
        FingerFile {
            name: "paper prototype".to_string(),
            finger: Finger::PAPER,
            drive: Self::PAPER_DRIVE,
            motor: Self::PAPER_MOTOR,
            encoder: Self::PAPER_ENCODER,
            current_sense: Self::PAPER_CURRENT_SENSE,
            stops: Stops::below_rest(&Finger::PAPER),
            contact: Self::PAPER_CONTACT,
            estimate: Self::PAPER_ESTIMATE,
        }
    }

    /// Parses and validates a finger description. Missing keys keep the paper's values;
    /// unknown keys, wrong types and non-physical values are errors naming the key.
    pub fn from_toml_str(text: &str) -> Result<FingerFile, ConfigError> {
        let raw: RawFile = toml::from_str(text).map_err(|e| {
            let message = e.message().to_string();
            // serde names the key alone; prefix the [table] it sits in.
            let table = e
                .span()
                .and_then(|sp| text.get(..sp.start))
                .filter(|before| {
                    // An unknown table header names itself: no prefix.
                    let line = before.rsplit('\n').next().unwrap_or(before);
                    !line.trim_start().starts_with('[')
                })
                .and_then(|before| {
                    before
                        .lines()
                        .rev()
                        .map(str::trim)
                        .find(|l| l.starts_with('[') && l.ends_with(']'))
                        .map(|l| l.trim_matches(|c| c == '[' || c == ']').trim().to_string())
                });
            let key = match (unknown_key(&message), table) {
                (Some(k), Some(t)) if !t.is_empty() => format!("{t}.{k}"),
                (Some(k), _) => k,
                (None, _) => String::new(),
            };
            let located = match e.span() {
                Some(span) => {
                    let line = text
                        .get(..span.start)
                        .map(|s| s.matches('\n').count() + 1)
                        .unwrap_or(0);
                    format!("{message} (line {line})")
                }
                None => message,
            };
            ConfigError::Parse {
                key,
                message: located,
            }
        })?;
        raw.into_validated()
    }

    /// Output torque T_a at the input crank (N·m) for a motor current (A).
    pub fn torque_from_current(&self, current_a: f64) -> f64 {
        current_a * self.motor.kt_nm_per_a * self.drive.gear_ratio * self.drive.efficiency
    }

    /// Motor current (A) that produces the output torque T_a (N·m).
    pub fn current_from_torque(&self, torque_nm: f64) -> f64 {
        torque_nm / (self.motor.kt_nm_per_a * self.drive.gear_ratio * self.drive.efficiency)
    }

    /// Change of θa (rad) per encoder count.
    pub fn rad_per_count(&self) -> f64 {
        2.0 * core::f64::consts::PI
            / (f64::from(self.encoder.counts_per_rev) * self.drive.gear_ratio)
    }

    /// The TOML text of this description (every key written), for `pts finger --print`.
    pub fn to_toml_string(&self) -> String {
        let f = &self.finger;
        let d = &self.drive;
        let m = &self.motor;
        let cs = &self.current_sense;
        format!(
            "name = {name:?}\n\n\
             [geometry]\nl1_m = {l1:?}\nl2_m = {l2:?}\na_m = {a:?}\nb_m = {b:?}\nc_m = {c:?}\nphi2_rad = {phi2:?}\n\n\
             [springs]\nk1_nm_per_rad = {k1:?}\nk2_nm_per_rad = {k2:?}\ntheta01_rad = {t01:?}\ntheta02_rad = {t02:?}\n\n\
             [drive]\ngear_ratio = {gr:?}\nefficiency = {eff:?}\ninertia_kgm2 = {jd:?}\nbacklash_rad = {bl:?}\n\n\
             [motor]\nkt_nm_per_a = {kt:?}\nresistance_ohm = {r:?}\nsupply_v = {v:?}\nmax_current_a = {imax:?}\n\n\
             [encoder]\ncounts_per_rev = {cpr}\n\n\
             [current_sense]\namps_per_count = {apc:?}\nzero_count = {zc}\nadc_bits = {bits}\n\n\
             [stops]\ntheta1_min_rad = {s1:?}\ntheta2_min_rad = {s2:?}\nstiffness_nm_per_rad = {sk:?}\n\n\
             [contact]\nmu_max = {mu:?}\n\n\
             [estimate]\ncontact_angle_sigma_rad = {sth:?}\nfriction_offset_sigma_nm = {sfr:?}\n",
            name = self.name,
            l1 = f.l1,
            l2 = f.l2,
            a = f.a,
            b = f.b,
            c = f.c,
            phi2 = f.phi2,
            k1 = f.k1,
            k2 = f.k2,
            t01 = f.theta01,
            t02 = f.theta02,
            gr = d.gear_ratio,
            eff = d.efficiency,
            jd = d.inertia_kgm2,
            bl = d.backlash_rad,
            kt = m.kt_nm_per_a,
            r = m.resistance_ohm,
            v = m.supply_v,
            imax = m.max_current_a,
            cpr = self.encoder.counts_per_rev,
            apc = cs.amps_per_count,
            zc = cs.zero_count,
            bits = cs.adc_bits,
            s1 = self.stops.theta1_min_rad,
            s2 = self.stops.theta2_min_rad,
            sk = self.stops.stiffness_nm_per_rad,
            mu = self.contact.mu_max,
            sth = self.estimate.contact_angle_sigma_rad,
            sfr = self.estimate.friction_offset_sigma_nm,
        )
    }
}

/// Pulls the key out of serde's "unknown field `x`, expected …" message.
fn unknown_key(message: &str) -> Option<String> {
    let rest = message.split("unknown field `").nth(1)?;
    rest.split('`').next().map(ToString::to_string)
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawFile {
    name: Option<String>,
    geometry: RawGeometry,
    springs: RawSprings,
    drive: RawDrive,
    motor: RawMotor,
    encoder: RawEncoder,
    current_sense: RawCurrentSense,
    stops: RawStops,
    contact: RawContact,
    estimate: RawEstimate,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawContact {
    mu_max: Option<f64>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawEstimate {
    contact_angle_sigma_rad: Option<f64>,
    friction_offset_sigma_nm: Option<f64>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawGeometry {
    l1_m: Option<f64>,
    l2_m: Option<f64>,
    a_m: Option<f64>,
    b_m: Option<f64>,
    c_m: Option<f64>,
    phi2_rad: Option<f64>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawSprings {
    k1_nm_per_rad: Option<f64>,
    k2_nm_per_rad: Option<f64>,
    theta01_rad: Option<f64>,
    theta02_rad: Option<f64>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawDrive {
    gear_ratio: Option<f64>,
    efficiency: Option<f64>,
    inertia_kgm2: Option<f64>,
    backlash_rad: Option<f64>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawMotor {
    kt_nm_per_a: Option<f64>,
    resistance_ohm: Option<f64>,
    supply_v: Option<f64>,
    max_current_a: Option<f64>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawStops {
    theta1_min_rad: Option<f64>,
    theta2_min_rad: Option<f64>,
    stiffness_nm_per_rad: Option<f64>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawEncoder {
    counts_per_rev: Option<i64>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawCurrentSense {
    amps_per_count: Option<f64>,
    zero_count: Option<i64>,
    adc_bits: Option<i64>,
}

/// A float key with its accepted interval (lo, hi]; `lo_closed` makes it [lo, hi].
fn real(
    key: &str,
    v: Option<f64>,
    default: f64,
    lo: f64,
    lo_closed: bool,
    hi: f64,
    unit: &str,
) -> Result<f64, ConfigError> {
    let Some(x) = v else { return Ok(default) };
    let above = if lo_closed { x >= lo } else { x > lo };
    if !x.is_finite() || !above || x > hi {
        let open = if lo_closed { '[' } else { '(' };
        return Err(ConfigError::invalid(
            key,
            format!("{x} is not physical: expected a finite value in {open}{lo}, {hi}] {unit}"),
        ));
    }
    Ok(x)
}

/// The smallest nonzero σ of a path-fit prior the file accepts: the firmware's integer kernel
/// weighs a prior by 1/σ² in Q32.32, which a σ below about 2e-5 overflows (every fit is then
/// refused as not determined).
const PRIOR_SIGMA_MIN: f64 = 1e-4;

/// A path-fit prior's σ: 0 (`zero`: what 0 means), or in [[`PRIOR_SIGMA_MIN`], `hi`] `unit`.
fn prior_sigma(
    key: &str,
    v: Option<f64>,
    default: f64,
    hi: f64,
    unit: &str,
    zero: &str,
) -> Result<f64, ConfigError> {
    let Some(x) = v else { return Ok(default) };
    if x == 0.0 || (x.is_finite() && (PRIOR_SIGMA_MIN..=hi).contains(&x)) {
        return Ok(x);
    }
    Err(ConfigError::invalid(
        key,
        format!("{x} is not allowed: expected 0 ({zero}) or a value in [{PRIOR_SIGMA_MIN}, {hi}] {unit}"),
    ))
}

fn integer(key: &str, v: Option<i64>, default: u32, lo: i64, hi: i64) -> Result<u32, ConfigError> {
    let Some(x) = v else { return Ok(default) };
    if x < lo || x > hi {
        return Err(ConfigError::invalid(
            key,
            format!("{x} is not physical: expected an integer in [{lo}, {hi}]"),
        ));
    }
    u32::try_from(x).map_err(|_| ConfigError::invalid(key, format!("{x} does not fit")))
}

const TAU: f64 = 2.0 * core::f64::consts::PI;

impl RawFile {
    fn into_validated(self) -> Result<FingerFile, ConfigError> {
        let finger = self.finger()?;
        check_linkage(&finger)?;
        let drive = self.drive()?;
        let motor = self.motor()?;
        let current_sense = self.current_sense()?;
        let encoder = Encoder {
            counts_per_rev: integer(
                "encoder.counts_per_rev",
                self.encoder.counts_per_rev,
                FingerFile::PAPER_ENCODER.counts_per_rev,
                4,
                1 << 24,
            )?,
        };
        let stops = self.stops(&finger)?;
        let contact = Contact {
            mu_max: real(
                "contact.mu_max",
                self.contact.mu_max,
                FingerFile::PAPER_CONTACT.mu_max,
                0.0,
                true,
                1.5,
                "(Coulomb coefficient)",
            )?,
        };
        let d = FingerFile::PAPER_ESTIMATE;
        let estimate = EstimatePriors {
            contact_angle_sigma_rad: prior_sigma(
                "estimate.contact_angle_sigma_rad",
                self.estimate.contact_angle_sigma_rad,
                d.contact_angle_sigma_rad,
                0.05,
                "rad",
                "the contact angle found is taken as exact",
            )?,
            friction_offset_sigma_nm: prior_sigma(
                "estimate.friction_offset_sigma_nm",
                self.estimate.friction_offset_sigma_nm,
                d.friction_offset_sigma_nm,
                0.5,
                "N·m",
                "no prior on the friction offset",
            )?,
        };
        Ok(FingerFile {
            name: self.name.unwrap_or_else(|| "unnamed finger".to_string()),
            finger,
            drive,
            motor,
            encoder,
            current_sense,
            stops,
            contact,
            estimate,
        })
    }

    /// `[stops]`: each below its rest angle (missing: [`Stops::below_rest`]).
    fn stops(&self, finger: &Finger) -> Result<Stops, ConfigError> {
        let d = Stops::below_rest(finger);
        let s = &self.stops;
        let below = |key: &str, v: Option<f64>, default: f64, rest: f64, joint: &str| {
            let Some(x) = v else { return Ok(default) };
            if x.is_finite() && x < rest && x >= rest - 1.0 {
                Ok(x)
            } else {
                Err(ConfigError::invalid(
                    key,
                    format!(
                        "{x} is not physical: expected a finite value in [{}, {rest}) rad, below \
                         the rest angle {joint} = {rest} by at most 1 rad",
                        rest - 1.0
                    ),
                ))
            }
        };
        Ok(Stops {
            theta1_min_rad: below(
                "stops.theta1_min_rad",
                s.theta1_min_rad,
                d.theta1_min_rad,
                finger.theta01,
                "springs.theta01_rad",
            )?,
            theta2_min_rad: below(
                "stops.theta2_min_rad",
                s.theta2_min_rad,
                d.theta2_min_rad,
                finger.theta02,
                "springs.theta02_rad",
            )?,
            stiffness_nm_per_rad: real(
                "stops.stiffness_nm_per_rad",
                s.stiffness_nm_per_rad,
                d.stiffness_nm_per_rad,
                0.0,
                false,
                1e7,
                "N·m/rad",
            )?,
        })
    }

    /// `[geometry]` and `[springs]`, each value in its physical range.
    fn finger(&self) -> Result<Finger, ConfigError> {
        let p = Finger::PAPER;
        let g = &self.geometry;
        let s = &self.springs;
        Ok(Finger {
            l1: real("geometry.l1_m", g.l1_m, p.l1, 0.0, false, 10.0, "m")?,
            l2: real("geometry.l2_m", g.l2_m, p.l2, 0.0, false, 10.0, "m")?,
            a: real("geometry.a_m", g.a_m, p.a, 0.0, false, 10.0, "m")?,
            b: real("geometry.b_m", g.b_m, p.b, 0.0, false, 10.0, "m")?,
            c: real("geometry.c_m", g.c_m, p.c, 0.0, false, 10.0, "m")?,
            phi2: real(
                "geometry.phi2_rad",
                g.phi2_rad,
                p.phi2,
                -TAU,
                true,
                TAU,
                "rad",
            )?,
            theta01: real(
                "springs.theta01_rad",
                s.theta01_rad,
                p.theta01,
                -TAU,
                true,
                TAU,
                "rad",
            )?,
            theta02: real(
                "springs.theta02_rad",
                s.theta02_rad,
                p.theta02,
                -TAU,
                true,
                TAU,
                "rad",
            )?,
            k1: real(
                "springs.k1_nm_per_rad",
                s.k1_nm_per_rad,
                p.k1,
                0.0,
                true,
                1e4,
                "N·m/rad",
            )?,
            k2: real(
                "springs.k2_nm_per_rad",
                s.k2_nm_per_rad,
                p.k2,
                0.0,
                false,
                1e4,
                "N·m/rad",
            )?,
        })
    }

    /// `[drive]`.
    fn drive(&self) -> Result<Drive, ConfigError> {
        let d = &self.drive;
        Ok(Drive {
            gear_ratio: real(
                "drive.gear_ratio",
                d.gear_ratio,
                FingerFile::PAPER_DRIVE.gear_ratio,
                0.0,
                false,
                1e5,
                "(motor turns per crank turn)",
            )?,
            efficiency: real(
                "drive.efficiency",
                d.efficiency,
                FingerFile::PAPER_DRIVE.efficiency,
                0.0,
                false,
                1.0,
                "",
            )?,
            inertia_kgm2: real(
                "drive.inertia_kgm2",
                d.inertia_kgm2,
                FingerFile::PAPER_DRIVE.inertia_kgm2,
                0.0,
                true,
                10.0,
                "(effective inertia at the crank)",
            )?,
            backlash_rad: real(
                "drive.backlash_rad",
                d.backlash_rad,
                FingerFile::PAPER_DRIVE.backlash_rad,
                0.0,
                true,
                0.1,
                "(at the crank)",
            )?,
        })
    }

    /// `[motor]`.
    fn motor(&self) -> Result<Motor, ConfigError> {
        let m = &self.motor;
        let pm = FingerFile::PAPER_MOTOR;
        Ok(Motor {
            kt_nm_per_a: real(
                "motor.kt_nm_per_a",
                m.kt_nm_per_a,
                pm.kt_nm_per_a,
                0.0,
                false,
                10.0,
                "N·m/A",
            )?,
            resistance_ohm: real(
                "motor.resistance_ohm",
                m.resistance_ohm,
                pm.resistance_ohm,
                0.0,
                false,
                1e4,
                "Ω",
            )?,
            supply_v: real(
                "motor.supply_v",
                m.supply_v,
                pm.supply_v,
                0.0,
                false,
                1e3,
                "V",
            )?,
            max_current_a: real(
                "motor.max_current_a",
                m.max_current_a,
                pm.max_current_a,
                0.0,
                false,
                1e3,
                "A",
            )?,
        })
    }

    /// `[current_sense]`: the zero code within the ADC's range.
    fn current_sense(&self) -> Result<CurrentSense, ConfigError> {
        let c = &self.current_sense;
        let pc = FingerFile::PAPER_CURRENT_SENSE;
        let adc_bits = integer("current_sense.adc_bits", c.adc_bits, pc.adc_bits, 8, 16)?;
        Ok(CurrentSense {
            amps_per_count: real(
                "current_sense.amps_per_count",
                c.amps_per_count,
                pc.amps_per_count,
                0.0,
                false,
                10.0,
                "A/count",
            )?,
            zero_count: integer(
                "current_sense.zero_count",
                c.zero_count,
                pc.zero_count,
                0,
                (1i64 << adc_bits) - 1,
            )?,
            adc_bits,
        })
    }
}

/// The linkage closes, and its rest pose assembles away from the toggle (else the model
/// cannot start at all).
fn check_linkage(finger: &Finger) -> Result<(), ConfigError> {
    if finger.validate().is_err() {
        return Err(ConfigError::invalid(
            "geometry.b_m",
            format!(
                "the linkage cannot close: the coupler b = {} m must lie strictly between \
                     |l1 − a| − c = {} m and l1 + a + c = {} m",
                finger.b,
                (finger.l1 - finger.a).abs() - finger.c,
                finger.l1 + finger.a + finger.c
            ),
        ));
    }
    let model =
        Model::<f64>::new(finger).map_err(|e| ConfigError::invalid("geometry", format!("{e}")))?;
    let rest_ok = match model.free_from_torque(0.0) {
        Ok(cfg) if cfg.x2 > crate::model::TOGGLE_X2 => Ok(()),
        Ok(cfg) => Err(format!("x2 = {} ≤ 0 (past the toggle)", cfg.x2)),
        Err(e) => Err(format!("{e}")),
    };
    if let Err(why) = rest_ok {
        return Err(ConfigError::invalid(
            "springs.theta02_rad",
            format!(
                "the rest pose (θ2 = {} rad) is not usable with this geometry: {why}",
                finger.theta02
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_file_is_the_paper_finger() {
        let f = FingerFile::from_toml_str("").unwrap();
        assert_eq!(f.finger, Finger::PAPER);
        assert_eq!(f.drive, FingerFile::PAPER_DRIVE);
    }

    #[test]
    fn round_trip_through_text() {
        let mut f = FingerFile::paper();
        f.finger.k1 = 0.5;
        f.drive.gear_ratio = 100.0;
        f.stops.theta2_min_rad = -0.125;
        f.contact.mu_max = 0.85;
        f.estimate.contact_angle_sigma_rad = 0.0015;
        f.estimate.friction_offset_sigma_nm = 0.02;
        let g = FingerFile::from_toml_str(&f.to_toml_string()).unwrap();
        assert_eq!(f, g);
    }

    #[test]
    fn stops_default_below_the_file_s_rest_angles_and_are_checked() {
        // The prototype's: π/4 − 0.05 and −0.05 (the simulated plant's `FingerGeom::PAPER`).
        let p = FingerFile::paper().stops;
        assert_eq!(p.theta1_min_rad, core::f64::consts::FRAC_PI_4 - 0.05);
        assert_eq!(p.theta2_min_rad, -0.05);
        // Without [stops], they follow the file's rest angles.
        let f =
            FingerFile::from_toml_str("[springs]\ntheta01_rad = 0.6\ntheta02_rad = 0.1\n").unwrap();
        assert_eq!(f.stops.theta1_min_rad, 0.6 - 0.05);
        assert_eq!(f.stops.theta2_min_rad, 0.1 - 0.05);
        let f = FingerFile::from_toml_str(
            "[stops]\ntheta1_min_rad = 0.7\ntheta2_min_rad = -0.2\nstiffness_nm_per_rad = 50\n",
        )
        .unwrap();
        assert_eq!(f.stops.theta1_min_rad, 0.7);
        assert_eq!(f.stops.theta2_min_rad, -0.2);
        assert_eq!(f.stops.stiffness_nm_per_rad, 50.0);
        // At or above the rest angle, more than 1 rad below, or a stiffness ≤ 0: named, with
        // the range.
        for (text, key, range) in [
            (
                "[stops]\ntheta1_min_rad = 0.8",
                "stops.theta1_min_rad",
                "0.785",
            ),
            (
                "[stops]\ntheta1_min_rad = -0.3",
                "stops.theta1_min_rad",
                "-0.214",
            ),
            (
                "[stops]\ntheta2_min_rad = 0.0",
                "stops.theta2_min_rad",
                "[-1, 0)",
            ),
            (
                "[stops]\ntheta2_min_rad = nan",
                "stops.theta2_min_rad",
                "[-1, 0)",
            ),
            (
                "[stops]\nstiffness_nm_per_rad = 0",
                "stops.stiffness_nm_per_rad",
                "(0, 10000000]",
            ),
            ("[stops]\nangle = 1", "stops.angle", ""),
        ] {
            assert_refused(text, key, range);
        }
    }

    /// `text` is refused, the error naming `key` and saying `range` (the allowed values).
    fn assert_refused(text: &str, key: &str, range: &str) {
        let e = FingerFile::from_toml_str(text).unwrap_err();
        assert_eq!(e.key(), key, "{text}: {e}");
        assert!(e.to_string().contains(range), "{text}: {e}");
    }

    #[test]
    fn the_contact_friction_prior_is_read_and_checked() {
        assert_eq!(FingerFile::from_toml_str("").unwrap().contact.mu_max, 0.4);
        let f = FingerFile::from_toml_str("[contact]\nmu_max = 0.0\n").unwrap();
        assert_eq!(f.contact.mu_max, 0.0);
        let f = FingerFile::from_toml_str("[contact]\nmu_max = 1.5\n").unwrap();
        assert_eq!(f.contact.mu_max, 1.5);
        for text in [
            "[contact]\nmu_max = -0.1",
            "[contact]\nmu_max = 1.6",
            "[contact]\nmu_max = inf",
        ] {
            assert_refused(text, "contact.mu_max", "[0, 1.5]");
        }
        assert_refused("[contact]\nmu = 0.3", "contact.mu", "");
    }

    #[test]
    fn the_path_fit_priors_are_read_and_checked() {
        let d = FingerFile::from_toml_str("").unwrap().estimate;
        assert_eq!(d, FingerFile::PAPER_ESTIMATE);
        let f = FingerFile::from_toml_str(
            "[estimate]\ncontact_angle_sigma_rad = 0.0\nfriction_offset_sigma_nm = 0.5\n",
        )
        .unwrap();
        assert_eq!(f.estimate.contact_angle_sigma_rad, 0.0);
        assert_eq!(f.estimate.friction_offset_sigma_nm, 0.5);
        let f = FingerFile::from_toml_str(
            "[estimate]\ncontact_angle_sigma_rad = 1e-4\nfriction_offset_sigma_nm = 0.0\n",
        )
        .unwrap();
        assert_eq!(f.estimate.contact_angle_sigma_rad, 1e-4);
        assert_eq!(f.estimate.friction_offset_sigma_nm, 0.0);
        for text in [
            "[estimate]\ncontact_angle_sigma_rad = -1e-3",
            "[estimate]\ncontact_angle_sigma_rad = 0.06",
            "[estimate]\ncontact_angle_sigma_rad = 1e-5",
        ] {
            assert_refused(
                text,
                "estimate.contact_angle_sigma_rad",
                "0 (the contact angle found is taken as exact) or a value in [0.0001, 0.05] rad",
            );
        }
        for text in [
            "[estimate]\nfriction_offset_sigma_nm = nan",
            "[estimate]\nfriction_offset_sigma_nm = 0.51",
            "[estimate]\nfriction_offset_sigma_nm = 5e-5",
        ] {
            assert_refused(
                text,
                "estimate.friction_offset_sigma_nm",
                "or a value in [0.0001, 0.5] N·m",
            );
        }
        assert_refused(
            "[estimate]\nfriction_prior = 0.01",
            "estimate.friction_prior",
            "",
        );
    }

    #[test]
    fn partial_file_overrides_only_its_keys() {
        let f = FingerFile::from_toml_str("[springs]\nk1_nm_per_rad = 0.3\n").unwrap();
        assert_eq!(f.finger.k1, 0.3);
        assert_eq!(f.finger.k2, Finger::PAPER.k2);
    }

    #[test]
    fn unknown_keys_are_named() {
        let e = FingerFile::from_toml_str("[springs]\nk3_nm_per_rad = 1.0\n").unwrap_err();
        assert_eq!(e.key(), "springs.k3_nm_per_rad", "{e}");
        assert!(e.to_string().contains("k3_nm_per_rad"), "{e}");
        let e = FingerFile::from_toml_str("[gearbox]\nratio = 1.0\n").unwrap_err();
        assert_eq!(e.key(), "gearbox", "{e}");
        let e = FingerFile::from_toml_str("[drive]\nefficiency = 0.5\n[gearbox]\nratio = 1.0\n")
            .unwrap_err();
        assert_eq!(e.key(), "gearbox", "{e}");
        let e = FingerFile::from_toml_str("colour = \"red\"\n").unwrap_err();
        assert_eq!(e.key(), "colour", "{e}");
    }

    #[test]
    fn wrong_type_is_a_parse_error_with_line() {
        let e = FingerFile::from_toml_str("[drive]\n\ngear_ratio = \"high\"\n").unwrap_err();
        assert!(matches!(e, ConfigError::Parse { .. }), "{e}");
        assert!(e.to_string().contains("line 3"), "{e}");
    }

    #[test]
    fn non_physical_values_are_named() {
        for (text, key) in [
            ("[geometry]\nl1_m = -0.1", "geometry.l1_m"),
            ("[geometry]\nl2_m = 0.0", "geometry.l2_m"),
            ("[geometry]\nb_m = 0.5", "geometry.b_m"),
            ("[springs]\nk1_nm_per_rad = -1.0", "springs.k1_nm_per_rad"),
            ("[springs]\nk2_nm_per_rad = 0.0", "springs.k2_nm_per_rad"),
            ("[springs]\ntheta01_rad = nan", "springs.theta01_rad"),
            ("[springs]\ntheta02_rad = 2.4", "springs.theta02_rad"),
            ("[drive]\ngear_ratio = 0.0", "drive.gear_ratio"),
            ("[drive]\nefficiency = 1.2", "drive.efficiency"),
            ("[motor]\nkt_nm_per_a = inf", "motor.kt_nm_per_a"),
            ("[encoder]\ncounts_per_rev = 0", "encoder.counts_per_rev"),
            ("[current_sense]\nadc_bits = 40", "current_sense.adc_bits"),
            (
                "[current_sense]\nadc_bits = 10\nzero_count = 2048",
                "current_sense.zero_count",
            ),
        ] {
            let e = FingerFile::from_toml_str(text).unwrap_err();
            assert_eq!(e.key(), key, "{text}: {e}");
            assert!(matches!(e, ConfigError::Invalid { .. }), "{text}: {e}");
            assert!(e.to_string().contains(key), "{e}");
        }
    }

    #[test]
    fn shipped_paper_file_is_the_default() {
        let text = include_str!("../../pts-cli/fingers/paper.toml");
        let f = FingerFile::from_toml_str(text).unwrap();
        assert_eq!(f, FingerFile::paper());
    }

    #[test]
    fn drive_conversions_are_inverse() {
        let f = FingerFile::paper();
        let t = f.torque_from_current(0.25);
        // 0.25 A · 4.5 mN·m/A · 3072 · 0.6175
        assert!((t - 0.25 * 0.0045 * 3072.0 * 0.6175).abs() < 1e-15);
        assert!((f.current_from_torque(t) - 0.25).abs() < 1e-15);
        let expected = 2.0 * core::f64::consts::PI / (64.0 * 3072.0);
        assert!((f.rad_per_count() - expected).abs() < 1e-18);
    }
}
