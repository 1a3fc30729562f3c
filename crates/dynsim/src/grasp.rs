//! One recorded-style grasp: 0.1 s at zero command, a 0.5 N·m/s ramp in free motion until the
//! simulated controller notices the contact (the engine's first contact, seen after a detection
//! delay), a ΔT_a rise over a given time, a hold; sampled at 1 kHz with optional encoder
//! quantisation and torque noise, and the ground truth from the engine's contact points.

use crate::linkage::{self, L2_M};
use crate::sim::{ContactPoint, EngineSettings, Finger, FingerParams, Object, VERTEX_RADIUS_M};
use std::fmt::Write as _;

/// The object of a grasp, in terms of where it is first touched.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Target {
    /// No object: ramp to `NO_OBJECT_TORQUE_NM` and hold.
    None,
    /// A vertex (0.5 mm edge, `radius_m` 0) or cylinder of radius `radius_m`, placed so the
    /// free-motion finger first touches it at `k_m` along the distal (or proximal) phalanx when the
    /// proximal angle is `theta1_c_rad`.
    Object {
        /// Cylinder radius, m (0: vertex).
        radius_m: f64,
        /// Intended contact location along the phalanx, m.
        k_m: f64,
        /// True: distal phalanx (k2 from O2); false: proximal (k1 from O1).
        distal: bool,
        /// Proximal angle at first contact in free motion, rad.
        theta1_c_rad: f64,
    },
}

/// Torque held by the no-object grasps, N·m.
pub const NO_OBJECT_TORQUE_NM: f64 = 0.8;

/// Everything that defines one grasp.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GraspSpec {
    /// The object.
    pub target: Target,
    /// Torque rise after the contact is noticed, N·m.
    pub delta_ta_nm: f64,
    /// Duration of that rise (a ramp; 0 is a step), s.
    pub rise_s: f64,
    /// Delay between the physical first contact and the start of the rise, s.
    pub detection_delay_s: f64,
    /// Hold after the rise, s.
    pub hold_s: f64,
    /// Approach ramp rate, N·m/s.
    pub ramp_nm_per_s: f64,
    /// The finger's drive and contact parameters.
    pub finger: FingerParams,
    /// Engine settings.
    pub engine: EngineSettings,
}

/// Sensor effects added to the recording.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorSpec {
    /// Encoder counts per crank turn (0: no quantisation).
    pub counts_per_turn: u32,
    /// White torque noise, standard deviation, N·m.
    pub torque_sigma_nm: f64,
    /// Constant torque offset, N·m.
    pub torque_offset_nm: f64,
    /// Seed of the noise and of the encoder's quantiser phase.
    pub seed: u64,
}

impl SensorSpec {
    /// A perfect sensor.
    pub const IDEAL: Self = Self {
        counts_per_turn: 0,
        torque_sigma_nm: 0.0,
        torque_offset_nm: 0.0,
        seed: 0,
    };

    /// The same sensor with another draw `draw` of its noise and quantiser phase (draw 0 is
    /// this one): the same grasp recorded again, to tell an error that depends on the sensor's
    /// draw from one that does not. The seeds lie far from the grids' own (1000 + case number).
    #[must_use]
    pub fn redrawn(self, draw: u64) -> Self {
        Self {
            seed: self.seed.wrapping_add(draw.wrapping_mul(1_000_000)),
            ..self
        }
    }

    /// Whether the sensor draws anything (noise or a quantiser phase): a perfect sensor
    /// records a grasp one way only.
    pub fn is_noisy(&self) -> bool {
        self.torque_sigma_nm > 0.0 || self.counts_per_turn > 0
    }
}

/// Ground truth of a grasp, from the engine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Truth {
    /// `distal`, `proximal` or `none`: the phalanx of the first contact.
    pub phalanx: &'static str,
    /// Contact location at the first contact (k2 from O2 or k1 from O1), m.
    pub k_c_m: Option<f64>,
    /// Contact location at the end, m.
    pub k_end_m: Option<f64>,
    /// Time of the first contact, s.
    pub t_contact_s: Option<f64>,
    /// θa at the first contact, rad.
    pub theta_a_c_rad: Option<f64>,
    /// True when, at some time, both phalanges touched (a second contact).
    pub both_phalanges: bool,
    /// Number of times the contact was lost and regained (bounces).
    pub contact_losses: u32,
}

/// One 1 kHz sample, before sensor effects.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Time, s.
    pub t_s: f64,
    /// θa, rad.
    pub theta_a_rad: f64,
    /// Motor torque at the crank, N·m.
    pub torque_nm: f64,
}

/// A simulated grasp.
#[derive(Clone, Debug, PartialEq)]
pub struct Recording {
    /// Samples at 1 kHz from t = 0.
    pub samples: Vec<Sample>,
    /// Ground truth.
    pub truth: Truth,
    /// Largest loop-closure gap at Ob over the run, m.
    pub max_loop_gap_m: f64,
}

/// Where to put the object so that the free-motion finger first touches it as `target` says;
/// None if it cannot be placed (no free-motion pose, or a cylinder that would cut the other phalanx).
pub fn place(target: Target) -> Option<Object> {
    let Target::Object {
        radius_m,
        k_m,
        distal,
        theta1_c_rad,
    } = target
    else {
        return Some(Object::None);
    };
    let r = if radius_m > 0.0 {
        radius_m
    } else {
        VERTEX_RADIUS_M
    };
    let (pose, _) = linkage::free_motion_pose(theta1_c_rad)?;
    let (point, normal) = if distal {
        (pose.distal_point(k_m), pose.distal_normal())
    } else {
        let (c, s) = (theta1_c_rad.cos(), theta1_c_rad.sin());
        ([k_m * c, k_m * s], [-s, c])
    };
    let center = [point[0] + r * normal[0], point[1] + r * normal[1]];
    // The ball must stay clear of the other phalanx's line segment.
    let (a, b) = if distal {
        ([0.0, 0.0], pose.o2_m)
    } else {
        (pose.o2_m, pose.distal_point(L2_M))
    };
    if segment_distance(center, a, b) < r * (1.0 + 1e-6) {
        return None;
    }
    Some(Object::Ball {
        center_m: center,
        radius_m: r,
    })
}

fn segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let ab = [b[0] - a[0], b[1] - a[1]];
    let ap = [p[0] - a[0], p[1] - a[1]];
    let t = ((ap[0] * ab[0] + ap[1] * ab[1]) / (ab[0] * ab[0] + ab[1] * ab[1])).clamp(0.0, 1.0);
    let d = [ap[0] - t * ab[0], ap[1] - t * ab[1]];
    (d[0] * d[0] + d[1] * d[1]).sqrt()
}

/// The location of the current contact (mean of its points) on the first-touched phalanx.
fn location(contacts: &[ContactPoint], distal: bool) -> Option<f64> {
    let ks: Vec<f64> = contacts
        .iter()
        .filter(|c| c.distal == distal)
        .map(|c| c.k_m)
        .collect();
    (!ks.is_empty()).then(|| ks.iter().sum::<f64>() / ks.len() as f64)
}

/// Runs the grasp. None if the object cannot be placed.
pub fn run(spec: &GraspSpec) -> Option<Recording> {
    let object = place(spec.target)?;
    let mut finger = Finger::new(spec.finger, object, spec.engine);
    let dt = spec.engine.dt_s;
    let steps_per_ms = (1.0e-3 / dt).round() as usize;
    assert!(
        (steps_per_ms as f64 * dt - 1.0e-3).abs() < 1e-12,
        "dt must divide 1 ms"
    );
    let mut samples = Vec::new();
    let mut truth = Truth {
        phalanx: "none",
        k_c_m: None,
        k_end_m: None,
        t_contact_s: None,
        theta_a_c_rad: None,
        both_phalanges: false,
        contact_losses: 0,
    };
    let mut noticed: Option<(f64, f64)> = None; // (time, command) when the rise starts
    let mut end_s = f64::INFINITY;
    let mut in_contact = false;
    let mut max_gap: f64 = 0.0;
    let mut step = 0usize;
    // A free-motion ramp that never meets its object gives up at this torque.
    let give_up_nm = 2.0;
    loop {
        let t = step as f64 * dt;
        if step % steps_per_ms == 0 {
            samples.push(Sample {
                t_s: t,
                theta_a_rad: finger.theta_a_rad(),
                torque_nm: finger.motor_nm(),
            });
            max_gap = max_gap.max(finger.loop_gap_m());
            if t >= end_s - 1e-9 {
                break;
            }
        }
        // Command for the coming step.
        let approach = (spec.ramp_nm_per_s * (t - 0.1)).max(0.0);
        let command = match noticed {
            Some((t_n, base)) => {
                let frac = if spec.rise_s > 0.0 {
                    ((t - t_n) / spec.rise_s).clamp(0.0, 1.0)
                } else {
                    1.0
                };
                base + spec.delta_ta_nm * frac
            }
            None => match spec.target {
                Target::None => approach.min(NO_OBJECT_TORQUE_NM),
                Target::Object { .. } => approach,
            },
        };
        if matches!(spec.target, Target::None)
            && end_s.is_infinite()
            && approach >= NO_OBJECT_TORQUE_NM
        {
            end_s = 0.1 + NO_OBJECT_TORQUE_NM / spec.ramp_nm_per_s + 0.5;
        }
        if noticed.is_none() && approach > give_up_nm {
            return None;
        }
        finger.step(command);
        step += 1;

        let contacts = finger.contacts();
        let touching = !contacts.is_empty();
        if touching && contacts.iter().any(|c| c.distal) && contacts.iter().any(|c| !c.distal) {
            truth.both_phalanges = true;
        }
        if touching && truth.t_contact_s.is_none() {
            let distal = contacts.iter().any(|c| c.distal);
            truth.phalanx = if distal { "distal" } else { "proximal" };
            truth.k_c_m = location(&contacts, distal);
            truth.t_contact_s = Some(step as f64 * dt);
            truth.theta_a_c_rad = Some(finger.theta_a_rad());
        }
        if in_contact && !touching {
            truth.contact_losses += 1;
        }
        in_contact = touching;
        if let Some(t_c) = truth.t_contact_s {
            let now = step as f64 * dt;
            if noticed.is_none() && now >= t_c + spec.detection_delay_s - 1e-12 {
                noticed = Some((now, command));
                // End on a whole millisecond.
                end_s = ((now + spec.rise_s + spec.hold_s) * 1e3).ceil() * 1e-3;
            }
            if touching {
                truth.k_end_m = location(&contacts, truth.phalanx == "distal");
            }
        }
    }
    Some(Recording {
        samples,
        truth,
        max_loop_gap_m: max_gap,
    })
}

/// A deterministic generator (SplitMix64) for the sensor noise, so that traces are reproducible.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn gauss(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// The recording as the CSV a board would log: `t_s,theta_a_rad,torque_nm`, θa absolute (the
/// encoder is zeroed at rest and θa,rest added), with the sensor's quantisation and noise.
pub fn to_csv(rec: &Recording, sensor: &SensorSpec) -> String {
    let mut rng = Rng(sensor.seed);
    let rest = rec.samples.first().map_or(0.0, |s| s.theta_a_rad);
    let q = if sensor.counts_per_turn > 0 {
        2.0 * std::f64::consts::PI / sensor.counts_per_turn as f64
    } else {
        0.0
    };
    let phase = rng.uniform();
    let mut out = String::from("t_s,theta_a_rad,torque_nm\n");
    for s in &rec.samples {
        let theta = if q > 0.0 {
            rest + ((s.theta_a_rad - rest) / q + phase).floor() * q
        } else {
            s.theta_a_rad
        };
        let torque = s.torque_nm + sensor.torque_offset_nm + sensor.torque_sigma_nm * rng.gauss();
        let _ = writeln!(out, "{:.3},{:.9},{:.7}", s.t_s, theta, torque);
    }
    out
}

fn opt(x: Option<f64>) -> String {
    x.map_or_else(|| "null".to_string(), |v| format!("{v:.9}"))
}

/// The JSON ground truth, with the same fields as the shared sample traces.
pub fn to_json(id: &str, level: &str, spec: &GraspSpec, rec: &Recording) -> String {
    let t = &rec.truth;
    let (radius, expected) = match spec.target {
        Target::None => (0.0, "none"),
        Target::Object {
            radius_m, distal, ..
        } => (radius_m, if distal { "distal" } else { "proximal" }),
    };
    let distal = t.phalanx == "distal";
    format!(
        concat!(
            "{{\n  \"id\": \"{}\",\n  \"source\": \"rapier2d dynamic simulator (dynsim)\",\n",
            "  \"level\": \"{}\",\n  \"expected\": \"{}\",\n  \"truth\": {{\n",
            "    \"k2_c_m\": {},\n    \"k2_end_m\": {},\n    \"phalanx\": \"{}\",\n",
            "    \"radius_m\": {},\n    \"delta_ta_nm\": {},\n    \"t_contact_s\": {},\n",
            "    \"theta_a_c_rad\": {}\n  }},\n  \"contact_friction_mu\": {},\n",
            "  \"drive_inertia_kgm2\": {},\n  \"drive_coulomb_nm\": {},\n  \"detection_delay_s\": {}\n}}\n"
        ),
        id,
        level,
        expected,
        opt(if distal { t.k_c_m } else { None }),
        opt(if distal { t.k_end_m } else { None }),
        t.phalanx,
        radius,
        if matches!(spec.target, Target::None) {
            "null".to_string()
        } else {
            format!("{}", spec.delta_ta_nm)
        },
        opt(t.t_contact_s),
        opt(t.theta_a_c_rad),
        spec.finger.contact_mu,
        spec.finger.drive_inertia_kgm2,
        spec.finger.friction.coulomb_nm,
        spec.detection_delay_s,
    )
}
