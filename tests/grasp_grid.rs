//! The grid: vertex and cylinders (R = 0.5, 1, 2.5, 5 cm) × contacts at k2 = 0.1…0.9 l2 ×
//! ΔT_a = 0.1, 0.2, 0.5, 0.8 N·m, with the plant ideal (noise, friction, backlash, gear
//! losses and sensor errors off) and at its realistic defaults. Every grasp is the real
//! controller closed loop against the plant; the contact is made at θ1,c = 1.2797 rad.
//!
//! Print the tables: `cargo test --test grasp_grid -- --nocapture`
//!
//! References, all independent of the controller: the contact location the plant placed
//! (initial), the plant's true contact location when the controller said "settled" (final),
//! and the quasi-static frictionless two-point estimate (`plant::quasi_static_path` + the f64
//! `pts` model), which is what the paper's method gives with perfect sensing.
mod common;

use common::*;
use grasp::{FaultReason, State};
use plant::path::ContactSpec;
use plant::scene::ObjectSpec;
use plant::{Phalanx, Scene};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

const THETA1_C: f64 = 1.2797;
const RADII: [f64; 5] = [0.0, 0.005, 0.01, 0.025, 0.05];
const K2_FRACS: [f64; 9] = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9];
const DTAS: [f64; 4] = [0.1, 0.2, 0.5, 0.8];
/// Control period of the grid runs (s).
const GRID_DT_S: f64 = 2e-4;

#[derive(Clone, Copy, Debug)]
struct Case {
    realistic: bool,
    radius: f64,
    k2: f64,
    dta: f64,
}

#[derive(Clone, Copy, Debug)]
enum Res {
    /// Estimate (m), final true location (m), quasi-static reference estimate (m).
    Ok {
        k2_hat: f64,
        k2_final: f64,
        k2_ref: Option<f64>,
        /// Contact detection delay: controller detection − plant first contact (s).
        delay_s: Option<f64>,
    },
    /// Proximal / ambiguous classification.
    Class(grasp::Located),
    /// The controller ended in a fault (reason kind), with what the plant saw.
    Fault(FaultReason, bool),
    /// Something else (state).
    Other(State),
}

fn scene(c: &Case) -> Scene {
    let s = Scene {
        name: "grid",
        object: ObjectSpec::Touching(ContactSpec {
            theta1_c_rad: THETA1_C,
            phalanx: Phalanx::Distal,
            k_c_m: c.k2,
            radius_m: c.radius,
        }),
        // 5 kHz control instead of the plant's default 10 kHz: half the cost, same physics
        // (the controller's settings are in seconds; the plant substeps 8× per period).
        dt_s: GRID_DT_S,
        ..Scene::DEFAULT
    };
    if c.realistic {
        s
    } else {
        s.ideal()
    }
}

fn reference(c: &Case) -> Option<f64> {
    let spec = ContactSpec {
        theta1_c_rad: THETA1_C,
        phalanx: Phalanx::Distal,
        k_c_m: c.k2,
        radius_m: c.radius,
    };
    let p = plant::quasi_static_path(&plant::FingerGeom::PAPER, &spec, c.dta).ok()?;
    let m = pts::Model::<f64>::paper().ok()?;
    let e = m
        .estimate_two_point(p.theta_a_c_rad, p.ta_c_nm, p.theta_a_rad, p.ta_nm)
        .ok()?;
    e.contact.k2
}

/// The path fit (`Estimator::PathFit`) on the same request, f64 model: k2 (m) or why not.
type Pf = Option<Result<f64, &'static str>>;

fn run_case(c: &Case) -> (Res, Pf) {
    let s = scene(c);
    // The grid measures the paper's two-point method in closed loop, on the static points
    // the seated controller takes (the path fit is run on the same request below).
    let cfg = grasp::ControllerConfig {
        estimator: grasp::Estimator::TwoPoint,
        ..seated(&s, c.dta)
    };
    let o = run(&s, cfg, 20.0, 0.0, |_, _, _| {});
    let pf = o.request.as_ref().map(|req| {
        let m = pts::Model::<f64>::paper().expect("paper model");
        match grasp::estimate::path_fit(&m, &cfg.drive, req) {
            Ok(r) => r.k2_um.map(|k| f64::from(k) * 1e-6).ok_or("proximal"),
            Err(e) => Err(e.kind()),
        }
    });
    let res = match (o.state, o.estimate) {
        (State::Holding, Some(Ok(r))) => match (r.located, r.k2_um) {
            (grasp::Located::Distal, Some(k)) => Res::Ok {
                k2_hat: f64::from(k) * 1e-6,
                k2_final: o.truth_settled.map(|t| t.k_m).unwrap_or(f64::NAN),
                k2_ref: reference(c),
                delay_s: o
                    .first_contact
                    .zip(o.detected_s)
                    .map(|((tc, _), td)| td - tc),
            },
            (l, _) => Res::Class(l),
        },
        (State::Fault(f), _) => {
            assert!(o.bridge_off, "{c:?}: fault {f:?} with the bridge on");
            Res::Fault(f, o.second_contact_s.is_some())
        }
        (s, _) => Res::Other(s),
    };
    (res, pf)
}

fn cell(r: &Res, k2: f64) -> String {
    match r {
        Res::Ok {
            k2_hat, k2_final, ..
        } => format!(
            "{:+5.1}/{:+5.1}",
            (k2_hat - k2) / L2 * 100.0,
            (k2_hat - k2_final) / L2 * 100.0
        ),
        Res::Class(l) => format!("{:>11}", format!("{l:?}")),
        Res::Fault(f, plant_second) => {
            let k = f.kind();
            format!(
                "{:>11}",
                format!(
                    "{}{}",
                    &k[..k.len().min(9)],
                    if *plant_second { "*" } else { "" }
                )
            )
        }
        Res::Other(s) => format!("{:>11}", format!("{s:?}")),
    }
}

#[test]
fn grid_of_objects_locations_and_steps() {
    let mut cases = Vec::new();
    for realistic in [false, true] {
        for &radius in &RADII {
            for &dta in &DTAS {
                for &f in &K2_FRACS {
                    cases.push(Case {
                        realistic,
                        radius,
                        k2: f * L2,
                        dta,
                    });
                }
            }
        }
    }
    let results: Mutex<Vec<Option<(Res, Pf)>>> = Mutex::new(vec![None; cases.len()]);
    let next = AtomicUsize::new(0);
    let threads = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(2)
        .clamp(1, 4);
    let t0 = std::time::Instant::now();
    std::thread::scope(|sc| {
        for _ in 0..threads {
            sc.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(c) = cases.get(i) else { break };
                let r = run_case(c);
                results.lock().unwrap()[i] = Some(r);
            });
        }
    });
    let (results, pathfit): (Vec<Res>, Vec<Pf>) = results
        .into_inner()
        .unwrap()
        .into_iter()
        .map(|r| r.expect("every case ran"))
        .unzip();
    println!(
        "\n{} closed-loop grasps in {:.1} s on {threads} threads",
        cases.len(),
        t0.elapsed().as_secs_f64()
    );
    println!(
        "cells: error of k2_hat in % of l2 vs the initial / the final contact location; \
         faults by reason (* = the plant saw a second contact)"
    );

    // Per-table summaries: (max |e_init|, max |e_final|, max |closed loop − quasi-static ref|, n ok).
    let mut summary = Vec::new();
    for realistic in [false, true] {
        println!(
            "\n== plant {} ==",
            if realistic {
                "realistic defaults (noise, friction, backlash, gear losses, sensor errors)"
            } else {
                "ideal (noise and friction off)"
            }
        );
        print!("{:>14}", "object  ΔT_a");
        for f in K2_FRACS {
            print!(" {:>11}", format!("k2={:.1}l2", f));
        }
        println!();
        for &radius in &RADII {
            for &dta in &DTAS {
                let name = if radius == 0.0 {
                    "vertex".to_string()
                } else {
                    format!("R={:.1}cm", radius * 100.0)
                };
                print!("{:>14}", format!("{name} {dta:.1}"));
                let mut m = (0.0f64, 0.0f64, 0.0f64, 0usize, 0usize);
                for (c, r) in cases.iter().zip(&results) {
                    if c.realistic != realistic || c.radius != radius || c.dta != dta {
                        continue;
                    }
                    print!(" {}", cell(r, c.k2));
                    m.4 += 1;
                    if let Res::Ok {
                        k2_hat,
                        k2_final,
                        k2_ref,
                        ..
                    } = r
                    {
                        m.0 = m.0.max(((k2_hat - c.k2) / L2 * 100.0).abs());
                        m.1 = m.1.max(((k2_hat - k2_final) / L2 * 100.0).abs());
                        if let Some(k) = k2_ref {
                            m.2 = m.2.max(((k2_hat - k) / L2 * 100.0).abs());
                        }
                        m.3 += 1;
                    }
                }
                println!();
                summary.push((realistic, radius, dta, m));
            }
        }
    }
    // The path fit on the same requests (every grasp that settled), error vs the initial
    // location; the two-point columns above for comparison.
    let mut pf_summary = Vec::new();
    for realistic in [false, true] {
        println!(
            "\n== path fit (Estimator::PathFit) on the same runs, plant {}: error vs initial (% of l2) ==",
            if realistic { "realistic" } else { "ideal" }
        );
        for &radius in &RADII {
            for &dta in &DTAS {
                let name = if radius == 0.0 {
                    "vertex".to_string()
                } else {
                    format!("R={:.1}cm", radius * 100.0)
                };
                print!("{:>14}", format!("{name} {dta:.1}"));
                let mut mx = 0.0f64;
                let mut n = 0usize;
                for (c, pf) in cases.iter().zip(&pathfit) {
                    if c.realistic != realistic || c.radius != radius || c.dta != dta {
                        continue;
                    }
                    match pf {
                        Some(Ok(k)) => {
                            let e = (k - c.k2) / L2 * 100.0;
                            mx = mx.max(e.abs());
                            n += 1;
                            print!(" {e:>+11.1}");
                        }
                        Some(Err(kind)) => print!(" {:>11}", &kind[..kind.len().min(11)]),
                        None => print!(" {:>11}", "-"),
                    }
                }
                println!();
                pf_summary.push((mx, n));
            }
        }
    }

    println!("\nmax |error| over the located contacts (% of l2):");
    println!(
        "{:>10} {:>8} {:>6} {:>9} {:>9} {:>12} {:>6} {:>12}",
        "plant", "object", "ΔT_a", "initial", "final", "vs q-static", "ok", "pathfit init"
    );
    for ((realistic, radius, dta, m), pf) in summary.iter().zip(&pf_summary) {
        println!(
            "{:>10} {:>8} {:>6.1} {:>9.1} {:>9.1} {:>12.2} {:>3}/{} {:>8.1} ({})",
            if *realistic { "realistic" } else { "ideal" },
            if *radius == 0.0 {
                "vertex".to_string()
            } else {
                format!("R={:.1}cm", radius * 100.0)
            },
            dta,
            m.0,
            m.1,
            m.2,
            m.3,
            m.4,
            pf.0,
            pf.1
        );
    }

    // Contact detection delay over every located grasp.
    for realistic in [false, true] {
        let d: Vec<f64> = cases
            .iter()
            .zip(&results)
            .filter(|(c, _)| c.realistic == realistic)
            .filter_map(|(_, r)| match r {
                Res::Ok { delay_s, .. } => *delay_s,
                _ => None,
            })
            .collect();
        let max = d.iter().cloned().fold(0.0, f64::max);
        let mean = d.iter().sum::<f64>() / d.len().max(1) as f64;
        println!(
            "contact detection delay ({}): mean {:.1} ms, max {:.1} ms over {} grasps",
            if realistic { "realistic" } else { "ideal" },
            mean * 1e3,
            max * 1e3,
            d.len()
        );
        // Window 10 × 4 ms samples, 2 confirmations, and the finger's inertia carrying it
        // ~10 mrad into the contact before the stiffness shows: measured ≤ 60 ms.
        assert!(max < 0.08, "detection delay {max} s");
        assert!(d.iter().all(|&x| x > 0.0), "detected before the contact");
    }

    // ---- Bounds, justified by the measured tables above (see the README quote). ----
    for (c, r) in cases.iter().zip(&results) {
        // Nothing ends anywhere but holding a located contact or a fault with a reason,
        // and every fault leaves the bridge off (checked by the harness state).
        assert!(
            matches!(r, Res::Ok { .. } | Res::Fault(..) | Res::Class(_)),
            "{c:?}: {r:?}"
        );
    }
    for (realistic, radius, dta, m) in &summary {
        let (e_init, e_final, e_ref, ok, n) = *m;
        // Measured (cargo test --test grasp_grid -- --nocapture), every static point of the
        // estimate taken after the drive is seen sliding forward: ideal, the closed loop is
        // within 4.9 / 1.44 / 0.56 / 0.52 % l2 of the quasi-static two-point estimate for
        // ΔT_a = 0.1 / 0.2 / 0.5 / 0.8 N·m (torque quantization 2.2 mN·m per ADC code without
        // noise to dither it, and the back-dating from the first loading point, weigh most on
        // the small steps); vs the final location within 5.1 / 2.5 / 3.6 / 6.0 %; vs the
        // initial one, the paper's bias, up to 21.3 % (R = 5 cm, ΔT_a = 0.8). Bounds keep a
        // margin over those.
        let (b_ref, b_final) = match dta {
            d if *d < 0.15 => (6.0, 6.5),
            d if *d < 0.35 => (2.0, 3.0),
            d if *d < 0.65 => (0.75, 4.5),
            _ => (0.75, 7.0),
        };
        if !realistic {
            assert!(
                e_ref <= b_ref,
                "ideal R={radius} ΔT={dta}: {e_ref} % l2 from the quasi-static estimate"
            );
            assert!(
                e_final <= b_final,
                "ideal R={radius} ΔT={dta}: {e_final} % l2 vs final"
            );
            assert!(
                e_init <= 25.0,
                "ideal R={radius} ΔT={dta}: {e_init} % l2 vs initial"
            );
            assert!(
                ok + 1 >= n,
                "ideal R={radius} ΔT={dta}: only {ok}/{n} located"
            );
        } else {
            // Realistic: the transmission's stiction band (≈ 0.11 N·m at the base link, and
            // η_back·η_drive ≈ 0.36 to back-drive) holds the finger wherever the impact left
            // it; the loading points after the forward slide carry the same Coulomb offset as
            // the approach, so it cancels in ΔT_a. Measured within 1.62 / 2.29 % l2 of the
            // quasi-static two-point estimate for ΔT_a = 0.5 / 0.8 (was 14.2 / 10.5 with the
            // impact's rest point as the first static point), 9/9 located at 0.5 and 8/9 at
            // 0.8 (k2 = 0.9 l2 on R ≥ 2.5 cm reads beyond the tip, as in the ideal grid);
            // vs the final location within 3.5 / 6.1 %. ΔT_a = 0.2: the slide out of the
            // impact's stiction leaves room for the loading points only at k2 = 0.1 l2
            // (within 0.78 % of the quasi-static estimate), elsewhere NoMotion; ΔT_a = 0.1
            // is inside the band: NoMotion everywhere (was located 2/9 at 26–43 % l2).
            let (b_ref_r, b_final_r, min_ok) = match dta {
                d if *d < 0.15 => (0.0, 0.0, 0),
                d if *d < 0.35 => (1.5, 3.0, 1),
                d if *d < 0.65 => (2.25, 4.5, 9),
                _ => (3.0, 7.0, 8),
            };
            assert!(
                e_ref <= b_ref_r,
                "realistic R={radius} ΔT={dta}: {e_ref} % l2 from the quasi-static estimate"
            );
            assert!(
                e_final <= b_final_r,
                "realistic R={radius} ΔT={dta}: {e_final} % l2 vs final"
            );
            assert!(
                ok >= min_ok,
                "realistic R={radius} ΔT={dta}: only {ok}/{n} located"
            );
        }
    }
    // Realistic steps inside the stiction band are refused as such, never located.
    for (c, r) in cases.iter().zip(&results) {
        if c.realistic && c.dta < 0.15 {
            assert!(
                matches!(r, Res::Fault(FaultReason::NoMotion { .. }, _)),
                "{c:?}: {r:?}"
            );
        }
    }
}
