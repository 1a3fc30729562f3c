//! The drive: Maxon RE10 DC motor, GP10A-class planetary gearhead, a pulley + cable stage to the
//! base link, transmission friction (Coulomb with stiction, viscous), backlash and rotor inertia.
//!
//! Every default with its source or reasoning (see also the crate README section):
//!
//! | constant | default | source / reasoning |
//! |---|---|---|
//! | supply | 6 V | the RE10 winding chosen is the 6 V one; the bridge runs from its nominal voltage (choice) |
//! | R | 20 Ω | RE 10 (1.5 W class) 6 V winding, recalled catalogue order of magnitude: **guess ±30 %** |
//! | L | 0.10 mH | same family, ironless winding, L/R ≈ 5 µs: **guess** |
//! | kt = ke | 4.5 mN·m/A | 6 V winding, ≈ 12 000 rpm no-load at 6 V ⇒ ke ≈ 6/1260 V·s/rad: **guess ±20 %** |
//! | J rotor | 7.0e-9 kg·m² (0.07 g·cm²) | RE 10 rotor inertia order of magnitude; τm = RJ/kt² ≈ 7 ms: **guess** |
//! | gearhead | 256:1, 4 stages | GP 10 A catalogue ratio (4ⁿ series); chosen with the cable stage to reach ~1.5 N·m |
//! | cable stage | 12:1 | the paper's prototype adds pulleys + cable after the gearhead; ratio is a **choice** so that stall at 6 V gives ≈ 2.5 N·m at the base link |
//! | N total | 3072 | 256 × 12 |
//! | η driving | 0.6175 | GP 10 A 4-stage ≈ 0.65 (≈ 0.9 per stage, catalogue style) × cable 0.95 (**guess**) |
//! | η driven | 0.585 | per stage (2η_s − 1)/η_s with η_s = 0.65^¼ (gear loss factor reflected on reversal) × 0.95 |
//! | backlash | 3.0e-3 rad at the base link | GP 10 A no-load backlash ≈ 2° at its output ÷ 12, plus cable slack: **guess** |
//! | Coulomb | 40 µN·m at the motor | motor no-load current ≈ 9 mA × kt plus gearhead no-load losses: **guess** |
//! | stiction | 60 µN·m at the motor | 1.5 × Coulomb, a common ratio for small gearmotors: **guess** |
//! | viscous | 2.0e-9 N·m·s/rad at the motor | no-load current rising a few mA over the speed range: **guess** |
//!
//! With these, the stall torque at 6 V is N·η·kt·V/R ≈ 2.56 N·m and 1.5 N·m needs ≈ 0.18 A.

/// Parameters of the drive. All motor-side quantities are at the motor shaft.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriveParams {
    /// H-bridge supply (V); duty ±1 applies ±supply.
    pub supply_v: f64,
    /// Terminal resistance (Ω).
    pub r_ohm: f64,
    /// Terminal inductance (H).
    pub l_h: f64,
    /// Torque constant = back-EMF constant (N·m/A = V·s/rad).
    pub kt_nm_per_a: f64,
    /// Rotor (+ first gear stage) inertia (kg·m²).
    pub rotor_inertia_kgm2: f64,
    /// Total reduction motor → base link (motor rad per base-link rad).
    pub gear_ratio: f64,
    /// Efficiency when the motor drives the finger (0, 1].
    pub eff_drive: f64,
    /// Efficiency when the finger back-drives the motor (0, 1].
    pub eff_back: f64,
    /// Total backlash at the base link (rad), a dead band of this width.
    pub backlash_rad: f64,
    /// Coulomb friction at the motor shaft (N·m).
    pub coulomb_nm: f64,
    /// Breakaway (stiction) torque at the motor shaft (N·m), ≥ Coulomb.
    pub stiction_nm: f64,
    /// Viscous friction at the motor shaft (N·m·s/rad).
    pub viscous_nm_s_per_rad: f64,
    /// Speed below which the shaft counts as stopped for stiction (rad/s at the motor).
    pub stick_speed_rad_s: f64,
    /// Integration substeps per control period (electrical: implicit Euler; mechanics: semi-implicit).
    pub substeps: u16,
}

impl DriveParams {
    /// Realistic defaults: RE10 6 V + GP10A 256:1 + 12:1 cable stage (see the module table).
    pub const RE10_GP10A: DriveParams = DriveParams {
        supply_v: 6.0,
        r_ohm: 20.0,
        l_h: 0.10e-3,
        kt_nm_per_a: 4.5e-3,
        rotor_inertia_kgm2: 7.0e-9,
        gear_ratio: 3072.0,
        eff_drive: 0.6175,
        eff_back: 0.585,
        backlash_rad: 3.0e-3,
        coulomb_nm: 40e-6,
        stiction_nm: 60e-6,
        viscous_nm_s_per_rad: 2.0e-9,
        stick_speed_rad_s: 0.2,
        substeps: 4,
    };

    /// The same drive with friction, backlash and gear losses switched off (η = 1).
    pub const fn ideal(self) -> DriveParams {
        DriveParams {
            eff_drive: 1.0,
            eff_back: 1.0,
            backlash_rad: 0.0,
            coulomb_nm: 0.0,
            stiction_nm: 0.0,
            viscous_nm_s_per_rad: 0.0,
            ..self
        }
    }

    /// Checks the values; the error names the key.
    pub fn validate(&self) -> Result<(), crate::PlantError> {
        use crate::PlantError::Invalid;
        let pos = |v: f64, lo_excl: f64, hi: f64, key: &'static str| {
            if v.is_finite() && v > lo_excl && v <= hi {
                Ok(())
            } else {
                Err(Invalid(key))
            }
        };
        let nonneg = |v: f64, hi: f64, key: &'static str| {
            if v.is_finite() && (0.0..=hi).contains(&v) {
                Ok(())
            } else {
                Err(Invalid(key))
            }
        };
        pos(self.supply_v, 0.0, 100.0, "drive.supply_v")?;
        pos(self.r_ohm, 0.0, 1e4, "drive.r_ohm")?;
        pos(self.l_h, 0.0, 1.0, "drive.l_h")?;
        pos(self.kt_nm_per_a, 0.0, 10.0, "drive.kt_nm_per_a")?;
        pos(
            self.rotor_inertia_kgm2,
            0.0,
            1.0,
            "drive.rotor_inertia_kgm2",
        )?;
        pos(self.gear_ratio, 0.0, 1e6, "drive.gear_ratio")?;
        pos(self.eff_drive, 0.0, 1.0, "drive.eff_drive")?;
        pos(self.eff_back, 0.0, 1.0, "drive.eff_back")?;
        nonneg(self.backlash_rad, 0.5, "drive.backlash_rad")?;
        nonneg(self.coulomb_nm, 1.0, "drive.coulomb_nm")?;
        nonneg(self.stiction_nm, 1.0, "drive.stiction_nm")?;
        if self.stiction_nm < self.coulomb_nm {
            return Err(Invalid("drive.stiction_nm"));
        }
        nonneg(self.viscous_nm_s_per_rad, 1.0, "drive.viscous_nm_s_per_rad")?;
        nonneg(self.stick_speed_rad_s, 1e3, "drive.stick_speed_rad_s")?;
        if self.substeps == 0 || self.substeps > 1000 {
            return Err(Invalid("drive.substeps"));
        }
        Ok(())
    }

    /// Output torque at the base link for motor current `i_a` at stall when driving (N·m):
    /// N·η·kt·i (friction not included).
    pub fn stall_torque_nm(&self, i_a: f64) -> f64 {
        self.gear_ratio * self.eff_drive * self.kt_nm_per_a * i_a
    }
}

/// How the motor is driven during one control period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Input {
    /// PWM duty in [−1, 1] (averaged bridge voltage = duty × supply).
    Duty(f64),
    /// Ideal current source (A): the electrical dynamics are bypassed.
    Current(f64),
    /// Ideal motor torque source at the motor shaft (N·m), i = τ/kt.
    MotorTorque(f64),
    /// Bridge off: all switches open; the winding current decays through the body diodes
    /// into the supply (modelled as the current driven to zero within the substep).
    Off,
}

/// Dynamic state of the drive.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct DriveState {
    /// Winding current (A).
    pub current_a: f64,
    /// Motor speed (rad/s).
    pub speed_rad_s: f64,
    /// Motor angle from its start (rad).
    pub angle_rad: f64,
    /// Shaft held by stiction.
    pub stuck: bool,
    /// Terminal voltage of the last substep (V).
    pub voltage_v: f64,
}

/// The load the finger puts on the gear output during one control period, linearised about
/// the pose solved at the start of the period: T(θa) = t0 + k (θa − θa0), zero in the dead band.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Load {
    /// θa at which the finger exerts no torque (the rest pose, rad).
    pub theta_a_zero_rad: f64,
    /// θa at the start of the period (rad).
    pub theta_a0_rad: f64,
    /// T_a there (N·m).
    pub t0_nm: f64,
    /// dT_a/dθa (N·m/rad), ≥ 0.
    pub k_nm_per_rad: f64,
}

impl DriveParams {
    /// Finger θa for a gear-output angle θg (rad): the massless finger sits where its torque is
    /// zero unless a flank of the backlash pushes it.
    pub fn finger_angle(&self, gear_out_rad: f64, theta_a_zero_rad: f64) -> f64 {
        let h = 0.5 * self.backlash_rad;
        theta_a_zero_rad.clamp(gear_out_rad - h, gear_out_rad + h)
    }

    /// Advances the drive by `dt_s` (s) with `input`. `gear_zero_rad` is the gear output angle
    /// at motor angle 0 (rad, absolute model angle). `r_ohm` may differ from the parameter
    /// (fault injection). Never panics; non-finite inputs are treated as zero.
    pub fn advance(
        &self,
        st: &mut DriveState,
        input: Input,
        load: &Load,
        gear_zero_rad: f64,
        r_ohm: f64,
        dt_s: f64,
    ) {
        let n = self.substeps.max(1);
        let h = dt_s / f64::from(n);
        let kt = self.kt_nm_per_a;
        // Per-period constants (soft-float division is expensive on the target).
        let h_over_l = h / self.l_h;
        let inv_el = 1.0 / (1.0 + h * r_ohm / self.l_h);
        let h_over_j = h / self.rotor_inertia_kgm2;
        let inv_visc = 1.0 / (1.0 + h * self.viscous_nm_s_per_rad / self.rotor_inertia_kgm2);
        let inv_n = 1.0 / self.gear_ratio;
        let fwd_gain = inv_n / self.eff_drive;
        let back_gain = self.eff_back * inv_n;
        let duty_v = match input {
            Input::Duty(d) if d.is_finite() => d.clamp(-1.0, 1.0) * self.supply_v,
            _ => 0.0,
        };
        let forced_i = match input {
            Input::Current(i) if i.is_finite() => i.clamp(-100.0, 100.0),
            Input::MotorTorque(t) if t.is_finite() => (t / kt).clamp(-100.0, 100.0),
            _ => 0.0,
        };
        for _ in 0..n {
            // Electrical.
            match input {
                Input::Duty(_) => {
                    let emf = kt * st.speed_rad_s;
                    // Implicit Euler on L di/dt = v − R i − emf (stable for any h).
                    st.current_a = (st.current_a + h_over_l * (duty_v - emf)) * inv_el;
                    st.voltage_v = duty_v;
                }
                Input::Current(_) | Input::MotorTorque(_) => {
                    st.current_a = forced_i;
                    st.voltage_v = r_ohm * st.current_a + kt * st.speed_rad_s;
                }
                Input::Off => {
                    // Diodes clamp the winding to ±supply against the current: fast decay.
                    let v = -self.supply_v * sign(st.current_a);
                    let emf = kt * st.speed_rad_s;
                    let next = (st.current_a + h_over_l * (v - emf)) * inv_el;
                    st.current_a = if next * st.current_a <= 0.0 {
                        0.0
                    } else {
                        next
                    };
                    st.voltage_v = v;
                }
            }
            // Mechanical.
            let gear = gear_zero_rad + st.angle_rad * inv_n;
            let theta_a = self.finger_angle(gear, load.theta_a_zero_rad);
            let engaged = theta_a != load.theta_a_zero_rad || self.backlash_rad == 0.0;
            let t_out = if engaged {
                load.t0_nm + load.k_nm_per_rad * (theta_a - load.theta_a0_rad)
            } else {
                0.0
            };
            let t_out = if t_out.is_finite() { t_out } else { 0.0 };
            let tm = kt * st.current_a;
            // Reflected load: driving (power to the finger) vs back-driven.
            let refl_fwd = t_out * fwd_gain;
            let refl_back = t_out * back_gain;
            let w = st.speed_rad_s;
            if st.stuck || w.abs() < self.stick_speed_rad_s {
                // Karnopp band: the shaft is (nearly) stopped. Impending motion in + must beat the
                // load (reflected as driving if t_out ≥ 0, else as back-driving) plus stiction.
                let load_pos = if t_out >= 0.0 { refl_fwd } else { refl_back };
                let load_neg = if t_out >= 0.0 { refl_back } else { refl_fwd };
                if tm - load_pos - self.stiction_nm > 0.0 {
                    st.stuck = false;
                    st.speed_rad_s = w.max(0.0) + h_over_j * (tm - load_pos - self.coulomb_nm);
                } else if tm - load_neg + self.stiction_nm < 0.0 {
                    st.stuck = false;
                    st.speed_rad_s = w.min(0.0) + h_over_j * (tm - load_neg + self.coulomb_nm);
                } else {
                    st.stuck = true;
                    st.speed_rad_s = 0.0;
                }
            } else {
                let refl = if t_out * w >= 0.0 {
                    refl_fwd
                } else {
                    refl_back
                };
                let fric = self.coulomb_nm * sign(w);
                // Viscous term implicit.
                let w_new = (w + h_over_j * (tm - refl - fric)) * inv_visc;
                if w_new * w < 0.0 {
                    // Reversal inside the substep: stop; the band logic decides the next substep.
                    st.speed_rad_s = 0.0;
                } else {
                    st.speed_rad_s = w_new;
                }
            }
            st.speed_rad_s = st.speed_rad_s.clamp(-1e5, 1e5);
            st.angle_rad += h * st.speed_rad_s;
            if !st.angle_rad.is_finite() {
                st.angle_rad = 0.0;
            }
            if !st.current_a.is_finite() {
                st.current_a = 0.0;
            }
        }
    }
}

fn sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}
