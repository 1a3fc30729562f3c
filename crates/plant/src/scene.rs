//! A scene: finger, object, drive, sensors, command profile and faults — plain `const` data.

use crate::drive::DriveParams;
use crate::geom::FingerGeom;
use crate::kin::Object;
use crate::path::ContactSpec;
use crate::sensors::SensorParams;
use crate::PlantError;

/// Where the object is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ObjectSpec {
    /// No object (free motion only).
    None,
    /// Fixed position in the world frame at O1.
    At(Object),
    /// Placed so that the free-moving finger first touches it at this contact (tangent on the
    /// phalanx's left normal at θ1,c).
    Touching(ContactSpec),
}

/// What drives the plant when the scene runs open-loop (`Plant::step_scene`); a closed-loop
/// controller ignores it and calls `Plant::step` itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CommandMode {
    /// The caller drives the plant; `step_scene` applies duty 0.
    External,
    /// PWM duty in [−1, 1].
    Duty,
    /// Motor current (A), ideal current source.
    Current,
}

/// A linear ramp from `from` to `to` over `[t_start_s, t_start_s + ramp_s]`, held after.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CommandProfile {
    /// What the value means.
    pub mode: CommandMode,
    /// Value before and at `t_start_s` (duty or A).
    pub from: f64,
    /// Value after the ramp (duty or A).
    pub to: f64,
    /// Ramp start (s).
    pub t_start_s: f64,
    /// Ramp duration (s); 0 is a step.
    pub ramp_s: f64,
}

impl CommandProfile {
    /// Externally driven.
    pub const EXTERNAL: CommandProfile = CommandProfile {
        mode: CommandMode::External,
        from: 0.0,
        to: 0.0,
        t_start_s: 0.0,
        ramp_s: 0.0,
    };

    /// The commanded value at time `t_s`.
    pub fn value_at(&self, t_s: f64) -> f64 {
        if t_s <= self.t_start_s {
            self.from
        } else if self.ramp_s <= 0.0 || t_s >= self.t_start_s + self.ramp_s {
            self.to
        } else {
            self.from + (self.to - self.from) * (t_s - self.t_start_s) / self.ramp_s
        }
    }
}

/// Scheduled faults (times in s; `f64::INFINITY` = never).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaultSpec {
    /// From this time the encoder output freezes (s).
    pub encoder_stuck_at_s: f64,
    /// At this time the encoder count jumps by `encoder_jump_counts` (s).
    pub encoder_jump_at_s: f64,
    /// Size of the jump (counts, ×4 units).
    pub encoder_jump_counts: i32,
    /// From this time the winding is partly shorted: its resistance becomes `short_r_ohm` (s).
    pub short_at_s: f64,
    /// Winding resistance once shorted (Ω).
    pub short_r_ohm: f64,
    /// At this time the object is removed (loss of contact) (s).
    pub remove_object_at_s: f64,
    /// |current| above this raises an `OverCurrent` event (A).
    pub over_current_a: f64,
    /// The finger powered up this far from its rest pose (θa, rad, flexion positive; 0 = at
    /// rest): it starts there held by the gear's friction with no current, and the encoder
    /// reads 0 there, where a firmware that zeroes at power-up puts θa,rest.
    pub power_up_offset_rad: f64,
}

impl FaultSpec {
    /// No faults; over-current flagged above 0.28 A (≈ 6 V / 20 Ω stall current × 0.93).
    pub const NONE: FaultSpec = FaultSpec {
        encoder_stuck_at_s: f64::INFINITY,
        encoder_jump_at_s: f64::INFINITY,
        encoder_jump_counts: 0,
        short_at_s: f64::INFINITY,
        short_r_ohm: 2.0,
        remove_object_at_s: f64::INFINITY,
        over_current_a: 0.28,
        power_up_offset_rad: 0.0,
    };
}

/// A complete simulation scene. Plain data, `const`-constructible.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scene {
    /// Name (for by-name lookup and traces).
    pub name: &'static str,
    /// Finger geometry, springs and stops.
    pub finger: FingerGeom,
    /// The object.
    pub object: ObjectSpec,
    /// Motor, gearhead, friction.
    pub drive: DriveParams,
    /// Encoder and current sensor.
    pub sensors: SensorParams,
    /// Open-loop command (`Plant::step_scene`); closed-loop runners drive the plant with the
    /// controller and do not read it.
    pub command: CommandProfile,
    /// Scheduled faults.
    pub faults: FaultSpec,
    /// Control period (s); `Plant::step` advances by this.
    pub dt_s: f64,
    /// Run length of an open-loop run (s); closed-loop runners have their own limit.
    pub duration_s: f64,
    /// Start the finger in free motion at this θa (rad) instead of at rest — an approach
    /// shortcut for slow (QEMU, soft-float) runs. The encoder still counts from the rest pose
    /// (as if the motor had driven there), the gear sits on its flexion flank and the winding
    /// carries the current that holds the finger, T_a/(N·η·kt). `None`: start at rest.
    pub start_theta_a_rad: Option<f64>,
}

impl Scene {
    /// Defaults: paper finger, no object, realistic drive and sensors, 10 kHz, 2 s.
    pub const DEFAULT: Scene = Scene {
        name: "default",
        finger: FingerGeom::PAPER,
        object: ObjectSpec::None,
        drive: DriveParams::RE10_GP10A,
        sensors: SensorParams::DEFAULT,
        command: CommandProfile::EXTERNAL,
        faults: FaultSpec::NONE,
        dt_s: 100e-6,
        duration_s: 2.0,
        start_theta_a_rad: None,
    };

    /// This scene with friction, backlash, gear losses and sensor errors/noise switched off.
    pub const fn ideal(self) -> Scene {
        Scene {
            drive: self.drive.ideal(),
            sensors: self.sensors.ideal(),
            ..self
        }
    }

    /// Checks every value; the error names the offending key.
    pub fn validate(&self) -> Result<(), PlantError> {
        self.finger.validate()?;
        self.drive.validate()?;
        self.sensors.validate()?;
        if !(self.dt_s.is_finite() && self.dt_s >= 1e-6 && self.dt_s <= 0.1) {
            return Err(PlantError::Invalid("dt_s"));
        }
        if !(self.duration_s.is_finite() && self.duration_s >= 0.0 && self.duration_s <= 1e5) {
            return Err(PlantError::Invalid("duration_s"));
        }
        if let Some(t) = self.start_theta_a_rad {
            if !(t.is_finite() && t.abs() <= core::f64::consts::TAU) {
                return Err(PlantError::Invalid("start_theta_a_rad"));
            }
        }
        let c = &self.command;
        let lim = match c.mode {
            CommandMode::Duty => 1.0,
            CommandMode::Current => 10.0,
            CommandMode::External => f64::INFINITY,
        };
        if !(c.from.is_finite() && c.from.abs() <= lim) {
            return Err(PlantError::Invalid("command.from"));
        }
        if !(c.to.is_finite() && c.to.abs() <= lim) {
            return Err(PlantError::Invalid("command.to"));
        }
        if !(c.t_start_s.is_finite() && c.t_start_s >= 0.0) {
            return Err(PlantError::Invalid("command.t_start_s"));
        }
        if !(c.ramp_s.is_finite() && c.ramp_s >= 0.0) {
            return Err(PlantError::Invalid("command.ramp_s"));
        }
        let f = &self.faults;
        for (v, key) in [
            (f.encoder_stuck_at_s, "faults.encoder_stuck_at_s"),
            (f.encoder_jump_at_s, "faults.encoder_jump_at_s"),
            (f.short_at_s, "faults.short_at_s"),
            (f.remove_object_at_s, "faults.remove_object_at_s"),
        ] {
            if v.is_nan() || v < 0.0 {
                return Err(PlantError::Invalid(key));
            }
        }
        if !(f.short_r_ohm.is_finite() && f.short_r_ohm > 0.0) {
            return Err(PlantError::Invalid("faults.short_r_ohm"));
        }
        if !(f.over_current_a.is_finite() && f.over_current_a > 0.0) {
            return Err(PlantError::Invalid("faults.over_current_a"));
        }
        if !(f.power_up_offset_rad.is_finite() && f.power_up_offset_rad.abs() <= 1.0) {
            return Err(PlantError::Invalid("faults.power_up_offset_rad"));
        }
        if f.power_up_offset_rad != 0.0 && self.start_theta_a_rad.is_some() {
            // Two different starting poses: refuse rather than pick one.
            return Err(PlantError::Invalid("faults.power_up_offset_rad"));
        }
        match self.object {
            ObjectSpec::None => {}
            ObjectSpec::At(o) => {
                if !(o.x_m.is_finite() && o.x_m.abs() <= 10.0) {
                    return Err(PlantError::Invalid("object.x_m"));
                }
                if !(o.y_m.is_finite() && o.y_m.abs() <= 10.0) {
                    return Err(PlantError::Invalid("object.y_m"));
                }
                if !(o.radius_m.is_finite() && (0.0..=1.0).contains(&o.radius_m)) {
                    return Err(PlantError::Invalid("object.radius_m"));
                }
            }
            ObjectSpec::Touching(spec) => {
                crate::path::place_object(&self.finger, &spec)?;
            }
        }
        Ok(())
    }

    /// The object in world coordinates (resolving a `Touching` placement).
    pub fn resolve_object(&self) -> Result<Option<Object>, PlantError> {
        match self.object {
            ObjectSpec::None => Ok(None),
            ObjectSpec::At(o) => Ok(Some(o)),
            ObjectSpec::Touching(spec) => {
                Ok(Some(crate::path::place_object(&self.finger, &spec)?.0))
            }
        }
    }
}
