//! `cargo xtask test`: the one command that runs every check of the project, on a fresh Debian
//! machine too. Every stage runs (a failure does not hide the others), nothing is skipped, and
//! the last line is `N passed, M failed`; the exit status is non-zero when anything failed.

use std::process::Command;
use std::time::Instant;

use crate::log::{self, int, word};
use crate::qemu::{self, Frame, INSTR_PER_TICK};
use crate::size;
use crate::util::{self, Res};

/// Scenes run in QEMU: three that must end in an estimate, one that must end in the safe state.
const ESTIMATE_SCENES: &[&str] = &["table2", "vertex_k2_30", "cyl10_k2_20"];
const FAULT_SCENE: &str = "fault_encoder_stuck";
/// The controller events every estimate scene must show, in this order.
const ESTIMATE_SEQUENCE: &[&str] = &[
    "Calibrated",
    "ContactDetected",
    "StepDone",
    "Settled",
    "Estimated",
    "Holding",
];
/// Tolerance of the QEMU estimate against the host run of the same controller, × l2.
const K2_TOL_REL_L2: f64 = 1e-4;
/// A finger that is not the paper's (another l2, springs and gear ratio), for the one-finger
/// check: firmware, host runner and `pts` built from this one file.
const TEST_FINGER: &str = "crates/pts-cli/fingers/long_stiff.toml";
/// The firmware's default ΔT_a (src/ctl.rs), given to `pts sim` so both run the same grasp (N·m).
const FW_DELTA_TA: &str = "0.8";
/// How far the firmware's default estimate (the path fit) may sit from the plant's first
/// contact with the non-paper finger, × l2: the bound issue 16 sets for recordings (4 %). This
/// grasp measures 2.9 % (the paper finger's plant grid stays below 2 %); the same grasp
/// estimated on the paper finger's model misses by 12.8 % (`pts estimate --trace
/// target/finger_check.csv` without `--finger`).
const PATH_FIT_VS_FIRST_CONTACT_TOL_REL_L2: f64 = 0.04;

#[derive(Default)]
struct Stages {
    passed: Vec<String>,
    failed: Vec<(String, String)>,
    /// Run only the stages whose name contains this (case-insensitive); `None`: all.
    only: Option<String>,
    /// The stages not selected, by name (listed when none was).
    skipped: Vec<String>,
}

impl Stages {
    fn selected(&self, name: &str) -> bool {
        self.only
            .as_ref()
            .is_none_or(|o| name.to_lowercase().contains(&o.to_lowercase()))
    }

    fn run(&mut self, name: &str, f: impl FnOnce() -> Res) {
        if !self.selected(name) {
            self.skipped.push(name.to_string());
            return;
        }
        eprintln!("\n==== {name} ====");
        let t = Instant::now();
        let r = f();
        eprintln!(
            "{}",
            verdict_line(name, r.is_ok(), t.elapsed().as_secs_f64())
        );
        match r {
            Ok(()) => self.passed.push(name.to_string()),
            Err(e) => {
                eprintln!("{e}");
                self.failed.push((name.to_string(), e));
            }
        }
    }
}

/// A stage's verdict as printed (and as [`LaneLines::take`] reads it back from a lane).
fn verdict_line(name: &str, ok: bool, seconds: f64) -> String {
    let verdict = if ok { "ok" } else { "FAILED" };
    format!("==== {name}: {verdict} ({seconds:.1} s)")
}

/// Makes sure the rustup targets of rust-toolchain.toml are there.
fn toolchain() -> Res {
    let out = util::output(Command::new("rustup").args(["target", "list", "--installed"]))?;
    for t in ["thumbv7em-none-eabihf", "thumbv6m-none-eabi"] {
        if !out.lines().any(|l| l.trim() == t) {
            util::run(Command::new("rustup").args(["target", "add", t]))?;
        }
    }
    Ok(())
}

fn cargo(args: &[&str]) -> Res {
    util::run(util::cargo().args(args))
}

/// The host run of the same control path (src/host.rs) for a scene: its log and its exit
/// status (the firmware's status convention).
fn host_run(scene: &str) -> Res<(Vec<Frame>, i32)> {
    // Build first, so a compile error is reported as such and not as an exit status.
    util::run(util::cargo().args(["build", "-q", "-p", "finger-fw"]))?;
    let scene = qemu::scene_arg(scene)?;
    let (out, code) = util::output_code(util::cargo().args([
        "run",
        "-q",
        "-p",
        "finger-fw",
        "--",
        "simulate",
        "--scene",
        &scene,
    ]))?;
    let frames = out
        .lines()
        .map(|l| Frame {
            ts: None,
            level: "HOST".into(),
            msg: l.to_string(),
        })
        .collect();
    Ok((frames, code))
}

fn expect_end(frames: &[Frame]) -> Res<&Frame> {
    log::last(frames, "END").ok_or_else(|| "no END line in the log".to_string())
}

/// Runs one scene in QEMU and on the host and checks the log.
/// Runs `f` with an environment variable set for the cargo builds it starts.
fn with_env(key: &str, value: &str, f: impl FnOnce() -> Res) -> Res {
    let old = std::env::var_os(key);
    std::env::set_var(key, value);
    let r = f();
    match old {
        Some(v) => std::env::set_var(key, v),
        None => std::env::remove_var(key),
    }
    r
}

fn scene_check(scene: &str, expect_fault: bool, work: &mut Vec<Work>) -> Res {
    scene_check_frames(scene, expect_fault, work).map(|_| ())
}

/// A fault scene's end: a Fault event, exit status 2, the Fault state, the bridge off.
fn fault_end_errors(ev_q: &[String], status: i32, end: &Frame) -> Vec<String> {
    let mut errs = Vec::new();
    if !ev_q.iter().any(|e| e == "Fault") {
        errs.push(format!("fault scene without a Fault event: {ev_q:?}"));
    }
    if status != 2 {
        errs.push(format!("fault scene exited {status} (expected 2)"));
    }
    if !word(&end.msg, "state").unwrap_or("").starts_with("Fault") {
        errs.push(format!(
            "fault scene did not end in the Fault state: {}",
            end.msg
        ));
    }
    if word(&end.msg, "bridge_safe") != Some("true") {
        errs.push(format!("fault scene ended with the bridge on: {}", end.msg));
    }
    errs
}

/// An estimate scene's end: the controller's events in order, exit status 0, and the QEMU
/// estimate equal to the host's within 1e-4·l2.
fn estimate_errors(
    scene: &str,
    ev_q: &[String],
    status: i32,
    end: &Frame,
    q: &[Frame],
    host: &[Frame],
) -> Res<Vec<String>> {
    let mut errs = Vec::new();
    let mut it = ev_q.iter();
    for want in ESTIMATE_SEQUENCE {
        if !it.any(|e| e == want) {
            errs.push(format!(
                "event {want} missing or out of order; got {ev_q:?} (expected {ESTIMATE_SEQUENCE:?} in order)"
            ));
            break;
        }
    }
    if status != 0 {
        errs.push(format!("exit status {status} (expected 0): {}", end.msg));
    }
    let l2_um = log::first(q, "BOOT")
        .and_then(|b| int(&b.msg, "l2_um"))
        .ok_or("no l2_um in the BOOT line")? as f64;
    let k2 = |frames: &[Frame]| log::last(frames, "E Estimated").and_then(|e| int(&e.msg, "k2_um"));
    match (k2(q), k2(host)) {
        (Some(kq), Some(kh)) => {
            let d = (kq - kh).abs() as f64;
            let tol = K2_TOL_REL_L2 * l2_um;
            println!(
                "{scene}: k2 qemu {kq} µm, host {kh} µm, |Δ| = {d} µm (tolerance {tol:.1} µm = 1e-4·l2)"
            );
            if d > tol {
                errs.push(format!(
                    "k2 differs between QEMU ({kq} µm) and host ({kh} µm) by more than 1e-4·l2"
                ));
            }
        }
        other => errs.push(format!(
            "no k2 estimate in both logs (qemu, host) = {other:?}"
        )),
    }
    Ok(errs)
}

/// [`scene_check`], returning the QEMU run's log.
fn scene_check_frames(scene: &str, expect_fault: bool, work: &mut Vec<Work>) -> Res<Vec<Frame>> {
    let elf = qemu::build(scene)?;
    let run = qemu::run(&elf, &mut |f| {
        if !f.msg.starts_with("S ") {
            println!("{}", log::show(f))
        }
    })?;
    let (host, host_status) = host_run(scene)?;
    let q = &run.frames;
    let end = expect_end(q)?;
    let mut errs = Vec::new();
    if host_status != run.status {
        errs.push(format!(
            "exit status differs: QEMU {} vs host {host_status}",
            run.status
        ));
    }

    // The sequence of controller events: as required, and identical on both ISAs.
    let ev_q = log::events(q);
    let ev_h = log::events(&host);
    if ev_q != ev_h {
        errs.push(format!(
            "event sequence differs from the host run of the same controller:\n  qemu: {ev_q:?}\n  host: {ev_h:?}"
        ));
    }
    if expect_fault {
        errs.extend(fault_end_errors(&ev_q, run.status, end));
    } else {
        errs.extend(estimate_errors(scene, &ev_q, run.status, end, q, &host)?);
    }
    for key in ["work_max", "est_work_max", "sup_work_max"] {
        if int(&end.msg, key).is_none() {
            errs.push(format!("END line without {key}"));
        }
    }
    // A fresh QEMU start is a power-on: the settings store's RAM "flash" comes erased.
    match log::first(q, "SETTINGS") {
        Some(f) if word(&f.msg, "status") == Some("empty") => {}
        other => errs.push(format!(
            "expected `SETTINGS status=empty` at the first boot, got {:?}",
            other.map(|f| &f.msg)
        )),
    }
    let per = instr_per_stamp(q)?;
    match size::stack_check(q) {
        Ok(line) => println!("{scene}: {line}"),
        Err(e) => errs.push(e),
    }
    // The stack SAFETY.md quotes: the Table 2 scene of the paper finger, per estimator.
    if scene == "table2" && std::env::var_os("FINGER_TOML").is_none() {
        let est = std::env::var("FINGER_FW_ESTIMATOR").unwrap_or_else(|_| "path-fit".into());
        if let Err(e) = size::stack_used(q).and_then(|u| size::stack_documented(&est, u)) {
            errs.push(e);
        }
    }
    match watchdog_window(q, per) {
        Ok(line) => println!("{scene}: {line}"),
        Err(e) => errs.push(e),
    }
    work.push((
        scene.to_string(),
        int(&end.msg, "work_max").unwrap_or(0) as f64 * per,
        int(&end.msg, "work_mean_x100").unwrap_or(0) as f64 * 0.01 * per,
        int(&end.msg, "est_work_max").unwrap_or(0) as f64 * per,
        int(&end.msg, "sup_work_max").unwrap_or(0) as f64 * per,
    ));
    println!(
        "{scene}: exit {}, {} frames, QEMU wall {:.1} s",
        run.status,
        q.len(),
        run.wall.as_secs_f64()
    );
    if errs.is_empty() {
        Ok(run.frames)
    } else {
        Err(errs.join("\n"))
    }
}

/// The rest check refuses (issue 19): powered up 0.3 rad flexed with the encoder stuck, the
/// QEMU firmware (and the host runner, same events) ends in `rest_not_found` with the bridge
/// off, never approaching, within the check's two timeouts (20 s of control time).
fn rest_not_found_check() -> Res {
    with_env("FINGER_FW_REST_CHECK", "on", || {
        let mut w = Vec::new();
        let q = scene_check_frames("fault_power_up_stuck_encoder", true, &mut w)?;
        let fault = log::last(&q, "E Fault").ok_or("no Fault event")?;
        let end = expect_end(&q)?;
        let ticks = int(&end.msg, "ticks").ok_or("END without ticks")?;
        println!(
            "fault_power_up_stuck_encoder: {} ; END after {ticks} ticks ({:.2} s)",
            fault.msg,
            ticks as f64 * 1e-4
        );
        let mut errs = Vec::new();
        if !fault.msg.contains("RestNotFound") {
            errs.push(format!("expected RestNotFound: {}", fault.msg));
        }
        if log::events(&q).iter().any(|e| e == "ContactDetected") {
            errs.push("the finger approached after a refused rest check".into());
        }
        if ticks > 200_100 {
            errs.push(format!("refused after {ticks} ticks (> 20 s)"));
        }
        if errs.is_empty() {
            Ok(())
        } else {
            Err(errs.join("\n"))
        }
    })
}

/// Powered up away from rest (issue 19): with the rest check on, the QEMU firmware on
/// `fault_power_up_away` (0.45 rad flexed, the encoder reading 0 there) finds the open stop,
/// reports the power-up pose and estimates θa,c as a finger powered up at rest does (the host
/// runner on table2); QEMU = host as for every scene. Without the check the host runner's
/// θa,c is off by the offset (shown, and required, so the stage fails if the fault injection
/// stops injecting).
fn power_up_away_check() -> Res {
    const SCENE: &str = "fault_power_up_away";
    const OFFSET_URAD: i64 = 450_000;
    let theta_c = |frames: &[Frame]| {
        log::last(frames, "E Estimated").and_then(|e| int(&e.msg, "theta_a_c_urad"))
    };
    let blind = host_run(SCENE)?.0;
    with_env("FINGER_FW_REST_CHECK", "on", || {
        let mut w = Vec::new();
        let q = scene_check_frames(SCENE, false, &mut w)?;
        let rest = log::first(&q, "REST").ok_or("no REST line in the QEMU log")?;
        let seen = int(&rest.msg, "power_up_urad").ok_or("REST without power_up_urad")?;
        let done = int(&rest.msg, "done_ticks").ok_or("REST without done_ticks")?;
        let stop = int(&rest.msg, "stop_ticks").ok_or("REST without stop_ticks")?;
        let (at_rest, _) = host_run("table2")?;
        let (tq, tr, tb) = (theta_c(&q), theta_c(&at_rest), theta_c(&blind));
        println!(
            "{SCENE}: power-up pose seen {seen} µrad (injected {OFFSET_URAD} + half the 3 mrad \
             backlash), stop after {stop} ticks, back at rest after {done} ticks; θa,c QEMU \
             {tq:?} µrad, table2 at rest {tr:?}, without the check {tb:?}"
        );
        let mut errs = Vec::new();
        // The gear sits on its flexion flank at power-up: the encoder's zero is 1.5 mrad
        // beyond the finger's pose.
        if (seen - OFFSET_URAD - 1_500).abs() > 1_000 {
            errs.push(format!("power-up pose {seen} µrad, injected {OFFSET_URAD}"));
        }
        match (tq, tr, tb) {
            (Some(q), Some(r), Some(b)) => {
                if (q - r).abs() > 300 {
                    errs.push(format!("θa,c {q} µrad vs {r} at rest (> 0.3 mrad)"));
                }
                if (b - r).abs() < OFFSET_URAD / 2 {
                    errs.push(format!(
                        "without the check θa,c {b} µrad is not off (at rest {r}): no fault injected?"
                    ));
                }
            }
            other => errs.push(format!("missing θa,c (QEMU, at rest, blind) = {other:?}")),
        }
        if errs.is_empty() {
            Ok(())
        } else {
            Err(errs.join("\n"))
        }
    })
}

/// The first number after the successive keys `path` in a JSON text (enough for `pts --json`
/// output, whose keys are unique along these paths).
fn json_number(text: &str, path: &[&str]) -> Option<f64> {
    let mut rest = text;
    for key in path {
        let at = rest.find(&format!("\"{key}\":"))?;
        rest = &rest[at + key.len() + 3..];
    }
    let end = rest
        .find(|c: char| !(c.is_ascii_digit() || "+-.eE".contains(c)))
        .unwrap_or(rest.len());
    rest[..end].parse().ok()
}

/// One finger everywhere: with [`TEST_FINGER`] the QEMU firmware, the host runner,
/// `pts sim --finger` and `pts estimate --finger` (replaying the grasp `pts sim` recorded) give
/// the same k2 within 1e-4·l2, the firmware's BOOT line shows the file's l2, and the estimate
/// lies near the plant's own contact.
fn finger_check() -> Res {
    let file = util::root().join(TEST_FINGER);
    let file_s = file
        .to_str()
        .ok_or("repository path is not UTF-8")?
        .to_string();
    with_env("FINGER_TOML", &file_s, || {
        let mut w = Vec::new();
        scene_check("table2", false, &mut w)?;
        let (host, _) = host_run("table2")?;
        let l2_um = log::first(&host, "BOOT")
            .and_then(|b| int(&b.msg, "l2_um"))
            .ok_or("no l2_um in the host BOOT line")? as f64;
        let k2_host = log::last(&host, "E Estimated")
            .and_then(|e| int(&e.msg, "k2_um"))
            .ok_or("no k2 estimate from the host runner")? as f64;
        let csv = util::root().join("target").join("finger_check.csv");
        let csv_s = csv.to_str().ok_or("path is not UTF-8")?;
        let pts = util::build_pts()?;
        let sim = util::output(
            std::process::Command::new(&pts)
                .current_dir(util::root())
                .args([
                    "sim",
                    "--scene",
                    "table2",
                    "--dta",
                    FW_DELTA_TA,
                    "--finger",
                    &file_s,
                    "--csv",
                    csv_s,
                    "--json",
                ]),
        )?;
        let est = util::output(
            std::process::Command::new(&pts)
                .current_dir(util::root())
                .args(["estimate", "--trace", csv_s, "--finger", &file_s, "--json"]),
        )?;
        let k2_sim = json_number(&sim, &["estimate", "k2"]).ok_or("pts sim gave no k2")? * 1e6;
        let k2_est = json_number(&est, &["contacts", "k2"]).ok_or("pts estimate gave no k2")? * 1e6;
        let first = json_number(&sim, &["truth", "first_contact", "k"])
            .ok_or("pts sim gave no first contact")?
            * 1e6;
        println!(
            "finger {TEST_FINGER} (l2 {l2_um} µm): k2 host runner {k2_host} µm (= QEMU, checked above), \
             pts sim {k2_sim:.0} µm, pts estimate {k2_est:.0} µm; plant's first contact {first:.0} µm"
        );
        let mut errs = Vec::new();
        if (l2_um - 90_000.0).abs() > 0.5 {
            errs.push(format!(
                "BOOT l2_um {l2_um}: the file's l2 (90000 µm) did not reach the firmware"
            ));
        }
        let tol = K2_TOL_REL_L2 * l2_um;
        for (who, k) in [("pts sim", k2_sim), ("pts estimate", k2_est)] {
            if (k - k2_host).abs() > tol {
                errs.push(format!(
                    "{who} k2 {k:.0} µm differs from the firmware's {k2_host} µm by more than 1e-4·l2"
                ));
            }
        }
        if (k2_host - first).abs() > PATH_FIT_VS_FIRST_CONTACT_TOL_REL_L2 * l2_um {
            errs.push(format!(
                "firmware k2 {k2_host} µm is {:.2} % of l2 from the plant's first contact ({first:.0} µm)",
                (k2_host - first).abs() / l2_um * 100.0
            ));
        }
        if errs.is_empty() {
            Ok(())
        } else {
            Err(errs.join("\n"))
        }
    })
}

/// The function symbol of an ELF that contains `addr` (the Thumb bit ignored), and the
/// first halfword of the instruction there.
fn function_at(elf: &std::path::Path, addr: u64) -> Res<(Option<String>, Option<u16>)> {
    use object::{Object, ObjectSection, ObjectSymbol, SymbolKind};
    let bytes = std::fs::read(elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    let file = object::File::parse(&*bytes).map_err(|e| format!("{}: {e}", elf.display()))?;
    let name = file
        .symbols()
        .filter(|s| s.kind() == SymbolKind::Text)
        .find(|s| {
            let a = s.address() & !1;
            a <= addr && addr < a + s.size()
        })
        .and_then(|s| s.name().ok().map(str::to_string));
    let half = file.sections().find_map(|sec| {
        let a = sec.address();
        if a > addr || addr + 2 > a + sec.size() {
            return None;
        }
        let data = sec.data().ok()?;
        let i = (addr - a) as usize;
        Some(u16::from_le_bytes([*data.get(i)?, *data.get(i + 1)?]))
    });
    Ok((name, half))
}

/// The injected HardFault's report names the faulting instruction: its PC lies in the
/// sampling task (`ADC`), where the injection's read from unmapped memory is inlined, and
/// the instruction there is a load (Thumb LDR immediate, 16-bit `0x68xx`-`0x6Fxx` or 32-bit
/// `0xF8Dx`). The PC comes from the exception frame the HardFault entry reads before it
/// re-seats the stack, so this checks that entry's frame offset.
fn hardfault_pc_check(line: &str, elf: &std::path::Path) -> Res {
    let pc = word(line, "pc")
        .and_then(|p| u64::from_str_radix(p.trim_start_matches("0x"), 16).ok())
        .ok_or_else(|| format!("no pc in {line}"))?;
    let (name, half) = function_at(elf, pc)?;
    let is_load = half.is_some_and(|h| h & 0xF800 == 0x6800 || h & 0xFFF0 == 0xF8D0);
    if name.as_deref() == Some("ADC") && is_load {
        println!(
            "HardFault pc {pc:#x} is a load ({:#06x}) in ADC (the sampling task, where it was injected)",
            half.unwrap_or(0)
        );
        Ok(())
    } else {
        Err(format!(
            "HardFault pc {pc:#x} is in {name:?} (instruction {half:x?}): not the injected load in the sampling task ADC"
        ))
    }
}

/// A panic or HardFault injected into the QEMU firmware must reach the safe state, say so
/// in the log and exit with its own status. Returns the report line and the ELF.
fn inject_check(
    kind: &str,
    tick: u32,
    status: i32,
    tag: &str,
) -> Res<(String, std::path::PathBuf)> {
    let elf = qemu::build_with("table2", Some(&format!("{kind}@{tick}")))?;
    let run = qemu::run(&elf, &mut |f| {
        if !f.msg.starts_with("S ") {
            println!("{}", log::show(f))
        }
    })?;
    let line = log::last(&run.frames, tag).ok_or_else(|| format!("no {tag} line in the log"))?;
    let mut errs = Vec::new();
    if run.status != status {
        errs.push(format!("exit status {} (expected {status})", run.status));
    }
    if word(&line.msg, "bridge_safe") != Some("true") {
        errs.push(format!("bridge not in the safe state: {}", line.msg));
    }
    if line.ts != Some(u64::from(tick)) {
        errs.push(format!(
            "fault reported at tick {:?}, injected at {tick}",
            line.ts
        ));
    }
    if errs.is_empty() {
        Ok((line.msg.clone(), elf))
    } else {
        Err(errs.join("\n"))
    }
}

/// A reset mid-grasp with a latched fault: the next boot reports the cause and the latch,
/// and waits (exit 5 on QEMU) with the bridge off instead of starting a new grasp.
fn latch_check() -> Res {
    let elf = qemu::build_with("table2", Some("reset@3000"))?;
    let run = qemu::run(&elf, &mut |f| {
        if !f.msg.starts_with("S ") {
            println!("{}", log::show(f))
        }
    })?;
    let q = &run.frames;
    let mut errs = Vec::new();
    if run.status != 5 {
        errs.push(format!("exit status {} (expected 5: latched)", run.status));
    }
    let boots = q.iter().filter(|f| f.msg.starts_with("BOOT")).count();
    if boots != 2 {
        errs.push(format!(
            "{boots} boots (expected 2: before and after the reset)"
        ));
    }
    let reset = log::last(q, "RESET")
        .map(|f| f.msg.clone())
        .unwrap_or_default();
    if word(&reset, "cause") != Some("software") || int(&reset, "latched_info") != Some(3000) {
        errs.push(format!("second boot did not report the latch: {reset:?}"));
    }
    match q.iter().position(|f| f.msg.starts_with("LATCHED")) {
        Some(i) if i + 1 == q.len() => {}
        Some(_) => errs.push("the firmware went on after LATCHED".into()),
        None => errs.push("no LATCHED line".into()),
    }
    let calibrations = q
        .iter()
        .filter(|f| f.msg.starts_with("E Calibrated"))
        .count();
    if calibrations != 1 {
        errs.push(format!(
            "{calibrations} calibrations (a second grasp started)"
        ));
    }
    if errs.is_empty() {
        Ok(())
    } else {
        Err(errs.join("\n"))
    }
}

/// Ticks the firmware's `telstall` injection holds the telemetry task (src/telemetry.rs).
const TELEMETRY_STALL_TICKS: i64 = 70_000;
/// Tick at which the telemetry task is stalled.
const TELEMETRY_STALL_AT: i64 = 3000;
/// Ticks the stalled run's END may lie from the unstalled one's. Under `-icount` the virtual
/// clock counts instructions, and a message dropped on a full queue costs fewer than one queued,
/// so the estimate task (below the loop) publishes its result up to a tick sooner; a blocked
/// loop or supervisor would end thousands of ticks late (the stall lasts 70,000).
const STALL_END_TICKS_TOL: i64 = 2;
/// The sampling task's worst work with the queue full may exceed the unstalled run's by this
/// share (a failed `try_send` costs a few instructions; a blocked loop would cost periods).
const STALL_WORK_TOL: f64 = 0.1;

/// A full telemetry queue (FINGER_FW_INJECT=telstall@3000: the telemetry task stops taking
/// messages mid-approach until after the run is over) blocks neither the 10 kHz loop nor the
/// supervisor: the run ends within [`STALL_END_TICKS_TOL`] ticks, in the same state and with the same status as
/// the QEMU run without the stall, and the sampling task's worst work stays within
/// [`STALL_WORK_TOL`] of it; every message that did not get through is counted (logged +
/// dropped = what the host run of the same controller printed); the END report still gets
/// out.
fn telemetry_full_check() -> Res {
    let elf = qemu::build_with("table2", Some(&format!("telstall@{TELEMETRY_STALL_AT}")))?;
    let run = qemu::run(&elf, &mut |f| {
        if !f.msg.starts_with("S ") {
            println!("{}", log::show(f))
        }
    })?;
    let (host, _) = host_run("table2")?;
    let normal = qemu::run(&qemu::build("table2")?, &mut |_| {})?;
    let q = &run.frames;
    let end = expect_end(q)?;
    let host_end = expect_end(&host)?;
    let normal_end = expect_end(&normal.frames)?;
    let counted = |frames: &[Frame]| {
        frames
            .iter()
            .filter(|f| {
                f.msg.starts_with("E ") || f.msg.starts_with("P ") || f.msg.starts_with("TRUTH")
            })
            .count() as i64
    };
    let (logged, produced) = (counted(q), counted(&host));
    let dropped = int(&end.msg, "dropped").ok_or("END without dropped")?;
    let mut errs = Vec::new();
    if log::first(q, "STALL").is_none() {
        errs.push("the telemetry stall was not injected (no STALL line)".to_string());
    }
    if run.status != normal.status {
        errs.push(format!(
            "exit status {} (without the stall: {})",
            run.status, normal.status
        ));
    }
    for key in ["status", "state"] {
        if word(&end.msg, key) != word(&normal_end.msg, key) {
            errs.push(format!(
                "END {key} differs from the run without the stall: {} vs {}",
                end.msg, normal_end.msg
            ));
        }
    }
    match (int(&end.msg, "ticks"), int(&normal_end.msg, "ticks")) {
        (Some(a), Some(b)) if (a - b).abs() <= STALL_END_TICKS_TOL => {}
        _ => errs.push(format!(
            "END ticks more than {STALL_END_TICKS_TOL} apart from the run without the stall: {} vs {}",
            end.msg, normal_end.msg
        )),
    }
    let work = |m: &str| int(m, "work_max").map(|w| w as f64);
    match (work(&end.msg), work(&normal_end.msg)) {
        (Some(w), Some(n)) if w <= n * (1.0 + STALL_WORK_TOL) => {}
        other => errs.push(format!(
            "sampling task's worst work (stalled, unstalled) = {other:?}: beyond {STALL_WORK_TOL} over"
        )),
    }
    if dropped == 0 {
        errs.push("nothing dropped: the queue never filled".to_string());
    }
    if logged + dropped != produced {
        errs.push(format!(
            "{logged} messages logged + {dropped} counted as dropped != {produced} the host run printed"
        ));
    }
    let resumed = TELEMETRY_STALL_AT + TELEMETRY_STALL_TICKS;
    let late = end.ts.map(|t| t as i64 - resumed);
    println!(
        "telemetry stalled at tick {TELEMETRY_STALL_AT} for {TELEMETRY_STALL_TICKS} ticks: run ended at tick {} (without the stall {}; host {}), work_max {} stamps (without {}), {logged} messages logged, {dropped} dropped, {produced} produced by the host run; END logged {late:?} ticks after the telemetry resumed",
        int(&end.msg, "ticks").unwrap_or(-1),
        int(&normal_end.msg, "ticks").unwrap_or(-1),
        int(&host_end.msg, "ticks").unwrap_or(-1),
        int(&end.msg, "work_max").unwrap_or(-1),
        int(&normal_end.msg, "work_max").unwrap_or(-1),
    );
    if errs.is_empty() {
        Ok(())
    } else {
        Err(errs.join("\n"))
    }
}

/// The settings store's round trip in QEMU (FINGER_FW_INJECT=settings@0): the first boot
/// finds the store empty, stores test settings through the RAM-backed flash and resets; the
/// second boot loads exactly them (sequence 1) and the grasp runs as usual.
fn settings_check() -> Res {
    // The firmware's test payload (src/settings_flash.rs, INJECTED_PAYLOAD).
    const PAYLOAD_LEN: i64 = "settings stored by the test command".len() as i64;
    let elf = qemu::build_with("table2", Some("settings@0"))?;
    let run = qemu::run(&elf, &mut |f| {
        if f.msg.starts_with("SETTINGS") || f.msg.starts_with("BOOT") {
            println!("{}", log::show(f))
        }
    })?;
    let q = &run.frames;
    let lines: Vec<&str> = q
        .iter()
        .filter(|f| f.msg.starts_with("SETTINGS"))
        .map(|f| f.msg.as_str())
        .collect();
    let mut errs = Vec::new();
    let boots = q.iter().filter(|f| f.msg.starts_with("BOOT")).count();
    if boots != 2 {
        errs.push(format!("{boots} boots (expected 2: store, reset, load)"));
    }
    let has = |pred: &dyn Fn(&str) -> bool| lines.iter().any(|l| pred(l));
    if lines.first().and_then(|l| word(l, "status")) != Some("empty") {
        errs.push(format!("first boot did not find an empty store: {lines:?}"));
    }
    if !has(&|l| l.starts_with("SETTINGS stored") && int(l, "sequence") == Some(1)) {
        errs.push(format!("no store of sequence 1: {lines:?}"));
    }
    if !has(&|l| {
        word(l, "status") == Some("loaded")
            && int(l, "sequence") == Some(1)
            && int(l, "len") == Some(PAYLOAD_LEN)
    }) {
        errs.push(format!(
            "second boot did not load sequence 1 with {PAYLOAD_LEN} bytes: {lines:?}"
        ));
    }
    if !has(&|l| word(l, "payload_matches") == Some("true")) {
        errs.push(format!(
            "loaded payload differs from the stored one: {lines:?}"
        ));
    }
    if run.status != 0 {
        errs.push(format!(
            "exit status {} (expected 0: the grasp ran)",
            run.status
        ));
    }
    if errs.is_empty() {
        Ok(())
    } else {
        Err(errs.join("\n"))
    }
}

/// A damaged settings store in QEMU (FINGER_FW_INJECT=settings-corrupt@0): the first boot
/// programs a word that is neither the magic nor erased at slot A and resets; the second
/// boot reports the store corrupt with that word, falls back to the build's defaults, and
/// the grasp runs as usual.
fn settings_corrupt_check() -> Res {
    // The firmware's damage word (src/settings_flash.rs, INJECTED_DAMAGE).
    const DAMAGE: i64 = 0x1234_5678;
    let elf = qemu::build_with("table2", Some("settings-corrupt@0"))?;
    let run = qemu::run(&elf, &mut |f| {
        if f.msg.starts_with("SETTINGS") || f.msg.starts_with("BOOT") || f.msg.starts_with("END") {
            println!("{}", log::show(f))
        }
    })?;
    let q = &run.frames;
    let lines: Vec<&str> = q
        .iter()
        .filter(|f| f.msg.starts_with("SETTINGS status"))
        .map(|f| f.msg.as_str())
        .collect();
    let mut errs = Vec::new();
    let statuses: Vec<Option<&str>> = lines.iter().map(|l| word(l, "status")).collect();
    if statuses != [Some("empty"), Some("corrupt")] {
        errs.push(format!(
            "expected an empty then a corrupt store over two boots: {lines:?}"
        ));
    }
    // defmt prints the found word in decimal inside the Corrupt status.
    if !lines
        .last()
        .is_some_and(|l| l.contains("Magic") && l.contains(&DAMAGE.to_string()))
    {
        errs.push(format!(
            "corrupt status does not name the damaged word {DAMAGE:#x}: {lines:?}"
        ));
    }
    if run.status != 0 {
        errs.push(format!(
            "exit status {} (expected 0: the grasp ran on the defaults)",
            run.status
        ));
    }
    if errs.is_empty() {
        Ok(())
    } else {
        Err(errs.join("\n"))
    }
}

/// Instructions per work stamp, from the firmware's calibration loop (CAL line); must agree
/// with the icount arithmetic (1 ns per instruction, 40 ns per 25 MHz timer tick).
pub fn instr_per_stamp(frames: &[Frame]) -> Res<f64> {
    let cal = log::first(frames, "CAL").ok_or("no CAL line in the log")?;
    let n = int(&cal.msg, "instructions").ok_or("CAL without instructions")? as f64;
    let s = int(&cal.msg, "stamps").ok_or("CAL without stamps")? as f64;
    let per = n / s.max(1.0);
    if (per - INSTR_PER_TICK as f64).abs() > 0.5 {
        return Err(format!(
            "work counter calibration: {per:.2} instructions per stamp, expected {INSTR_PER_TICK} (-icount shift=0 and a 25 MHz timer)"
        ));
    }
    Ok(per)
}

/// Worst IWDG timeout over the LSI's tolerance (17–47 kHz for a nominal 10 ms), ms.
const WDG_TIMEOUT_WORST_MS: f64 = 6.8;
/// Cycles per instruction assumed on the board (flash wait states behind the ART
/// accelerator): a conservative 2, so the instruction budget is half the cycle budget.
const BOARD_CYCLES_PER_INSTR: f64 = 2.0;
/// The board's slower core clock (Hz): 96 MHz in device mode, where USB needs the PLL's exact
/// 48 MHz (src/board; 100 MHz otherwise). Time bounds in instructions use it.
const BOARD_SYSCLK_MIN_HZ: f64 = 96e6;

/// The watchdog's first window: from its start (end of init) to its first feed must take at
/// most half the worst timeout on the board (at its slower clock, 96 MHz). Init's own length
/// is reported (the watchdog is not running during it).
fn watchdog_window(frames: &[Frame], per: f64) -> Res<String> {
    let init = log::first(frames, "INIT")
        .and_then(|f| int(&f.msg, "stamps"))
        .ok_or("no INIT line with stamps in the log")? as f64
        * per;
    let wdg = log::first(frames, "WDG first feed")
        .and_then(|f| int(&f.msg, "start"))
        .ok_or("no `WDG first feed` line: the watchdog is never fed")? as f64
        * per;
    let budget = WDG_TIMEOUT_WORST_MS * 1e-3 * BOARD_SYSCLK_MIN_HZ / 2.0 / BOARD_CYCLES_PER_INSTR;
    let line = format!(
        "init {init:.0} instructions (watchdog not yet started); watchdog start -> first feed {wdg:.0} instructions (budget {budget:.0}: half of {WDG_TIMEOUT_WORST_MS} ms at {} MHz, {BOARD_CYCLES_PER_INSTR} cycles/instruction)",
        BOARD_SYSCLK_MIN_HZ / 1e6
    );
    if wdg > budget {
        return Err(format!("watchdog window too long: {line}"));
    }
    Ok(line)
}

/// The two halves of the stages, which `cargo xtask test` runs side by side: QEMU emulates
/// one core and the host's stages are mostly compiling, so one after the other they leave a
/// core of a two-core machine idle for much of the run.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Lane {
    /// Format, lint (the firmware's too), docs, the workspace's tests, the thumb builds of
    /// `pts`, the instruction-count gate and the figures: everything that writes no firmware
    /// ELF, or writes it into a target directory of its own.
    Host,
    /// Every release build of the firmware (QEMU's, the panic call graph's, the board's for
    /// its size budgets) and every QEMU run. The firmware's ELF has one path per build
    /// profile, so these stay in one lane.
    Firmware,
}

impl Lane {
    fn name(self) -> &'static str {
        match self {
            Lane::Host => "host",
            Lane::Firmware => "firmware",
        }
    }

    fn parse(name: &str) -> Res<Lane> {
        match name {
            "host" => Ok(Lane::Host),
            "firmware" => Ok(Lane::Firmware),
            _ => Err(format!(
                "`--lane` takes `host` or `firmware` (got {name:?})"
            )),
        }
    }

    /// The lane's stages, in order.
    fn run(self, st: &mut Stages, work: &mut Vec<Work>) {
        match self {
            Lane::Host => {
                host_stages(st);
                firmware_lint_stages(st);
                gate_stages(st);
            }
            Lane::Firmware => {
                // QEMU first: its runs use one core while the host lane compiles on the other.
                qemu_scene_stages(st, work);
                qemu_fault_and_device_stages(st);
                firmware_build_stages(st);
            }
        }
    }
}

/// What the firmware lane's child process prints before each of its lines.
const LANE_PREFIX: &str = "fw| ";

/// A scene's work on the target ISA: (scene, sampling task max, its mean, estimate task max,
/// state machine max), in instructions.
type Work = (String, f64, f64, f64, f64);

/// `cargo xtask test [STAGE | --lane host|firmware]`: every stage (two lanes side by side),
/// only those whose name contains STAGE (case-insensitive), e.g. `cargo xtask test
/// "non-paper finger"`, or one lane's; the last two one after the other.
pub fn main(args: &[String]) -> Res<i32> {
    let (lanes, only, side_by_side) = match args {
        [] => (vec![Lane::Host, Lane::Firmware], None, true),
        [flag, lane] if flag == "--lane" => (vec![Lane::parse(lane)?], None, false),
        [stage] if !stage.starts_with('-') => {
            (vec![Lane::Host, Lane::Firmware], Some(stage.clone()), false)
        }
        _ => {
            return Err(format!(
                "`test` takes a part of a stage name or `--lane host|firmware` (got {args:?})"
            ))
        }
    };
    let start = Instant::now();
    let mut st = Stages {
        only,
        ..Stages::default()
    };
    // Set-up runs whatever was selected, before a second lane starts.
    if let Err(e) = toolchain().and_then(|()| qemu::ensure_qemu()) {
        st.failed
            .push(("toolchain targets and qemu-system-arm".into(), e));
    }
    let mut work = Vec::new();
    let mut work_lines = Vec::new();
    if side_by_side {
        match LaneChild::spawn(Lane::Firmware) {
            Ok(child) => {
                Lane::Host.run(&mut st, &mut work);
                eprintln!(
                    "\n==== the host lane is done ({:.0} s); waiting for the firmware lane ====",
                    start.elapsed().as_secs_f64()
                );
                child.finish(&mut st, &mut work_lines);
            }
            Err(e) => {
                // No second process: run both lanes here, one after the other.
                eprintln!("{e}; running the firmware lane after the host lane");
                for lane in lanes {
                    lane.run(&mut st, &mut work);
                }
            }
        }
    } else {
        for lane in lanes {
            lane.run(&mut st, &mut work);
        }
    }
    work_lines.extend(work.iter().map(work_line));
    summary(st, start, &work_lines)
}

/// The firmware lane running as `xtask test --lane firmware` in a child process; its output
/// is passed on line by line behind [`LANE_PREFIX`], and its stage verdicts are read from the
/// same lines.
struct LaneChild {
    child: std::process::Child,
    readers: Vec<std::thread::JoinHandle<LaneLines>>,
    name: &'static str,
}

/// What a reader thread took from the child's output.
#[derive(Default)]
struct LaneLines {
    passed: Vec<String>,
    failed: Vec<String>,
    work: Vec<String>,
}

impl LaneLines {
    /// Files one line of the child's output: a stage verdict, a work line, or nothing.
    fn take(&mut self, line: &str) {
        let verdict = line
            .strip_prefix("==== ")
            .and_then(|rest| rest.rsplit_once(" ("))
            .map(|(head, _)| head);
        if let Some(head) = verdict {
            if let Some(name) = head.strip_suffix(": ok") {
                self.passed.push(name.to_string());
            } else if let Some(name) = head.strip_suffix(": FAILED") {
                self.failed.push(name.to_string());
            }
        } else if line.starts_with("work on the target ISA") {
            self.work.push(line.to_string());
        }
    }
}

impl LaneChild {
    /// Starts `xtask test --lane NAME` for `lane`.
    fn spawn(lane: Lane) -> Res<LaneChild> {
        let exe = std::env::current_exe().map_err(|e| format!("no path to xtask itself: {e}"))?;
        let mut cmd = Command::new(exe);
        cmd.args(["test", "--lane", lane.name()])
            .current_dir(util::root());
        LaneChild::start(cmd, lane.name())
    }

    /// Starts `cmd` as a lane: its output is passed on behind [`LANE_PREFIX`] and read for
    /// the stage verdicts.
    fn start(mut cmd: Command, name: &'static str) -> Res<LaneChild> {
        let mut child = cmd
            .stdin(std::process::Stdio::null())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .map_err(|e| format!("cannot start the {name} lane: {e}"))?;
        eprintln!(
            "\n==== the {name} lane runs beside this one; its lines start with `{LANE_PREFIX}` ===="
        );
        let mut readers = Vec::new();
        let out = child
            .stdout
            .take()
            .map(|s| Box::new(s) as Box<dyn std::io::Read + Send>);
        let err = child
            .stderr
            .take()
            .map(|s| Box::new(s) as Box<dyn std::io::Read + Send>);
        for stream in [out, err].into_iter().flatten() {
            readers.push(std::thread::spawn(move || {
                use std::io::BufRead;
                let mut lines = LaneLines::default();
                for line in std::io::BufReader::new(stream).split(b'\n') {
                    let Ok(bytes) = line else { break };
                    let line = String::from_utf8_lossy(&bytes);
                    let line = line.trim_end_matches('\r');
                    eprintln!("{LANE_PREFIX}{line}");
                    lines.take(line);
                }
                lines
            }));
        }
        Ok(LaneChild {
            child,
            readers,
            name,
        })
    }

    /// Waits for the child and adds its verdicts and work lines to this run's.
    fn finish(mut self, st: &mut Stages, work: &mut Vec<String>) {
        let mut lines = LaneLines::default();
        for r in self.readers {
            if let Ok(l) = r.join() {
                lines.passed.extend(l.passed);
                lines.failed.extend(l.failed);
                lines.work.extend(l.work);
            }
        }
        let status = self.child.wait();
        let failed_stage = !lines.failed.is_empty();
        let any_stage = failed_stage || !lines.passed.is_empty();
        st.passed.extend(lines.passed);
        for name in lines.failed {
            st.failed
                .push((name, format!("see the `{LANE_PREFIX}` lines above")));
        }
        work.extend(lines.work);
        match status {
            // A failed stage explains a failed status.
            Ok(s) if any_stage && (s.success() || failed_stage) => {}
            other => st.failed.push((
                format!("{} lane (xtask test --lane {})", self.name, self.name),
                format!("ended with {other:?} after the stages above"),
            )),
        }
    }
}

/// Format, lint and the workspace's tests on the host; the model crate for both thumb targets.
fn host_stages(st: &mut Stages) {
    st.run("cargo fmt --check", || {
        cargo(&["fmt", "--all", "--", "--check"])
    });
    st.run("cargo clippy -D warnings", || {
        cargo(&[
            "clippy",
            "--workspace",
            "--all-targets",
            "--",
            "-D",
            "warnings",
        ])
    });
    // A broken intra-doc link is a wrong pointer in the reference a user reads.
    st.run(
        "rustdoc without warnings (cargo doc --workspace --no-deps)",
        || {
            with_env("RUSTDOCFLAGS", "-D warnings", || {
                cargo(&["doc", "--workspace", "--no-deps"])
            })
        },
    );
    st.run("cargo test --workspace", || {
        cargo(&["test", "--workspace", "--no-fail-fast"])
    });
    // The fuzz targets live outside the workspace (nightly cargo-fuzz runs them), so nothing
    // else would notice an API change that breaks them; stable `cargo check` does.
    st.run("fuzz targets compile (cargo check, fuzz/)", || {
        cargo(&[
            "check",
            "--manifest-path",
            "fuzz/Cargo.toml",
            "--bins",
            "--no-default-features",
        ])
    });
    for t in ["thumbv6m-none-eabi", "thumbv7em-none-eabihf"] {
        st.run(&format!("pts builds for {t}"), || {
            cargo(&["build", "-p", "pts", "--target", t])
        });
    }
}

/// Clippy on the firmware in every configuration (checks only: no ELF is written).
fn firmware_lint_stages(st: &mut Stages) {
    st.run("clippy: firmware for QEMU (thumbv7em)", || {
        cargo(&[
            "clippy",
            "-p",
            "finger-fw",
            "--target",
            qemu::TARGET,
            "--no-default-features",
            "--features",
            "qemu",
            "--",
            "-D",
            "warnings",
        ])
    });
    st.run("clippy: firmware for the board (thumbv7em)", || {
        cargo(&[
            "clippy",
            "-p",
            "finger-fw",
            "--target",
            qemu::TARGET,
            "--",
            "-D",
            "warnings",
        ])
    });
    st.run(
        "clippy: firmware for the board in device mode, USB (thumbv7em)",
        || {
            cargo(&[
                "clippy",
                "-p",
                "finger-fw",
                "--target",
                qemu::TARGET,
                "--no-default-features",
                "--features",
                size::DEVICE_FEATURES,
                "--",
                "-D",
                "warnings",
            ])
        },
    );
}

/// The firmware's release builds: the panic call graph, and the board builds' flash and RAM
/// against their budgets.
fn firmware_build_stages(st: &mut Stages) {
    st.run(
        "no panic reachable from a firmware task (xtask panics)",
        || crate::panics::main(&[]),
    );
    st.run(
        "board firmware (release) within flash/RAM budgets, as documented",
        || {
            let elf = size::build_board()?;
            let s = size::measure(&elf)?;
            size::report("power-up grasp", s)?;
            size::documented("power-up grasp", s)
        },
    );
    st.run(
        "board firmware in device mode, USB (release) within flash/RAM budgets, as documented",
        || {
            let elf = size::build_board_device(size::DEVICE_FEATURES)?;
            let s = size::measure(&elf)?;
            let label = format!("device mode, USB, {}", size::DEVICE_FEATURES);
            size::report(&label, s)?;
            size::documented(&label, s)
        },
    );
    st.run(
        "board firmware in device mode, USB, both estimators (release) within flash/RAM budgets, as documented",
        || {
            let elf = size::build_board_device(size::DEVICE_BOTH_FEATURES)?;
            let s = size::measure(&elf)?;
            let label = format!("device mode, USB, {}", size::DEVICE_BOTH_FEATURES);
            size::report(&label, s)?;
            size::documented(&label, s)
        },
    );
}

/// The firmware in QEMU against the host runner: the estimate scenes, a fault scene, the
/// two-point build, the rest check and a non-paper finger.
fn qemu_scene_stages(st: &mut Stages, work: &mut Vec<Work>) {
    for s in ESTIMATE_SCENES {
        st.run(
            &format!("QEMU scene {s}: events, estimate = host within 1e-4·l2"),
            || scene_check(s, false, work),
        );
    }
    st.run(
        &format!("QEMU fault scene {FAULT_SCENE}: ends in the safe state"),
        || scene_check(FAULT_SCENE, true, work),
    );
    // The two-point build (the paper's method only, the smaller firmware) on the Table 2
    // scene: the same checks, QEMU against the host build of the same estimator.
    st.run(
        "QEMU scene table2, FINGER_FW_ESTIMATOR=two-point: estimate = host within 1e-4·l2",
        || {
            with_env("FINGER_FW_ESTIMATOR", "two-point", || {
                let mut w = Vec::new();
                let r = scene_check("table2", false, &mut w);
                for (s, _, _, est, _) in &w {
                    println!("{s} (two-point): estimate task worst case {est:.0} instructions");
                }
                r
            })
        },
    );
    st.run(
        "QEMU rest check: powered up 0.45 rad away -> homed, θa,c as at rest, = host",
        power_up_away_check,
    );
    st.run(
        "QEMU rest check: powered up with a stuck encoder -> rest_not_found, bridge off, <= 20 s",
        rest_not_found_check,
    );
    st.run(
        "non-paper finger file: QEMU = host runner = pts sim = pts estimate within 1e-4·l2",
        finger_check,
    );
}

/// The instruction-count gate and the documented figures.
fn gate_stages(st: &mut Stages) {
    // The numerics owner's benchmark gate (xtask/src/bench.rs), run as its own command so
    // the two modules stay independent.
    st.run("cargo xtask bench --check", || {
        util::run(util::cargo().args(["run", "-q", "-p", "xtask", "--", "bench", "--check"]))
    });
    st.run(
        "documented figures are what the code draws now (cargo xtask figures --check)",
        crate::figures::check_current,
    );
}

/// Injected faults in QEMU (panic, HardFault, stack overflow, a latched fault across reset,
/// a full telemetry queue), the settings store, and device mode driven by `pts board`.
fn qemu_fault_and_device_stages(st: &mut Stages) {
    st.run("QEMU: injected panic -> bridge safe, exit 101", || {
        inject_check("panic", 3000, 101, "PANIC").map(|_| ())
    });
    st.run("QEMU: injected HardFault -> bridge safe, exit 102", || {
        let (line, elf) = inject_check("hardfault", 3000, 102, "HARDFAULT")?;
        hardfault_pc_check(&line, &elf)
    });
    st.run(
        "QEMU: injected stack overflow -> HardFault, bridge safe, exit 102",
        || {
            let (line, _) = inject_check("stackoverflow", 3000, 102, "HARDFAULT")?;
            // Reported as the overflow it is (flip-link + the entry that re-seats the
            // stack), not as some other HardFault.
            if word(&line, "stack_overflow") == Some("true") {
                Ok(())
            } else {
                Err(format!(
                    "HardFault not reported as a stack overflow: {line}"
                ))
            }
        },
    );
    st.run(
        "QEMU: reset mid-grasp with a latched fault -> waits, exit 5",
        latch_check,
    );
    st.run(
        "QEMU: full telemetry queue -> loop and supervisor unaffected, drops counted",
        telemetry_full_check,
    );
    st.run(
        "QEMU: settings stored, reset, loaded (RAM-backed flash)",
        settings_check,
    );
    st.run(
        "QEMU: settings store damaged, reset -> corrupt, build defaults, grasp runs",
        settings_corrupt_check,
    );
    st.run(
        "QEMU device mode over pts board: typed errors, stop, disconnect, three grasps = host within 1e-4·l2, calibration sweep = host within σ",
        crate::device::check,
    );
}

/// A scene's line of the closing report.
fn work_line((scene, w, m, e, sv): &Work) -> String {
    format!(
        "work on the target ISA ({scene}): sampling task max {w:.0} / mean {m:.0} instructions per 10 kHz tick, state machine max {sv:.0} per run, estimate task max {e:.0} instructions (±{INSTR_PER_TICK})"
    )
}

/// The closing report: the work on the target ISA, each stage's verdict, `N passed, M failed`.
fn summary(st: Stages, start: Instant, work: &[String]) -> Res<i32> {
    eprintln!(
        "\n==== summary ({:.0} s) ====",
        start.elapsed().as_secs_f64()
    );
    for line in work {
        eprintln!("{line}");
    }
    for p in &st.passed {
        eprintln!("  ok      {p}");
    }
    for (f, _) in &st.failed {
        eprintln!("  FAILED  {f}");
    }
    if st.passed.is_empty() && st.failed.is_empty() {
        return Err(format!(
            "no stage name contains {:?}; the stages:\n  {}",
            st.only.unwrap_or_default(),
            st.skipped.join("\n  ")
        ));
    }
    println!("{} passed, {} failed", st.passed.len(), st.failed.len());
    Ok(if st.failed.is_empty() { 0 } else { 1 })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(msg: &str) -> Frame {
        Frame {
            ts: None,
            level: "INFO".into(),
            msg: msg.into(),
        }
    }

    #[test]
    fn a_lane_s_verdicts_are_read_back_from_its_lines() {
        let name = "QEMU scene table2: events, estimate = host within 1e-4·l2";
        let mut l = LaneLines::default();
        l.take(&verdict_line(name, true, 72.6));
        l.take(&verdict_line(
            "QEMU: injected panic -> bridge safe, exit 101",
            false,
            6.7,
        ));
        l.take(&format!("==== {name} ===="));
        l.take("==== summary (2275 s) ====");
        l.take("table2: exit 0, 267 frames, QEMU wall 32.0 s");
        l.take(&work_line(&("table2".into(), 1.0, 2.0, 3.0, 4.0)));
        assert_eq!(l.passed, [name]);
        assert_eq!(l.failed, ["QEMU: injected panic -> bridge safe, exit 101"]);
        assert_eq!(l.work.len(), 1);
        assert!(l.work[0].contains("(table2)"), "{:?}", l.work);
    }

    /// A stand-in lane: a shell that prints the given verdict lines and exits with `code`.
    fn fake_lane(lines: &[String], code: i32) -> (Stages, Vec<String>) {
        let script: String = lines
            .iter()
            .map(|l| format!("printf '%s\\n' '{l}' >&2; "))
            .chain([format!("exit {code}")])
            .collect();
        let mut cmd = Command::new("sh");
        cmd.args(["-c", &script]);
        let child = LaneChild::start(cmd, "firmware").expect("sh starts");
        let (mut st, mut work) = (Stages::default(), Vec::new());
        child.finish(&mut st, &mut work);
        (st, work)
    }

    #[test]
    fn a_lane_s_failed_stage_fails_the_run() {
        let (st, _) = fake_lane(
            &[
                verdict_line("QEMU: a", true, 1.0),
                verdict_line("QEMU: b", false, 2.0),
            ],
            1,
        );
        assert_eq!(st.passed, ["QEMU: a"]);
        let failed: Vec<&str> = st.failed.iter().map(|f| f.0.as_str()).collect();
        assert_eq!(failed, ["QEMU: b"]);
    }

    #[test]
    fn a_lane_that_dies_or_runs_nothing_fails_the_run() {
        // Ended without a verdict for the stage it failed in (killed, panicked).
        let (st, _) = fake_lane(&[verdict_line("QEMU: a", true, 1.0)], 101);
        assert_eq!(st.passed, ["QEMU: a"]);
        assert_eq!(st.failed.len(), 1);
        assert!(st.failed[0].0.contains("firmware lane"), "{:?}", st.failed);
        // No stage at all, even with a clean exit.
        let (st, _) = fake_lane(&[], 0);
        assert!(st.passed.is_empty());
        assert_eq!(st.failed.len(), 1, "{:?}", st.failed);
        // A clean run adds nothing to fail.
        let (st, work) = fake_lane(
            &[
                verdict_line("QEMU: a", true, 1.0),
                work_line(&("table2".into(), 1.0, 2.0, 3.0, 4.0)),
            ],
            0,
        );
        assert!(st.failed.is_empty(), "{:?}", st.failed);
        assert_eq!(work.len(), 1);
    }

    #[test]
    fn json_number_follows_the_key_path() {
        let t = r#"{"estimate":{"phalanx":"distal","k2":0.037265},"truth":{"k":1e-3,"k2":-2.5}}"#;
        assert_eq!(json_number(t, &["estimate", "k2"]), Some(0.037265));
        assert_eq!(json_number(t, &["truth", "k2"]), Some(-2.5));
        assert_eq!(json_number(t, &["truth", "k"]), Some(1e-3));
        assert_eq!(json_number(t, &["missing"]), None);
        assert_eq!(json_number(r#"{"estimate":null}"#, &["estimate"]), None);
    }

    #[test]
    fn calibration_checks_the_icount_arithmetic() {
        let ok = [frame("CAL instructions=200002 stamps=5000")];
        assert!((instr_per_stamp(&ok).unwrap() - 40.0).abs() < 1e-3);
        // A different clock or icount shift must be caught, not silently rescaled.
        let bad = [frame("CAL instructions=200002 stamps=10000")];
        assert!(instr_per_stamp(&bad).is_err());
        assert!(instr_per_stamp(&[frame("BOOT")]).is_err());
    }

    #[test]
    fn watchdog_window_is_checked_against_half_the_worst_timeout() {
        let init = frame("INIT stamps=33144 (watchdog started at its end)");
        let ok = [
            init.clone(),
            frame("WDG first feed, stamps since start=155"),
        ];
        assert!(watchdog_window(&ok, 40.0).is_ok());
        // 163,200 instructions (half of 6.8 ms at 96 MHz, 2 cycles each) is the budget: the
        // stamp that reaches it passes, one stamp more fails.
        let edge = [
            init.clone(),
            frame("WDG first feed, stamps since start=4080"),
        ];
        assert!(watchdog_window(&edge, 40.0).is_ok());
        let late = [
            init.clone(),
            frame("WDG first feed, stamps since start=4081"),
        ];
        assert!(watchdog_window(&late, 40.0).is_err());
        // Never fed at all is a failure, not a pass.
        assert!(watchdog_window(&[init], 40.0).is_err());
    }
}
