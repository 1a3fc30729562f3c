//! `pts estimate --trace` and `pts trace --from-defmt` as commands.

use crate::method::Method;
use crate::replay::{self, TraceMeta};
use crate::trace::{self, located_name, quality_name, Trace};
use grasp::EstimateResult;
use serde_json::{json, Value};
use std::io::{Read, Write};
use std::path::Path;

/// Default ΔT_a (N·m) when neither the flag nor the trace says: the controller's default.
pub const DEFAULT_DTA_NM: f64 = 0.2;

/// Largest trace or log file the tools read (bytes): far above any grasp (a 10 s trace at
/// 10 kHz is about 4 MB), small enough that a wrong file cannot exhaust the machine.
pub const TEXT_MAX_BYTES: u64 = 64 << 20;

/// Reads a text file (`-` = stdin) with a clear message; non-UTF-8 bytes are replaced. Files
/// above [`TEXT_MAX_BYTES`] are refused, naming the limit.
pub fn read_text(path: &Path) -> Result<String, String> {
    read_text_limited(path, TEXT_MAX_BYTES)
}

/// [`read_text`] with a given limit (bytes).
pub fn read_text_limited(path: &Path, limit: u64) -> Result<String, String> {
    let too_big = |what: &str| format!("{what} is larger than the {limit}-byte limit for a trace");
    // Sized from the file's length when it has one, so that reading does not grow the buffer
    // geometrically (up to twice the file).
    let mut bytes = vec![];
    if path.as_os_str() == "-" {
        std::io::stdin()
            .lock()
            .take(limit + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| format!("reading stdin: {e}"))?;
        if bytes.len() as u64 > limit {
            return Err(too_big("stdin"));
        }
    } else {
        let f = std::fs::File::open(path)
            .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        if let Ok(m) = f.metadata() {
            bytes.reserve_exact(m.len().min(limit + 1) as usize + 1);
        }
        f.take(limit + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        if bytes.len() as u64 > limit {
            return Err(too_big(&path.display().to_string()));
        }
    }
    // Valid UTF-8 (the usual case) becomes the string without a copy.
    Ok(String::from_utf8(bytes)
        .unwrap_or_else(|e| String::from_utf8_lossy(e.as_bytes()).into_owned()))
}

/// Loads and replays a trace; the returned trace is the one replayed.
pub fn load_and_replay(
    path: &Path,
    finger: Option<&Path>,
    dta: Option<f64>,
    dt_s: Option<f64>,
    method: Method,
) -> Result<(Trace, replay::Replay, f64), String> {
    let text = read_text(path)?;
    replay_text(path, &text, finger, dta, dt_s, method)
}

/// [`load_and_replay`] on text already read.
pub fn replay_text(
    path: &Path,
    text: &str,
    finger: Option<&Path>,
    dta: Option<f64>,
    dt_s: Option<f64>,
    method: Method,
) -> Result<(Trace, replay::Replay, f64), String> {
    let mut file = crate::load_finger(finger)?;
    let meta = TraceMeta::find(text);
    // A trace from `pts sim` says which drive constants its controller used: without a
    // finger file, replay with those (e.g. an ideal-drive scene has η = 1).
    if let (None, Some(d)) = (finger, meta.and_then(|m| m.drive)) {
        d.apply(&mut file)
            .map_err(|e| format!("{}: the # pts-sim line: {e}", path.display()))?;
        if let Err(e) = pts::config::FingerFile::from_toml_str(&file.to_toml_string()) {
            return Err(format!("{}: the # pts-sim line: {e}", path.display()));
        }
    }
    let conv = |i: f64| file.torque_from_current(i);
    let tr = trace::read_csv(text, &conv).map_err(|e| format!("{}: {e}", path.display()))?;
    let source = if dta.is_some() {
        "--dta"
    } else {
        "the # pts-sim line's ΔT_a"
    };
    let dta = dta.or(meta.map(|m| m.dta_nm)).unwrap_or(DEFAULT_DTA_NM);
    if !(dta.is_finite() && dta > 0.0 && dta <= 2.0) {
        return Err(format!("{source} {dta} N·m is outside (0, 2] N·m"));
    }
    if let Some(dt) = dt_s {
        if !(dt.is_finite() && dt > 0.0 && dt <= 0.1) {
            return Err(format!("--dt-s {dt} s is outside (0, 0.1] s"));
        }
    }
    let dt_s = dt_s.or(meta.map(|m| m.dt_s));
    let settings = meta.map(|m| m.controller).unwrap_or_default();
    let rep = replay::replay(&tr, &file, dta, dt_s, method, &settings)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    Ok((tr, rep, dta))
}

/// Writes an estimate's fields (SI units) into a JSON contact object.
fn put_result(v: &mut Value, r: &EstimateResult) {
    // The contact point the estimator used (it may refine the detection's).
    v["theta_a_c"] = n(f64::from(r.theta_a_c_urad) / 1e6);
    v["ta_c"] = n(f64::from(r.ta_c_unm) / 1e6);
    v["phalanx"] = json!(located_name(r.located));
    v["k2"] = r.k2_um.map_or(Value::Null, |k| n(f64::from(k) / 1e6));
    v["kc_hat"] = crate::sim::kc_hat_nm_per_rad(r).map_or(Value::Null, n);
    v["dta"] = n(f64::from(r.delta_ta_unm) / 1e6);
    v["dtheta_a"] = n(f64::from(r.delta_theta_a_urad) / 1e6);
    v["quality"] = json!(quality_name(r.quality));
}

fn n(x: f64) -> Value {
    crate::eval::num(x)
}

/// Largest |`--theta-a-offset`| (rad): a whole turn.
pub const THETA_A_OFFSET_MAX_RAD: f64 = core::f64::consts::TAU;

/// What `pts estimate` was asked.
#[derive(Clone, Copy, Debug)]
pub struct EstimateArgs<'a> {
    /// The recorded grasp (CSV; `-` for stdin).
    pub trace: &'a Path,
    /// Finger file; `None`: the paper's prototype.
    pub finger: Option<&'a Path>,
    /// ΔT_a (N·m) for a `pts sim` trace's replay.
    pub dta: Option<f64>,
    /// Control period (s) for a `pts sim` trace's replay.
    pub dt_s: Option<f64>,
    /// One JSON object instead of text.
    pub json: bool,
    /// The estimator; `None`: the recording's, else the path fit.
    pub method: Option<Method>,
    /// Added to every row's θa (rad) of a recording before it is read: brings an encoder
    /// zeroed elsewhere into the finger's absolute model angle.
    pub theta_a_offset_rad: Option<f64>,
}

/// Why `pts estimate` gave no answer.
enum Failure {
    /// Nothing was read: the arguments, the file or the recording as a whole. `kind` is the
    /// snake_case name a `--json` reader matches on.
    Unread { kind: &'static str, message: String },
    /// The recording was read and reported (its JSON printed); no contact was answered.
    NoEstimate(String),
}

/// A message of a step that reads nothing, as a [`Failure::Unread`] of `kind`.
fn unread(kind: &'static str) -> impl Fn(String) -> Failure {
    move |message| Failure::Unread { kind, message }
}

/// Runs `pts estimate`. With `--json` a recording that cannot be read at all prints one JSON
/// object too, `{"trace": …, "error": {"kind": …, "message": …}}`, so that a script over
/// many files gets a line for each.
pub fn run(args: &EstimateArgs<'_>) -> Result<(), String> {
    match run_reporting(args) {
        Ok(()) => Ok(()),
        Err(Failure::NoEstimate(message)) => Err(message),
        Err(Failure::Unread { kind, message }) => {
            if args.json {
                let out = json!({
                    "trace": args.trace.display().to_string(),
                    "error": { "kind": kind, "message": message },
                });
                crate::outln!("{out}");
            }
            Err(message)
        }
    }
}

/// [`run`] up to the failure, which it leaves to [`run`] to report.
fn run_reporting(args: &EstimateArgs<'_>) -> Result<(), Failure> {
    let EstimateArgs {
        trace: path,
        finger,
        dta,
        dt_s,
        json: json_out,
        method,
        theta_a_offset_rad,
    } = *args;
    if let Some(o) = theta_a_offset_rad {
        if !(o.is_finite() && o.abs() <= THETA_A_OFFSET_MAX_RAD) {
            return Err(unread("bad_argument")(format!(
                "--theta-a-offset {o} rad is outside [-{THETA_A_OFFSET_MAX_RAD:.4}, \
                 {THETA_A_OFFSET_MAX_RAD:.4}] rad"
            )));
        }
    }
    let text = read_text(path).map_err(unread("unreadable_file"))?;
    // A trace written by `pts sim` (our controller in the loop): replay that controller, bit
    // for bit. Any other recorded grasp: find its contacts with crate::offline.
    if TraceMeta::find(&text).is_none() {
        let method = method.unwrap_or(Method::Pathfit);
        return run_segmented(args, &text, method);
    }
    if theta_a_offset_rad.is_some() {
        return Err(unread("bad_argument")(format!(
            "{}: --theta-a-offset is for recordings; this is a `pts sim` trace, in the finger's \
             model angle already",
            path.display()
        )));
    }
    // The recording's own estimator unless the user names one.
    let recorded = TraceMeta::find(&text).and_then(|m| m.controller.estimator);
    let method = method.or(recorded).unwrap_or(Method::Pathfit);
    let (tr, rep, dta) =
        replay_text(path, &text, finger, dta, dt_s, method).map_err(unread("unreadable_trace"))?;
    let warnings: Vec<String> = tr.warnings.iter().chain(&rep.warnings).cloned().collect();
    let fault = match rep.state {
        grasp::State::Fault(r) => Some(r.kind()),
        _ => None,
    };
    let (t0, t1) = (
        tr.t_s.first().copied().unwrap_or(0.0),
        tr.t_s.last().copied().unwrap_or(0.0),
    );
    let outcome = match (&rep.contact, &rep.estimate, fault) {
        (_, Some(Ok(_)), _) => Ok(()),
        (_, _, Some(f)) => Err(format!("the grasp ended in the fault {f}: no estimate")),
        (None, _, None) => Err("no contact found: no estimate".to_string()),
        (Some(_), Some(Err(e)), None) => {
            Err(format!("the estimator refused the grasp: {}", e.kind))
        }
        (Some(_), None, None) => Err("the step did not settle: no estimate".to_string()),
    };
    if json_out {
        let contacts: Vec<Value> = match (&rep.contact, &rep.estimate) {
            (None, _) => vec![],
            (Some((t, thc, tac)), est) => {
                let mut c = json!({
                    "t_s": n(*t),
                    "theta_a_c": n(*thc),
                    "ta_c": n(*tac),
                    "fault": fault,
                });
                match est {
                    Some(Ok(r)) => {
                        put_result(&mut c, r);
                    }
                    Some(Err(e)) => {
                        c["estimate_error"] = json!(e.kind);
                    }
                    None => {}
                }
                vec![c]
            }
        };
        let out = json!({
            "trace": path.display().to_string(),
            "rows": tr.len(),
            "t_s": [n(t0), n(t1)],
            "dt_s": n(rep.dt_s),
            "dta_cmd": n(dta),
            "method": method.name(),
            "exact_replay": rep.raw,
            "state": trace::state_name(rep.state),
            "contacts": contacts,
            "warnings": warnings,
        });
        crate::outln!("{out}");
        return outcome.map_err(Failure::NoEstimate);
    }
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    crate::outln!(
        "{}: {} rows, t = {t0:.4} … {t1:.4} s, control period {} s, ΔT_a = {dta} N·m, {} estimate{}",
        path.display(),
        tr.len(),
        rep.dt_s,
        method.name(),
        if rep.raw {
            ", raw encoder/ADC columns"
        } else {
            ""
        }
    );
    match (&rep.contact, &rep.estimate) {
        (None, _) => crate::outln!(
            "no contact found (controller ended in {})",
            trace::state_name(rep.state)
        ),
        (Some((t, thc, tac)), est) => {
            let (thc, tac) = match est {
                Some(Ok(r)) => (
                    f64::from(r.theta_a_c_urad) / 1e6,
                    f64::from(r.ta_c_unm) / 1e6,
                ),
                _ => (*thc, *tac),
            };
            crate::outln!("contact 1 at t = {t:.4} s: θa,c = {thc:.6} rad, T_a,c = {tac:.4} N·m");
            match est {
                Some(Ok(r)) => crate::outln!("  {}", crate::sim::describe(r)),
                Some(Err(e)) => crate::outln!("  estimate refused: {} ({e})", e.kind),
                None => crate::outln!("  the step did not settle: no estimate"),
            }
        }
    }
    if let Some(f) = fault {
        crate::outln!("  fault: {f}");
    }
    outcome.map_err(Failure::NoEstimate)
}

/// `pts estimate` on a trace without the `# pts-sim` line: the offline segmenter finds each
/// contact, its step and settled end, and the firmware's estimator runs on each request.
fn run_segmented(args: &EstimateArgs<'_>, text: &str, method: Method) -> Result<(), Failure> {
    let (path, json_out) = (args.trace, args.json);
    let file = crate::load_finger(args.finger).map_err(unread("finger_file"))?;
    let conv = |i: f64| file.torque_from_current(i);
    let mut tr = trace::read_csv(text, &conv)
        .map_err(|e| unread("unreadable_trace")(format!("{}: {e}", path.display())))?;
    if let Some(o) = args.theta_a_offset_rad {
        for th in &mut tr.theta_a_rad {
            *th += o;
        }
    }
    if replay::median_dt(&tr).is_none() {
        return Err(unread("too_few_rows")(format!(
            "{}: the trace needs at least two rows with increasing t_s",
            path.display()
        )));
    }
    let seg = replay::segment(&tr, &file, method).map_err(|e| Failure::Unread {
        kind: e.kind,
        message: format!("{}: {e}", path.display()),
    })?;
    let mut warnings = tr.warnings.clone();
    if args.dta.is_some() || args.dt_s.is_some() {
        warnings.push(
            "no # pts-sim line: --dta/--dt-s are ignored (ΔT_a is measured from the trace)".into(),
        );
    }
    let (t0, t1) = (
        tr.t_s.first().copied().unwrap_or(0.0),
        tr.t_s.last().copied().unwrap_or(0.0),
    );
    let outcome = if seg.contacts.iter().any(|c| c.estimate.is_ok()) {
        Ok(())
    } else if seg.contacts.is_empty() {
        Err("no contact found: no estimate".to_string())
    } else {
        Err("the estimator refused every contact: no estimate".to_string())
    };
    if json_out {
        let contacts: Vec<Value> = seg
            .contacts
            .iter()
            .map(|c| {
                let mut v = json!({
                    "t_s": n(c.t_s),
                    "theta_a_c": n(c.theta_a_c),
                    "ta_c": n(c.ta_c),
                    "t_end_s": n(c.end_t_s),
                    "fault": Value::Null,
                });
                match &c.estimate {
                    Ok(r) => {
                        put_result(&mut v, r);
                    }
                    Err(e) => v["estimate_error"] = json!(e.kind),
                }
                if let Some(s) = c.sigma_k2_m {
                    v["sigma_k2"] = n(s);
                }
                if let Some((a, total)) = c.phases {
                    v["phases"] = json!({ "answered": a, "total": total });
                }
                if let Some(d) = &c.drive {
                    v["drive"] = json!({
                        "inertia_kgm2": n(d.inertia_kgm2),
                        "sigma_inertia_kgm2": n(d.sigma_inertia_kgm2),
                        "viscous_nm_s_per_rad": n(d.viscous_nm_s_per_rad),
                        "sigma_viscous_nm_s_per_rad": n(d.sigma_viscous_nm_s_per_rad),
                        "offset_nm": n(d.offset_nm),
                        "sigma_offset_nm": n(d.sigma_offset_nm),
                        "stiction_excess_nm": d.stiction_excess_nm.map(|s| n(s.0)),
                        "sigma_stiction_excess_nm": d.stiction_excess_nm.map(|s| n(s.1)),
                        "noise_nm": n(d.noise_nm),
                        "blocks": d.blocks,
                    });
                }
                if let Some(p) = &c.path_reading {
                    let (gap, sigma) = match p {
                        crate::replay::PathReading::LoadingRows(
                            crate::replay::LoadingReason::PathHysteresis { gap_nm, sigma_nm },
                        ) => (Some(n(*gap_nm)), Some(n(*sigma_nm))),
                        _ => (None, None),
                    };
                    v["path_read"] = json!({
                        "samples": p.name(),
                        "reason": p.reason(),
                        "hysteresis_nm": gap,
                        "sigma_hysteresis_nm": sigma,
                    });
                }
                if let Some(d) = c.contact_dynamics {
                    v["contact_inertia_kgm2"] = n(d.inertia_kgm2);
                    v["sigma_contact_inertia_kgm2"] = n(d.sigma_inertia_kgm2);
                    v["contact_viscous_nm_s_per_rad"] = n(d.viscous_nm_s_per_rad);
                }
                if let Some(tp) = &c.two_point {
                    let mut t = json!({});
                    match tp {
                        Ok(r) => put_result(&mut t, r),
                        Err(e) => t["estimate_error"] = json!(e.kind),
                    }
                    v["two_point"] = t;
                }
                v
            })
            .collect();
        let errors: Vec<Value> = seg.errors.iter().map(|(k, _)| json!(k)).collect();
        let out = json!({
            "trace": path.display().to_string(),
            "rows": tr.len(),
            "t_s": [n(t0), n(t1)],
            "block_s": n(seg.block_s),
            "method": method.name(),
            "segmented": true,
            "exact_replay": false,
            "contacts": contacts,
            "segment_errors": errors,
            "gaps_s": seg.gaps_s.iter().map(|(a, b)| [n(*a), n(*b)]).collect::<Vec<_>>(),
            "warnings": warnings,
        });
        println!("{out}");
        return outcome.map_err(Failure::NoEstimate);
    }
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    println!(
        "{}: {} rows, t = {t0:.4} … {t1:.4} s, no # pts-sim line: contacts found by segmentation \
         ({} ms blocks), {} estimate",
        path.display(),
        tr.len(),
        seg.block_s * 1e3,
        method.name(),
    );
    for (a, b) in &seg.gaps_s {
        println!(
            "no rows from t = {a:.4} to {b:.4} s (more than {} s): read as two recordings",
            replay::GAP_SPLIT_S
        );
    }
    for (i, c) in seg.contacts.iter().enumerate() {
        let (thc, tac) = match &c.estimate {
            Ok(r) => (
                f64::from(r.theta_a_c_urad) / 1e6,
                f64::from(r.ta_c_unm) / 1e6,
            ),
            Err(_) => (c.theta_a_c, c.ta_c),
        };
        println!(
            "contact {} at t = {:.4} s: θa,c = {thc:.6} rad, T_a,c = {tac:.4} N·m, settled at t = {:.4} s",
            i + 1,
            c.t_s,
            c.end_t_s
        );
        if let Some(d) = &c.drive {
            println!(
                "  drive from the approach: inertia {:.3e} ± {:.1e} kg·m², viscous {:.4} ± {:.1e} N·m·s/rad, \
                 offset {:.4} ± {:.1e} N·m, noise {:.4} N·m ({} blocks)",
                d.inertia_kgm2,
                d.sigma_inertia_kgm2,
                d.viscous_nm_s_per_rad,
                d.sigma_viscous_nm_s_per_rad,
                d.offset_nm,
                d.sigma_offset_nm,
                d.noise_nm,
                d.blocks
            );
            match d.stiction_excess_nm {
                Some((e, s)) => println!(
                    "  stiction: breakaway {e:.4} ± {s:.1e} N·m above the sliding friction"
                ),
                None => println!(
                    "  stiction: not seen (the recording does not start with the crank at rest)"
                ),
            }
        }
        if let Some(p) = &c.path_reading {
            println!("  path read: {}", p.describe());
        }
        if let Some(d) = c.contact_dynamics {
            println!(
                "  inertia on the contact path: {:.3e} ± {:.1e} kg·m², viscous {:.4} N·m·s/rad (read there: the approach's inertia differs by more than 3σ)",
                d.inertia_kgm2, d.sigma_inertia_kgm2, d.viscous_nm_s_per_rad
            );
        }
        match &c.estimate {
            Ok(r) => println!("  {}", crate::sim::describe(r)),
            Err(e) => println!("  estimate refused: {} ({e})", e.kind),
        }
        if let Some(s) = c.sigma_k2_m {
            println!("  σ(k2,c) = {:.2} mm", s * 1e3);
        }
        if let Some((a, n)) = c.phases {
            println!("  block phases answering on the distal phalanx: {a} of {n}");
        }
        match &c.two_point {
            Some(Ok(r)) => println!("  two-point (reference): {}", crate::sim::describe(r)),
            Some(Err(e)) => println!("  two-point (reference) refused: {} ({e})", e.kind),
            None => {}
        }
    }
    if seg.contacts.is_empty() && seg.errors.is_empty() {
        println!("no contact found");
    }
    for (kind, detail) in &seg.errors {
        println!(
            "{}: {kind} ({detail})",
            if seg.contacts.is_empty() {
                "no contact found"
            } else if !seg.gaps_s.is_empty() {
                "not read"
            } else {
                "after the last contact"
            }
        );
    }
    outcome.map_err(Failure::NoEstimate)
}

/// Runs `pts trace --from-defmt`.
pub fn from_defmt(
    input: &Path,
    out: Option<&Path>,
    finger: Option<&Path>,
    dt_s: Option<f64>,
) -> Result<(), String> {
    let file = crate::load_finger(finger)?;
    let text = read_text(input)?;
    let conv = |i: f64| file.torque_from_current(i);
    let tr = trace::from_defmt(&text, dt_s, &conv);
    for w in &tr.warnings {
        eprintln!("warning: {w}");
    }
    if tr.is_empty() {
        return Err(format!(
            "{}: no telemetry sample lines (`S tick=… theta_a_urad=… torque_unm=…`) found",
            input.display()
        ));
    }
    let rows = tr.to_rows();
    match out {
        Some(p) => {
            let f = std::fs::File::create(p)
                .map_err(|e| format!("cannot create {}: {e}", p.display()))?;
            let mut w = std::io::BufWriter::new(f);
            trace::write_csv(&rows, &mut w)
                .and_then(|()| w.flush())
                .map_err(|e| format!("writing {}: {e}", p.display()))?;
            eprintln!("wrote {} ({} rows)", p.display(), tr.len());
        }
        None => {
            let mut w = std::io::BufWriter::new(std::io::stdout().lock());
            trace::write_csv(&rows, &mut w)
                .and_then(|()| w.flush())
                .map_err(|e| format!("writing stdout: {e}"))?;
        }
    }
    Ok(())
}

/// Runs `pts plot signals`: replays the trace (to find the contact and the estimate) and draws it.
pub fn plot_signals(
    path: &Path,
    finger: Option<&Path>,
    dta: Option<f64>,
    method: Method,
    window: (Option<f64>, Option<f64>),
    out: &Path,
    size: crate::plot::Size,
) -> Result<(), String> {
    let (tr, rep, dta) = load_and_replay(path, finger, dta, None, method)?;
    for w in tr.warnings.iter().chain(&rep.warnings) {
        eprintln!("warning: {w}");
    }
    // Every column of every row, for the plot.
    let mut all = tr.to_rows();
    // Show the controller state the replay went through when the trace has none.
    for (row, st) in all.iter_mut().zip(&rep.states) {
        if row.state.is_none() {
            row.state = Some(st.clone());
        }
    }
    // The plant's first contact (simulated traces), before the window cuts it away.
    let truth = all
        .iter()
        .find(|r| r.true_contact.as_deref() == Some("distal"))
        .and_then(|r| r.true_k_m);
    let (from, to) = window;
    let rows: Vec<_> = all
        .into_iter()
        .filter(|r| from.is_none_or(|f| r.t_s >= f) && to.is_none_or(|t| r.t_s <= t))
        .collect();
    if rows.len() < 2 {
        return Err("fewer than two rows in the time window".into());
    }
    // The horizontal estimated-K_c line belongs to the two-point method only: the path fit does not
    // estimate from that ratio.
    let kc_hat = match (&rep.estimate, method) {
        (Some(Ok(r)), Method::TwoPoint) => crate::sim::kc_hat_nm_per_rad(r),
        _ => None,
    };
    let sig = crate::sim_cmd::signals(&rows, rep.contact, kc_hat);
    let l2_m = crate::load_finger(finger)?.finger.l2;
    let name = path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    let result = match &rep.estimate {
        Some(Ok(r)) => match r.k2_um {
            Some(k2) => {
                let k2_mm = f64::from(k2) / 1e3;
                match truth {
                    Some(k) => format!(
                        "k2 = {k2_mm:.2} mm vs {:.2} mm at first contact ({:+.1} % of l2)",
                        k * 1e3,
                        (k2_mm / 1e3 - k) / l2_m * 100.0
                    ),
                    None => format!("k2 = {k2_mm:.2} mm"),
                }
            }
            None => format!("contact on the {:?} phalanx", r.located).to_lowercase(),
        },
        Some(Err(e)) => format!("estimate refused: {}", e.kind),
        None => "no estimate".into(),
    };
    let title = format!("{name}, {}, ΔT_a {dta} N·m: {result}", method.name());
    crate::plot::signals(out, size, &title, &sig)?;
    eprintln!("wrote {}", out.display());
    Ok(())
}

#[cfg(test)]
mod limit_tests {
    use super::*;

    #[test]
    fn a_file_above_the_limit_is_refused_naming_the_limit() {
        let dir = std::env::temp_dir().join(format!("pts-limit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("t.csv");
        std::fs::write(&p, vec![b'x'; 101]).unwrap();
        let e = read_text_limited(&p, 100).unwrap_err();
        assert!(e.contains("100-byte limit"), "{e}");
        std::fs::write(&p, vec![b'x'; 100]).unwrap();
        assert_eq!(read_text_limited(&p, 100).unwrap().len(), 100);
        // Bytes that are not UTF-8 are replaced, not refused.
        std::fs::write(&p, [b'a', 0xFF, b'b']).unwrap();
        assert_eq!(read_text_limited(&p, 100).unwrap(), "a\u{FFFD}b");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
