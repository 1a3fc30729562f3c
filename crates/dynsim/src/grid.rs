//! The grids of grasps the binary writes and the tests replay: vertex and cylinders × k2,c ×
//! ΔT_a × contact µ × drive inertia × pose at first contact × the torque step's protocol ×
//! drive friction off (`ideal`, no sensor noise) / realistic (`default`: encoder, torque noise
//! and offset), plus no-object and proximal negatives.

use crate::grasp::{GraspSpec, SensorSpec, Target};
use crate::linkage::L2_M;
use crate::sim::{DriveFriction, EngineSettings, FingerParams};

/// Proximal angle at first contact for the distal grid (the Table 2 pose), rad.
pub const THETA1_C_RAD: f64 = 1.2797;

/// How the recording's torque step follows the contact: the rise of ΔT_a, when it starts and
/// how long it is held.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Protocol {
    /// Duration of the rise (a ramp; 0 is a step), s.
    pub rise_s: f64,
    /// From the physical first contact to the start of the rise, s; `None`: 5, 10, 15 or
    /// 20 ms (the sample recordings' spread), in turn along every axis of the grid and both
    /// friction levels.
    pub delay_s: Option<f64>,
    /// Hold after the rise, s.
    pub hold_s: f64,
}

impl Protocol {
    /// The sample recordings' `dyn…` protocol, the grids' default: a 0.2 s rise 5–20 ms after
    /// the contact, held 0.3 s.
    pub const SAMPLES: Protocol = Protocol {
        rise_s: 0.2,
        delay_s: None,
        hold_s: 0.3,
    };
}

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
    /// Torque-step protocols.
    pub protocols: &'static [Protocol],
}

/// The grid (608 traces, about 11 min in release on one core).
pub const FULL: Axes = Axes {
    radii_m: &[0.0, 0.005, 0.01, 0.02, 0.05],
    k2_frac: &[0.2, 0.35, 0.5, 0.65, 0.8],
    delta_ta_nm: &[0.2, 0.5, 0.8],
    mu: &[0.0, 0.3],
    inertia_kgm2: &[5.0e-4, 5.0e-3],
    theta1_c_rad: &[THETA1_C_RAD],
    protocols: &[Protocol::SAMPLES],
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
    protocols: &[Protocol::SAMPLES],
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
    protocols: &[Protocol::SAMPLES],
};

/// A slice of the same kinds (44 traces).
pub const SMALL: Axes = Axes {
    radii_m: &[0.0, 0.01, 0.05],
    k2_frac: &[0.2, 0.5, 0.8],
    delta_ta_nm: &[0.5],
    mu: &[0.3],
    inertia_kgm2: &[5.0e-4, 5.0e-3],
    theta1_c_rad: &[THETA1_C_RAD],
    protocols: &[Protocol::SAMPLES],
};

/// The torque step as other recordings may hold it (the accuracy issue's range): a step, a
/// 0.05 s or a 1 s ramp, starting at the contact or 30 ms after it, held only 0.2 s; vertex,
/// R 1 and 5 cm × k2,c 0.35 / 0.65 l2 × ΔT_a 0.2 / 0.8 N·m × µ 0 / 0.3 × both drive
/// inertias, plus the negatives (624 traces; the ids name the protocol,
/// `_rise1000_del30_hold200`).
pub const PROTOCOL: Axes = Axes {
    radii_m: &[0.0, 0.01, 0.05],
    k2_frac: &[0.35, 0.65],
    delta_ta_nm: &[0.2, 0.8],
    mu: &[0.0, 0.3],
    inertia_kgm2: &[5.0e-4, 5.0e-3],
    theta1_c_rad: &[THETA1_C_RAD],
    protocols: &[
        Protocol {
            rise_s: 0.0,
            delay_s: Some(0.0),
            hold_s: 0.2,
        },
        Protocol {
            rise_s: 0.0,
            delay_s: Some(0.03),
            hold_s: 0.2,
        },
        Protocol {
            rise_s: 0.05,
            delay_s: Some(0.0),
            hold_s: 0.2,
        },
        Protocol {
            rise_s: 0.05,
            delay_s: Some(0.03),
            hold_s: 0.2,
        },
        Protocol {
            rise_s: 1.0,
            delay_s: Some(0.0),
            hold_s: 0.2,
        },
        Protocol {
            rise_s: 1.0,
            delay_s: Some(0.03),
            hold_s: 0.2,
        },
    ],
};

/// One grasp of a grid.
#[derive(Clone, Debug)]
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

fn spec(
    target: Target,
    delta: f64,
    mu: f64,
    inertia: f64,
    realistic: bool,
    turn: usize,
    protocol: &Protocol,
) -> GraspSpec {
    GraspSpec {
        target,
        delta_ta_nm: delta,
        rise_s: protocol.rise_s,
        detection_delay_s: protocol.delay_s.unwrap_or(0.005 * (1 + turn % 4) as f64),
        hold_s: protocol.hold_s,
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

/// The id suffix of a protocol: none for the samples' (every older grid's ids stay as they
/// were), else rise, delay and hold in ms.
fn protocol_name(p: &Protocol) -> String {
    if *p == Protocol::SAMPLES {
        return String::new();
    }
    let ms = |s: f64| (s * 1e3).round() as u32;
    format!(
        "_rise{:03}_del{:02}_hold{:03}",
        ms(p.rise_s),
        p.delay_s.map_or(99, ms),
        ms(p.hold_s)
    )
}

/// Where `v` stands on `axis` (0 if it does not).
fn index_in<T: PartialEq>(axis: &[T], v: &T) -> usize {
    axis.iter().position(|a| a == v).unwrap_or(0)
}

/// Every grasp of a grid, distal positives first, then the negatives.
pub fn cases(axes: &Axes) -> Vec<Case> {
    let mut out = Vec::new();
    let cells = axes.radii_m.iter().flat_map(|&r| {
        axes.k2_frac.iter().flat_map(move |&k| {
            axes.delta_ta_nm.iter().flat_map(move |&d| {
                axes.mu.iter().flat_map(move |&mu| {
                    axes.inertia_kgm2.iter().flat_map(move |&j| {
                        axes.theta1_c_rad.iter().flat_map(move |&th| {
                            axes.protocols.iter().map(move |&p| (r, k, d, mu, j, th, p))
                        })
                    })
                })
            })
        })
    });
    for (r, k, d, mu, j, th, p) in cells {
        // The sum of the cell's axis indices picks the default delay (see `spec`): it turns
        // along every axis, so no axis value and no friction level keeps to some delays.
        let turn = index_in(axes.radii_m, &r)
            + index_in(axes.k2_frac, &k)
            + index_in(axes.delta_ta_nm, &d)
            + index_in(axes.mu, &mu)
            + index_in(axes.inertia_kgm2, &j)
            + index_in(axes.theta1_c_rad, &th)
            + index_in(axes.protocols, &p);
        for realistic in [false, true] {
            let n = out.len();
            let turn = turn + usize::from(realistic);
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
            let pose = pose + &protocol_name(&p);
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
                spec: spec(target, d, mu, j, realistic, turn, &p),
                sensor: sensor(realistic, n),
            });
        }
    }
    // Negatives: no object, and a proximal contact (R 7.5 mm at k1 = 55 mm, θ1,c = 1.05).
    for (j, p) in axes
        .inertia_kgm2
        .iter()
        .flat_map(|&j| axes.protocols.iter().map(move |p| (j, p)))
    {
        let turn = index_in(axes.inertia_kgm2, &j) + index_in(axes.protocols, p);
        let proto = protocol_name(p);
        for realistic in [false, true] {
            let n = out.len();
            let turn = turn + usize::from(realistic);
            let level = if realistic { "default" } else { "ideal" };
            out.push(Case {
                id: format!("rap{n:03}_neg_noobject_J{j:.0e}{proto}__{level}"),
                level,
                spec: spec(Target::None, 0.0, 0.3, j, realistic, turn, p),
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
                id: format!("rap{n:03}_neg_proximal_R07p5mm_k1_55mm_J{j:.0e}{proto}__{level}"),
                level,
                spec: spec(target, 0.5, 0.3, j, realistic, turn, p),
                sensor: sensor(realistic, n),
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The samples' spread of delays reaches every friction level, drive inertia and contact µ
    /// alike: each combination of the three holds each delay within a grasp of a quarter of it.
    #[test]
    fn default_delays_rotate_along_every_axis() {
        let full = cases(&FULL);
        let mut counts = std::collections::BTreeMap::new();
        for c in full.iter().filter(|c| c.spec.delta_ta_nm > 0.0) {
            let f = &c.spec.finger;
            let key = (
                c.level,
                f.drive_inertia_kgm2.to_bits(),
                f.contact_mu.to_bits(),
            );
            let ms = (c.spec.detection_delay_s * 1e3).round() as usize;
            assert!([5, 10, 15, 20].contains(&ms), "{}: {ms} ms", c.id);
            counts.entry(key).or_insert([0usize; 4])[ms / 5 - 1] += 1;
        }
        assert_eq!(counts.len(), 8);
        for (key, n) in &counts {
            let total: usize = n.iter().sum();
            for &k in n {
                assert!(4 * k + 4 >= total && 4 * k <= total + 4, "{key:?}: {n:?}");
            }
        }
    }

    /// The protocol axis leaves every older grid's grasps and ids as they were (results and
    /// notes cite them), and names the others' protocol in the id and the spec.
    #[test]
    fn grids_keep_their_ids_and_protocol_grasps_carry_theirs() {
        let full = cases(&FULL);
        assert_eq!(full.len(), 608);
        assert_eq!(full[193].id, "rap193_R05p0mm_k65_dT02_mu00_J5e-4__default");
        assert_eq!(
            full[607].id,
            "rap607_neg_proximal_R07p5mm_k1_55mm_J5e-3__default"
        );
        assert!(full
            .iter()
            .all(|c| c.spec.rise_s == 0.2 && c.spec.hold_s == 0.3));
        let proto = cases(&PROTOCOL);
        assert_eq!(proto.len(), 3 * 2 * 2 * 2 * 2 * 6 * 2 + 2 * 6 * 4);
        let c = proto
            .iter()
            .find(|c| c.id.contains("_rise1000_del30_hold200__"))
            .expect("a 1 s ramp 30 ms after the contact");
        assert_eq!(
            (c.spec.rise_s, c.spec.detection_delay_s, c.spec.hold_s),
            (1.0, 0.03, 0.2)
        );
        let step = proto
            .iter()
            .find(|c| c.id.contains("_rise000_del00_"))
            .expect("a step at the contact");
        assert_eq!((step.spec.rise_s, step.spec.detection_delay_s), (0.0, 0.0));
    }
}
