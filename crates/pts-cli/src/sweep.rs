//! Calibration sweeps on the simulated finger: a slow free close-and-open sweep (and the
//! touch against a known fixed post) within a safe torque, recorded in the trace CSV format
//! `pts estimate` and `pts calibrate` read.
//!
//! The plant is the truth and the finger file the nominal: [`Perturbation`] builds a plant
//! whose springs, rest angles, friction and inertia are off the file, and the recorder
//! converts the plant's encoder counts and ADC codes with the *nominal* file's constants, as a
//! firmware built from that file would.

use crate::trace::TraceRow;
use plant::drive::Input;
use plant::scene::ObjectSpec;
use plant::{Object, Plant, Scene};
use pts::config::FingerFile;

/// How a plant finger differs from its finger file (the file is the nominal, the plant the
/// truth). Factors are dimensionless, offsets in degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Perturbation {
    /// True K1 / nominal K1.
    pub k1_factor: f64,
    /// True K2 / nominal K2.
    pub k2_factor: f64,
    /// True θ0,1 − nominal θ0,1 (degrees).
    pub theta01_deg: f64,
    /// True θ0,2 − nominal θ0,2 (degrees).
    pub theta02_deg: f64,
    /// Factor on the plant's Coulomb, stiction and viscous friction.
    pub friction_factor: f64,
    /// Factor on the plant's rotor inertia.
    pub inertia_factor: f64,
}

impl Perturbation {
    /// No perturbation: the plant is the file.
    pub const NONE: Perturbation = Perturbation {
        k1_factor: 1.0,
        k2_factor: 1.0,
        theta01_deg: 0.0,
        theta02_deg: 0.0,
        friction_factor: 1.0,
        inertia_factor: 1.0,
    };

    /// Parses `k1=1.25,k2=0.75,theta01_deg=3,theta02_deg=-3,friction=2,inertia=3` (any
    /// subset; missing keys keep [`Perturbation::NONE`]'s value). Spring, friction and inertia
    /// factors must be in [0.2, 5], rest-angle offsets in [−10, 10] degrees.
    pub fn parse(text: &str) -> Result<Perturbation, String> {
        let mut p = Perturbation::NONE;
        for item in text.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let (k, v) = item
                .split_once('=')
                .ok_or_else(|| format!("--perturb: `{item}` is not KEY=VALUE"))?;
            let v: f64 = v
                .trim()
                .parse()
                .map_err(|_| format!("--perturb: {k} = `{v}` is not a number"))?;
            let (slot, lo, hi) = match k.trim() {
                "k1" => (&mut p.k1_factor, 0.2, 5.0),
                "k2" => (&mut p.k2_factor, 0.2, 5.0),
                "theta01_deg" => (&mut p.theta01_deg, -10.0, 10.0),
                "theta02_deg" => (&mut p.theta02_deg, -10.0, 10.0),
                "friction" => (&mut p.friction_factor, 0.2, 5.0),
                "inertia" => (&mut p.inertia_factor, 0.2, 5.0),
                other => {
                    return Err(format!(
                        "--perturb: unknown key `{other}` (k1, k2, theta01_deg, theta02_deg, \
                         friction, inertia)"
                    ))
                }
            };
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(format!("--perturb: {k} = {v} is outside [{lo}, {hi}]"));
            }
            *slot = v;
        }
        Ok(p)
    }

    /// The finger file of the perturbed finger's springs and rest angles (the "true file").
    pub fn apply_to_file(&self, nominal: &FingerFile) -> FingerFile {
        let mut f = nominal.clone();
        f.finger.k1 *= self.k1_factor;
        f.finger.k2 *= self.k2_factor;
        f.finger.theta01 += self.theta01_deg.to_radians();
        f.finger.theta02 += self.theta02_deg.to_radians();
        // The stops keep their place relative to the rest angles: a rest angle moved below
        // its stop would leave the simulated finger preloaded against it.
        f.stops.theta1_min_rad += self.theta01_deg.to_radians();
        f.stops.theta2_min_rad += self.theta02_deg.to_radians();
        f.drive.inertia_kgm2 *= self.inertia_factor;
        f
    }

    /// The plant scene of the perturbed finger: the file's finger and drive constants, then
    /// the springs, rest angles, friction and inertia moved by this perturbation. The scene's
    /// sensor model (offset, gain error, noise) stays.
    pub fn scene(&self, base: Scene, nominal: &FingerFile) -> Result<Scene, String> {
        let truth = self.apply_to_file(nominal);
        // (The plant's extension stops are the true file's, moved with its rest angles.)
        let (mut scene, _) = crate::sim::finger_scene(base, &truth)?;
        let d = &mut scene.drive;
        d.coulomb_nm *= self.friction_factor;
        d.stiction_nm *= self.friction_factor;
        d.viscous_nm_s_per_rad *= self.friction_factor;
        // The rotor inertia follows the true file's (`finger_scene`), already scaled.
        Ok(scene)
    }
}

/// A fixed post touching the proximal phalanx: a point at distance `k1_m` from O1 on the
/// line at angle `theta1_rad` (the world frame of `docs/MODEL.md`). Its place is a property
/// of the calibration fixture, known independently of the springs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Post {
    /// θ1 at which the proximal phalanx reaches the post (rad).
    pub theta1_rad: f64,
    /// Distance of the post from O1 along the proximal phalanx (m).
    pub k1_m: f64,
}

impl Post {
    /// The object the plant puts there (a vertex).
    pub fn object(&self) -> Object {
        Object {
            x_m: self.k1_m * self.theta1_rad.cos(),
            y_m: self.k1_m * self.theta1_rad.sin(),
            radius_m: 0.0,
        }
    }
}

/// A fixed post the distal phalanx meets while the finger closes freely: a point at
/// (`x_m`, `y_m`) in the world frame at O1, known from the calibration fixture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DistalPost {
    /// x (m).
    pub x_m: f64,
    /// y (m).
    pub y_m: f64,
}

impl DistalPost {
    /// Where the nominal finger's distal phalanx, closing freely, meets a point at
    /// `k_frac`·l2 from O2 when θ1 = `theta1_rad`.
    pub fn for_file(file: &FingerFile, theta1_rad: f64, k_frac: f64) -> Result<DistalPost, String> {
        let f = &file.finger;
        let m = pts::Model::<f64>::new(f).map_err(|e| e.to_string())?;
        let cfg = m
            .free_from_torque(f.k1 * (theta1_rad - f.theta01))
            .map_err(|e| e.to_string())?;
        let (t1, t2) = (cfg.theta1, cfg.theta1 + cfg.theta2);
        let k = k_frac * f.l2;
        Ok(DistalPost {
            x_m: f.l1 * t1.cos() + k * t2.cos(),
            y_m: f.l1 * t1.sin() + k * t2.sin(),
        })
    }

    /// The object the plant puts there (a vertex).
    pub fn object(&self) -> Object {
        Object {
            x_m: self.x_m,
            y_m: self.y_m,
            radius_m: 0.0,
        }
    }
}

/// The sweep's command: a torque triangle 0 → `safe_torque_nm` → 0 with a small sinusoidal
/// dither (it makes the inertia and the viscous term visible).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SweepPlan {
    /// Largest commanded torque at the crank (N·m), in (0, 1.5].
    pub safe_torque_nm: f64,
    /// Duration of the closing ramp and of the opening ramp, each (s), in [1, 120].
    pub ramp_s: f64,
    /// Rest before and after the ramps (s).
    pub pause_s: f64,
    /// Dither amplitude (N·m), ≥ 0 and below a tenth of the safe torque.
    pub dither_nm: f64,
    /// Dither frequency (Hz).
    pub dither_hz: f64,
    /// Plant steps per recorded row, ≥ 1.
    pub decimate: u32,
}

impl SweepPlan {
    /// The default sweep: 0.6 N·m in 8 s up and 8 s down, 0.02 N·m of 2 Hz dither, rows at
    /// 1 kHz on the plant's 10 kHz.
    pub const DEFAULT: SweepPlan = SweepPlan {
        safe_torque_nm: 0.6,
        ramp_s: 8.0,
        pause_s: 0.5,
        dither_nm: 0.02,
        dither_hz: 2.0,
        decimate: 10,
    };

    fn check(&self) -> Result<(), String> {
        if !(self.safe_torque_nm.is_finite()
            && self.safe_torque_nm > 0.0
            && self.safe_torque_nm <= 1.5)
        {
            return Err(format!(
                "safe torque {} N·m is outside (0, 1.5]",
                self.safe_torque_nm
            ));
        }
        if !(self.ramp_s.is_finite() && (1.0..=120.0).contains(&self.ramp_s)) {
            return Err(format!("ramp {} s is outside [1, 120]", self.ramp_s));
        }
        if !(self.pause_s.is_finite() && (0.0..=10.0).contains(&self.pause_s)) {
            return Err(format!("pause {} s is outside [0, 10]", self.pause_s));
        }
        if !(self.dither_nm.is_finite()
            && self.dither_nm >= 0.0
            && self.dither_nm <= 0.1 * self.safe_torque_nm)
        {
            return Err(format!(
                "dither {} N·m is outside [0, {}] (a tenth of the safe torque)",
                self.dither_nm,
                0.1 * self.safe_torque_nm
            ));
        }
        if !(self.dither_hz.is_finite() && (0.1..=50.0).contains(&self.dither_hz)) {
            return Err(format!("dither {} Hz is outside [0.1, 50]", self.dither_hz));
        }
        if self.decimate == 0 {
            return Err(format!("decimate {} must be ≥ 1", self.decimate));
        }
        Ok(())
    }

    /// Longest duration (s): the pauses, the ramp up and at most twice the ramp down.
    pub fn duration_s(&self) -> f64 {
        2.0 * self.pause_s + 3.0 * self.ramp_s
    }

    /// The commanded torque at time `t_s` (N·m) and whether the sweep is over, given how far
    /// the encoder is from its zero (`dtheta_a_rad`): up from 0 to the safe torque over the
    /// ramp, then down at the same rate (below zero if the gear does not back-drive, never
    /// below −safe torque) until the finger is back within 0.03 rad of rest; then 0. A
    /// sinusoidal dither rides on the ramps.
    pub fn torque_at(&self, t_s: f64, opening_done: bool) -> f64 {
        let t = t_s - self.pause_s;
        if t <= 0.0 || opening_done {
            return 0.0;
        }
        let tri = if t <= self.ramp_s {
            t / self.ramp_s
        } else {
            (2.0 - t / self.ramp_s).max(-1.0)
        };
        let base = tri * self.safe_torque_nm;
        let fade = (t / self.ramp_s).min(1.0);
        let d = self.dither_nm * (core::f64::consts::TAU * self.dither_hz * t).sin() * fade;
        (base + d).clamp(-self.safe_torque_nm, self.safe_torque_nm)
    }
}

/// Runs a sweep on the plant of `scene` (its object replaced by `post`, or none), commanding
/// the motor current the nominal file converts the torque to, and records rows as a firmware
/// built from `nominal` would see them: θa = the file's rest angle + encoder counts, T_a from
/// the ADC code with the file's constants. Raw `encoder_count` and `current_code` columns and
/// the plant's truth are included.
pub fn record(
    scene: &Scene,
    nominal: &FingerFile,
    plan: &SweepPlan,
    post: Option<Post>,
) -> Result<Vec<TraceRow>, String> {
    record_object(scene, nominal, plan, post.map(|p| p.object()))
}

/// [`record`] with any fixed object (e.g. a [`DistalPost`]), or none.
pub fn record_object(
    scene: &Scene,
    nominal: &FingerFile,
    plan: &SweepPlan,
    object: Option<Object>,
) -> Result<Vec<TraceRow>, String> {
    plan.check()?;
    let mut scene = *scene;
    scene.object = match object {
        Some(o) => ObjectSpec::At(o),
        None => ObjectSpec::None,
    };
    scene.duration_s = plan.duration_s();
    let cfg = crate::replay::controller_config(nominal, scene.dt_s)?;
    let rest_nominal = cfg.drive.theta_a_rest_rad;
    let mut plant = Plant::new(&scene).map_err(|e| format!("sweep plant: {e}"))?;
    let rad_per_count = nominal.rad_per_count();
    let zero = f64::from(nominal.current_sense.zero_count);
    let apc = nominal.current_sense.amps_per_count;
    let steps = (plan.duration_s() / scene.dt_s).ceil() as u64;
    let mut rows = Vec::with_capacity((steps / u64::from(plan.decimate)) as usize + 1);
    let count0 = plant.encoder_count_unwrapped();
    let mut done_at: Option<f64> = None;
    for n in 0..steps {
        let t = n as f64 * scene.dt_s;
        let dth = (plant.encoder_count_unwrapped() - count0) as f64 * rad_per_count;
        if done_at.is_none() && t > plan.pause_s + plan.ramp_s && dth < 0.03 {
            done_at = Some(t);
        }
        if done_at.is_some_and(|d| t > d + plan.pause_s) {
            break;
        }
        let torque_ref = plan.torque_at(t, done_at.is_some());
        plant.step_input(Input::Current(nominal.current_from_torque(torque_ref)));
        if plant.solver_failed() {
            return Err(format!("the plant's solver failed at t = {t:.3} s"));
        }
        if n % u64::from(plan.decimate) == 0 {
            let truth = plant.truth();
            let code = plant.current_adc();
            let counts = plant.encoder_count_unwrapped() - count0;
            rows.push(TraceRow {
                t_s: truth.t_s,
                theta_a_rad: rest_nominal + counts as f64 * rad_per_count,
                torque_nm: nominal.torque_from_current((f64::from(code) - zero) * apc),
                torque_ref_nm: Some(torque_ref),
                duty: None,
                state: Some(if object.is_some() { "touch" } else { "sweep" }.into()),
                encoder_count: Some(plant.encoder_count()),
                current_code: Some(code),
                true_theta_a_rad: Some(truth.theta_a_rad),
                true_torque_nm: Some(truth.torque_a_nm),
                true_contact: Some(truth.contact.name().to_string()),
                true_k_m: Some(truth.k_m),
            });
        }
    }
    Ok(rows)
}

/// The drive and sensor truth of a scene at the crank, in the units of the torque a file's
/// current conversion reports (the sensor's gain error included): what `pts calibrate` should
/// find. Returns (Coulomb N·m, stiction N·m, viscous N·m·s/rad, inertia kg·m², back-driven
/// efficiency product, torque offset N·m).
pub fn drive_truth(scene: &Scene, nominal: &FingerFile) -> [f64; 6] {
    let d = &scene.drive;
    let s = &scene.sensors;
    let g = 1.0 + s.gain_error;
    let n = d.gear_ratio;
    let crank = n * d.eff_drive * g;
    let offset_a = s.offset_error_v / (s.shunt_ohm * s.amp_gain);
    [
        crank * d.coulomb_nm,
        crank * d.stiction_nm,
        crank * n * d.viscous_nm_s_per_rad,
        crank * n * d.rotor_inertia_kgm2,
        d.eff_drive * d.eff_back,
        nominal.torque_from_current(offset_a),
    ]
}

/// One recorded tick of the firmware's calibration sweep as a trace row: θa from the
/// firmware's conversion (µrad), T_a from the raw ADC code with the *nominal* file's zero and
/// scale (so the identification sees the current sensor's offset), the reference and duty it
/// applied, and the raw readings. The same for a sweep simulated here and one recorded from
/// the device (`pts board calibrate`).
pub fn firmware_row(nominal: &FingerFile, t_s: f64, s: &proto::Sample) -> TraceRow {
    let zero = f64::from(nominal.current_sense.zero_count);
    let apc = nominal.current_sense.amps_per_count;
    TraceRow {
        t_s,
        theta_a_rad: f64::from(s.theta_a_urad) * 1e-6,
        torque_nm: nominal.torque_from_current((f64::from(s.current_code) - zero) * apc),
        torque_ref_nm: Some(f64::from(s.torque_ref_unm) * 1e-6),
        duty: Some(f64::from(s.duty) / f64::from(grasp::DUTY_MAX)),
        state: Some(s.state.name().into()),
        encoder_count: Some(s.encoder_count),
        current_code: Some(s.current_code),
        ..TraceRow::default()
    }
}

/// Runs the firmware's calibration sweep against the plant of `scene`: the loop the device
/// runs on `calibrate` ([`grasp::ControlLoop::for_sweep`], with its current calibration, fast
/// faults and torque loop), configured from `nominal`, ticking [`sim_board::PlantBoard`].
/// The rows it records (one in the sweep's decimation) as [`firmware_row`] writes them, with
/// the plant's truth beside them. `object` is a fixed object, or none. Ends with the sweep's
/// final phase (a loop fault reads as aborted).
pub fn record_firmware(
    scene: &Scene,
    nominal: &FingerFile,
    cfg: grasp::calibrate::SweepConfig,
    object: Option<Object>,
) -> Result<(Vec<TraceRow>, grasp::calibrate::Phase), String> {
    use grasp::calibrate::{Phase, Sweep};
    let mut scene = *scene;
    scene.object = match object {
        Some(o) => ObjectSpec::At(o),
        None => ObjectSpec::None,
    };
    let ctl = crate::replay::controller_config(nominal, scene.dt_s)?;
    let p = ctl
        .params()
        .map_err(|e| format!("controller parameters: {e:?}"))?;
    let sweep = Sweep::new(cfg).map_err(|e| format!("calibration sweep: {e:?}"))?;
    let mut lp = grasp::ControlLoop::for_sweep(&p, sweep);
    let mut link = grasp::Link::new();
    let mut hw =
        sim_board::PlantBoard::new(Plant::new(&scene).map_err(|e| format!("sweep plant: {e}"))?);
    let mut rows = vec![];
    let mut t_start = None;
    // The sweep's own time limit ends it; this bound only guards against a loop that never
    // starts it (current calibration and rest check take far less).
    let limit = u64::from(cfg.timeout_ticks) + 1_000_000;
    for _ in 0..limit {
        let raw = (hw.plant.encoder_count(), hw.plant.current_adc());
        let out = grasp::loop_tick_dyn(&mut lp, &mut link, &mut hw);
        if let Some(phase @ (Phase::Done | Phase::Aborted(_))) = lp.sweep_phase() {
            hw.advance();
            if let Some(grasp::Input::LoopFault { tick, reason }) = link.next_input() {
                return Err(format!(
                    "the calibration sweep tripped at tick {tick}: {reason:?} (bridge off)"
                ));
            }
            return Ok((rows, phase));
        }
        if lp.sweep_record() {
            let truth = hw.plant.truth();
            let t0 = *t_start.get_or_insert(truth.t_s);
            let sample = proto::Sample {
                tick: out.tick,
                theta_a_urad: out.theta_a_urad,
                torque_unm: out.torque_unm,
                torque_ref_unm: out.torque_ref_unm,
                duty: out.duty,
                state: proto::DeviceState::Sweeping,
                encoder_count: raw.0,
                current_code: raw.1,
            };
            rows.push(TraceRow {
                true_theta_a_rad: Some(truth.theta_a_rad),
                true_torque_nm: Some(truth.torque_a_nm),
                true_contact: Some(truth.contact.name().to_string()),
                true_k_m: Some(truth.k_m),
                ..firmware_row(nominal, truth.t_s - t0, &sample)
            });
        }
        hw.advance();
    }
    Err(format!(
        "the calibration sweep did not end within {limit} ticks"
    ))
}
