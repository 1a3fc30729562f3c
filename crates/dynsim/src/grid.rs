//! The grids of grasps the binary writes and the tests replay: vertex and cylinders × k2,c ×
//! ΔT_a × contact µ × drive inertia × drive friction off (`ideal`, no sensor noise) / realistic
//! (`default`: encoder, torque noise and offset), plus no-object and proximal negatives.

use crate::grasp::{GraspSpec, SensorSpec, Target};
use crate::linkage::L2_M;
use crate::sim::{DriveFriction, EngineSettings, FingerParams};

/// Proximal angle at first contact for the distal grid (the Table 2 pose), rad.
pub const THETA1_C_RAD: f64 = 1.2797;

/// The axes of a grid.
pub struct Axes {
    /// Object radii, m (0: vertex).
    pub radii_m: &'static [f64],
    /// First-contact locations, fractions of l2.
    pub k2_frac: &'static [f64],
    /// Torque rises after the contact, N·m.
    pub delta_ta_nm: &'static [f64],
    /// Contact friction coefficients.
    pub mu: &'static [f64],
    /// Drive inertias at the crank, kg·m².
    pub inertia_kgm2: &'static [f64],
    /// Proximal angles at first contact, rad (the object placed where the finger, closing
    /// freely, meets it at this θ1).
    pub theta1_c_rad: &'static [f64],
}

/// The grid (608 traces, about 11 min in release on one core).
pub const FULL: Axes = Axes {
    radii_m: &[0.0, 0.005, 0.01, 0.02, 0.05],
    k2_frac: &[0.2, 0.35, 0.5, 0.65, 0.8],
    delta_ta_nm: &[0.2, 0.5, 0.8],
    mu: &[0.0, 0.3],
    inertia_kgm2: &[5.0e-4, 5.0e-3],
    theta1_c_rad: &[THETA1_C_RAD],
};

/// Drive inertias across the range a recording may hold (1e-4 … 0.1 kg·m² at the crank),
/// at one ΔT_a: vertex, R 1 and 5 cm × k2,c 0.35 / 0.65 l2 × µ 0 / 0.3 (84 traces). The
/// heaviest drive, on this grasp's open-loop torque ramp, hits the object at about 1.5 rad/s
/// and swings far past the contact and back: what it records has to be refused, not read.
pub const INERTIA: Axes = Axes {
    radii_m: &[0.0, 0.01, 0.05],
    k2_frac: &[0.35, 0.65],
    delta_ta_nm: &[0.5],
    mu: &[0.0, 0.3],
    inertia_kgm2: &[1.0e-4, 2.0e-2, 1.0e-1],
    theta1_c_rad: &[THETA1_C_RAD],
};

/// Other poses at first contact than the Table 2 one: the finger meets the object earlier
/// (θ1,c 1.10 rad) or later (1.35 rad) in its closing, at ΔT_a 0.3 and 0.6 N·m, with contact
/// friction up to the estimator's prior bound (µ 0.4), on the light drive (148 traces).
pub const POSE: Axes = Axes {
    radii_m: &[0.0, 0.0075, 0.035],
    k2_frac: &[0.27, 0.5, 0.72],
    delta_ta_nm: &[0.3, 0.6],
    mu: &[0.0, 0.4],
    inertia_kgm2: &[5.0e-4],
    theta1_c_rad: &[1.10, 1.35],
};

/// A slice of the same kinds (44 traces).
pub const SMALL: Axes = Axes {
    radii_m: &[0.0, 0.01, 0.05],
    k2_frac: &[0.2, 0.5, 0.8],
    delta_ta_nm: &[0.5],
    mu: &[0.3],
    inertia_kgm2: &[5.0e-4, 5.0e-3],
    theta1_c_rad: &[THETA1_C_RAD],
};

/// One grasp of a grid.
pub struct Case {
    /// File stem, e.g. `rap000_vtx_k20_dT05_mu03_J5e-4__ideal`.
    pub id: String,
    /// `ideal` (friction off, perfect sensor) or `default` (realistic friction and sensor).
    pub level: &'static str,
    /// The grasp.
    pub spec: GraspSpec,
    /// The sensor effects of its recording.
    pub sensor: SensorSpec,
}

impl Case {
    /// The id and sensor of the case's recording with sensor draw `draw`
    /// ([`SensorSpec::redrawn`]): draw 0 is the case itself, draw i its id with `__r<i>`.
    pub fn drawn(&self, draw: u64) -> (String, SensorSpec) {
        if draw == 0 {
            (self.id.clone(), self.sensor)
        } else {
            (format!("{}__r{draw}", self.id), self.sensor.redrawn(draw))
        }
    }
}

fn spec(target: Target, delta: f64, mu: f64, inertia: f64, realistic: bool, n: usize) -> GraspSpec {
    GraspSpec {
        target,
        delta_ta_nm: delta,
        rise_s: 0.2,
        // 5, 10, 15, 20 ms in turn.
        detection_delay_s: 0.005 * (1 + n % 4) as f64,
        hold_s: 0.3,
        ramp_nm_per_s: 0.5,
        finger: FingerParams {
            drive_inertia_kgm2: inertia,
            friction: if realistic {
                DriveFriction::REALISTIC
            } else {
                DriveFriction::OFF
            },
            contact_mu: mu,
            torque_lag_s: 5.0e-4,
        },
        engine: EngineSettings::default(),
    }
}

fn sensor(realistic: bool, n: usize) -> SensorSpec {
    if realistic {
        SensorSpec {
            counts_per_turn: 16384,
            torque_sigma_nm: 0.004,
            torque_offset_nm: 0.003,
            seed: 1000 + n as u64,
        }
    } else {
        SensorSpec::IDEAL
    }
}

/// Every grasp of a grid, distal positives first, then the negatives.
pub fn cases(axes: &Axes) -> Vec<Case> {
    let mut out = Vec::new();
    let cells = axes.radii_m.iter().flat_map(|&r| {
        axes.k2_frac.iter().flat_map(move |&k| {
            axes.delta_ta_nm.iter().flat_map(move |&d| {
                axes.mu.iter().flat_map(move |&mu| {
                    axes.inertia_kgm2.iter().flat_map(move |&j| {
                        axes.theta1_c_rad
                            .iter()
                            .map(move |&th| (r, k, d, mu, j, th))
                    })
                })
            })
        })
    });
    for (r, k, d, mu, j, th) in cells {
        for realistic in [false, true] {
            let n = out.len();
            let obj = if r > 0.0 {
                format!("R{:04.1}mm", r * 1e3).replace('.', "p")
            } else {
                "vtx".to_string()
            };
            // The Table 2 pose is the grids' default and goes unnamed (the samples' style).
            let pose = if th == THETA1_C_RAD {
                String::new()
            } else {
                format!("_th{:03}", (th * 100.0).round())
            };
            let level = if realistic { "default" } else { "ideal" };
            let target = Target::Object {
                radius_m: r,
                k_m: k * L2_M,
                distal: true,
                theta1_c_rad: th,
            };
            out.push(Case {
                id: format!(
                    "rap{n:03}_{obj}_k{:02}_dT{:02}_mu{:02}_J{:.0e}{pose}__{level}",
                    (k * 100.0).round(),
                    (d * 10.0).round(),
                    (mu * 10.0).round(),
                    j
                ),
                level,
                spec: spec(target, d, mu, j, realistic, n),
                sensor: sensor(realistic, n),
            });
        }
    }
    // Negatives: no object, and a proximal contact (R 7.5 mm at k1 = 55 mm, θ1,c = 1.05).
    for &j in axes.inertia_kgm2 {
        for realistic in [false, true] {
            let n = out.len();
            let level = if realistic { "default" } else { "ideal" };
            out.push(Case {
                id: format!("rap{n:03}_neg_noobject_J{j:.0e}__{level}"),
                level,
                spec: spec(Target::None, 0.0, 0.3, j, realistic, n),
                sensor: sensor(realistic, n),
            });
            let n = out.len();
            let target = Target::Object {
                radius_m: 0.0075,
                k_m: 0.055,
                distal: false,
                theta1_c_rad: 1.05,
            };
            out.push(Case {
                id: format!("rap{n:03}_neg_proximal_R07p5mm_k1_55mm_J{j:.0e}__{level}"),
                level,
                spec: spec(target, 0.5, 0.3, j, realistic, n),
                sensor: sensor(realistic, n),
            });
        }
    }
    out
}
