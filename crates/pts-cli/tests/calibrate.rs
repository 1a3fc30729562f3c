//! Calibration acceptance (issue #17): on plant fingers whose springs, rest angles, friction
//! and inertia are off their finger file, `pts calibrate`'s identification (free sweep + touch
//! against a post, recorded on the plant) is compared with the plant's true parameters, and
//! the k2 estimate of grasps replayed with the nominal, the calibrated and the true file is
//! scored against the plant's first contact. The calibration uses three recordings: the free
//! sweep, the touch against a post on the proximal phalanx and the closing onto a post that
//! the distal phalanx meets (positions known from the fixture, independent of the springs).
//!
//! `cargo test --release -p pts-cli --test calibrate -- --nocapture` runs the CI slice (two
//! perturbed fingers × three grasps); `CALIB_GRID=full` runs all sixteen sign combinations of
//! springs ±25 % and rest angles ±3° (friction ×2, inertia ×3) and prints the same table.

use plant::scene::ObjectSpec;
use plant::{ContactSpec, Phalanx, Scene};
use pts::config::FingerFile;
use pts_cli::calibrate::{identify, identify_with, CalibError, Calibration};
use pts_cli::method::Method;
use pts_cli::replay::replay;
use pts_cli::sim::{run, SimOptions};
use pts_cli::sweep::{
    drive_truth, record, record_object, DistalPost, Perturbation, Post, SweepPlan,
};
use pts_cli::trace::Trace;

/// Grasps: (θ1 at contact, k2 at contact as a fraction of l2, radius m).
const GRASPS: [(f64, f64, f64); 3] = [(1.2797, 0.3, 0.01), (1.2797, 0.6, 0.0), (1.15, 0.45, 0.01)];

fn nominal() -> FingerFile {
    pts_cli::load_finger(None).expect("paper finger")
}

fn post(f: &FingerFile) -> Post {
    Post {
        theta1_rad: f.finger.theta01 + 0.45,
        k1_m: 0.07,
    }
}

fn tip_post(f: &FingerFile) -> DistalPost {
    DistalPost::for_file(f, f.finger.theta01 + 0.35, 0.5).expect("distal post")
}

fn calibrate(pert: &Perturbation, nominal: &FingerFile) -> (Scene, Calibration) {
    let scene = pert
        .scene(Scene::DEFAULT, nominal)
        .expect("perturbed scene");
    let sweep = record(&scene, nominal, &SweepPlan::DEFAULT, None).expect("sweep");
    let p = post(nominal);
    let touch = record(&scene, nominal, &SweepPlan::DEFAULT, Some(p)).expect("touch");
    let dp = tip_post(nominal);
    let tip = record_object(&scene, nominal, &SweepPlan::DEFAULT, Some(dp.object())).expect("tip");
    let cal = identify_with(&sweep, Some((&touch, p)), Some((&tip, dp)), nominal)
        .expect("identification");
    (scene, cal)
}

/// Each identified parameter against the plant's truth (springs and drive terms in the units
/// of the measured torque: the sensor's gain error scales them all). Returns the failures.
fn check_params(
    pert: &Perturbation,
    scene: &Scene,
    nominal: &FingerFile,
    cal: &Calibration,
) -> Vec<String> {
    let truth = pert.apply_to_file(nominal);
    let g = 1.0 + scene.sensors.gain_error;
    let [fc, st, visc, j, rho, off] = drive_truth(scene, nominal);
    let expect = [
        ("k1", truth.finger.k1 * g),
        ("k2", truth.finger.k2 * g),
        ("theta01", truth.finger.theta01),
        ("theta02", truth.finger.theta02),
        ("backdrive_ratio", rho),
        ("coulomb", fc),
        ("stiction", st),
        ("viscous", visc),
        ("inertia", j),
        ("torque_offset", off),
    ];
    let mut bad = vec![];
    for (name, t) in expect {
        let p = cal.get(name).expect("parameter");
        let s = p.sigma.expect("identified");
        let z = (p.value - t) / s;
        eprintln!(
            "  {name:<16} {:>12.6} ± {:<10.3e} truth {:>12.6}  z = {z:+.2}",
            p.value, s, t
        );
        if z.is_nan() || z.abs() > 3.0 {
            bad.push(format!(
                "{name}: {} ± {s:.3e} vs truth {t} (z = {z:.2})",
                p.value
            ));
        }
    }
    bad
}

/// |k̂2 − k2,c| / l2 (%) of one grasp recorded on `scene`'s plant, replayed with each file;
/// path-fit refusals because the model could not be built for the file (its table) are added
/// to `model_refusals`.
fn grasp_errors(
    scene: &Scene,
    files: &[&FingerFile],
    g: (f64, f64, f64),
    method: Method,
    model_refusals: &mut Vec<String>,
) -> Vec<Option<f64>> {
    let l2 = scene.finger.l2_m;
    let mut s = plant::scenes::table2();
    s.finger = scene.finger;
    s.drive = scene.drive;
    s.sensors = scene.sensors;
    s.object = ObjectSpec::Touching(ContactSpec {
        theta1_c_rad: g.0,
        phalanx: Phalanx::Distal,
        k_c_m: g.1 * l2,
        radius_m: g.2,
    });
    let rep = run(&SimOptions {
        scene: s,
        delta_ta_nm: 0.8,
        max_s: 10.0,
        extra_s: 0.2,
        record: true,
        method,
        overcurrent_a: None,
        priors: None,
        step_shape: None,
        seating: None,
    })
    .expect("grasp");
    let Some((_, "distal", k_true)) = rep.first_contact else {
        return vec![None; files.len()];
    };
    let trace = Trace::from_rows(&rep.rows, vec![]);
    files
        .iter()
        .map(|f| {
            let r = match replay(&trace, f, 0.8, Some(rep.dt_s), method, &Default::default()) {
                Ok(r) => r,
                Err(e) => {
                    eprintln!("    {}: replay failed: {e}", f.name);
                    return None;
                }
            };
            let Some(est) = r.estimate else {
                eprintln!("    {}: no estimate (state {:?})", f.name, r.state);
                return None;
            };
            let k = match est {
                Ok(e) => match e.k2_um {
                    Some(k) => f64::from(k) / 1e6,
                    None => {
                        eprintln!("    {}: located {:?}", f.name, e.located);
                        return None;
                    }
                },
                Err(e) => {
                    eprintln!("    {} refused: {} {}", f.name, e.kind, e.detail);
                    let model = ["toggle", "out_of_range", "not_assemblable", "singular"];
                    if method == Method::Pathfit && model.contains(&e.kind) {
                        model_refusals.push(format!("{}: {} {}", f.name, e.kind, e.detail));
                    }
                    return None;
                }
            };
            Some(((k - k_true) / l2 * 100.0).abs())
        })
        .collect()
}

fn fingers() -> Vec<Perturbation> {
    let base = Perturbation {
        friction_factor: 2.0,
        inertia_factor: 3.0,
        ..Perturbation::NONE
    };
    let all: Vec<Perturbation> = (0..16)
        .map(|i| Perturbation {
            k1_factor: if i & 1 == 0 { 1.25 } else { 0.75 },
            k2_factor: if i & 2 == 0 { 0.75 } else { 1.25 },
            theta01_deg: if i & 4 == 0 { 3.0 } else { -3.0 },
            theta02_deg: if i & 8 == 0 { -3.0 } else { 3.0 },
            ..base
        })
        .collect();
    if std::env::var("CALIB_GRID").as_deref() == Ok("full") {
        all
    } else {
        vec![all[0], all[15]]
    }
}

#[test]
fn calibration_acceptance_on_the_plant() {
    let nominal = nominal();
    let mut sums = [[0.0f64; 3]; 2];
    let mut counts = [0usize; 2];
    let mut nominal_counts = [0usize; 2];
    let mut failures = vec![];
    eprintln!("| finger (K1, K2, Δθ01, Δθ02) | grasp (θ1c, k2c/l2, R) | method | nominal % | calibrated % | true % |");
    eprintln!("|---|---|---|---|---|---|");
    for pert in fingers() {
        let (scene, cal) = calibrate(&pert, &nominal);
        eprintln!("finger {pert:?}: residual {:.5} N·m", cal.residual_rms_nm);
        failures.extend(check_params(&pert, &scene, &nominal, &cal));
        let truth = pert.apply_to_file(&nominal);
        let mut refusals = Vec::new();
        for (mi, method) in [Method::TwoPoint, Method::Pathfit].into_iter().enumerate() {
            for g in GRASPS {
                let e = grasp_errors(
                    &scene,
                    &[&nominal, &cal.file, &truth],
                    g,
                    method,
                    &mut refusals,
                );
                let cell = |x: Option<f64>| x.map_or("-".to_string(), |v| format!("{v:.2}"));
                eprintln!(
                    "| ×{}, ×{}, {:+}°, {:+}° | {}, {}, {} mm | {} | {} | {} | {} |",
                    pert.k1_factor,
                    pert.k2_factor,
                    pert.theta01_deg,
                    pert.theta02_deg,
                    g.0,
                    g.1,
                    g.2 * 1e3,
                    method.name(),
                    cell(e[0]),
                    cell(e[1]),
                    cell(e[2])
                );
                // The criterion compares the calibrated and the true file on the grasps both
                // answered; the nominal file's mean is over the grasps it answered.
                if let [_, Some(b), Some(c)] = e[..] {
                    sums[mi][1] += b;
                    sums[mi][2] += c;
                    counts[mi] += 1;
                }
                if let Some(a) = e[0] {
                    sums[mi][0] += a;
                    nominal_counts[mi] += 1;
                }
            }
        }
        // Every finger of the grid is one a user may build: a file the finger check accepts
        // is one the estimators can model (a soft distal spring once had every path-fit
        // grasp refused at the toggle); only the recording may leave k2 undetermined.
        if !refusals.is_empty() {
            failures.push(format!("{pert:?}: refused for the model: {refusals:?}"));
        }
    }
    for (mi, name) in ["two-point", "path-fit"].iter().enumerate() {
        let n = counts[mi].max(1) as f64;
        let a = sums[mi][0] / nominal_counts[mi].max(1) as f64;
        let (b, c) = (sums[mi][1] / n, sums[mi][2] / n);
        eprintln!(
            "mean |error| % of l2, {name}: nominal {a:.2} ({} grasps), calibrated {b:.2} and \
             true {c:.2} ({} grasps both answered)",
            nominal_counts[mi], counts[mi]
        );
        assert!(counts[mi] > 0, "{name}: no grasp answered with both files");
        if b > 1.25 * c {
            failures.push(format!(
                "{name}: calibrated mean error {b:.3} % > 1.25 × true-file {c:.3} %"
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

fn sweep_rows(
    pert: &Perturbation,
    post: Option<Post>,
    plan: &SweepPlan,
) -> Vec<pts_cli::trace::TraceRow> {
    let nominal = nominal();
    let scene = pert.scene(Scene::DEFAULT, &nominal).expect("scene");
    record(&scene, &nominal, plan, post).expect("record")
}

#[test]
fn a_free_sweep_cannot_separate_k1_from_k2_and_says_so() {
    let nominal = nominal();
    let rows = sweep_rows(&Perturbation::NONE, None, &SweepPlan::DEFAULT);
    let cal = identify(&rows, None, &nominal).expect("free sweep");
    assert!(cal.get("theta01").unwrap().sigma.is_none());
    assert!(
        cal.notes
            .iter()
            .any(|n| n.contains("K1 and K2 are poorly separated")),
        "{:?}",
        cal.notes
    );
    // The series compliance at rest, 1/K1 + x2²/K2, is what the free sweep does pin down:
    // compare with the plant's (gain-scaled) truth through the file's model.
    let x2 = pts::Model::<f64>::new(&nominal.finger)
        .unwrap()
        .closure(nominal.finger.theta02)
        .unwrap()
        .x2;
    let c = |k1: f64, k2: f64| 1.0 / k1 + x2 * x2 / k2;
    let g = 1.0 + plant::Scene::DEFAULT.sensors.gain_error;
    let got = c(cal.get("k1").unwrap().value, cal.get("k2").unwrap().value);
    let want = c(nominal.finger.k1 * g, nominal.finger.k2 * g);
    assert!(
        (got / want - 1.0).abs() < 0.03,
        "compliance {got} vs {want}"
    );
}

#[test]
fn a_sweep_that_touches_an_object_is_refused() {
    let nominal = nominal();
    // The "free" sweep recorded with the post in place.
    let rows = sweep_rows(
        &Perturbation::NONE,
        Some(post(&nominal)),
        &SweepPlan::DEFAULT,
    );
    match identify(&rows, None, &nominal) {
        Err(CalibError::ObjectTouched { .. }) => {}
        other => panic!("expected ObjectTouched, got {other:?}"),
    }
}

#[test]
fn a_stalled_motor_is_refused() {
    let nominal = nominal();
    // A safe torque below the stiction: the finger never moves.
    let plan = SweepPlan {
        safe_torque_nm: 0.1,
        dither_nm: 0.0,
        ..SweepPlan::DEFAULT
    };
    let rows = sweep_rows(&Perturbation::NONE, None, &plan);
    match identify(&rows, None, &nominal) {
        Err(CalibError::Stalled { .. }) => {}
        other => panic!("expected Stalled, got {other:?}"),
    }
}

#[test]
fn a_short_sweep_is_refused() {
    let nominal = nominal();
    let rows = sweep_rows(&Perturbation::NONE, None, &SweepPlan::DEFAULT);
    match identify(&rows[..1500], None, &nominal) {
        Err(CalibError::TooShort { .. }) => {}
        other => panic!("expected TooShort, got {other:?}"),
    }
}

#[test]
fn a_noisy_sweep_is_refused() {
    let nominal = nominal();
    let mut rows = sweep_rows(&Perturbation::NONE, None, &SweepPlan::DEFAULT);
    // Deterministic pseudo-noise of 0.1 N·m rms on the torque.
    let mut s = 0x1234_5678_u64;
    for r in &mut rows {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let u = (s >> 11) as f64 / (1u64 << 53) as f64;
        r.torque_nm += (u - 0.5) * 0.1 * 12f64.sqrt();
    }
    match identify(&rows, None, &nominal) {
        Err(CalibError::TooNoisy { .. }) => {}
        other => panic!("expected TooNoisy, got {other:?}"),
    }
}

#[test]
fn the_calibrated_file_is_accepted_by_every_consumer() {
    let nominal = nominal();
    // θ0,2 below the plant's default θ2 stop: the plant built from the file must follow.
    let pert =
        Perturbation::parse("k1=0.8,k2=1.2,theta01_deg=2,theta02_deg=-4,friction=2").unwrap();
    let (_, cal) = calibrate(&pert, &nominal);
    let text = cal.file.to_toml_string();
    let path = std::env::temp_dir().join(format!("pts-calibrated-{}.toml", std::process::id()));
    std::fs::write(&path, &text).unwrap();
    // `pts finger`, `pts estimate --finger`, `pts sim --finger` and the firmware build all
    // load through this function.
    let back = pts_cli::load_finger(Some(&path)).expect("accepted");
    let _ = std::fs::remove_file(&path);
    assert_eq!(back.finger, cal.file.finger);
    assert_eq!(back.current_sense, cal.file.current_sense);
    assert_eq!(back.drive, cal.file.drive);
    // `pts sim --finger`: the plant and the controller built from it run a grasp.
    let (scene, control) =
        pts_cli::sim::finger_scene(plant::scenes::table2(), &back).expect("scene");
    let rep = run(&SimOptions {
        scene,
        delta_ta_nm: 0.8,
        max_s: 10.0,
        extra_s: 0.2,
        record: false,
        method: Method::TwoPoint,
        overcurrent_a: Some(control.overcurrent_a),
        priors: Some(control.priors),
        step_shape: None,
        seating: None,
    })
    .expect("pts sim --finger");
    assert!(rep.k2_hat_m().is_some(), "{:?}", rep.state);
}

/// A sweep on the independent rapier2d finger (crates/dynsim: the paper's springs and rest
/// angles as its own constants, a Stribeck drive friction, the drive inertia on the crank): the
/// same torque command, θa from the crank angle quantised to the file's encoder counts from
/// the rest, T_a the motor torque with a seeded noise.
fn dynsim_sweep(
    nominal: &FingerFile,
    params: dynsim::sim::FingerParams,
    plan: &SweepPlan,
    object: dynsim::sim::Object,
) -> Vec<pts_cli::trace::TraceRow> {
    let engine = dynsim::sim::EngineSettings::default();
    let mut f = dynsim::sim::Finger::new(params, object, engine);
    let rest_nominal = pts::Model::<f64>::new(&nominal.finger)
        .unwrap()
        .theta_a(nominal.finger.theta01, nominal.finger.theta02)
        .unwrap();
    let th0 = f.theta_a_rad();
    let rpc = nominal.rad_per_count();
    let dt = engine.dt_s;
    let steps = (plan.duration_s() / dt).ceil() as u64;
    let mut rows = vec![];
    let mut done_at: Option<f64> = None;
    let mut s = 0x9E37_79B9_7F4A_7C15_u64;
    for n in 0..steps {
        let t = n as f64 * dt;
        let dth = f.theta_a_rad() - th0;
        if done_at.is_none() && t > plan.pause_s + plan.ramp_s && dth < 0.03 {
            done_at = Some(t);
        }
        if done_at.is_some_and(|d| t > d + plan.pause_s) {
            break;
        }
        f.step(plan.torque_at(t, done_at.is_some()));
        if n % u64::from(plan.decimate) == 0 {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = (s >> 11) as f64 / (1u64 << 53) as f64;
            let counts = ((f.theta_a_rad() - th0) / rpc).round();
            rows.push(pts_cli::trace::TraceRow {
                t_s: t + dt,
                theta_a_rad: rest_nominal + counts * rpc,
                torque_nm: f.motor_nm() + (u - 0.5) * 0.002 * 12f64.sqrt(),
                torque_ref_nm: None,
                duty: None,
                state: None,
                encoder_count: None,
                current_code: None,
                true_theta_a_rad: Some(f.theta_a_rad()),
                true_torque_nm: None,
                true_contact: None,
                true_k_m: None,
            });
        }
    }
    rows
}

/// The same identification on the engine-based finger, whose springs and rest angles are its
/// own constants (the paper's): the *file* is the perturbed one here (springs ±25 %, rest
/// angles ±3°), with the engine's drive friction ×2 and drive inertia ×3.
#[test]
fn calibration_on_the_engine_finger() {
    use dynsim::linkage as L;
    let truth = nominal();
    let pert = Perturbation {
        k1_factor: 0.8,
        k2_factor: 1.25,
        theta01_deg: -3.0,
        theta02_deg: 3.0,
        ..Perturbation::NONE
    };
    let nominal = pert.apply_to_file(&truth);
    let fr = dynsim::sim::DriveFriction::REALISTIC;
    let params = dynsim::sim::FingerParams {
        drive_inertia_kgm2: 3.0 * 5.0e-4,
        friction: dynsim::sim::DriveFriction {
            coulomb_nm: 2.0 * fr.coulomb_nm,
            stiction_nm: 2.0 * fr.stiction_nm,
            viscous_nm_s_per_rad: 2.0 * fr.viscous_nm_s_per_rad,
            ..fr
        },
        contact_mu: 0.3,
        torque_lag_s: 0.0,
    };
    let plan = SweepPlan {
        ramp_s: 4.0,
        ..SweepPlan::DEFAULT
    };
    // The engine has no backlash: the file says so.
    let mut nominal = nominal;
    nominal.drive.backlash_rad = 0.0;
    let ball = |x: f64, y: f64, normal_angle: f64| {
        // The vertex is a ball of VERTEX_RADIUS_M: its centre sits that far on the phalanx's
        // left normal from the point the line meets.
        let r = dynsim::sim::VERTEX_RADIUS_M;
        let n = normal_angle + std::f64::consts::FRAC_PI_2;
        dynsim::sim::Object::Ball {
            center_m: [x + r * n.cos(), y + r * n.sin()],
            radius_m: r,
        }
    };
    let p = post(&nominal);
    let dp = tip_post(&nominal);
    // The distal phalanx's angle where the nominal finger meets the tip post (θ1 + θ2).
    let m = pts::Model::<f64>::new(&nominal.finger).unwrap();
    let c = m
        .free_from_torque(nominal.finger.k1 * 0.35)
        .expect("nominal configuration");
    let t0 = std::time::Instant::now();
    let sweep = dynsim_sweep(&nominal, params, &plan, dynsim::sim::Object::None);
    let touch = dynsim_sweep(
        &nominal,
        params,
        &plan,
        ball(
            p.k1_m * p.theta1_rad.cos(),
            p.k1_m * p.theta1_rad.sin(),
            p.theta1_rad,
        ),
    );
    let tip = dynsim_sweep(
        &nominal,
        params,
        &plan,
        ball(dp.x_m, dp.y_m, c.theta1 + c.theta2),
    );
    eprintln!("engine sweeps: {:?}", t0.elapsed());
    let cal = identify_with(&sweep, Some((&touch, p)), Some((&tip, dp)), &nominal)
        .expect("identification");
    eprintln!("{cal}");
    // The engine's own constants, and its drive: no back-driving loss (ρ = 1), no torque
    // offset. Its friction is a Stribeck curve (above Coulomb at the slow speeds of the sweep,
    // a shape the identified model does not have), the links add their own inertia and the
    // joints a structural damping: the Coulomb, stiction, inertia and viscous terms have no
    // single engine value to compare with and are printed only.
    let expect = [
        ("k1", L::K1_NM_PER_RAD),
        ("k2", L::K2_NM_PER_RAD),
        ("theta01", L::THETA01_RAD),
        ("theta02", L::THETA02_RAD),
        ("backdrive_ratio", 1.0),
        ("torque_offset", 0.0),
    ];
    let mut bad = vec![];
    for (name, t) in expect {
        let q = cal.get(name).expect("parameter");
        let s = q.sigma.expect("identified");
        let z = (q.value - t) / s;
        eprintln!(
            "  {name:<16} {:>12.6} ± {:<10.3e} engine {:>12.6}  z = {z:+.2}",
            q.value, s, t
        );
        if z.is_nan() || z.abs() > 3.0 {
            bad.push(format!(
                "{name}: {} ± {s:.3e} vs engine {t} (z = {z:.2})",
                q.value
            ));
        }
    }
    // Grasps on the engine (its CI grid's distal cases, realistic level, with this drive),
    // read as a board's log with each file and scored against the engine's first contact.
    // A firmware adds its file's rest angle to the encoder: the trace's θa is re-based.
    let mut true_file = truth.clone();
    true_file.drive.backlash_rad = 0.0;
    let files = [
        (&nominal, "nominal"),
        (&cal.file, "calibrated"),
        (&true_file, "true"),
    ];
    let rest_of = |f: &FingerFile| {
        pts::Model::<f64>::new(&f.finger)
            .unwrap()
            .theta_a(f.finger.theta01, f.finger.theta02)
            .unwrap()
    };
    let axes = dynsim::grid::Axes {
        radii_m: &[0.0, 0.01],
        k2_frac: &[0.35, 0.65],
        delta_ta_nm: &[0.5],
        mu: &[0.3],
        inertia_kgm2: &[5.0e-4],
        theta1_c_rad: &[dynsim::grid::THETA1_C_RAD],
        protocols: &[dynsim::grid::Protocol::SAMPLES],
    };
    let mut sums = [0.0f64; 3];
    let mut n = 0usize;
    eprintln!("| engine grasp | nominal % | calibrated % | true % |");
    eprintln!("|---|---|---|---|");
    for mut c in dynsim::grid::cases(&axes) {
        if c.level != "default" {
            continue;
        }
        c.spec.finger = params;
        let Some(rec) = dynsim::grasp::run(&c.spec) else {
            continue;
        };
        let Some(k_true) = (rec.truth.phalanx == "distal")
            .then_some(rec.truth.k_c_m)
            .flatten()
        else {
            continue;
        };
        if rec.truth.both_phalanges {
            continue;
        }
        let csv = dynsim::grasp::to_csv(&rec, &c.sensor);
        let errs: Vec<Option<f64>> = files
            .iter()
            .map(|(f, _)| {
                let mut tr = pts_cli::trace::read_csv(&csv, &|i| f.torque_from_current(i)).ok()?;
                let shift = rest_of(f) - rest_of(&truth);
                for th in &mut tr.theta_a_rad {
                    *th += shift;
                }
                let seg = pts_cli::replay::segment(&tr, f, Method::Pathfit).ok()?;
                let est = seg.contacts.first()?.estimate.as_ref().ok()?;
                let k = f64::from(est.k2_um?) * 1e-6;
                Some(((k - k_true) / dynsim::linkage::L2_M * 100.0).abs())
            })
            .collect();
        let cell = |x: Option<f64>| x.map_or("-".to_string(), |v| format!("{v:.2}"));
        eprintln!(
            "| {} | {} | {} | {} |",
            c.id,
            cell(errs[0]),
            cell(errs[1]),
            cell(errs[2])
        );
        if let [Some(a), Some(b), Some(c)] = errs[..] {
            sums[0] += a;
            sums[1] += b;
            sums[2] += c;
            n += 1;
        }
    }
    let m = sums.map(|s| s / n.max(1) as f64);
    eprintln!(
        "engine, path fit, mean |error| % of l2 over {n} grasps: nominal {:.2}, calibrated {:.2}, true {:.2}",
        m[0], m[1], m[2]
    );
    assert!(n > 0, "no engine grasp answered with all three files");
    if m[1] > 1.25 * m[2] {
        bad.push(format!(
            "engine: calibrated {:.3} % > 1.25 × true {:.3} %",
            m[1], m[2]
        ));
    }
    assert!(bad.is_empty(), "{bad:#?}");
}

/// The firmware's sweep (grasp::calibrate with the firmware's sensors and torque loop, run by
/// the host against the plant) records what the identification needs: the same parameters,
/// within 3σ of the plant's truth.
#[test]
fn the_firmware_sweep_calibrates_the_plant_finger() {
    use grasp::calibrate::{Phase, SweepConfig};
    use pts_cli::sweep::record_firmware;
    let nominal = nominal();
    let pert = fingers()[1];
    let scene = pert
        .scene(Scene::DEFAULT, &nominal)
        .expect("perturbed scene");
    let cfg = SweepConfig::DEFAULT;
    let run = |object| {
        let (rows, phase) = record_firmware(&scene, &nominal, cfg, object).expect("firmware sweep");
        assert_eq!(phase, Phase::Done, "the sweep must finish in time");
        rows
    };
    let p = post(&nominal);
    let dp = tip_post(&nominal);
    let free = run(None);
    let touch = run(Some(p.object()));
    let tip = run(Some(dp.object()));
    // Never beyond the safe torque, never past the angle limit.
    for r in free.iter().chain(&touch).chain(&tip) {
        let rf = r.torque_ref_nm.unwrap();
        assert!(rf.abs() <= f64::from(cfg.safe_torque_unm) / 1e6 + 1e-12);
        assert!(r.theta_a_rad - free[0].theta_a_rad <= f64::from(cfg.max_dtheta_urad) / 1e6);
    }
    let cal = identify_with(&free, Some((&touch, p)), Some((&tip, dp)), &nominal)
        .expect("identification");
    eprintln!("{cal}");
    let bad = check_params(&pert, &scene, &nominal, &cal);
    assert!(bad.is_empty(), "{bad:#?}");
}

#[test]
fn the_firmware_sweep_refuses_to_start_on_a_bad_configuration() {
    let nominal = nominal();
    let cfg = grasp::calibrate::SweepConfig {
        safe_torque_unm: 3_000_000,
        ..grasp::calibrate::SweepConfig::DEFAULT
    };
    let e = pts_cli::sweep::record_firmware(&Scene::DEFAULT, &nominal, cfg, None).unwrap_err();
    assert!(e.contains("safe_torque_unm"), "{e}");
}

/// The command end to end: `pts calibrate --simulate` writes the three recordings and the true
/// file, `pts calibrate` reads them back (the posts from the recordings' comment lines) and
/// writes a finger file `pts finger` accepts, with the springs near the true file's.
#[test]
fn the_command_records_identifies_and_writes_a_finger_file() {
    use pts_cli::calibrate::{run as calibrate_cmd, Args};
    let dir = std::env::temp_dir().join(format!("pts-calibrate-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = |n: &str| dir.join(n);
    let args = Args {
        trace: path("free.csv"),
        touch: Some(path("touch.csv")),
        tip_touch: Some(path("tip.csv")),
        post_theta1_rad: None,
        post_k1_m: None,
        finger: None,
        out: Some(path("calibrated.toml")),
        json: true,
        simulate: true,
        perturb: "k1=1.2,k2=0.8,theta01_deg=2,theta02_deg=2".into(),
        safe_torque_nm: 0.6,
        truth_out: Some(path("true.toml")),
        firmware: true,
    };
    calibrate_cmd(&args).expect("simulate");
    calibrate_cmd(&Args {
        simulate: false,
        ..args.clone()
    })
    .expect("identify");
    let cal = pts_cli::load_finger(Some(&path("calibrated.toml"))).expect("pts finger accepts it");
    let truth = pts_cli::load_finger(Some(&path("true.toml"))).expect("true file");
    for (a, b) in [
        (cal.finger.k1, truth.finger.k1),
        (cal.finger.k2, truth.finger.k2),
    ] {
        assert!((a / b - 1.0).abs() < 0.05, "{a} vs {b}");
    }
    assert!((cal.finger.theta01 - truth.finger.theta01).abs() < 0.01);
    // The free sweep with its torque negated or in mN·m is refused as such, not as the
    // noise or the touched object its identification then sees.
    let text = std::fs::read_to_string(path("free.csv")).unwrap();
    for (name, scale, needle) in [
        ("negated.csv", -1.0, "negate every row's torque"),
        ("mnm.csv", 1000.0, "not in N·m"),
    ] {
        let mut out = String::new();
        for l in text.lines() {
            let mut c: Vec<String> = l.split(',').map(str::to_owned).collect();
            if let Some(t) = c.get_mut(2).filter(|_| !l.starts_with(['#', 't'])) {
                *t = format!("{:.10}", scale * t.parse::<f64>().unwrap());
            }
            out += &c.join(",");
            out.push('\n');
        }
        std::fs::write(path(name), out).unwrap();
        let e = calibrate_cmd(&Args {
            simulate: false,
            trace: path(name),
            touch: None,
            tip_touch: None,
            out: None,
            ..args.clone()
        })
        .unwrap_err();
        assert!(
            e.contains("torque_frame") && e.contains(needle),
            "{name}: {e}"
        );
    }
    // A bad value is an error naming it, not a panic.
    let e = calibrate_cmd(&Args {
        safe_torque_nm: f64::NAN,
        ..args.clone()
    })
    .unwrap_err();
    assert!(e.contains("safe_torque_unm"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
