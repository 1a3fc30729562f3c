//! Writes a grid of engine-simulated grasp traces: `<id>.csv` (t_s,theta_a_rad,torque_nm at 1 kHz)
//! and `<id>.json` (ground truth) per grasp, plus `index.csv` listing them.
//!
//! `dynsim --out DIR [--grid small|full]`; progress on stderr.

use dynsim::grasp::{self, GraspSpec, SensorSpec, Target};
use dynsim::linkage::L2_M;
use dynsim::sim::{DriveFriction, EngineSettings, FingerParams};
use std::io::Write as _;
use std::path::PathBuf;

/// Proximal angle at first contact for the distal grid (the Table 2 pose), rad.
const THETA1_C_RAD: f64 = 1.2797;

struct Axes {
    radii_m: &'static [f64],
    k2_frac: &'static [f64],
    delta_ta_nm: &'static [f64],
    mu: &'static [f64],
    inertia_kgm2: &'static [f64],
}

const FULL: Axes = Axes {
    radii_m: &[0.0, 0.005, 0.01, 0.02, 0.05],
    k2_frac: &[0.2, 0.35, 0.5, 0.65, 0.8],
    delta_ta_nm: &[0.2, 0.5, 0.8],
    mu: &[0.0, 0.3],
    inertia_kgm2: &[5.0e-4, 5.0e-3],
};

const SMALL: Axes = Axes {
    radii_m: &[0.0, 0.01, 0.05],
    k2_frac: &[0.2, 0.5, 0.8],
    delta_ta_nm: &[0.5],
    mu: &[0.3],
    inertia_kgm2: &[5.0e-4, 5.0e-3],
};

struct Case {
    id: String,
    level: &'static str,
    spec: GraspSpec,
    sensor: SensorSpec,
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

fn cases(axes: &Axes) -> Vec<Case> {
    let mut out = Vec::new();
    for &r in axes.radii_m {
        for &k in axes.k2_frac {
            for &d in axes.delta_ta_nm {
                for &mu in axes.mu {
                    for &j in axes.inertia_kgm2 {
                        for realistic in [false, true] {
                            let n = out.len();
                            let obj = if r > 0.0 {
                                format!("R{:04.1}mm", r * 1e3).replace('.', "p")
                            } else {
                                "vtx".to_string()
                            };
                            let level = if realistic { "default" } else { "ideal" };
                            let target = Target::Object {
                                radius_m: r,
                                k_m: k * L2_M,
                                distal: true,
                                theta1_c_rad: THETA1_C_RAD,
                            };
                            out.push(Case {
                                id: format!(
                                    "rap{n:03}_{obj}_k{:02}_dT{:02}_mu{:02}_J{:.0e}__{level}",
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
                }
            }
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

fn usage() -> ! {
    eprintln!("usage: dynsim --out DIR [--grid small|full]");
    std::process::exit(2);
}

fn main() {
    let mut out: Option<PathBuf> = None;
    let mut grid = "small".to_string();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--out" => out = Some(args.next().unwrap_or_else(|| usage()).into()),
            "--grid" => grid = args.next().unwrap_or_else(|| usage()),
            _ => usage(),
        }
    }
    let Some(dir) = out else { usage() };
    let axes = match grid.as_str() {
        "small" => &SMALL,
        "full" => &FULL,
        _ => usage(),
    };
    std::fs::create_dir_all(&dir).expect("create the output directory");
    let cases = cases(axes);
    let start = std::time::Instant::now();
    let mut index =
        String::from("id,expected,phalanx,k2_c_m,k2_end_m,contact_losses,max_loop_gap_m\n");
    let (mut written, mut skipped) = (0, 0);
    for (i, c) in cases.iter().enumerate() {
        eprint!("\r[{}/{}] {:<60}", i + 1, cases.len(), c.id);
        let _ = std::io::stderr().flush();
        let Some(rec) = grasp::run(&c.spec) else {
            eprintln!(
                "\nskipped {}: the object cannot be placed or is never reached",
                c.id
            );
            skipped += 1;
            continue;
        };
        if rec.truth.both_phalanges {
            eprintln!("\nskipped {}: both phalanges touched", c.id);
            skipped += 1;
            continue;
        }
        let csv = grasp::to_csv(&rec, &c.sensor);
        let json = grasp::to_json(&c.id, c.level, &c.spec, &rec);
        std::fs::write(dir.join(format!("{}.csv", c.id)), csv).expect("write csv");
        std::fs::write(dir.join(format!("{}.json", c.id)), json).expect("write json");
        let f = |x: Option<f64>| x.map_or(String::new(), |v| format!("{v:.6}"));
        index.push_str(&format!(
            "{},{},{},{},{},{},{:.3e}\n",
            c.id,
            match c.spec.target {
                Target::None => "none",
                Target::Object { distal: true, .. } => "distal",
                Target::Object { distal: false, .. } => "proximal",
            },
            rec.truth.phalanx,
            f(rec.truth.k_c_m),
            f(rec.truth.k_end_m),
            rec.truth.contact_losses,
            rec.max_loop_gap_m
        ));
        written += 1;
    }
    std::fs::write(dir.join("index.csv"), index).expect("write index");
    eprintln!(
        "\n{written} traces written to {}, {skipped} skipped, in {:.1} s",
        dir.display(),
        start.elapsed().as_secs_f64()
    );
}
