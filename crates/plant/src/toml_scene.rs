//! Scenes from TOML (std feature). Every table and key is optional and overrides the realistic
//! defaults ([`Scene::DEFAULT`]); unknown keys and non-physical values are rejected with the key.
//!
//! ```toml
//! name = "table2"
//! dt_s = 1e-4            # control period (s)
//! duration_s = 5.0       # open-loop run length (s); closed-loop runners have their own limit
//! ideal = false          # true: friction, backlash, gear losses and sensor errors off
//! start_theta_a_rad = -0.3  # optional: start in free motion there (approach shortcut)
//!
//! [object]               # kind = "none" | "vertex" | "cylinder"
//! kind = "cylinder"
//! radius_m = 0.05
//! phalanx = 2            # first contact on the distal phalanx ...
//! k_m = 0.02927          # ... at k2 (m) ...
//! theta1_c_rad = 1.2797  # ... when θ1 = 1.2797 rad (or give x_m, y_m instead)
//!
//! [command]              # open-loop drive: mode = "external" | "duty" | "current"; the
//!                        # closed-loop runners (pts sim, the firmware) drive with the controller
//! mode = "duty"
//! from = 0.0
//! to = 0.8
//! ramp_s = 0.3
//!
//! [finger]   # l1_m l2_m a_m b_m c_m phi2_rad theta01_rad theta02_rad k1_nm_per_rad ...
//! [drive]    # supply_v r_ohm l_h kt_nm_per_a rotor_inertia_kgm2 gear_ratio eff_drive ...
//! [sensors]  # encoder_cpt shunt_ohm amp_gain offset_v offset_error_v gain_error noise_v_rms ...
//! [faults]   # encoder_stuck_at_s encoder_jump_at_s encoder_jump_counts short_at_s ...
//! ```

use std::boxed::Box;
use std::format;
use std::string::{String, ToString};

use serde::Deserialize;

use crate::kin::{Object, Phalanx};
use crate::path::ContactSpec;
use crate::scene::{CommandMode, ObjectSpec, Scene};
use crate::scenes;

/// Why a TOML scene was rejected; the message names the key.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SceneError {
    /// The offending key (e.g. `drive.r_ohm`), or empty for a syntax error.
    pub key: String,
    /// Human-readable reason.
    pub message: String,
}

impl core::fmt::Display for SceneError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        if self.key.is_empty() {
            write!(f, "{}", self.message)
        } else {
            write!(f, "`{}`: {}", self.key, self.message)
        }
    }
}

impl std::error::Error for SceneError {}

macro_rules! section {
    ($name:ident { $($field:ident : $ty:ty),* $(,)? }) => {
        #[derive(Deserialize, Default)]
        #[serde(deny_unknown_fields)]
        struct $name { $($field: Option<$ty>),* }
    };
}

section!(FingerT {
    l1_m: f64,
    l2_m: f64,
    a_m: f64,
    b_m: f64,
    c_m: f64,
    phi2_rad: f64,
    theta01_rad: f64,
    theta02_rad: f64,
    k1_nm_per_rad: f64,
    k2_nm_per_rad: f64,
    theta1_min_rad: f64,
    theta1_max_rad: f64,
    theta2_min_rad: f64,
    theta2_max_rad: f64,
    k_lock_nm_per_rad: f64,
});
section!(ObjectT {
    kind: String,
    radius_m: f64,
    x_m: f64,
    y_m: f64,
    phalanx: i64,
    k_m: f64,
    theta1_c_rad: f64,
});
section!(DriveT {
    supply_v: f64,
    r_ohm: f64,
    l_h: f64,
    kt_nm_per_a: f64,
    rotor_inertia_kgm2: f64,
    gear_ratio: f64,
    eff_drive: f64,
    eff_back: f64,
    backlash_rad: f64,
    coulomb_nm: f64,
    stiction_nm: f64,
    viscous_nm_s_per_rad: f64,
    stick_speed_rad_s: f64,
    substeps: i64,
});
section!(SensorsT {
    encoder_cpt: i64,
    shunt_ohm: f64,
    amp_gain: f64,
    offset_v: f64,
    offset_error_v: f64,
    gain_error: f64,
    noise_v_rms: f64,
    adc_vref_v: f64,
    adc_bits: i64,
    seed: i64,
});
section!(CommandT {
    mode: String,
    from: f64,
    to: f64,
    t_start_s: f64,
    ramp_s: f64
});
section!(FaultsT {
    encoder_stuck_at_s: f64,
    encoder_jump_at_s: f64,
    encoder_jump_counts: i64,
    short_at_s: f64,
    short_r_ohm: f64,
    remove_object_at_s: f64,
    over_current_a: f64,
    power_up_offset_rad: f64,
});

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct SceneT {
    name: Option<String>,
    dt_s: Option<f64>,
    duration_s: Option<f64>,
    start_theta_a_rad: Option<f64>,
    ideal: Option<bool>,
    finger: Option<FingerT>,
    object: Option<ObjectT>,
    drive: Option<DriveT>,
    sensors: Option<SensorsT>,
    command: Option<CommandT>,
    faults: Option<FaultsT>,
}

fn err(key: &str, message: impl Into<String>) -> SceneError {
    SceneError {
        key: key.to_string(),
        message: message.into(),
    }
}

fn int<T: TryFrom<i64>>(v: Option<i64>, dflt: T, key: &str) -> Result<T, SceneError> {
    match v {
        None => Ok(dflt),
        Some(x) => T::try_from(x).map_err(|_| err(key, format!("{x} is out of range"))),
    }
}

/// Parses a scene from TOML text. Missing keys take the realistic defaults.
pub fn from_toml_str(text: &str) -> Result<Scene, SceneError> {
    let t: SceneT = toml::from_str(text).map_err(|e| parse_error(text, &e))?;
    let mut s = Scene::DEFAULT;
    if let Some(n) = t.name {
        // Built-in names map to their static string; others are leaked once (a scene is loaded
        // once per process, and `Scene` must stay `Copy` + const-constructible).
        s.name = match scenes::NAMES.iter().find(|k| **k == n) {
            Some(k) => k,
            None => Box::leak(n.into_boxed_str()),
        };
    }
    if let Some(v) = t.dt_s {
        s.dt_s = v;
    }
    if let Some(v) = t.duration_s {
        s.duration_s = v;
    }
    s.start_theta_a_rad = t.start_theta_a_rad;
    if let Some(f) = t.finger {
        apply_finger(&mut s, f);
    }
    if let Some(d) = t.drive {
        apply_drive(&mut s, d)?;
    }
    if let Some(x) = t.sensors {
        apply_sensors(&mut s, x)?;
    }
    if let Some(c) = t.command {
        apply_command(&mut s, c)?;
    }
    if let Some(f) = t.faults {
        apply_faults(&mut s, f)?;
    }
    if let Some(o) = t.object {
        s.object = object(o)?;
    }
    if t.ideal == Some(true) {
        s = s.ideal();
    }
    s.validate().map_err(|e| match e {
        crate::PlantError::Invalid(key) => err(key, "non-physical or out-of-range value"),
        other => err("object", other.to_string()),
    })?;
    Ok(s)
}

/// A TOML or schema error, with the offending key qualified by the table it sits in.
fn parse_error(text: &str, e: &toml::de::Error) -> SceneError {
    let msg = e.message().to_string();
    // serde names the unknown key in the message: "unknown field `x`, expected …".
    let field = msg
        .split('`')
        .nth(1)
        .filter(|_| msg.starts_with("unknown field"))
        .unwrap_or("");
    // Qualify it with the table it sits in (the last `[table]` header before the error).
    let table = e
        .span()
        .and_then(|sp| text.get(..sp.start))
        .and_then(|before| {
            before.lines().rev().find_map(|l| {
                let l = l.trim();
                l.strip_prefix('[')
                    .and_then(|r| r.strip_suffix(']'))
                    .map(str::trim)
            })
        });
    let key = match (field, table) {
        ("", _) => String::new(),
        (f, Some(t)) => format!("{t}.{f}"),
        (f, None) => f.to_string(),
    };
    err(&key, msg)
}

/// `[finger]`: each key given replaces the default.
fn apply_finger(s: &mut Scene, f: FingerT) {
    let g = &mut s.finger;
    macro_rules! set { ($($k:ident),*) => { $( if let Some(v) = f.$k { g.$k = v; } )* } }
    set!(
        l1_m,
        l2_m,
        a_m,
        b_m,
        c_m,
        phi2_rad,
        theta01_rad,
        theta02_rad,
        k1_nm_per_rad,
        k2_nm_per_rad,
        theta1_min_rad,
        theta1_max_rad,
        theta2_min_rad,
        theta2_max_rad,
        k_lock_nm_per_rad
    );
}

/// `[drive]`.
fn apply_drive(s: &mut Scene, d: DriveT) -> Result<(), SceneError> {
    let g = &mut s.drive;
    macro_rules! set { ($($k:ident),*) => { $( if let Some(v) = d.$k { g.$k = v; } )* } }
    set!(
        supply_v,
        r_ohm,
        l_h,
        kt_nm_per_a,
        rotor_inertia_kgm2,
        gear_ratio,
        eff_drive,
        eff_back,
        backlash_rad,
        coulomb_nm,
        stiction_nm,
        viscous_nm_s_per_rad,
        stick_speed_rad_s
    );
    g.substeps = int(d.substeps, g.substeps, "drive.substeps")?;
    Ok(())
}

/// `[sensors]`.
fn apply_sensors(s: &mut Scene, x: SensorsT) -> Result<(), SceneError> {
    let g = &mut s.sensors;
    macro_rules! set { ($($k:ident),*) => { $( if let Some(v) = x.$k { g.$k = v; } )* } }
    set!(
        shunt_ohm,
        amp_gain,
        offset_v,
        offset_error_v,
        gain_error,
        noise_v_rms,
        adc_vref_v
    );
    g.encoder_cpt = int(x.encoder_cpt, g.encoder_cpt, "sensors.encoder_cpt")?;
    g.adc_bits = int(x.adc_bits, g.adc_bits, "sensors.adc_bits")?;
    if let Some(seed) = x.seed {
        // A 64-bit pattern: TOML integers are i64, so the top bit reads as a sign.
        g.seed = seed as u64;
    }
    Ok(())
}

/// `[command]`: the open-loop command profile.
fn apply_command(s: &mut Scene, c: CommandT) -> Result<(), SceneError> {
    let g = &mut s.command;
    if let Some(m) = c.mode {
        g.mode = match m.as_str() {
            "external" => CommandMode::External,
            "duty" => CommandMode::Duty,
            "current" => CommandMode::Current,
            _ => return Err(err("command.mode", "expected external, duty or current")),
        };
    }
    macro_rules! set { ($($k:ident),*) => { $( if let Some(v) = c.$k { g.$k = v; } )* } }
    set!(from, to, t_start_s, ramp_s);
    Ok(())
}

/// `[faults]`: injected faults.
fn apply_faults(s: &mut Scene, f: FaultsT) -> Result<(), SceneError> {
    let g = &mut s.faults;
    macro_rules! set { ($($k:ident),*) => { $( if let Some(v) = f.$k { g.$k = v; } )* } }
    set!(
        encoder_stuck_at_s,
        encoder_jump_at_s,
        short_at_s,
        short_r_ohm,
        remove_object_at_s,
        over_current_a,
        power_up_offset_rad
    );
    g.encoder_jump_counts = int(
        f.encoder_jump_counts,
        g.encoder_jump_counts,
        "faults.encoder_jump_counts",
    )?;
    Ok(())
}

fn object(o: ObjectT) -> Result<ObjectSpec, SceneError> {
    let kind = o.kind.as_deref().unwrap_or("cylinder");
    let radius = match kind {
        "none" => return Ok(ObjectSpec::None),
        "vertex" => {
            if o.radius_m.is_some_and(|r| r != 0.0) {
                return Err(err("object.radius_m", "a vertex has radius 0"));
            }
            0.0
        }
        "cylinder" => match o.radius_m {
            Some(r) if r > 0.0 => r,
            _ => return Err(err("object.radius_m", "a cylinder needs radius_m > 0")),
        },
        _ => return Err(err("object.kind", "expected none, vertex or cylinder")),
    };
    match (o.x_m, o.y_m, o.phalanx, o.k_m, o.theta1_c_rad) {
        (Some(x_m), Some(y_m), None, None, None) => Ok(ObjectSpec::At(Object {
            x_m,
            y_m,
            radius_m: radius,
        })),
        (None, None, Some(ph), Some(k_c_m), Some(theta1_c_rad)) => {
            let phalanx = match ph {
                1 => Phalanx::Proximal,
                2 => Phalanx::Distal,
                _ => return Err(err("object.phalanx", "expected 1 or 2")),
            };
            Ok(ObjectSpec::Touching(ContactSpec {
                theta1_c_rad,
                phalanx,
                k_c_m,
                radius_m: radius,
            }))
        }
        _ => Err(err(
            "object",
            "give either x_m and y_m, or phalanx, k_m and theta1_c_rad",
        )),
    }
}

/// Reads and parses a scene file.
pub fn from_toml_file(path: &std::path::Path) -> Result<Scene, SceneError> {
    let text =
        std::fs::read_to_string(path).map_err(|e| err("", format!("{}: {e}", path.display())))?;
    from_toml_str(&text)
}

/// Renders a scene as TOML that [`from_toml_str`] reads back to the same scene.
pub fn to_toml_string(s: &Scene) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let f = &s.finger;
    let d = &s.drive;
    let x = &s.sensors;
    let c = &s.command;
    let fl = &s.faults;
    let _ = writeln!(
        o,
        "name = \"{}\"\ndt_s = {:?}\nduration_s = {:?}",
        s.name, s.dt_s, s.duration_s
    );
    if let Some(v) = s.start_theta_a_rad {
        let _ = writeln!(o, "start_theta_a_rad = {v:?}");
    }
    o.push('\n');
    match s.object {
        ObjectSpec::None => {
            let _ = writeln!(o, "[object]\nkind = \"none\"\n");
        }
        ObjectSpec::At(ob) => {
            let kind = if ob.radius_m > 0.0 {
                "cylinder"
            } else {
                "vertex"
            };
            let _ = writeln!(
                o,
                "[object]\nkind = \"{kind}\"\nradius_m = {:?}\nx_m = {:?}\ny_m = {:?}\n",
                ob.radius_m, ob.x_m, ob.y_m
            );
        }
        ObjectSpec::Touching(sp) => {
            let kind = if sp.radius_m > 0.0 {
                "cylinder"
            } else {
                "vertex"
            };
            let _ = writeln!(
                o,
                "[object]\nkind = \"{kind}\"\nradius_m = {:?}\nphalanx = {}\nk_m = {:?}\ntheta1_c_rad = {:?}\n",
                sp.radius_m,
                sp.phalanx.index(),
                sp.k_c_m,
                sp.theta1_c_rad
            );
        }
    }
    let mode = match c.mode {
        CommandMode::External => "external",
        CommandMode::Duty => "duty",
        CommandMode::Current => "current",
    };
    let _ = writeln!(
        o,
        "[command]\nmode = \"{mode}\"\nfrom = {:?}\nto = {:?}\nt_start_s = {:?}\nramp_s = {:?}\n",
        c.from, c.to, c.t_start_s, c.ramp_s
    );
    let _ = writeln!(
        o,
        "[finger]\nl1_m = {:?}\nl2_m = {:?}\na_m = {:?}\nb_m = {:?}\nc_m = {:?}\nphi2_rad = {:?}\ntheta01_rad = {:?}\ntheta02_rad = {:?}\nk1_nm_per_rad = {:?}\nk2_nm_per_rad = {:?}\ntheta1_min_rad = {:?}\ntheta1_max_rad = {:?}\ntheta2_min_rad = {:?}\ntheta2_max_rad = {:?}\nk_lock_nm_per_rad = {:?}\n",
        f.l1_m, f.l2_m, f.a_m, f.b_m, f.c_m, f.phi2_rad, f.theta01_rad, f.theta02_rad, f.k1_nm_per_rad,
        f.k2_nm_per_rad, f.theta1_min_rad, f.theta1_max_rad, f.theta2_min_rad, f.theta2_max_rad,
        f.k_lock_nm_per_rad
    );
    let _ = writeln!(
        o,
        "[drive]\nsupply_v = {:?}\nr_ohm = {:?}\nl_h = {:?}\nkt_nm_per_a = {:?}\nrotor_inertia_kgm2 = {:?}\ngear_ratio = {:?}\neff_drive = {:?}\neff_back = {:?}\nbacklash_rad = {:?}\ncoulomb_nm = {:?}\nstiction_nm = {:?}\nviscous_nm_s_per_rad = {:?}\nstick_speed_rad_s = {:?}\nsubsteps = {}\n",
        d.supply_v, d.r_ohm, d.l_h, d.kt_nm_per_a, d.rotor_inertia_kgm2, d.gear_ratio, d.eff_drive,
        d.eff_back, d.backlash_rad, d.coulomb_nm, d.stiction_nm, d.viscous_nm_s_per_rad,
        d.stick_speed_rad_s, d.substeps
    );
    let _ = writeln!(
        o,
        "[sensors]\nencoder_cpt = {}\nshunt_ohm = {:?}\namp_gain = {:?}\noffset_v = {:?}\noffset_error_v = {:?}\ngain_error = {:?}\nnoise_v_rms = {:?}\nadc_vref_v = {:?}\nadc_bits = {}\nseed = {}\n",
        x.encoder_cpt, x.shunt_ohm, x.amp_gain, x.offset_v, x.offset_error_v, x.gain_error,
        x.noise_v_rms, x.adc_vref_v, x.adc_bits, x.seed as i64
    );
    let t = |v: f64| {
        if v.is_finite() {
            format!("{v:?}")
        } else {
            "inf".to_string()
        }
    };
    let _ = writeln!(
        o,
        "[faults]\nencoder_stuck_at_s = {}\nencoder_jump_at_s = {}\nencoder_jump_counts = {}\nshort_at_s = {}\nshort_r_ohm = {:?}\nremove_object_at_s = {}\nover_current_a = {:?}\npower_up_offset_rad = {:?}",
        t(fl.encoder_stuck_at_s), t(fl.encoder_jump_at_s), fl.encoder_jump_counts, t(fl.short_at_s),
        fl.short_r_ohm, t(fl.remove_object_at_s), fl.over_current_a, fl.power_up_offset_rad
    );
    o
}

fn rust_f64(v: f64) -> String {
    if v.is_nan() {
        "f64::NAN".to_string()
    } else if v == f64::INFINITY {
        "f64::INFINITY".to_string()
    } else if v == f64::NEG_INFINITY {
        "f64::NEG_INFINITY".to_string()
    } else {
        // `{:?}` always prints a decimal point or exponent: a valid f64 literal.
        format!("{v:?}")
    }
}

/// A Rust constant expression of type `plant::Scene` equal to `s`, with full paths, for build
/// scripts that turn a TOML scene into `const` data for the firmware (no parsing on target).
/// (`{:?}` of a scene is not valid Rust: infinite fault times print as `inf`.)
pub fn to_rust_expr(s: &Scene) -> String {
    let f = &s.finger;
    let d = &s.drive;
    let x = &s.sensors;
    let c = &s.command;
    let fl = &s.faults;
    let r = rust_f64;
    let object = match s.object {
        ObjectSpec::None => "plant::scene::ObjectSpec::None".to_string(),
        ObjectSpec::At(o) => format!(
            "plant::scene::ObjectSpec::At(plant::Object {{ x_m: {}, y_m: {}, radius_m: {} }})",
            r(o.x_m),
            r(o.y_m),
            r(o.radius_m)
        ),
        ObjectSpec::Touching(sp) => format!(
            "plant::scene::ObjectSpec::Touching(plant::ContactSpec {{ theta1_c_rad: {}, phalanx: plant::Phalanx::{:?}, k_c_m: {}, radius_m: {} }})",
            r(sp.theta1_c_rad),
            sp.phalanx,
            r(sp.k_c_m),
            r(sp.radius_m)
        ),
    };
    let start = match s.start_theta_a_rad {
        None => "None".to_string(),
        Some(v) => format!("Some({})", r(v)),
    };
    format!(
        "plant::Scene {{ name: {:?}, \
         finger: plant::FingerGeom {{ l1_m: {}, l2_m: {}, a_m: {}, b_m: {}, c_m: {}, phi2_rad: {}, theta01_rad: {}, theta02_rad: {}, k1_nm_per_rad: {}, k2_nm_per_rad: {}, theta1_min_rad: {}, theta1_max_rad: {}, theta2_min_rad: {}, theta2_max_rad: {}, k_lock_nm_per_rad: {} }}, \
         object: {object}, \
         drive: plant::drive::DriveParams {{ supply_v: {}, r_ohm: {}, l_h: {}, kt_nm_per_a: {}, rotor_inertia_kgm2: {}, gear_ratio: {}, eff_drive: {}, eff_back: {}, backlash_rad: {}, coulomb_nm: {}, stiction_nm: {}, viscous_nm_s_per_rad: {}, stick_speed_rad_s: {}, substeps: {} }}, \
         sensors: plant::sensors::SensorParams {{ encoder_cpt: {}, shunt_ohm: {}, amp_gain: {}, offset_v: {}, offset_error_v: {}, gain_error: {}, noise_v_rms: {}, adc_vref_v: {}, adc_bits: {}, seed: {} }}, \
         command: plant::scene::CommandProfile {{ mode: plant::scene::CommandMode::{:?}, from: {}, to: {}, t_start_s: {}, ramp_s: {} }}, \
         faults: plant::scene::FaultSpec {{ encoder_stuck_at_s: {}, encoder_jump_at_s: {}, encoder_jump_counts: {}, short_at_s: {}, short_r_ohm: {}, remove_object_at_s: {}, over_current_a: {}, power_up_offset_rad: {} }}, \
         dt_s: {}, duration_s: {}, start_theta_a_rad: {start} }}",
        s.name,
        r(f.l1_m), r(f.l2_m), r(f.a_m), r(f.b_m), r(f.c_m), r(f.phi2_rad), r(f.theta01_rad),
        r(f.theta02_rad), r(f.k1_nm_per_rad), r(f.k2_nm_per_rad), r(f.theta1_min_rad),
        r(f.theta1_max_rad), r(f.theta2_min_rad), r(f.theta2_max_rad), r(f.k_lock_nm_per_rad),
        r(d.supply_v), r(d.r_ohm), r(d.l_h), r(d.kt_nm_per_a), r(d.rotor_inertia_kgm2),
        r(d.gear_ratio), r(d.eff_drive), r(d.eff_back), r(d.backlash_rad), r(d.coulomb_nm),
        r(d.stiction_nm), r(d.viscous_nm_s_per_rad), r(d.stick_speed_rad_s), d.substeps,
        x.encoder_cpt, r(x.shunt_ohm), r(x.amp_gain), r(x.offset_v), r(x.offset_error_v),
        r(x.gain_error), r(x.noise_v_rms), r(x.adc_vref_v), x.adc_bits, x.seed,
        c.mode, r(c.from), r(c.to), r(c.t_start_s), r(c.ramp_s),
        r(fl.encoder_stuck_at_s), r(fl.encoder_jump_at_s), fl.encoder_jump_counts,
        r(fl.short_at_s), r(fl.short_r_ohm), r(fl.remove_object_at_s), r(fl.over_current_a), r(fl.power_up_offset_rad),
        r(s.dt_s), r(s.duration_s)
    )
}
