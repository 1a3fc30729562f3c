//! The simulated board: `plant::Plant` behind `grasp::Hardware`.
//!
//! One adapter for every place that runs the controller against the simulated finger (the
//! `pts` tool, the host tests, the firmware's host runner and its QEMU board), so they cannot
//! drift apart. It lives in its own crate because `plant` must not import `grasp` (the judge
//! shares nothing with the judged) and `grasp` must not import `plant`.
#![no_std]
#![forbid(unsafe_code)]

pub mod log;
pub mod run;

use grasp::{DriveConfig, Hardware, RestCheck, DUTY_MAX};
use plant::{Plant, Scene};

/// The plant wired to an H-bridge: the duty the controller sets is applied for the next
/// control period by [`PlantBoard::advance`].
pub struct PlantBoard {
    /// The simulated finger.
    pub plant: Plant,
    duty: f64,
    off: bool,
    bridge_off_calls: u32,
    duty_clamped: u32,
}

impl PlantBoard {
    /// Wraps a plant, bridge off until the first `set_duty`.
    pub fn new(plant: Plant) -> Self {
        Self {
            plant,
            duty: 0.0,
            off: true,
            bridge_off_calls: 0,
            duty_clamped: 0,
        }
    }

    /// One control period with what the controller commanded (coasting when the bridge is off).
    pub fn advance(&mut self) {
        if self.off {
            self.plant.step_off();
        } else {
            self.plant.step(self.duty);
        }
    }

    /// The duty in force, −1…1 (0 with the bridge off).
    pub fn duty(&self) -> f64 {
        if self.off {
            0.0
        } else {
            self.duty
        }
    }

    /// Whether the bridge is off now.
    pub fn is_off(&self) -> bool {
        self.off
    }

    /// How many times the controller turned the bridge off.
    pub fn bridge_off_calls(&self) -> u32 {
        self.bridge_off_calls
    }

    /// How many duties outside ±`DUTY_MAX` the controller asked for (clamped; a controller
    /// bug, which tests assert never happens).
    pub fn duty_clamped(&self) -> u32 {
        self.duty_clamped
    }
}

impl Hardware for PlantBoard {
    fn encoder_count(&mut self) -> u16 {
        self.plant.encoder_count()
    }
    fn current_raw(&mut self) -> u16 {
        self.plant.current_adc()
    }
    fn set_duty(&mut self, duty: i16) {
        if !(-DUTY_MAX..=DUTY_MAX).contains(&duty) {
            self.duty_clamped = self.duty_clamped.saturating_add(1);
        }
        self.off = false;
        self.duty = f64::from(duty.clamp(-DUTY_MAX, DUTY_MAX)) / f64::from(DUTY_MAX);
    }
    fn bridge_off(&mut self) {
        self.off = true;
        self.duty = 0.0;
        self.bridge_off_calls = self.bridge_off_calls.saturating_add(1);
    }
}

/// The scene with its finger replaced by `finger` (geometry and springs), its extension stops by
/// `stops` (the flexion stops stay the scene's) and its drive's nominal constants by `drive`'s
/// (gear ratio, efficiency, motor constant, resistance, supply, the rotor inertia behind the
/// drive's effective inertia, backlash; the friction and sensor models stay the scene's): the
/// plant built from the same finger the controller is.
pub fn scene_for_finger(
    mut scene: Scene,
    finger: &pts::Finger,
    drive: &DriveConfig,
    stops: &pts::Stops,
) -> Scene {
    let g = &mut scene.finger;
    g.l1_m = finger.l1;
    g.l2_m = finger.l2;
    g.a_m = finger.a;
    g.b_m = finger.b;
    g.c_m = finger.c;
    g.phi2_rad = finger.phi2;
    g.theta1_min_rad = stops.theta1_min_rad;
    g.theta2_min_rad = stops.theta2_min_rad;
    g.k_lock_nm_per_rad = stops.stiffness_nm_per_rad;
    g.theta01_rad = finger.theta01;
    g.theta02_rad = finger.theta02;
    g.k1_nm_per_rad = finger.k1;
    g.k2_nm_per_rad = finger.k2;
    let d = &mut scene.drive;
    d.gear_ratio = drive.gear_ratio;
    d.eff_drive = drive.efficiency;
    d.kt_nm_per_a = drive.kt_nm_per_a;
    d.r_ohm = drive.resistance_ohm;
    d.supply_v = drive.bus_v;
    // The drive's inertia as the measured torque sees it is η·J·N²; the plant needs a rotor
    // with some inertia, so a file's zero keeps the plant's own.
    let rotor = drive.inertia_kgm2 / (drive.efficiency * drive.gear_ratio * drive.gear_ratio);
    if rotor.is_finite() && rotor > 0.0 {
        d.rotor_inertia_kgm2 = rotor;
    }
    d.backlash_rad = drive.backlash_rad;
    scene
}

/// The controller's view of a scene's drive and sensors: the nominal constants a firmware
/// would be built with (the plant's gain/offset errors and noise stay unknown to it), with
/// the actuator angle at rest `theta_a_rest_rad` (rad).
pub fn scene_drive(scene: &Scene, theta_a_rest_rad: f64) -> DriveConfig {
    let d = &scene.drive;
    let s = &scene.sensors;
    DriveConfig {
        dt_s: scene.dt_s,
        gear_ratio: d.gear_ratio,
        efficiency: d.eff_drive,
        kt_nm_per_a: d.kt_nm_per_a,
        resistance_ohm: d.r_ohm,
        bus_v: d.supply_v,
        encoder_counts_per_rev: f64::from(s.counts_per_turn()),
        amps_per_code: 1.0 / s.codes_per_amp(),
        adc_zero_code: s.zero_code(),
        theta_a_rest_rad,
        // The measurement model of this drive: what the torque sees of the rotor through the
        // gearhead's driving efficiency, and its backlash.
        inertia_kgm2: d.eff_drive * d.rotor_inertia_kgm2 * d.gear_ratio * d.gear_ratio,
        backlash_rad: d.backlash_rad,
        priors: DriveConfig::DEFAULT.priors,
    }
}

/// The rest check for a finger, its drive and its stops (a finger file's): [`scene_rest_check`]
/// of the plant built from them ([`scene_for_finger`] on the default scene, whose drive
/// friction a finger file does not describe). What the board's build takes (build.rs).
pub fn finger_rest_check(
    finger: &pts::Finger,
    drive: &DriveConfig,
    stops: &pts::Stops,
) -> Option<RestCheck> {
    scene_rest_check(&scene_for_finger(Scene::DEFAULT, finger, drive, stops))
}

/// The rest check for a simulated finger: its open stop (both joints on their extension stops)
/// relative to its rest pose from the scene's geometry, the stop's stiffness and the drive's
/// backlash, what a board would take from its finger's data; the torques and times of
/// [`RestCheck::PAPER`]. `None` when the geometry has no rest or stop pose.
pub fn scene_rest_check(scene: &Scene) -> Option<RestCheck> {
    let g = &scene.finger;
    let kin = plant::kin::Kin::new(*g, None);
    let rest = kin.rest().ok()?.theta_a_rad;
    let stop = g.theta1_min_rad + g.linkage(g.theta2_min_rad).ok()?.phi_rad;
    // T_a holding the free finger at the stop's pose: the springs' share, not the stop's.
    let held = kin
        .solve(stop, plant::kin::Active::None, g.theta2_min_rad)
        .ok()?
        .torque_nm;
    Some(RestCheck {
        stop_from_rest_rad: stop - rest,
        stop_spring_nm: -held,
        friction_nm: scene.drive.coulomb_nm * scene.drive.gear_ratio * scene.drive.eff_drive,
        stop_compliance_rad_per_nm: 1.0 / g.k_lock_nm_per_rad,
        backlash_rad: scene.drive.backlash_rad,
        ..RestCheck::PAPER
    })
}
