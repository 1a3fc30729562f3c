//! `cargo xtask demo` without `--scene`: the device-mode firmware in QEMU driven through its
//! host protocol, as a robot would drive the board. One power-up, three grasps on different
//! simulated objects with different torque steps, each shown live by `pts board watch --grasp`
//! and released before the next; then each estimate against the plant's truth.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::log::{self, int, word};
use crate::qemu::{self, Frame};
use crate::util::{self, Res};

/// The grasps: (scene, ΔT_a in N·m). The path fit runs each (the two-point reference beside it).
pub const GRASPS: &[(&str, &str)] = &[
    ("table2", "0.8"),
    ("cyl10_k2_20", "0.6"),
    ("vertex_k2_30", "1.0"),
];

/// One grasp's outcome, read from the firmware's log.
#[derive(Debug, Default, PartialEq)]
pub struct Outcome {
    /// The estimate's k2, its σ and the two-point reference (µm).
    pub k2_um: Option<i64>,
    pub sigma_um: Option<i64>,
    pub two_point_um: Option<i64>,
    /// The plant's first contact: phalanx and location along it (µm).
    pub truth_phalanx: Option<String>,
    pub truth_um: Option<i64>,
    /// The fault's name when the grasp ended in one.
    pub fault: Option<String>,
}

/// The outcome of the grasp whose log lines are `frames` (those after its start).
pub fn outcome(frames: &[Frame]) -> Outcome {
    let est = log::last(frames, "E Estimated");
    let first = log::first(frames, "P first_contact");
    Outcome {
        k2_um: est.and_then(|e| int(&e.msg, "k2_um")),
        sigma_um: est.and_then(|e| int(&e.msg, "k2_sigma_um")),
        two_point_um: est.and_then(|e| int(&e.msg, "two_point_k2_um")),
        truth_phalanx: first.and_then(|c| word(&c.msg, "phalanx").map(str::to_string)),
        truth_um: first.and_then(|c| int(&c.msg, "k_um")),
        fault: log::last(frames, "E Fault").map(|f| {
            f.msg
                .split_once("reason: ")
                .map_or("?", |(_, r)| {
                    r.split(|c: char| !c.is_ascii_alphanumeric())
                        .next()
                        .unwrap_or("?")
                })
                .to_string()
        }),
    }
}

/// The final table's row for one grasp; `l2_um` scales the error.
pub fn row(scene: &str, dta: &str, o: &Outcome, l2_um: i64) -> String {
    let mm = |um: i64| format!("{:.2}", um as f64 / 1000.0);
    let estimate = match (o.k2_um, o.sigma_um, &o.fault) {
        (_, _, Some(f)) => format!("fault {f}"),
        (Some(k), Some(s), _) => format!("{} ± {} mm", mm(k), mm(s)),
        (Some(k), None, _) => format!("{} mm", mm(k)),
        (None, _, _) => "not distal".into(),
    };
    let truth = match (&o.truth_phalanx, o.truth_um) {
        (Some(p), Some(k)) if p == "distal" => format!("{} mm", mm(k)),
        (Some(p), _) => p.clone(),
        _ => "no contact".into(),
    };
    let error = match (o.k2_um, o.truth_um, o.truth_phalanx.as_deref(), &o.fault) {
        (Some(k), Some(t), Some("distal"), None) if l2_um > 0 => {
            format!("{:+.1} %", (k - t) as f64 / l2_um as f64 * 100.0)
        }
        _ => "-".into(),
    };
    let reference = o
        .two_point_um
        .map_or("-".into(), |k| format!("{} mm", mm(k)));
    format!("{scene:<13} {dta:>5}  {estimate:<17} {reference:<10} {truth:<10} {error:>7}")
}

/// `pts board ARGS` against the QEMU socket, output captured; must succeed.
fn board(pts: &Path, addr: &str, args: &[&str]) -> Res<String> {
    let out = Command::new(pts)
        .args(["board", "--connect", addr])
        .args(args)
        .output()
        .map_err(|e| format!("cannot run {}: {e}", pts.display()))?;
    if !out.status.success() {
        return Err(format!(
            "pts board {} failed: {}{}",
            args.join(" "),
            String::from_utf8_lossy(&out.stdout).trim(),
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    Ok(String::from_utf8_lossy(&out.stdout).to_string())
}

/// Entry point: builds, starts QEMU, runs the grasps, prints the table. Exit status 0 when
/// every grasp gave an estimate, 2 when one faulted.
pub fn main() -> Res<i32> {
    qemu::ensure_qemu()?;
    println!("building the device-mode firmware (QEMU) and pts; the first run takes minutes");
    let elf = crate::device::build()?;
    let pts: PathBuf = util::build_pts()?;
    let port = crate::device::free_port()?;
    let addr = format!("127.0.0.1:{port}");
    let log_path = util::root().join("target").join("finger-fw-demo.defmt");
    let mut child = qemu::spawn_device(&elf, port, &log_path)?;
    let r = session(&elf, &log_path, &pts, &addr);
    let _ = child.kill();
    let _ = child.wait();
    r
}

fn session(elf: &Path, log_path: &Path, pts: &Path, addr: &str) -> Res<i32> {
    let t0 = Instant::now();
    let hello = loop {
        match board(pts, addr, &["hello"]) {
            Ok(h) => break h,
            Err(_) if t0.elapsed() < Duration::from_secs(20) => {
                std::thread::sleep(Duration::from_millis(200))
            }
            Err(e) => return Err(format!("the firmware did not answer: {e}")),
        }
    };
    println!("device: {}", hello.trim());
    let boot = qemu::decode_file(elf, log_path)?;
    let boot = log::first(&boot, "BOOT");
    let l2_um = boot.and_then(|b| int(&b.msg, "l2_um")).unwrap_or(0);
    println!(
        "finger: {} (l2 = {:.2} mm); the simulated object is chosen per grasp (`pts board set scene`)",
        boot.map_or("?", |b| crate::demo::boot_finger(&b.msg)),
        l2_um as f64 / 1000.0
    );
    board(pts, addr, &["set", "estimator", "path-fit"])?;
    let mut rows = Vec::new();
    let mut status = 0;
    for (i, (scene, dta)) in GRASPS.iter().enumerate() {
        board(pts, addr, &["set", "scene", scene])?;
        board(pts, addr, &["set", "delta_ta_nm", dta])?;
        println!(
            "\n── grasp {} of {}: scene {scene}, ΔT_a = {dta} N·m, path fit ──",
            i + 1,
            GRASPS.len()
        );
        let before = qemu::decode_file(elf, log_path)?.len();
        // The live view: the terminal UI on a terminal, summary lines otherwise.
        let watched = Command::new(pts)
            .args([
                "board",
                "--connect",
                addr,
                "watch",
                "--grasp",
                "--rate",
                "200",
            ])
            .stdin(Stdio::inherit())
            .status()
            .map_err(|e| format!("cannot run {}: {e}", pts.display()))?;
        // The log's last lines (estimate, holding) can trail the reply by a moment.
        std::thread::sleep(Duration::from_millis(300));
        let frames = qemu::decode_file(elf, log_path)?;
        let o = outcome(frames.get(before..).unwrap_or(&[]));
        if o.fault.is_some() || !watched.success() {
            status = 2;
            board(pts, addr, &["stop"])?;
        } else {
            board(pts, addr, &["release"])?;
        }
        rows.push(row(scene, dta, &o, l2_um));
    }
    println!("\n{}", "=".repeat(80));
    println!(
        "One power-up, {} grasps driven over the host protocol (pts board), path fit with the\n\
         paper's two-point method beside it. Error: (k2 − first contact) / l2, l2 = {:.2} mm.\n",
        GRASPS.len(),
        l2_um as f64 / 1000.0
    );
    println!(
        "{:<13} {:>5}  {:<17} {:<10} {:<10} {:>7}",
        "object", "ΔT_a", "k2 (path fit)", "two-point", "truth", "error"
    );
    for r in &rows {
        println!("{r}");
    }
    println!(
        "\nThe two-point method reads between the first and the final contact location (the\n\
         contact rolls outward under the step; the paper's Table 2 shows the same bias). The\n\
         path fit models the path from the first contact and reports where the object first\n\
         touched. (QEMU wall time {:.0} s)",
        t0.elapsed().as_secs_f64()
    );
    Ok(status)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(msg: &str) -> Frame {
        Frame {
            ts: None,
            level: "INFO".into(),
            msg: msg.to_string(),
        }
    }

    /// A grasp's log read by hand: the estimate, its σ and reference, the plant's first contact.
    #[test]
    fn outcome_and_row_from_log_lines() {
        // The plant's line as the firmware writes it.
        let mut plant_line = String::new();
        proto::log::render(
            &mut plant_line,
            proto::log::PLANT,
            &[
                &"first_contact",
                &4_460_400u32,
                &-223_770i32,
                &340_800i32,
                &"distal",
                &29_270i32,
            ],
        )
        .unwrap();
        let frames = [
            frame(&plant_line),
            frame("E Estimated { tick: 1, result: EstimateResult { located: Distal, k2_um: Some(29719), k2_sigma_um: Some(1184), radius_um: None, two_point_k2_um: Some(41993), quality: Good } }"),
        ];
        let o = outcome(&frames);
        assert_eq!(o.k2_um, Some(29_719));
        assert_eq!(o.sigma_um, Some(1_184));
        assert_eq!(o.two_point_um, Some(41_993));
        assert_eq!(o.truth_um, Some(29_270));
        assert_eq!(o.fault, None);
        let r = row("table2", "0.8", &o, 75_000);
        // (29.719 − 29.270)/75 = +0.599 %.
        assert!(
            r.contains("29.72 ± 1.18 mm") && r.contains("41.99 mm"),
            "{r}"
        );
        assert!(r.trim_end().ends_with("+0.6 %"), "{r}");

        let faulted = [frame(
            "E Fault { tick: 5, reason: NoMotion { travel_urad: 12 } }",
        )];
        let o = outcome(&faulted);
        assert_eq!(o.fault.as_deref(), Some("NoMotion"));
        let r = row("table2", "0.1", &o, 75_000);
        assert!(
            r.contains("fault NoMotion") && r.contains("no contact"),
            "{r}"
        );
    }
}
