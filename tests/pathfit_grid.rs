//! Acceptance grid of the path-fit estimator (issue 7), closed loop: the real
//! `grasp::Controller` against `plant::Plant`, the estimate computed from the controller's
//! `EstimateRequest` by `pathfit` — the generic fit in f64 (the reference) and the
//! firmware's integer kernel `pathfit::q` on the controller's integer samples, each
//! summarised and held to the targets — and, beside them, by the paper's two-point method
//! (`grasp::run_estimate`) on the same run.
//!
//! Vertex and cylinders R = 0.5, 1, 2.5, 5, 9.75 cm × k2,c = 0.1 … 0.9 l2 × ΔT_a = 0.05, 0.2,
//! 0.5, 0.8, 1.0 N·m, ideal plant (noise and friction off) and realistic plant. Runs that end
//! in a second contact or past the tip (plant events) are expected to be refused and counted.
//!
//! `cargo test --release --test pathfit_grid -- --nocapture` prints the tables (and, per
//! object, which way ΔT_a ≥ 0.5 N·m is read);
//! the grid runs the seated controller (`seating on`); `PATHFIT_NO_SEATING=RATE` (N·m/s) runs
//! it without the seating stages, as the default controller does, the step a ramp of RATE
//! (printed only: the guards below are the seated controller's), or with `PATHFIT_RAMP_S=T`
//! a ramp over T seconds whatever ΔT_a;
//! `PATHFIT_INERTIA_SCALE=F` fits with F × the drive's inertia (printed only too);
//! `PATHFIT_GAIN_ERROR=G` gives the realistic plant's current sensor the relative gain error G
//! (the scene's is +0.01; printed only), which the estimate cannot see without calibration;
//! `PATHFIT_SOURCES_OFF=coulomb,viscous,efficiency,backlash,noise,offset` (any of them)
//! switches those error sources of the realistic plant's drive and current sensor off
//! (printed only): which of them an estimate is sensitive to. The controller's drive, and so
//! the estimate's, follows the scene, unless `PATHFIT_FINGER=FILE` gives the realistic plant's
//! controller and estimate a finger file, e.g. one `pts calibrate` identified on that plant
//! (printed only).
//! (Owned by the pathfit helper; the harness in `tests/common` is the grasp owner's.)
mod common;

use common::*;
use grasp::{run_estimate, Controller, EstimateRequest, FaultReason, Hardware, State};
use pathfit::q::{fit_path_q, PathTable, RawSample};
use pathfit::{fit_path, FittedObject, PathFit, PathFitConfig, PathFitError, PathSample};
use plant::kin::Phalanx as PPhalanx;
use plant::path::ContactSpec;
use plant::scene::ObjectSpec;
use plant::{EventKind, Plant, Scene};
use pts::Model;

const RADII: [f64; 6] = [0.0, 0.005, 0.01, 0.025, 0.05, 0.0975];
const DTAS: [f64; 5] = [0.05, 0.2, 0.5, 0.8, 1.0];
const K2S: [f64; 9] = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9];

/// A positive finite number from the environment variable `name`.
fn positive_env(name: &str) -> Option<f64> {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|v| v.is_finite() && *v > 0.0)
}

/// `PATHFIT_NO_SEATING=RATE`: the step ramp (N·m/s) of a grid run without seating.
fn no_seating() -> Option<f64> {
    positive_env("PATHFIT_NO_SEATING")
}

/// `PATHFIT_RAMP_S=SECONDS` (with `PATHFIT_NO_SEATING`): the unseated step ramps over this
/// time whatever ΔT_a, its rate ΔT_a/SECONDS, instead of at one rate (diagnosis: whether a
/// small step suffers from its short ramp's dynamics).
fn ramp_duration() -> Option<f64> {
    positive_env("PATHFIT_RAMP_S")
}

/// `PATHFIT_INERTIA_SCALE=F`: the fit's drive inertia is F × the scene's (diagnosis: how much
/// the estimate depends on knowing it). The firmware's own estimate is then another
/// computation, so the check that the tables score what ships is skipped.
fn inertia_scale() -> Option<f64> {
    positive_env("PATHFIT_INERTIA_SCALE")
}

/// `PATHFIT_GAIN_ERROR=G`: the realistic plant's current-sensor gain error (relative, |G| ≤
/// 0.1; the scene's own is +0.01).
fn gain_error() -> Option<f64> {
    std::env::var("PATHFIT_GAIN_ERROR")
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|g| g.is_finite() && g.abs() <= 0.1)
}

/// The realistic plant's error sources `PATHFIT_SOURCES_OFF` can switch off: the drive's
/// Coulomb friction with its stiction, viscous friction, gear efficiency and backlash; the
/// current sensor's noise and offset error (its gain error is `PATHFIT_GAIN_ERROR`'s).
const SOURCES: [&str; 6] = [
    "coulomb",
    "viscous",
    "efficiency",
    "backlash",
    "noise",
    "offset",
];

/// `PATHFIT_SOURCES_OFF=…`: the sources to switch off; `None` when unset. An unknown name is
/// an error, so a typo cannot pass for a measurement.
fn sources_off() -> Option<Vec<String>> {
    let v = std::env::var("PATHFIT_SOURCES_OFF").ok()?;
    let names: Vec<String> = v.split(',').map(|n| n.trim().to_string()).collect();
    for n in &names {
        assert!(
            SOURCES.contains(&n.as_str()),
            "PATHFIT_SOURCES_OFF: unknown source {n:?} (one of {SOURCES:?})"
        );
    }
    Some(names)
}

/// No diagnosis variable changes this test's fit from the firmware's: the check that the
/// tables score what ships applies.
fn adapter_is_firmware() -> bool {
    [
        "PATHFIT_INERTIA_SCALE",
        "PATHFIT_OLD_MEAS",
        "PATHFIT_SC",
        "PATHFIT_CYL",
        "PATHFIT_BINS",
        "PATHFIT_NOFITC",
        "PATHFIT_KINK",
        "PATHFIT_TRUE_TC",
    ]
    .iter()
    .all(|v| std::env::var_os(v).is_none())
}

/// The controller of a grid run: the seated one (the guards below are its), or without
/// seating (the default), the step a ramp of `unseated_rate` (N·m/s).
fn grid_config(scene: &Scene, dta: f64, unseated_rate: Option<f64>) -> grasp::ControllerConfig {
    match unseated_rate {
        Some(rate) => grasp::ControllerConfig {
            seating: false,
            step_shape: grasp::StepShape::Ramp(ramp_duration().map_or(rate, |t| dta / t)),
            ..config(scene, dta)
        },
        None => seated(scene, dta),
    }
}

/// What the summaries read of a fit, from either back end.
#[derive(Clone, Debug)]
struct FitOut {
    k2: f64,
    sigma: f64,
    radius: f64,
    radius_observable: bool,
    object: FittedObject,
    friction: f64,
    chi2: f64,
    path_evals: u8,
}

impl<R: pts::Real> From<PathFit<R>> for FitOut {
    fn from(f: PathFit<R>) -> Self {
        FitOut {
            k2: f.k2_contact_m.to_f64(),
            sigma: f.sigma_k2_m.to_f64(),
            radius: f.radius_m.to_f64(),
            radius_observable: f.radius_observable,
            object: f.object,
            friction: f.friction_nm.to_f64(),
            chi2: f.chi2_per_dof.to_f64(),
            path_evals: f.path_evals,
        }
    }
}

/// One grid case's outcome.
#[derive(Clone, Debug)]
struct Case {
    radius: f64,
    k2c: f64,
    dta: f64,
    /// The plant reported a second contact or the contact passing the tip.
    plant_end: Option<&'static str>,
    /// Path fit (f64).
    fit: Option<Result<FitOut, PathFitError>>,
    /// Path fit on the firmware's integer kernel.
    fit_q: Option<Result<FitOut, PathFitError>>,
    /// Two-point k2 (m), when it gave one.
    two_point: Option<f64>,
    /// The firmware's path-fit entry on the same request.
    fw: Option<Result<grasp::EstimateResult, grasp::EstimateError>>,
    /// The same estimate on the generic f64 back end.
    fw_f64: Option<Result<grasp::EstimateResult, grasp::EstimateError>>,
    /// The controller never produced a request (state at the end).
    no_request: Option<State>,
    /// The plant reported a second contact or the contact passing the tip after the estimate.
    plant_after: Option<&'static str>,
    /// The controller's state once it took the firmware's path-fit outcome and finished with
    /// it (held, released or faulted; the unseated controller probes first when the outcome
    /// locates no distal contact).
    after_estimate: Option<State>,
}

fn grid_scene(base: Scene, radius: f64, k2c: f64) -> Scene {
    Scene {
        object: ObjectSpec::Touching(ContactSpec {
            theta1_c_rad: plant::scenes::TABLE2_THETA1_C_RAD,
            phalanx: PPhalanx::Distal,
            k_c_m: k2c,
            radius_m: radius,
        }),
        ..base
    }
}

/// The samples of a request from contact to settle, as the estimator takes them.
fn samples(req: &EstimateRequest) -> impl DoubleEndedIterator<Item = PathSample<f64>> + Clone + '_ {
    // With PATHFIT_KINK the approach history goes in too (the fit finds the kink).
    let kink = std::env::var("PATHFIT_KINK").is_ok();
    let kt = if kink {
        req.path.first().map_or(u32::MAX, |s| s.tick)
    } else {
        req.contact.tick
    };
    req.pre
        .iter()
        .filter(move |s| if kink { s.tick < kt } else { s.tick > kt })
        .chain(req.path.iter())
        .map(|s| PathSample {
            time_s: f64::from(s.tick) * 1e-4,
            theta_a_rad: f64::from(s.theta_a_urad) * 1e-6,
            torque_nm: f64::from(s.torque_unm) * 1e-6,
        })
}

/// The same samples as the controller recorded them (ticks of 100 µs, µrad, µN·m).
fn raw_samples(req: &EstimateRequest) -> impl DoubleEndedIterator<Item = RawSample> + '_ {
    let kt = req.contact.tick;
    req.pre
        .iter()
        .filter(move |s| s.tick > kt)
        .chain(req.path.iter())
        .map(|s| RawSample {
            tick: s.tick,
            theta_a_urad: s.theta_a_urad,
            torque_unm: s.torque_unm,
        })
}

/// `PATHFIT_FINGER=FILE`: the controller and the estimate of the realistic plant's grasps take
/// this finger file (one `pts calibrate` identified on the plant, say) instead of the scene's
/// nominal constants; the plant stays the scene's.
fn finger_file() -> Option<pts::config::FingerFile> {
    let path = std::env::var_os("PATHFIT_FINGER")?;
    let shown = std::path::Path::new(&path).display().to_string();
    let text =
        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("PATHFIT_FINGER={shown}: {e}"));
    Some(
        pts::config::FingerFile::from_toml_str(&text)
            .unwrap_or_else(|e| panic!("PATHFIT_FINGER={shown}: {e}")),
    )
}

fn run_case(base: Scene, radius: f64, k2c_frac: f64, dta: f64, unseated_rate: Option<f64>) -> Case {
    let k2c = k2c_frac * L2;
    let scene = grid_scene(base, radius, k2c);
    let mut case = Case {
        radius,
        k2c,
        dta,
        plant_end: None,
        fit: None,
        fit_q: None,
        two_point: None,
        fw: None,
        fw_f64: None,
        no_request: None,
        plant_after: None,
        after_estimate: None,
    };
    let Ok(plant) = Plant::new(&scene) else {
        case.plant_end = Some("scene");
        return case;
    };
    let mut hw = PlantHw::new(plant);
    let mut ccfg = grid_config(&scene, dta, unseated_rate);
    let realistic = scene.sensors != scene.ideal().sensors;
    let file = finger_file().filter(|_| realistic);
    if let Some(f) = &file {
        ccfg = ccfg
            .with_finger_file(f, scene.dt_s)
            .unwrap_or_else(|e| panic!("PATHFIT_FINGER: {e}"));
    }
    let finger = ccfg.finger;
    let mut c = Controller::new(ccfg).expect("config valid");
    let m = Model::<f64>::new(&finger).expect("the finger's model");
    // The estimator's measurement model of this scene's drive (ideal: η = 1, no backlash), as
    // the controller's drive carries it to the firmware's estimate.
    let d = &scene.drive;
    let mut cfg = PathFitConfig::DEFAULT.with_drive_model(
        d.eff_drive * d.rotor_inertia_kgm2 * d.gear_ratio * d.gear_ratio,
        d.backlash_rad,
    );
    if file.is_some() {
        cfg = ccfg.drive.path_fit_config();
    }
    assert_eq!(cfg, ccfg.drive.path_fit_config());
    if std::env::var("PATHFIT_OLD_MEAS").is_ok() {
        // Diagnosis: the previous measurement model (J N², no lead, plateaus kept).
        cfg.inertia_kgm2 = d.rotor_inertia_kgm2 * d.gear_ratio * d.gear_ratio;
        cfg.encoder_lead_rad = 0.0;
        cfg.drop_plateaus = false;
    }
    if let Some(v) = std::env::var("PATHFIT_SC")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        cfg.contact_angle_sigma_rad = v;
    }
    if std::env::var("PATHFIT_CYL").is_ok() {
        cfg.object = pathfit::ObjectModel::Cylinder;
    }
    if let Some(v) = std::env::var("PATHFIT_BINS")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        cfg.bins = v;
    }
    if let Some(v) = inertia_scale() {
        cfg.inertia_kgm2 *= v;
    }
    if std::env::var("PATHFIT_NOFITC").is_ok() {
        cfg.fit_contact_angle = false;
    }
    if let Ok(v) = std::env::var("PATHFIT_KINK") {
        cfg.approach_span_rad = v.parse().unwrap_or(0.0);
        cfg.drop_plateaus = true;
    }
    let max_ticks = (12.0 / scene.dt_s) as u64;
    // PATHFIT_TRUTH: the plant's truth at every tick (diagnosis of the measurement model).
    let want_truth = std::env::var("PATHFIT_TRUTH").is_ok();
    let mut truth: Vec<plant::Truth> = Vec::new();
    for _ in 0..max_ticks {
        if want_truth {
            truth.push(hw.plant.truth());
        }
        let o = grasp::tick_dyn(&mut c, &mut hw);
        if o.estimate_ready {
            if let Some(req) = c.take_request() {
                // θa,c and T_a,c as the firmware's adapter (grasp::estimate::path_fit) gets them.
                let (mut th_c, t_c) = grasp::estimate::contact_point_model(&m, &req)
                    .unwrap_or_else(|| grasp::estimate::contact_point(&req));
                if std::env::var("PATHFIT_TRUE_TC").is_ok() {
                    // Diagnosis: the plant's true contact angle instead of the controller's.
                    let t1 = plant::scenes::TABLE2_THETA1_C_RAD;
                    let ta = pts::Finger::PAPER.k1 * (t1 - pts::Finger::PAPER.theta01);
                    th_c = m
                        .free_from_torque(ta)
                        .map_or(th_c, |c| c.theta_a + cfg.encoder_lead_rad);
                }
                if let Ok(path) = std::env::var("PATHFIT_DUMP") {
                    let mut out = format!("{th_c:.9} {t_c:.9}\n");
                    for s in samples(&req) {
                        out +=
                            &format!("{:.9} {:.9} {:.9}\n", s.time_s, s.theta_a_rad, s.torque_nm);
                    }
                    // A directory gets one file per request (the cost benchmark's cases).
                    let path = std::path::Path::new(&path);
                    let file = if path.is_dir() {
                        let plant = if scene.sensors == scene.ideal().sensors {
                            "ideal"
                        } else {
                            "realistic"
                        };
                        path.join(format!("{plant}_r{radius}_k{k2c_frac:.1}_dta{dta}.txt"))
                    } else {
                        path.to_path_buf()
                    };
                    std::fs::write(file, out).expect("dump");
                }
                if std::env::var("PATHFIT_TRACE").is_ok() {
                    println!(
                        "contact_point θa,c {th_c:.6} T_a,c {t_c:.5}; knee {:?}; end {:?}",
                        req.contact, req.end
                    );
                    for s in req.pre.iter() {
                        println!(
                            "  pre  {} {:.6} {:.5}",
                            s.tick,
                            f64::from(s.theta_a_urad) * 1e-6,
                            f64::from(s.torque_unm) * 1e-6
                        );
                    }
                    for s in req.path.iter() {
                        println!(
                            "  path {} {:.6} {:.5}",
                            s.tick,
                            f64::from(s.theta_a_urad) * 1e-6,
                            f64::from(s.torque_unm) * 1e-6
                        );
                    }
                }
                if want_truth {
                    truth_report(&m, &scene, &req, &truth, th_c, t_c);
                }
                case.fit =
                    Some(fit_path(&m, &cfg, th_c, Some(t_c), samples(&req)).map(FitOut::from));
                let fx = |v: f64| pts::FirmwareReal::from_f64(v);
                let table = PathTable::new(&finger, &cfg, 1e-4).expect("table");
                case.fit_q = Some(
                    fit_path_q(&table, fx(th_c), Some(fx(t_c)), raw_samples(&req))
                        .map(FitOut::from),
                );
                let mut fw_req = req.clone();
                fw_req.estimator = grasp::Estimator::PathFit;
                case.fw = Some(run_estimate(&finger, &ccfg.drive, &fw_req));
                case.fw_f64 = Some(grasp::run_estimate_with(&m, &ccfg.drive, &fw_req));
                let mut tp_req = req.clone();
                tp_req.estimator = grasp::Estimator::TwoPoint;
                let r = run_estimate(&finger, &ccfg.drive, &tp_req);
                case.two_point = r.ok().and_then(|e| e.k2_um.map(|k| f64::from(k) * 1e-6));
                if let Some(fw) = case.fw {
                    c.deliver(&mut hw, fw);
                }
            }
        }
        if case.fit.is_some()
            && matches!(
                c.state(),
                State::Holding | State::Releasing | State::Done | State::Fault(_)
            )
        {
            case.after_estimate = Some(c.state());
            break;
        }
        while c.poll_event().is_some() {}
        hw.advance();
        while let Some(e) = hw.plant.poll_event() {
            match e.kind {
                // After the estimate (the unseated controller's probe pushes on) apart: the
                // tables count what the estimate saw.
                EventKind::SecondContact { .. } if case.fw.is_some() => {
                    case.plant_after = Some("second_contact")
                }
                EventKind::BeyondTip { .. } if case.fw.is_some() => {
                    case.plant_after = Some("past_tip")
                }
                EventKind::SecondContact { .. } => case.plant_end = Some("second_contact"),
                EventKind::BeyondTip { .. } => case.plant_end = Some("past_tip"),
                _ => {}
            }
        }
        if matches!(c.state(), State::Done | State::Fault(_)) {
            break;
        }
    }
    if case.fit.is_none() {
        case.no_request = Some(c.state());
    }
    case
}

use pts::Real as _;

/// Diagnosis (PATHFIT_TRUTH): each request sample beside the plant's truth averaged over the
/// same ticks, and the split of the measured torque into finger torque, reflected inertia and
/// friction.
fn truth_report(
    m: &Model<f64>,
    scene: &Scene,
    req: &EstimateRequest,
    truth: &[plant::Truth],
    th_c: f64,
    t_c: f64,
) {
    let d = &scene.drive;
    let n = d.gear_ratio;
    let st = req.sample_ticks.max(1) as usize;
    let kt = req.contact.tick;
    let true_c = truth
        .iter()
        .find(|t| !matches!(t.contact, plant::ContactState::Free))
        .copied();
    println!(
        "truth: controller θa,c {th_c:.6} T_a,c {t_c:.5}; plant first contact {:?}",
        true_c.map(|t| (t.t_s, t.theta_a_rad, t.torque_a_nm, t.k_m))
    );
    println!(
        "  tick  θmeas−θtrue(mrad) gear−θ  Tmeas  Ttrue  Tm−Tt  Nηkt·i−Tt  ηJN²θ̈(avg)  ω_m  k2"
    );
    for s in req
        .pre
        .iter()
        .filter(|s| s.tick + 400 > kt)
        .chain(req.path.iter())
    {
        let end = s.tick as usize;
        let (Some(lo), true) = (end.checked_sub(st), end < truth.len()) else {
            continue;
        };
        let w = &truth[lo + 1..=end];
        let k = w.len() as f64;
        let avg = |f: &dyn Fn(&plant::Truth) -> f64| w.iter().map(f).sum::<f64>() / k;
        let th = avg(&|t| t.theta_a_rad);
        let gear = avg(&|t| t.gear_out_rad);
        let tt = avg(&|t| t.torque_a_nm);
        let ti = avg(&|t| t.current_a) * d.kt_nm_per_a * n * d.eff_drive;
        let wm = avg(&|t| t.motor_speed_rad_s);
        // Inertia: η J N² θ̈a, θ̈a over the window from the motor speed at its ends.
        let acc =
            (w[w.len() - 1].motor_speed_rad_s - truth[lo].motor_speed_rad_s) / (k * scene.dt_s) / n;
        let inert = d.eff_drive * d.rotor_inertia_kgm2 * n * n * acc;
        let tm = f64::from(s.torque_unm) * 1e-6;
        let thm = f64::from(s.theta_a_urad) * 1e-6;
        println!(
            "  {:6} {:7.3} {:7.3} {:7.4} {:7.4} {:7.4} {:7.4} {:7.4} {:7.2} {:.5}",
            s.tick,
            1e3 * (thm - th),
            1e3 * (gear - th),
            tm,
            tt,
            tm - tt,
            ti - tt,
            inert,
            wm,
            w[w.len() - 1].k_m
        );
    }
    let _ = m;
}

fn run_grid(base: Scene, unseated_rate: Option<f64>) -> Vec<Case> {
    let mut jobs = Vec::new();
    for &r in &RADII {
        for &k in &K2S {
            for &d in &DTAS {
                jobs.push((r, k, d));
            }
        }
    }
    let threads = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
        .min(4);
    let chunks: Vec<Vec<(f64, f64, f64)>> = (0..threads)
        .map(|t| jobs.iter().skip(t).step_by(threads).cloned().collect())
        .collect();
    let handles: Vec<_> = chunks
        .into_iter()
        .map(|chunk| {
            std::thread::spawn(move || {
                chunk
                    .into_iter()
                    .map(|(r, k, d)| run_case(base, r, k, d, unseated_rate))
                    .collect::<Vec<_>>()
            })
        })
        .collect();
    handles
        .into_iter()
        .flat_map(|h| h.join().expect("grid thread"))
        .collect()
}

struct Summary {
    cases: usize,
    accepted: usize,
    expected_refusals: usize,
    refused_expected: usize,
    refused_other: usize,
    no_request: usize,
    mean: f64,
    max: f64,
    mean_2p: f64,
    max_2p: f64,
    within3: usize,
    radius_claims: usize,
    radius_ok: usize,
    /// Largest |k2 integer − k2 f64| (fraction of l2) where both chose the same object model.
    fx_max_diff: f64,
    /// The same in units of the larger of the two σ(k2).
    fx_max_sigmas: f64,
    /// Fits where the two chose different object models (the radius decision is a threshold).
    flips: usize,
}

/// A grid object's row label: `vertex`, or the cylinder's radius `R=…cm`.
fn object_label(radius_m: f64) -> String {
    if radius_m == 0.0 {
        "vertex".to_string()
    } else {
        format!("R={:.2}cm", radius_m * 100.0)
    }
}

fn summarize(
    name: &str,
    cases: &[Case],
    pick: fn(&Case) -> &Option<Result<FitOut, PathFitError>>,
) -> Summary {
    let mut s = Summary {
        cases: cases.len(),
        accepted: 0,
        expected_refusals: 0,
        refused_expected: 0,
        refused_other: 0,
        no_request: 0,
        mean: 0.0,
        max: 0.0,
        mean_2p: 0.0,
        max_2p: 0.0,
        within3: 0,
        radius_claims: 0,
        radius_ok: 0,
        fx_max_diff: 0.0,
        fx_max_sigmas: 0.0,
        flips: 0,
    };
    let mut n2p = 0usize;
    println!("\n{name}: max |k̂2,c − k2,c| in % of l2, path fit (two-point), [refused/events]");
    print!("{:>10} |", "object");
    for d in DTAS {
        print!(" ΔT_a={d:<4} N·m          |");
    }
    println!();
    for &r in &RADII {
        print!("{:>10} |", object_label(r));
        for &d in &DTAS {
            let cell: Vec<&Case> = cases
                .iter()
                .filter(|c| c.radius == r && c.dta == d)
                .collect();
            let mut mx: f64 = 0.0;
            let mut mx2: f64 = 0.0;
            let mut refused = 0;
            let mut events = 0;
            for c in &cell {
                if c.plant_end.is_some() {
                    events += 1;
                }
                match pick(c) {
                    Some(Ok(f)) => {
                        mx = mx.max((f.k2 - c.k2c).abs() / L2);
                    }
                    _ => refused += 1,
                }
                if let (Some(Ok(_)), Some(k)) = (pick(c), c.two_point) {
                    mx2 = mx2.max((k - c.k2c).abs() / L2);
                }
            }
            print!(
                " {:5.2} ({:5.1}) [{}/{}] |",
                100.0 * mx,
                100.0 * mx2,
                refused,
                events
            );
        }
        println!();
    }
    for c in cases {
        let expected = c.plant_end.is_some();
        if expected {
            s.expected_refusals += 1;
        }
        match pick(c) {
            None => s.no_request += 1,
            Some(Err(e)) => {
                if expected {
                    s.refused_expected += 1;
                } else {
                    s.refused_other += 1;
                    println!(
                        "  refused without a plant event: R={} k2c={:.2} ΔT={}: {}",
                        c.radius,
                        c.k2c / L2,
                        c.dta,
                        e.kind()
                    );
                }
            }
            Some(Ok(f)) => {
                s.accepted += 1;
                let e = (f.k2 - c.k2c).abs() / L2;
                s.mean += e;
                s.max = s.max.max(e);
                if (f.k2 - c.k2c).abs() <= 3.0 * f.sigma {
                    s.within3 += 1;
                } else {
                    println!(
                        "  outside 3σ: R={} k2c={:.2} ΔT={}: err {:.2} % σ {:.2} % ({:?}, R̂ {:.4}, T_f {:.4}, χ² {:.1}){}",
                        c.radius,
                        c.k2c / L2,
                        c.dta,
                        100.0 * e,
                        100.0 * f.sigma / L2,
                        f.object,
                        f.radius,
                        f.friction,
                        f.chi2,
                        if expected { " [plant event]" } else { "" }
                    );
                }
                if f.radius_observable {
                    s.radius_claims += 1;
                    if c.radius > 0.0 && (f.radius - c.radius).abs() <= 0.2 * c.radius {
                        s.radius_ok += 1;
                    }
                }
                if let Some(k) = c.two_point {
                    s.mean_2p += (k - c.k2c).abs() / L2;
                    s.max_2p = s.max_2p.max((k - c.k2c).abs() / L2);
                    n2p += 1;
                }
                if let (Some(Ok(a)), Some(Ok(b))) = (&c.fit, &c.fit_q) {
                    let d = (a.k2 - b.k2).abs() / L2;
                    if a.object == b.object {
                        s.fx_max_diff = s.fx_max_diff.max(d);
                        s.fx_max_sigmas = s
                            .fx_max_sigmas
                            .max((a.k2 - b.k2).abs() / a.sigma.max(b.sigma));
                    } else {
                        s.flips += 1;
                    }
                    if d > 5e-4 {
                        println!(
                            "  integer vs f64: R={} k2c={:.2} ΔT={}: {:.3} % l2 apart, errors {:.3} / {:.3} % l2 ({:?} / {:?}, evals {} / {})",
                            c.radius,
                            c.k2c / L2,
                            c.dta,
                            100.0 * d,
                            100.0 * (a.k2 - c.k2c).abs() / L2,
                            100.0 * (b.k2 - c.k2c).abs() / L2,
                            a.object,
                            b.object,
                            a.path_evals,
                            b.path_evals
                        );
                    }
                }
            }
        }
        if let Some(st) = c.no_request {
            println!(
                "  no estimate request: R={} k2c={:.2} ΔT={}: controller ended in {st:?}",
                c.radius,
                c.k2c / L2,
                c.dta
            );
        }
    }
    // Cost driver on the target: path evaluations per fit (crates/pathfit/benches/icount counts
    // instructions for dumped cases: ≈ 23 k for the sample pass + ≈ 13 k per evaluation, f32).
    let mut evals = [0usize; 25];
    for c in cases {
        if let Some(Ok(f)) = pick(c) {
            if let Some(e) = evals.get_mut(usize::from(f.path_evals)) {
                *e += 1;
            }
        }
    }
    let hist: Vec<String> = evals
        .iter()
        .enumerate()
        .filter(|(_, &n)| n > 0)
        .map(|(k, n)| format!("{k}:{n}"))
        .collect();
    let worst = cases
        .iter()
        .filter_map(|c| match pick(c) {
            Some(Ok(f)) => Some((f.path_evals, c.radius, c.k2c / L2, c.dta)),
            _ => None,
        })
        .max_by_key(|w| w.0);
    println!(
        "{name}: path evaluations per fit (evals:fits) {}; most: {worst:?} (evals, R, k2c/l2, ΔT_a)",
        hist.join(" ")
    );
    s.mean /= s.accepted.max(1) as f64;
    s.mean_2p /= n2p.max(1) as f64;
    println!(
        "{name}: {} runs, {} estimates, {} refused of {} with a plant event (second contact / past tip), \
         {} refused otherwise, {} without a request\n  path fit: mean {:.2} % max {:.2} % of l2 | \
         two-point on the same runs: mean {:.2} % max {:.2} % | within 3σ: {}/{} ({:.1} %) | \
         R within 20 %: {}/{} declared observable | integer kernel vs f64: max {:.4} % of l2 = {:.2} σ (same model), {} radius decisions differ",
        s.cases,
        s.accepted,
        s.refused_expected,
        s.expected_refusals,
        s.refused_other,
        s.no_request,
        100.0 * s.mean,
        100.0 * s.max,
        100.0 * s.mean_2p,
        100.0 * s.max_2p,
        s.within3,
        s.accepted,
        100.0 * s.within3 as f64 / s.accepted.max(1) as f64,
        s.radius_ok,
        s.radius_claims,
        100.0 * s.fx_max_diff,
        s.fx_max_sigmas,
        s.flips
    );
    s
}

/// Prints, per object, the signed mean, the mean and the max of (k̂2,c − k2,c) / l2 over the
/// answered cases at ΔT_a ≥ 0.5 N·m, by the back end `pick`: which way an object is read.
fn print_signed_by_object(
    name: &str,
    cases: &[Case],
    pick: fn(&Case) -> &Option<Result<FitOut, PathFitError>>,
) {
    println!("\n{name}, ΔT_a ≥ 0.5 N·m: (k̂2,c − k2,c) in % of l2 by object");
    println!("    object | answered | signed mean | mean |err| | max |err|");
    for &r in &RADII {
        let errs: Vec<f64> = cases
            .iter()
            .filter(|c| c.radius == r && c.dta >= 0.5)
            .filter_map(|c| match pick(c) {
                Some(Ok(f)) => Some(100.0 * (f.k2 - c.k2c) / L2),
                _ => None,
            })
            .collect();
        let n = errs.len().max(1) as f64;
        println!(
            "{:>10} | {:>8} | {:>+11.2} | {:>11.2} | {:>9.2}",
            object_label(r),
            errs.len(),
            errs.iter().sum::<f64>() / n,
            errs.iter().map(|e| e.abs()).sum::<f64>() / n,
            errs.iter().fold(0.0f64, |m, e| m.max(e.abs()))
        );
    }
}

/// |k̂2,c − k2,c| / l2 of the answered cases at ΔT_a ≥ 0.5 N·m, by the back end `pick`.
fn big_step_errors(
    cases: &[Case],
    pick: fn(&Case) -> &Option<Result<FitOut, PathFitError>>,
) -> Vec<f64> {
    cases
        .iter()
        .filter(|c| c.dta >= 0.5)
        .filter_map(|c| match pick(c) {
            Some(Ok(f)) => Some((f.k2 - c.k2c).abs() / L2),
            _ => None,
        })
        .collect()
}

#[test]
fn pathfit_grid_on_the_plant() {
    let ideal = run_grid(plant::Scene::DEFAULT.ideal(), no_seating());
    // PATHFIT_SEED=n: another noise seed for the realistic plant (robustness check).
    let mut real_scene = plant::Scene::DEFAULT;
    if let Some(seed) = std::env::var("PATHFIT_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        real_scene.sensors.seed = seed;
    }
    if let Some(g) = gain_error() {
        real_scene.sensors.gain_error = g;
    }
    for source in sources_off().unwrap_or_default() {
        let (d, s) = (&mut real_scene.drive, &mut real_scene.sensors);
        match source.as_str() {
            "coulomb" => (d.coulomb_nm, d.stiction_nm) = (0.0, 0.0),
            "viscous" => d.viscous_nm_s_per_rad = 0.0,
            "efficiency" => (d.eff_drive, d.eff_back) = (1.0, 1.0),
            "backlash" => d.backlash_rad = 0.0,
            "noise" => s.noise_v_rms = 0.0,
            _ => s.offset_error_v = 0.0,
        }
    }
    let real = run_grid(real_scene, no_seating());
    // The tables below score the integer kernel through this test's adapter; the firmware
    // calls `run_estimate` with the controller's drive. On both plants (the ideal drive's
    // η = 1 and no backlash reach the estimate through the drive) the two must be one
    // computation, so the tables measure what ships.
    let scored: Vec<&Case> = if adapter_is_firmware() {
        ideal.iter().chain(real.iter()).collect()
    } else {
        Vec::new()
    };
    // Collected, and asserted after the tables are printed (a mismatch still shows them).
    let mut mismatches = Vec::new();
    for c in scored {
        if let (Some(Ok(q)), Some(fw)) = (&c.fit_q, &c.fw) {
            let k = fw
                .as_ref()
                .ok()
                .and_then(|r| r.k2_um)
                .map(|k| f64::from(k) * 1e-6);
            if !k.is_some_and(|k| (k - q.k2).abs() <= 1e-4 * L2) {
                mismatches.push(format!(
                    "R={} k2c={:.2} ΔT={}: run_estimate {fw:?}, integer kernel k2 {:.6} m",
                    c.radius,
                    c.k2c / L2,
                    c.dta,
                    q.k2
                ));
            }
        }
    }
    // What the controller did with the firmware's outcome: a second contact the controller
    // named where the plant saw none is a false alarm (the unseated controller's probe must
    // not raise one).
    let mut false_second = Vec::new();
    for (plant, cases) in [("ideal", &ideal), ("realistic", &real)] {
        let (mut named, mut locked, mut probed_sound) = (0, 0, 0);
        for c in cases.iter() {
            let Some(state) = c.after_estimate else {
                continue;
            };
            let second = matches!(state, State::Fault(FaultReason::SecondContact { .. }));
            // The path fit's own verdict (a fitted object that would cut the proximal
            // phalanx) is the estimator's, counted with its refusals above.
            let fit_said = matches!(
                &c.fw,
                Some(Err(grasp::EstimateError::PathFit(
                    PathFitError::SecondContact
                )))
            );
            if c.plant_end.or(c.plant_after) == Some("second_contact") {
                locked += 1;
                named += usize::from(second);
                if !second {
                    println!(
                        "  {plant}: R={} k2c={:.2} ΔT={}: locked (plant, {}), ended {state:?} after {:?}",
                        c.radius,
                        c.k2c / L2,
                        c.dta,
                        if c.plant_end.is_some() { "before the estimate" } else { "in the probe" },
                        c.fw
                    );
                }
            } else if second && !fit_said {
                false_second.push(format!(
                    "{plant}: R={} k2c={:.2} ΔT={}: {state:?}",
                    c.radius,
                    c.k2c / L2,
                    c.dta
                ));
            } else if !second
                && !matches!(&c.fw, Some(Ok(r)) if r.located == grasp::Located::Distal)
            {
                probed_sound += 1;
            }
        }
        println!(
            "{plant} plant, after the estimate: second contacts named {named} of {locked} the plant \
             locked; grasps without a distal location and no second contact: {probed_sound}, none named"
        );
    }
    let f64_fit: fn(&Case) -> &Option<Result<FitOut, PathFitError>> = |c| &c.fit;
    let q_fit: fn(&Case) -> &Option<Result<FitOut, PathFitError>> = |c| &c.fit_q;
    // Every summary and verdict first, then the guards (a failure still shows both back ends).
    let mut results = Vec::new();
    for (label, pick) in [
        ("f64 reference", f64_fit),
        ("firmware integer kernel", q_fit),
    ] {
        let si = summarize(
            &format!("{label}, ideal plant (noise and friction off)"),
            &ideal,
            pick,
        );
        let sr = summarize(
            &format!("{label}, realistic plant (noise, friction, backlash)"),
            &real,
            pick,
        );
        // Issue 7's targets, printed as met or not (the README quotes these lines).
        let big_steps = |cases: &[Case]| {
            big_step_errors(cases, pick)
                .into_iter()
                .fold(0.0f64, f64::max)
        };
        let big_real = big_step_errors(&real, pick);
        let big_real_mean = big_real.iter().sum::<f64>() / big_real.len().max(1) as f64;
        let verdict = |ok: bool| if ok { "met" } else { "NOT met" };
        println!(
            "\n{label}: issue 7 targets: ideal max ≤ 1 % l2: {} ({:.2} %; ΔT_a ≥ 0.5 N·m only: {:.2} %)",
            verdict(si.max <= 0.01),
            100.0 * si.max,
            100.0 * big_steps(&ideal)
        );
        println!(
            "{label}: issue 7 targets: realistic mean ≤ 2 % and max ≤ 5 % l2: {} (mean {:.2} %, max {:.2} %; \
             ΔT_a ≥ 0.5 N·m only: {} estimates, mean {:.2} %, max {:.2} %)",
            verdict(sr.mean <= 0.02 && sr.max <= 0.05),
            100.0 * sr.mean,
            100.0 * sr.max,
            big_real.len(),
            100.0 * big_real_mean,
            100.0 * big_steps(&real)
        );
        for (plant, cases) in [("ideal", &ideal), ("realistic", &real)] {
            print_signed_by_object(&format!("{label}, {plant} plant"), cases, pick);
        }
        results.push((label, si, sr, big_steps(&ideal)));
    }
    assert!(
        mismatches.is_empty(),
        "the tables' adapter and the firmware's run_estimate differ by more than 1e-4·l2:\n{}",
        mismatches.join("\n")
    );
    assert!(
        false_second.is_empty(),
        "a second contact named where the plant saw none:\n{}",
        false_second.join("\n")
    );
    if no_seating().is_some()
        || inertia_scale().is_some()
        || gain_error().is_some()
        || sources_off().is_some()
        || finger_file().is_some()
    {
        return;
    }
    for (label, si, sr, big_ideal) in &results {
        let label = *label;
        // Regression guards at what this estimator measures today (it must not get worse).
        // Measured (drive measurement model, fitted θa,c, 8 bins): ideal mean 0.14 % max 0.74 %
        // (ΔT_a ≥ 0.5: 0.38 %), realistic mean 0.51 % max 1.88 % (seeds 1–3: max 2.04–2.30 %).
        // PATHFIT_BINS=n: 10 bins give 0.73 % / 1.81 %, 6 bins 1.12 % ideal (over the target).
        assert!(si.mean <= 0.002, "{label}: ideal mean {:.4}", si.mean);
        assert!(si.max <= 0.01, "{label}: ideal max {:.4}", si.max);
        assert!(*big_ideal <= 0.006, "{label}: ideal, ΔT_a ≥ 0.5 N·m");
        assert!(sr.mean <= 0.007, "{label}: realistic mean {:.4}", sr.mean);
        assert!(sr.max <= 0.03, "{label}: realistic max {:.4}", sr.max);
        assert!(
            sr.mean * 3.0 <= sr.mean_2p,
            "{label}: path fit vs two-point"
        );
        // The integer kernel is the same fit: where both chose the same object model they
        // agree to the fit's own convergence (measured ≤ 0.06 % of l2, ≤ 0.03 σ, and no
        // radius decision differs; 0.31 σ while the kernel rounded w·c to 12 bits in its
        // normal matrix); the decision is a threshold, so a rare borderline fit may go the
        // other way.
        for s in [si, sr] {
            assert!(
                s.fx_max_sigmas <= 0.1,
                "{label}: integer vs f64 {:.5} l2, {:.2} σ",
                s.fx_max_diff,
                s.fx_max_sigmas
            );
            assert!(
                s.flips * 50 <= s.accepted,
                "{label}: radius decisions differ: {}",
                s.flips
            );
            assert!(s.within3 * 100 >= s.accepted * 99, "{label}: 3σ coverage");
            assert_eq!(
                s.radius_ok, s.radius_claims,
                "{label}: radius within 20 % when observable"
            );
            assert!(s.accepted * 2 > s.cases, "{label}: too many refusals");
        }
    }
}

/// The harness type is used here; keep the import checked.
#[allow(dead_code)]
fn _uses(_: &dyn Hardware) {}

/// The paper's Table 2 contact (R = 5 cm, k2,c = 0.02927 m, ΔT_a = 0.8 N·m) on both plants.
#[test]
fn pathfit_table2_case() {
    if no_seating().is_some() {
        // Its checks are the seated controller's.
        return;
    }
    // PATHFIT_CASE="R,k2c/l2,ΔT" runs another case (for diagnosis).
    let (r, k, d) = std::env::var("PATHFIT_CASE")
        .ok()
        .and_then(|v| {
            let x: Vec<f64> = v.split(',').filter_map(|t| t.parse().ok()).collect();
            (x.len() == 3).then(|| (x[0], x[1], x[2]))
        })
        .unwrap_or((0.05, 0.02927 / L2, 0.8));
    for (name, base) in [
        ("ideal", plant::Scene::DEFAULT.ideal()),
        ("realistic", plant::Scene::DEFAULT),
    ] {
        let c = run_case(base, r, k, d, None);
        println!("{name}: {c:?}");
        for f in [&c.fit, &c.fit_q] {
            let f = f.as_ref().expect("request").as_ref().expect("estimate");
            assert!((f.k2 - k * L2).abs() < 0.02 * L2, "{f:?}");
        }
        // The firmware's σ and radius (µm) against the same estimate on the generic f64 back
        // end (the same request, the contact point from f64 Newton solves).
        let fw =
            c.fw.as_ref()
                .expect("request")
                .as_ref()
                .expect("firmware estimate");
        let f64_ref = c
            .fw_f64
            .as_ref()
            .expect("request")
            .as_ref()
            .expect("f64 estimate");
        println!("{name}: firmware {fw:?}\n{name}: f64 {f64_ref:?}");
        let (s_fw, s_ref) = (
            fw.k2_sigma_um.expect("σ of a distal answer"),
            f64_ref.k2_sigma_um.expect("σ of a distal answer"),
        );
        assert!(s_ref > 0, "{name}: σ {s_ref} µm");
        assert!(
            f64::from((s_fw - s_ref).abs()) < 0.1 * f64::from(s_ref),
            "{name}: firmware σ {s_fw} µm, f64 σ {s_ref} µm"
        );
        assert_eq!(
            fw.radius_um.is_some(),
            f64_ref.radius_um.is_some(),
            "{name}"
        );
        if let (Some(r_fw), Some(r_ref)) = (fw.radius_um, f64_ref.radius_um) {
            assert!(
                f64::from((r_fw - r_ref).abs()) < 0.1 * f64::from(r_ref).max(5_000.0),
                "{name}: firmware R {r_fw} µm, f64 R {r_ref} µm"
            );
        }
        assert_eq!(
            fw.two_point_k2_um, None,
            "the estimator leaves the reference to its caller"
        );
    }
}

/// Seated and unseated (a 4 N·m/s ramp from the detection) on the realistic plant, over the
/// current sensor's gain error (−1, 0, +1 %), which no estimate can see without calibration:
/// the firmware's integer kernel at ΔT_a ≥ 0.5 N·m. Which controller is the more accurate
/// must not hang on one sign of that error; docs/RESULTS.md ("Time to know") quotes this
/// table and the claim checked here: over the three gains the unseated controller's mean
/// and worst case are no worse than the seated one's.
#[test]
fn seated_and_unseated_over_the_sensor_gain() {
    let mut worst = [0.0f64; 2];
    let mut means = [0.0f64; 2];
    println!("\n| sensor gain error | seated: estimates, mean, max | unseated, ramp 4 N·m/s: estimates, mean, max |");
    println!("|---|---|---|");
    for gain in [-0.01, 0.0, 0.01] {
        let mut scene = plant::Scene::DEFAULT;
        scene.sensors.gain_error = gain;
        let mut cells = Vec::new();
        for (i, rate) in [None, Some(4.0)].into_iter().enumerate() {
            let errs = big_step_errors(&run_grid(scene, rate), |c| &c.fit_q);
            let mean = errs.iter().sum::<f64>() / errs.len().max(1) as f64;
            let max = errs.iter().copied().fold(0.0f64, f64::max);
            worst[i] = worst[i].max(max);
            means[i] += mean / 3.0;
            cells.push(format!(
                "{}, {:.2} %, {:.2} %",
                errs.len(),
                100.0 * mean,
                100.0 * max
            ));
        }
        println!("| {:+.0} % | {} | {} |", 100.0 * gain, cells[0], cells[1]);
    }
    println!(
        "over the three gains: seated mean {:.2} %, worst {:.2} %; unseated mean {:.2} %, worst {:.2} %",
        100.0 * means[0],
        100.0 * worst[0],
        100.0 * means[1],
        100.0 * worst[1]
    );
    assert!(
        means[1] <= means[0],
        "unseated mean {:.4} > seated {:.4}",
        means[1],
        means[0]
    );
    assert!(
        worst[1] <= worst[0],
        "unseated worst {:.4} > seated {:.4}",
        worst[1],
        worst[0]
    );
}
