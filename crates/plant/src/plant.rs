//! The plant stepped at the control rate: drive dynamics + quasi-static finger + sensors.

use crate::drive::{DriveState, Input, Load};
use crate::kin::{Active, Constraint, Kin, Phalanx};
use crate::scene::{CommandMode, Scene};
use crate::sensors::Rng;
use crate::track::{ev, Event, EventKind, Tracker};
use crate::PlantError;

/// Contact state of the finger, as the truth reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ContactState {
    /// Free motion.
    Free,
    /// The object touches the proximal phalanx.
    Proximal,
    /// The object touches the distal phalanx.
    Distal,
    /// A joint is on a mechanical stop (no contact).
    Limit,
    /// Two constraints hold the finger (second contact, contact + stop, two stops).
    Locked,
}

impl ContactState {
    /// Lower-case name (CSV).
    pub const fn name(self) -> &'static str {
        match self {
            ContactState::Free => "free",
            ContactState::Proximal => "proximal",
            ContactState::Distal => "distal",
            ContactState::Limit => "limit",
            ContactState::Locked => "locked",
        }
    }
    /// Small integer code (CSV/defmt): 0 free, 1 proximal, 2 distal, 3 limit, 4 locked.
    pub const fn code(self) -> u8 {
        match self {
            ContactState::Free => 0,
            ContactState::Proximal => 1,
            ContactState::Distal => 2,
            ContactState::Limit => 3,
            ContactState::Locked => 4,
        }
    }
}

/// The true state of the plant (what the sensors try to measure).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Truth {
    /// Simulated time (s).
    pub t_s: f64,
    /// Actuator angle θa (rad, absolute model angle).
    pub theta_a_rad: f64,
    /// Torque the finger exerts back on the base link, T_a (N·m).
    pub torque_a_nm: f64,
    /// θ1 (rad).
    pub theta1_rad: f64,
    /// θ2 (rad).
    pub theta2_rad: f64,
    /// Contact state.
    pub contact: ContactState,
    /// Contact location from the touched phalanx's lower joint (m); 0 when not in contact.
    pub k_m: f64,
    /// Contact force (N) or stop torque (N·m) of the active constraint; 0 when free.
    pub force: f64,
    /// Winding current (A).
    pub current_a: f64,
    /// Motor speed (rad/s).
    pub motor_speed_rad_s: f64,
    /// Motor angle since start (rad).
    pub motor_angle_rad: f64,
    /// Gear output angle (rad, absolute model angle; differs from θa inside the backlash).
    pub gear_out_rad: f64,
    /// Applied terminal voltage (V).
    pub voltage_v: f64,
}

/// Runtime fault injection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Fault {
    /// The encoder output freezes at its current value.
    EncoderStuck,
    /// The encoder count jumps by this many counts.
    EncoderJump(i32),
    /// The winding resistance drops to this value (Ω): shorted turns / wiring short.
    Short(f64),
    /// The object disappears (loss of contact).
    RemoveObject,
    /// Clears the encoder-stuck and short faults.
    Clear,
}

const EVENT_CAP: usize = 16;

/// The simulated finger.
#[derive(Clone, Debug)]
pub struct Plant {
    scene: Scene,
    tracker: Tracker,
    drive: DriveState,
    theta_a_rest_rad: f64,
    k_loc: f64,
    t_s: f64,
    steps: u64,
    rng: Rng,
    enc_offset: i64,
    enc_stuck: Option<u16>,
    r_ohm: f64,
    adc: u16,
    over_current: bool,
    failed: bool,
    jump_done: bool,
    removed: bool,
    events: [Option<Event>; EVENT_CAP],
    ev_head: usize,
    ev_len: usize,
    dropped: u32,
}

impl Plant {
    /// Builds the plant at the rest pose (encoder zero there, motor at rest, no current), or
    /// where the scene starts it (`start_theta_a_rad`, `faults.power_up_offset_rad`).
    pub fn new(scene: &Scene) -> Result<Plant, PlantError> {
        scene.validate()?;
        let object = scene.resolve_object()?;
        let kin = Kin::new(scene.finger, object);
        let mut tracker = Tracker::new(kin)?;
        let rest = tracker.pose.theta_a_rad;
        let mut drive = DriveState::default();
        let power_up = scene.faults.power_up_offset_rad;
        let start_at = match scene.start_theta_a_rad {
            Some(s) => Some((s, "start_theta_a_rad")),
            None if power_up != 0.0 => Some((rest + power_up, "faults.power_up_offset_rad")),
            None => None,
        };
        if let Some((start, key)) = start_at {
            let bad = PlantError::Invalid(key);
            let pose = kin
                .solve(start, Active::None, tracker.pose.theta2_rad)
                .map_err(|_| bad)?;
            for c in Constraint::ALL {
                if kin
                    .gap(c, pose.theta1_rad, pose.theta2_rad)
                    .is_some_and(|g| g.gap < 0.0)
                {
                    return Err(bad);
                }
            }
            tracker = Tracker::at(kin, pose);
            let d = &scene.drive;
            let half = 0.5 * d.backlash_rad;
            let gear = if start >= rest {
                start + half
            } else {
                start - half
            };
            drive.angle_rad = (gear - rest) * d.gear_ratio;
            drive.current_a = if power_up != 0.0 {
                // Powered up: nothing drives the winding, the gear's friction holds the finger.
                0.0
            } else {
                pose.torque_nm / (d.gear_ratio * d.eff_drive * d.kt_nm_per_a)
            };
            drive.stuck = true;
        }
        let mut p = Plant {
            scene: *scene,
            tracker,
            drive,
            theta_a_rest_rad: rest,
            k_loc: 0.5,
            t_s: 0.0,
            steps: 0,
            rng: Rng::new(scene.sensors.seed),
            enc_offset: 0,
            enc_stuck: None,
            r_ohm: scene.drive.r_ohm,
            adc: 0,
            over_current: false,
            failed: false,
            jump_done: false,
            removed: false,
            events: [None; EVENT_CAP],
            ev_head: 0,
            ev_len: 0,
            dropped: 0,
        };
        if power_up != 0.0 {
            // The encoder counts from power-up, not from the rest pose.
            p.enc_offset = p
                .scene
                .sensors
                .encoder_count_unwrapped(p.drive.angle_rad)
                .wrapping_neg();
        }
        p.k_loc = p.local_stiffness(p.tracker.pose.theta_a_rad).unwrap_or(0.5);
        p.sample_adc();
        Ok(p)
    }

    /// The scene this plant runs.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// θa at the rest pose (rad): the firmware's encoder zero.
    pub fn theta_a_rest_rad(&self) -> f64 {
        self.theta_a_rest_rad
    }

    /// One control period with a PWM duty in [−1, 1] (NaN → 0, clamped).
    pub fn step(&mut self, duty: f64) {
        self.step_input(Input::Duty(duty));
    }

    /// One control period with the bridge off (safe state).
    pub fn step_off(&mut self) {
        self.step_input(Input::Off);
    }

    /// One control period with the scene's open-loop command at the current time.
    pub fn step_scene(&mut self) {
        let c = &self.scene.command;
        let v = c.value_at(self.t_s);
        let input = match c.mode {
            CommandMode::External => Input::Duty(0.0),
            CommandMode::Duty => Input::Duty(v),
            CommandMode::Current => Input::Current(v),
        };
        self.step_input(input);
    }

    /// One control period with any input (duty, ideal current, ideal motor torque, off).
    pub fn step_input(&mut self, input: Input) {
        self.apply_scheduled_faults();
        let pose = self.tracker.pose;
        let load = Load {
            theta_a_zero_rad: self.theta_a_rest_rad,
            theta_a0_rad: pose.theta_a_rad,
            t0_nm: pose.torque_nm,
            k_nm_per_rad: self.k_loc,
        };
        let dt = self.scene.dt_s;
        self.scene.drive.advance(
            &mut self.drive,
            input,
            &load,
            self.theta_a_rest_rad,
            self.r_ohm,
            dt,
        );
        self.t_s = (self.steps.wrapping_add(1)) as f64 * dt;
        self.steps = self.steps.wrapping_add(1);
        let gear = self.gear_out();
        let theta_a = self.scene.drive.finger_angle(gear, self.theta_a_rest_rad);
        // A finger that did not move (stall, dead band, stiction) needs no new solve.
        if !self.failed && theta_a != pose.theta_a_rad {
            let t = self.t_s;
            let (th0, th1) = (pose.theta_a_rad, theta_a);
            let mut buf: [Option<Event>; 8] = [None; 8];
            let mut nb = 0usize;
            let res = self.tracker.advance(theta_a, &mut |e| {
                // Time of the event inside the period, interpolated on θa (the motor moves
                // smoothly over one period); clamped to the period.
                let frac = ((e.theta_a_rad - th0) / (th1 - th0)).clamp(0.0, 1.0);
                let frac = if frac.is_finite() { frac } else { 1.0 };
                if let Some(slot) = buf.get_mut(nb) {
                    *slot = Some(Event {
                        t_s: t - dt * (1.0 - frac),
                        ..e
                    });
                    nb += 1;
                }
            });
            for e in buf.iter().flatten() {
                self.push_event(*e);
            }
            match res {
                Ok(p) => {
                    let dth = p.theta_a_rad - pose.theta_a_rad;
                    if dth.abs() > 1e-7 && p.active == pose.active {
                        let k = (p.torque_nm - pose.torque_nm) / dth;
                        if k.is_finite() {
                            self.k_loc = k.clamp(0.0, self.scene.finger.k_lock_nm_per_rad);
                        }
                    } else if p.active != pose.active {
                        self.k_loc = self.local_stiffness(p.theta_a_rad).unwrap_or(self.k_loc);
                    }
                }
                Err(e) => {
                    self.failed = true;
                    self.push_event(Event {
                        t_s: self.t_s,
                        ..ev(&pose, EventKind::SolverFailure(e))
                    });
                }
            }
        }
        let i = self.drive.current_a;
        if i.abs() > self.scene.faults.over_current_a {
            if !self.over_current {
                self.over_current = true;
                let p = self.tracker.pose;
                self.push_event(Event {
                    t_s: self.t_s,
                    ..ev(&p, EventKind::OverCurrent { current_a: i })
                });
            }
        } else if i.abs() < 0.9 * self.scene.faults.over_current_a {
            self.over_current = false;
        }
        self.sample_adc();
    }

    fn local_stiffness(&self, theta_a: f64) -> Result<f64, PlantError> {
        let p0 = self.tracker.pose;
        let d = 1e-6;
        let q = self
            .tracker
            .kin
            .solve(theta_a + d, p0.active, p0.theta2_rad)?;
        let p = self.tracker.kin.solve(theta_a, p0.active, p0.theta2_rad)?;
        let k = (q.torque_nm - p.torque_nm) / d;
        if k.is_finite() {
            Ok(k.clamp(0.0, self.scene.finger.k_lock_nm_per_rad))
        } else {
            Err(PlantError::NonFinite)
        }
    }

    fn apply_scheduled_faults(&mut self) {
        let f = self.scene.faults;
        let t = self.t_s;
        if t >= f.encoder_stuck_at_s && self.enc_stuck.is_none() {
            self.inject(Fault::EncoderStuck);
        }
        if t >= f.encoder_jump_at_s && !self.jump_done {
            self.jump_done = true;
            self.inject(Fault::EncoderJump(f.encoder_jump_counts));
        }
        if t >= f.short_at_s && self.r_ohm != f.short_r_ohm {
            self.inject(Fault::Short(f.short_r_ohm));
        }
        if t >= f.remove_object_at_s && !self.removed {
            self.inject(Fault::RemoveObject);
        }
    }

    /// Injects a fault now.
    pub fn inject(&mut self, fault: Fault) {
        match fault {
            Fault::EncoderStuck => self.enc_stuck = Some(self.encoder_count_live()),
            Fault::EncoderJump(n) => self.enc_offset = self.enc_offset.wrapping_add(i64::from(n)),
            Fault::Short(r) => {
                if r.is_finite() && r > 0.0 {
                    self.r_ohm = r;
                }
            }
            Fault::RemoveObject => {
                self.removed = true;
                let was = self.tracker.pose;
                self.tracker.kin.object = None;
                let pose = self
                    .tracker
                    .kin
                    .solve(was.theta_a_rad, Active::None, was.theta2_rad);
                if let Active::One(Constraint::Contact(ph)) = was.active {
                    self.push_event(Event {
                        t_s: self.t_s,
                        ..ev(
                            &was,
                            EventKind::LossOfContact {
                                phalanx: ph,
                                k_m: was.k_m,
                            },
                        )
                    });
                }
                if let Ok(p) = pose {
                    self.tracker = Tracker::at(self.tracker.kin, p);
                    self.k_loc = self.local_stiffness(p.theta_a_rad).unwrap_or(self.k_loc);
                }
            }
            Fault::Clear => {
                self.enc_stuck = None;
                self.r_ohm = self.scene.drive.r_ohm;
            }
        }
    }

    fn gear_out(&self) -> f64 {
        self.theta_a_rest_rad + self.drive.angle_rad / self.scene.drive.gear_ratio
    }

    fn encoder_count_live(&self) -> u16 {
        let c = self
            .scene
            .sensors
            .encoder_count_unwrapped(self.drive.angle_rad)
            .wrapping_add(self.enc_offset);
        c as u16
    }

    fn sample_adc(&mut self) {
        let n = if self.scene.sensors.noise_v_rms > 0.0 {
            self.rng.normal()
        } else {
            0.0
        };
        self.adc = self.scene.sensors.adc_code(self.drive.current_a, n);
    }

    /// Quadrature ×4 count of the motor encoder (wrapping u16; zero at the rest pose).
    pub fn encoder_count(&self) -> u16 {
        self.enc_stuck.unwrap_or_else(|| self.encoder_count_live())
    }

    /// Unwrapped encoder count (no stuck fault applied; the jump fault is included).
    pub fn encoder_count_unwrapped(&self) -> i64 {
        self.scene
            .sensors
            .encoder_count_unwrapped(self.drive.angle_rad)
            .wrapping_add(self.enc_offset)
    }

    /// 12-bit ADC code of the shunt amplifier, sampled at the end of the last step.
    pub fn current_adc(&self) -> u16 {
        self.adc
    }

    /// θa as a controller would compute it from the encoder: rest + count·2π/(4·CPT·N) (rad).
    pub fn measured_theta_a_rad(&self) -> f64 {
        let s = &self.scene;
        let c = self.encoder_count_unwrapped() as f64;
        self.theta_a_rest_rad
            + c * core::f64::consts::TAU
                / (f64::from(s.sensors.counts_per_turn()) * s.drive.gear_ratio)
    }

    /// T_a as a controller would compute it from the ADC code with nominal constants:
    /// N·η_drive·kt·i (N·m).
    pub fn measured_torque_nm(&self) -> f64 {
        let s = &self.scene;
        let i = (f64::from(self.adc) - s.sensors.zero_code()) / s.sensors.codes_per_amp();
        s.drive.stall_torque_nm(i)
    }

    /// The true state.
    pub fn truth(&self) -> Truth {
        let p = self.tracker.pose;
        let (contact, k) = match p.active {
            Active::None => (ContactState::Free, 0.0),
            Active::One(Constraint::Contact(Phalanx::Proximal)) => (ContactState::Proximal, p.k_m),
            Active::One(Constraint::Contact(Phalanx::Distal)) => (ContactState::Distal, p.k_m),
            Active::One(_) => (ContactState::Limit, 0.0),
            Active::Two { .. } => (ContactState::Locked, p.k_m),
        };
        Truth {
            t_s: self.t_s,
            theta_a_rad: p.theta_a_rad,
            torque_a_nm: p.torque_nm,
            theta1_rad: p.theta1_rad,
            theta2_rad: p.theta2_rad,
            contact,
            k_m: k,
            force: if matches!(p.active, Active::None) {
                0.0
            } else {
                p.lambda
            },
            current_a: self.drive.current_a,
            motor_speed_rad_s: self.drive.speed_rad_s,
            motor_angle_rad: self.drive.angle_rad,
            gear_out_rad: self.gear_out(),
            voltage_v: self.drive.voltage_v,
        }
    }

    /// The next pending event, oldest first.
    pub fn poll_event(&mut self) -> Option<Event> {
        if self.ev_len == 0 {
            return None;
        }
        let e = self.events.get_mut(self.ev_head).and_then(Option::take);
        self.ev_head = (self.ev_head + 1) % EVENT_CAP;
        self.ev_len -= 1;
        e
    }

    /// Events dropped because the queue (16) was full.
    pub fn events_dropped(&self) -> u32 {
        self.dropped
    }

    /// True once the kinetostatic solver failed (the finger geometry is then frozen).
    pub fn solver_failed(&self) -> bool {
        self.failed
    }

    fn push_event(&mut self, e: Event) {
        if self.ev_len >= EVENT_CAP {
            self.dropped = self.dropped.saturating_add(1);
            return;
        }
        let idx = (self.ev_head + self.ev_len) % EVENT_CAP;
        if let Some(slot) = self.events.get_mut(idx) {
            *slot = Some(e);
            self.ev_len += 1;
        }
    }
}
