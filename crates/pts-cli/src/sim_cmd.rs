//! `pts sim` as a command: one scene (events, estimate vs truth, CSV, plot) or a sweep
//! (grid, progress bar on stderr, error table, heat map).

use crate::plot;
use crate::sim::{self, SimOptions, SimReport};
use crate::trace::{located_name, quality_name, write_csv, TraceRow};
use serde_json::{json, Value};
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

/// The options of `pts sim`.
#[derive(Clone, Debug)]
pub struct Args {
    /// Built-in scene.
    pub scene: String,
    /// List scenes and exit.
    pub list: bool,
    /// ΔT_a values (N·m).
    pub dta: Vec<f64>,
    /// CSV output.
    pub csv: Option<PathBuf>,
    /// Plot output.
    pub plot: Option<PathBuf>,
    /// JSON output.
    pub json: bool,
    /// Time limit per grasp (s).
    pub max_s: f64,
    /// Sweep mode.
    pub sweep: bool,
    /// Sweep radii (cm).
    pub radii_cm: Vec<f64>,
    /// Sweep contact locations (% l2).
    pub k2_pct: Vec<f64>,
    /// Ideal drive and sensors.
    pub ideal: bool,
    /// Estimator compared with the truth.
    pub method: crate::method::Method,
    /// Finger description: the plant and the controller are built from it (default: the
    /// scene's finger).
    pub finger: Option<PathBuf>,
    /// Step ramp rates (N·m/s, 0 = one step); empty: the controller's default.
    pub step_ramp: Vec<f64>,
    /// Seat the contact before the step (`Some(true)`) or step at once from the detection;
    /// `None`: the controller's default.
    pub seating: Option<bool>,
}

/// Largest step ramp rate accepted (N·m/s): above it a ramp is a step for any ΔT_a.
const STEP_RAMP_MAX_NM_PER_S: f64 = 1000.0;

/// The controller's step shape for a ramp rate (N·m/s; 0 = one step), checked.
fn step_shape(rate: f64) -> Result<grasp::StepShape, String> {
    if !(rate.is_finite() && (0.0..=STEP_RAMP_MAX_NM_PER_S).contains(&rate)) {
        return Err(format!(
            "--step-ramp {rate}: a ramp rate in 0..={STEP_RAMP_MAX_NM_PER_S} N·m/s (0 = one step)"
        ));
    }
    Ok(if rate == 0.0 {
        grasp::StepShape::Step
    } else {
        grasp::StepShape::Ramp(rate)
    })
}

/// The step settings a run or sweep uses: `None` is the controller's default.
fn step_shapes(a: &Args) -> Result<Vec<Option<grasp::StepShape>>, String> {
    if a.step_ramp.is_empty() {
        return Ok(vec![None]);
    }
    a.step_ramp
        .iter()
        .map(|&r| step_shape(r).map(Some))
        .collect()
}

/// A step setting in words.
fn step_name(s: Option<grasp::StepShape>) -> String {
    match s.unwrap_or(grasp::ControllerConfig::DEFAULT.step_shape) {
        grasp::StepShape::Step => "step".into(),
        grasp::StepShape::Ramp(r) => format!("ramp {r} N·m/s"),
    }
}

/// The scene as the finger file's finger, and what the file sets in the controller (none
/// without a file).
fn with_finger(
    a: &Args,
    scene: plant::Scene,
) -> Result<(plant::Scene, Option<sim::FileControl>), String> {
    match &a.finger {
        None => Ok((scene, None)),
        Some(path) => {
            let file = crate::load_finger(Some(path))?;
            let (scene, control) = sim::finger_scene(scene, &file)?;
            Ok((scene, Some(control)))
        }
    }
}

fn check_dta(dta: &[f64]) -> Result<(), String> {
    if dta.is_empty() {
        return Err("--dta: give at least one ΔT_a in (0, 2] N·m".into());
    }
    match dta
        .iter()
        .find(|d| !(d.is_finite() && **d > 0.0 && **d <= 2.0))
    {
        Some(d) => Err(format!("--dta: {d} N·m is outside (0, 2] N·m")),
        None => Ok(()),
    }
}

/// What a scene's `[command]` and `duration_s` are for, since `pts sim` does not use them.
pub const OPEN_LOOP_NOTE: &str =
    "A scene's [command] (a duty or current profile) and duration_s drive \
open-loop plant runs (`cargo run -p plant --example run_scene -- NAME`); pts sim runs the grasp \
controller instead, which drives the finger itself until it holds, faults or --max-s passes.";

/// A scene in words, from its data: the object and where it is touched, the drive, the faults.
pub fn scene_summary(sc: &plant::Scene) -> String {
    use plant::scene::ObjectSpec;
    let mm = |m: f64| format!("{:.1} mm", m * 1e3);
    let shape = |r: f64| {
        if r > 0.0 {
            format!("cylinder R {}", mm(r))
        } else {
            "vertex".to_string()
        }
    };
    let mut parts = vec![match sc.object {
        ObjectSpec::None => "no object (free motion)".to_string(),
        ObjectSpec::At(o) => format!(
            "{} fixed at ({}, {}) from O1",
            shape(o.radius_m),
            mm(o.x_m),
            mm(o.y_m)
        ),
        ObjectSpec::Touching(c) => format!(
            "{} first touching the {} phalanx at k = {} (θ1,c = {} rad)",
            shape(c.radius_m),
            match c.phalanx {
                plant::kin::Phalanx::Proximal => "proximal",
                plant::kin::Phalanx::Distal => "distal",
            },
            mm(c.k_c_m),
            c.theta1_c_rad
        ),
    }];
    let ideal = *sc == plant::Scene { ..sc.ideal() };
    parts.push(
        if ideal {
            "ideal drive"
        } else {
            "realistic drive"
        }
        .to_string(),
    );
    let f = &sc.faults;
    let at = |t: f64| t.is_finite().then_some(t);
    if let Some(t) = at(f.encoder_stuck_at_s) {
        parts.push(format!("encoder stuck from {t} s"));
    }
    if let Some(t) = at(f.encoder_jump_at_s) {
        parts.push(format!(
            "encoder jumps {} counts at {t} s",
            f.encoder_jump_counts
        ));
    }
    if let Some(t) = at(f.short_at_s) {
        parts.push(format!("winding shorted to {} Ω at {t} s", f.short_r_ohm));
    }
    if let Some(t) = at(f.remove_object_at_s) {
        parts.push(format!("object removed at {t} s"));
    }
    if f.power_up_offset_rad != 0.0 {
        parts.push(format!(
            "powered up {} rad from rest",
            f.power_up_offset_rad
        ));
    }
    parts.join("; ")
}

/// Runs `pts sim`.
pub fn run(a: &Args) -> Result<(), String> {
    if a.list {
        let width = plant::scenes::NAMES
            .iter()
            .map(|n| n.len())
            .max()
            .unwrap_or(0);
        for n in plant::scenes::NAMES {
            let what = plant::scenes::by_name(n).map_or(String::new(), |sc| scene_summary(&sc));
            crate::outln!("{n:<width$}  {what}");
        }
        crate::outln!("\n{OPEN_LOOP_NOTE}");
        return Ok(());
    }
    check_dta(&a.dta)?;
    if !(a.max_s.is_finite() && a.max_s > 0.0 && a.max_s <= 600.0) {
        return Err(format!("--max-s {} s is outside (0, 600] s", a.max_s));
    }
    if a.sweep {
        return sweep(a);
    }
    if a.dta.len() != 1 {
        return Err("--dta takes one value without --sweep".into());
    }
    let step = match step_shapes(a)?.as_slice() {
        [one] => *one,
        _ => return Err("--step-ramp takes one value without --sweep".into()),
    };
    // Resolved once: the run and the recording's `# pts-sim` line state the same controller.
    let step = step.unwrap_or(grasp::ControllerConfig::DEFAULT.step_shape);
    let seating = a
        .seating
        .unwrap_or(grasp::ControllerConfig::DEFAULT.seating);
    let (scene, from_file) = with_finger(a, sim::load_scene(&a.scene)?)?;
    if scene.command.mode != plant::scene::CommandMode::External {
        eprintln!("note: {OPEN_LOOP_NOTE}");
    }
    let t0 = Instant::now();
    let rep = sim::run(&SimOptions {
        scene,
        delta_ta_nm: a.dta[0],
        max_s: a.max_s,
        extra_s: 0.2,
        record: a.csv.is_some() || a.plot.is_some(),
        method: a.method,
        overcurrent_a: from_file.map(|c| c.overcurrent_a),
        priors: from_file.map(|c| c.priors),
        step_shape: Some(step),
        seating: Some(seating),
    })?;
    let wall = t0.elapsed().as_secs_f64();
    if let Some(path) = &a.csv {
        let file = std::fs::File::create(path)
            .map_err(|e| format!("cannot create {}: {e}", path.display()))?;
        let mut w = std::io::BufWriter::new(file);
        let meta = crate::replay::TraceMeta {
            dta_nm: a.dta[0],
            dt_s: rep.dt_s,
            drive: Some(crate::replay::MetaDrive::of(&rep.drive)),
            // What the replay needs to run the same controller, written out rather than left
            // to the defaults of whichever version replays it.
            controller: crate::replay::MetaController {
                estimator: Some(a.method),
                step_ramp_nm_per_s: Some(match step {
                    grasp::StepShape::Step => 0.0,
                    grasp::StepShape::Ramp(r) => r,
                }),
                seating: Some(seating),
                ..Default::default()
            },
        };
        writeln!(w, "{}", meta.line())
            .and_then(|()| write_csv(&rep.rows, &mut w))
            .and_then(|()| w.flush())
            .map_err(|e| format!("writing {}: {e}", path.display()))?;
        eprintln!("wrote {} ({} rows)", path.display(), rep.rows.len());
    }
    if let Some(path) = &a.plot {
        let sig = signals(&rep.rows, rep.contact, kc_hat(&rep));
        let title = format!("pts sim {} (ΔT_a = {} N·m)", rep.scene, a.dta[0]);
        plot::signals(
            path,
            plot::Size {
                width: 1200,
                height: 900,
            },
            &title,
            &sig,
        )?;
        eprintln!("wrote {}", path.display());
    }
    if a.json {
        crate::outln!("{}", report_json(&rep, a.dta[0]));
    } else {
        print_report(&rep, a.dta[0], wall);
    }
    // The report (and any CSV or plot) is written either way; the status says whether the
    // grasp produced what was asked for.
    match (&rep.estimate, rep.fault()) {
        (Some(Ok(_)), _) => Ok(()),
        (_, Some(f)) => Err(format!("the grasp ended in the fault {f}: no estimate")),
        (Some(Err(e)), None) => Err(format!("the estimator refused the grasp: {}", e.kind)),
        (None, None) => Err(format!(
            "no estimate within --max-s {} s (state {:?})",
            a.max_s, rep.state
        )),
    }
}

fn kc_hat(rep: &SimReport) -> Option<f64> {
    match &rep.estimate {
        Some(Ok(r)) => crate::sim::kc_hat_nm_per_rad(r),
        _ => None,
    }
}

/// Plot signals from trace rows.
pub fn signals(
    rows: &[TraceRow],
    contact: Option<(f64, f64, f64)>,
    kc_hat: Option<f64>,
) -> plot::Signals {
    let has = |f: &dyn Fn(&TraceRow) -> bool| !rows.is_empty() && rows.iter().all(f);
    plot::Signals {
        t_s: rows.iter().map(|r| r.t_s).collect(),
        theta_a_rad: rows.iter().map(|r| r.theta_a_rad).collect(),
        torque_nm: rows.iter().map(|r| r.torque_nm).collect(),
        torque_ref_nm: has(&|r| r.torque_ref_nm.is_some()).then(|| {
            rows.iter()
                .map(|r| r.torque_ref_nm.unwrap_or(0.0))
                .collect()
        }),
        state: has(&|r| r.state.is_some()).then(|| {
            rows.iter()
                .map(|r| r.state.clone().unwrap_or_default())
                .collect()
        }),
        k_true_m: has(&|r| r.true_k_m.is_some())
            .then(|| rows.iter().map(|r| r.true_k_m.unwrap_or(0.0)).collect()),
        contact,
        kc_hat,
    }
}

fn num(x: f64) -> Value {
    crate::eval::num(x)
}

fn report_json(rep: &SimReport, dta: f64) -> Value {
    let estimate = match &rep.estimate {
        Some(Ok(r)) => json!({
            "phalanx": located_name(r.located),
            "k2": r.k2_um.map(|k| num(f64::from(k) / 1e6)),
            "sigma_k2": r.k2_sigma_um.map(|s| num(f64::from(s) / 1e6)),
            "radius": r.radius_um.map(|v| num(f64::from(v) / 1e6)),
            "two_point_k2": r.two_point_k2_um.map(|k| num(f64::from(k) / 1e6)),
            "kc_hat": crate::sim::kc_hat_nm_per_rad(r).map(num),
            "dta": num(f64::from(r.delta_ta_unm) / 1e6),
            "dtheta_a": num(f64::from(r.delta_theta_a_urad) / 1e6),
            "theta_a_c": num(f64::from(r.theta_a_c_urad) / 1e6),
            "ta_c": num(f64::from(r.ta_c_unm) / 1e6),
            "quality": quality_name(r.quality),
        }),
        Some(Err(e)) => json!({"error": e.kind, "message": e.detail}),
        None => Value::Null,
    };
    json!({
        "scene": rep.scene,
        "dta_cmd": num(dta),
        "state": crate::trace::state_name(rep.state),
        "fault": rep.fault(),
        "estimate": estimate,
        "truth": {
            "first_contact": rep.first_contact.map(|(t, ph, k)| json!({"t_s": num(t), "phalanx": ph, "k": num(k)})),
            "k_at_settle": rep.k_at_settle_m.map(num),
        },
        "method": rep.method.name(),
        "error_pct_l2": rep.error_pct_l2().map(num),
        "time_to_know_s": rep.time_to_know_s().map(num),
        "events": rep.events.iter().map(|e| json!({
            "t_s": num(e.t_s), "source": e.source, "event": e.name, "detail": e.detail
        })).collect::<Vec<_>>(),
        "t_end_s": num(rep.t_end_s),
    })
}

fn print_report(rep: &SimReport, dta: f64, wall_s: f64) {
    crate::outln!(
        "scene {}  ΔT_a = {dta} N·m  ({:.2} s simulated in {wall_s:.1} s)",
        rep.scene,
        rep.t_end_s
    );
    crate::outln!("events:");
    for e in &rep.events {
        crate::outln!(
            "  {:>8.4} s  {:<5} {:<18} {}",
            e.t_s,
            e.source,
            e.name,
            e.detail
        );
    }
    match (&rep.estimate, rep.first_contact) {
        (Some(Ok(r)), truth) => {
            crate::outln!("estimate: {}", sim::describe(r));
            if let Some((t, ph, k)) = truth {
                crate::outln!(
                    "truth:    first contact at {t:.4} s on the {ph} phalanx, k = {:.2} mm",
                    k * 1e3
                );
            }
            if let Some(k) = rep.k_at_settle_m {
                crate::outln!("          contact at settle k = {:.2} mm", k * 1e3);
            }
            match rep.error_pct_l2() {
                Some(e) => crate::outln!(
                    "error:    k̂2 − k2,c = {e:+.2} % of l2 ({})",
                    rep.method.name()
                ),
                None => crate::outln!("error:    n/a (no distal location to compare)"),
            }
            if let Some(t) = rep.time_to_know_s() {
                crate::outln!("known:    {t:.3} s after the first contact");
            }
        }
        (Some(Err(e)), _) => crate::outln!("estimate refused: {} ({e})", e.kind),
        (None, _) => crate::outln!("no estimate"),
    }
    if let Some(f) = rep.fault() {
        crate::outln!("fault:    {f}");
    }
}

/// One cell of the sweep.
struct Cell {
    radius_cm: f64,
    k2_pct: f64,
    dta: f64,
    step: Option<grasp::StepShape>,
    err: Option<f64>,
    /// First contact → estimate delivered (s).
    time_to_know_s: Option<f64>,
    outcome: String,
}

fn sweep(a: &Args) -> Result<(), String> {
    let base = plant::scenes::table2();
    let base = if a.ideal { base.ideal() } else { base };
    let (base, from_file) = with_finger(a, base)?;
    let l2 = base.finger.l2_m;
    for r in &a.radii_cm {
        if !(r.is_finite() && (0.0..=20.0).contains(r)) {
            return Err("--radii-cm: radii in [0, 20] cm".into());
        }
    }
    for k in &a.k2_pct {
        if !(k.is_finite() && *k > 0.0 && *k <= 100.0) {
            return Err("--k2-pct: locations in (0, 100] % of l2".into());
        }
    }
    let steps = step_shapes(a)?;
    if a.plot.is_some() && steps.len() > 1 {
        return Err("--plot draws one step setting: give one --step-ramp value".into());
    }
    let mut jobs = vec![];
    for &st in &steps {
        for &r in &a.radii_cm {
            for &k in &a.k2_pct {
                for &d in &a.dta {
                    jobs.push((st, r, k, d));
                }
            }
        }
    }
    let total = jobs.len();
    let t0 = Instant::now();
    let mut cells = vec![];
    for (i, (st, r, k, d)) in jobs.into_iter().enumerate() {
        progress(i, total, t0);
        let scene = plant::Scene {
            name: "sweep",
            object: plant::scene::ObjectSpec::Touching(plant::ContactSpec {
                theta1_c_rad: plant::scenes::TABLE2_THETA1_C_RAD,
                phalanx: plant::Phalanx::Distal,
                k_c_m: k / 100.0 * l2,
                radius_m: r / 100.0,
            }),
            ..base
        };
        let rep = sim::run(&SimOptions {
            scene,
            delta_ta_nm: d,
            max_s: a.max_s,
            extra_s: 0.0,
            record: false,
            method: a.method,
            overcurrent_a: from_file.map(|c| c.overcurrent_a),
            priors: from_file.map(|c| c.priors),
            step_shape: st,
            seating: a.seating,
        });
        let time_to_know_s = rep.as_ref().ok().and_then(SimReport::time_to_know_s);
        let (err, outcome) = match rep {
            Err(e) => (None, format!("scene: {e}")),
            Ok(rep) => match (&rep.estimate, rep.error_pct_l2(), rep.fault()) {
                (_, Some(e), _) => (Some(e), "ok".to_string()),
                (Some(Err(e)), _, _) => (None, e.kind.to_string()),
                (_, _, Some(f)) => (None, f.to_string()),
                (Some(Ok(r)), None, None) => match rep.first_contact {
                    Some((_, ph, _)) if ph != "distal" => (None, format!("touched {ph}")),
                    _ => (None, located_name(r.located).to_string()),
                },
                (None, None, None) => (None, "no_estimate".to_string()),
            },
        };
        cells.push(Cell {
            radius_cm: r,
            k2_pct: k,
            dta: d,
            step: st,
            err,
            time_to_know_s,
            outcome,
        });
    }
    progress(total, total, t0);
    eprintln!();
    if a.json {
        let out = json!({
            "method": a.method.name(),
            "ideal": a.ideal,
            "l2": num(l2),
            "cells": cells.iter().map(|c| json!({
                "radius": num(c.radius_cm / 100.0),
                "k2_c": num(c.k2_pct / 100.0 * l2),
                "dta": num(c.dta),
                "step": step_name(c.step),
                "error_pct_l2": c.err.map(num),
                "time_to_know_s": c.time_to_know_s.map(num),
                "outcome": c.outcome,
            })).collect::<Vec<_>>(),
        });
        crate::outln!("{out}");
    } else {
        for &st in &steps {
            let cells: Vec<&Cell> = cells.iter().filter(|c| c.step == st).collect();
            print_error_table(a, &cells, st);
        }
        print_time_to_know(a, &cells, &steps);
        crate::outln!("({} runs in {:.1} s)", total, t0.elapsed().as_secs_f64());
    }
    if let Some(path) = &a.plot {
        let flat: Vec<SweepCell> = cells
            .iter()
            .map(|c| (c.radius_cm, c.k2_pct, c.dta, c.err))
            .collect();
        plot::heat_map(
            path,
            plot::Size {
                width: 1000,
                height: 700,
            },
            &heat_title(a.method.name(), a.ideal),
            &table(&flat),
        )?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// The location error per object × contact location (rows) and ΔT_a (columns) of one step
/// setting, with the largest |error| per object (as MODEL.md's table).
fn print_error_table(a: &Args, cells: &[&Cell], step: Option<grasp::StepShape>) {
    crate::outln!(
        "location error k̂2 − k2,c (% of l2), {} estimate, closed loop{}, {}; rows: object, contact location; columns: ΔT_a (N·m)",
        a.method.name(),
        if a.ideal { ", ideal drive" } else { "" },
        step_name(step)
    );
    let max_abs = |r: f64, d: f64| -> Option<f64> {
        let v: Vec<Option<f64>> = cells
            .iter()
            .filter(|c| c.radius_cm == r && c.dta == d)
            .map(|c| c.err.map(f64::abs))
            .collect();
        v.into_iter().flatten().reduce(f64::max)
    };
    let w = cells
        .iter()
        .map(|c| c.outcome.len() + 2)
        .chain([10])
        .max()
        .unwrap_or(10);
    let mut head = format!("{:<22}", "object / k2,c");
    for d in &a.dta {
        head += &format!("{:>w$}", format!("{d}"));
    }
    crate::outln!("{head}");
    for &r in &a.radii_cm {
        let obj = if r == 0.0 {
            "vertex".to_string()
        } else {
            format!("R = {r} cm")
        };
        for &k in &a.k2_pct {
            let mut line = format!("{:<22}", format!("{obj}, {k} %"));
            for &d in &a.dta {
                let c = cells
                    .iter()
                    .find(|c| c.radius_cm == r && c.k2_pct == k && c.dta == d);
                let txt = match c {
                    Some(Cell { err: Some(e), .. }) => format!("{e:+.2}"),
                    Some(c) => c.outcome.clone(),
                    None => "-".into(),
                };
                line += &format!("{txt:>w$}");
            }
            crate::outln!("{line}");
        }
        let mut line = format!("{:<22}", format!("{obj}, max |err|"));
        for &d in &a.dta {
            line += &format!(
                "{:>w$}",
                max_abs(r, d).map_or("-".to_string(), |v| format!("{v:.2}"))
            );
        }
        crate::outln!("{line}");
    }
}

/// Time to know against the error, per step setting and ΔT_a over the grid's objects and
/// contact locations: distal contacts answered, mean and largest |error|, median and largest
/// time from the first contact to the estimate.
fn print_time_to_know(a: &Args, cells: &[Cell], steps: &[Option<grasp::StepShape>]) {
    crate::outln!(
        "\ntime to know (first contact → estimate delivered) against the error, {} estimate:",
        a.method.name()
    );
    crate::outln!(
        "{:<18} {:>6} {:>9} {:>12} {:>11} {:>15} {:>12}",
        "step",
        "ΔT_a",
        "answered",
        "mean |err|",
        "max |err|",
        "median to know",
        "max to know"
    );
    for &st in steps {
        for &d in &a.dta {
            let sel: Vec<&Cell> = cells
                .iter()
                .filter(|c| c.step == st && c.dta == d)
                .collect();
            let errs: Vec<f64> = sel.iter().filter_map(|c| c.err.map(f64::abs)).collect();
            let mut know: Vec<f64> = sel
                .iter()
                .filter(|c| c.err.is_some())
                .filter_map(|c| c.time_to_know_s)
                .collect();
            know.sort_by(f64::total_cmp);
            let pct = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.2} %"));
            let secs = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.3} s"));
            let mean = (!errs.is_empty()).then(|| errs.iter().sum::<f64>() / errs.len() as f64);
            crate::outln!(
                "{:<18} {:>6} {:>9} {:>12} {:>11} {:>15} {:>12}",
                step_name(st),
                d,
                format!("{}/{}", errs.len(), sel.len()),
                pct(mean),
                pct(errs.iter().copied().reduce(f64::max)),
                secs(know.get(know.len() / 2).copied()),
                secs(know.last().copied())
            );
        }
    }
}

/// A sweep result: (radius cm, k2,c % of l2, ΔT_a N·m, signed error % of l2 or no estimate).
pub type SweepCell = (f64, f64, f64, Option<f64>);

fn heat_title(method: &str, ideal: bool) -> String {
    format!(
        "{method} estimate: location error, closed loop{}",
        if ideal {
            ", ideal drive"
        } else {
            ", realistic drive"
        }
    )
}

fn uniq(v: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut out: Vec<f64> = vec![];
    for x in v {
        if !out.contains(&x) {
            out.push(x);
        }
    }
    out.sort_by(|a, b| a.partial_cmp(b).unwrap_or(std::cmp::Ordering::Equal));
    out
}

/// The heat-map table of sweep cells (radius cm, k2 %, ΔT_a, signed error % l2): rows are the
/// contact locations when there is one radius, else the radii (max |error| over locations).
pub fn table(cells: &[SweepCell]) -> plot::Table {
    let radii = uniq(cells.iter().map(|c| c.0));
    let ks = uniq(cells.iter().map(|c| c.1));
    let dtas = uniq(cells.iter().map(|c| c.2));
    let pick = |f: &dyn Fn(&SweepCell) -> bool| -> Option<f64> {
        cells
            .iter()
            .filter(|c| f(c))
            .filter_map(|c| c.3.map(f64::abs))
            .reduce(f64::max)
    };
    if radii.len() == 1 {
        plot::Table {
            row_name: "contact location k2,c (% of l2)".into(),
            col_name: "torque step ΔT_a (N·m)".into(),
            cells: ks
                .iter()
                .map(|&k| {
                    dtas.iter()
                        .map(|&d| pick(&|c| c.1 == k && c.2 == d))
                        .collect()
                })
                .collect(),
            rows: ks,
            cols: dtas,
            value_name: "|estimated k2 − k2,c| (% of l2)".into(),
            notes: vec![],
            vmax: None,
        }
    } else {
        plot::Table {
            row_name: "object radius (mm; 0 = vertex)".into(),
            col_name: "torque step ΔT_a (N·m)".into(),
            cells: radii
                .iter()
                .map(|&r| {
                    dtas.iter()
                        .map(|&d| pick(&|c| c.0 == r && c.2 == d))
                        .collect()
                })
                .collect(),
            // Figures use mm throughout; the sweep's own unit is cm.
            rows: radii.iter().map(|r| r * 10.0).collect(),
            cols: dtas.clone(),
            notes: radii
                .iter()
                .map(|&r| {
                    dtas.iter()
                        .map(|&d| {
                            let all = cells.iter().filter(|c| c.0 == r && c.2 == d);
                            let n = all.clone().count();
                            let ok = all.filter(|c| c.3.is_some()).count();
                            if ok == n {
                                String::new()
                            } else {
                                format!("({ok} of {n})")
                            }
                        })
                        .collect()
                })
                .collect(),
            value_name: "max |estimated k2 − k2,c| (% of l2)".into(),
            vmax: None,
        }
    }
}

/// Runs `pts plot heat`: the JSON of `pts sim --sweep --json` as a heat map.
pub fn plot_heat(
    sweep: &std::path::Path,
    out: &std::path::Path,
    size: plot::Size,
    vmax: Option<f64>,
) -> Result<(), String> {
    let text = std::fs::read_to_string(sweep)
        .map_err(|e| format!("cannot read {}: {e}", sweep.display()))?;
    let v: Value = serde_json::from_str(&text).map_err(|e| {
        format!(
            "{}: not the JSON of `pts sim --sweep --json`: {e}",
            sweep.display()
        )
    })?;
    let Some(list) = v.get("cells").and_then(Value::as_array) else {
        return Err(format!("{}: no \"cells\" array", sweep.display()));
    };
    let l2 = v.get("l2").and_then(Value::as_f64).unwrap_or(0.075);
    let mut cells = vec![];
    for c in list {
        let f = |k: &str| c.get(k).and_then(Value::as_f64);
        let (Some(r), Some(k), Some(d)) = (f("radius"), f("k2_c"), f("dta")) else {
            return Err(format!(
                "{}: a cell lacks radius, k2_c or dta",
                sweep.display()
            ));
        };
        cells.push((
            r * 100.0,
            (k / l2 * 1000.0).round() / 10.0,
            d,
            f("error_pct_l2"),
        ));
    }
    if cells.is_empty() {
        return Err(format!("{}: the sweep has no cells", sweep.display()));
    }
    let method = v
        .get("method")
        .and_then(Value::as_str)
        .unwrap_or("two-point");
    let ideal = v.get("ideal").and_then(Value::as_bool).unwrap_or(false);
    let mut t = table(&cells);
    t.vmax = vmax;
    plot::heat_map(out, size, &heat_title(method, ideal), &t)?;
    eprintln!("wrote {}", out.display());
    Ok(())
}

/// Progress on stderr: a bar redrawn in place on a terminal; into a file or pipe, a plain line
/// at every tenth of the runs (no carriage-return frames in logs).
fn progress(done: usize, total: usize, t0: Instant) {
    use std::io::IsTerminal;
    if !std::io::stderr().is_terminal() {
        let tenth = (total / 10).max(1);
        if done % tenth == 0 || done == total {
            eprintln!("{done}/{total} runs, {:.0} s", t0.elapsed().as_secs_f64());
        }
        return;
    }
    let width = 30;
    let filled = (done * width)
        .checked_div(total)
        .unwrap_or(width)
        .min(width);
    let el = t0.elapsed().as_secs_f64();
    let eta = if done > 0 && done < total {
        format!(", ~{:.0} s left", el / done as f64 * (total - done) as f64)
    } else {
        String::new()
    };
    eprint!(
        "\r[{}{}] {done}/{total} runs, {el:.0} s{eta}   ",
        "#".repeat(filled),
        ".".repeat(width - filled)
    );
    let _ = std::io::stderr().flush();
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The `--list` descriptions say what the scene data holds: the values written in
    /// plant's scene catalogue (cylinder 10 mm at k2 = 15 mm; a 2 Ω short at 1 s; the ideal
    /// variant of table2; the power-up offset).
    #[test]
    fn scene_summaries_name_object_drive_and_faults() {
        let s = |n: &str| scene_summary(&plant::scenes::by_name(n).unwrap());
        let cyl = s("cyl10_k2_20");
        assert!(
            cyl.starts_with("cylinder R 10.0 mm first touching the distal phalanx at k = 15.0 mm")
                && cyl.ends_with("realistic drive"),
            "{cyl}"
        );
        assert!(s("table2_ideal").ends_with("; ideal drive"));
        assert!(s("vertex_k2_30").starts_with("vertex first touching the distal"));
        assert!(s("proximal_vertex_k1_50").contains("proximal phalanx at k = 50.0 mm"));
        assert!(s("free").starts_with("no object"));
        assert!(s("fault_short").ends_with("winding shorted to 2 Ω at 1 s"));
        assert!(s("fault_power_up_away").ends_with("powered up 0.45 rad from rest"));
        assert!(!s("table2").contains("stuck"));
    }
}
