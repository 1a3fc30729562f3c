//! `cargo xtask demo [--scene NAME|FILE]`: the README's main command.
//!
//! Builds the QEMU firmware for the scene, runs it in qemu-system-arm (installing it when
//! missing), decodes the defmt stream live and ends with the estimate next to the plant's truth.
//! Exits with the firmware's status (0: estimate delivered; 2: the controller faulted and
//! switched the bridge off; 101/102: panic/HardFault).

use crate::log::{self, int, word};
use crate::qemu::{self, Frame};
use crate::util::Res;

/// Parses `--scene X` (default table2).
pub fn scene_from_args(args: &[String]) -> Res<String> {
    let mut scene = "table2".to_string();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--scene" => {
                scene = it
                    .next()
                    .ok_or("--scene needs a scene name or a scene TOML file")?
                    .clone()
            }
            s if s.starts_with("--scene=") => scene = s["--scene=".len()..].to_string(),
            other => {
                return Err(format!(
                    "unknown argument `{other}` (usage: demo [--scene NAME|FILE])"
                ))
            }
        }
    }
    Ok(scene)
}

/// One frame as the live view shows it.
fn live(f: &Frame) {
    let m = &f.msg;
    let t_ms = |ticks: Option<u64>| ticks.map(|t| t as f64 * 0.1).unwrap_or(0.0);
    if m.starts_with("S ") {
        let th = int(m, "theta_a_urad").unwrap_or(0) as f64 * 1e-6;
        let ta = int(m, "torque_unm").unwrap_or(0) as f64 * 1e-6;
        let tr = int(m, "ref_unm").unwrap_or(0) as f64 * 1e-6;
        let st = word(m, "state").unwrap_or("?");
        // A bar for θa between rest (−0.85) and +0.4 rad.
        let pos = (((th + 0.85) / 1.25) * 40.0).clamp(0.0, 40.0) as usize;
        let bar: String = (0..40).map(|i| if i < pos { '=' } else { ' ' }).collect();
        println!(
            "{:>8.1} ms  θa {:+.4} rad  T_a {:+.4} N·m (ref {:+.4})  |{bar}|  {st}",
            t_ms(f.ts),
            th,
            ta,
            tr
        );
    } else if m.starts_with("E ") || m.starts_with("P ") || m.starts_with("TRUTH") {
        let who = if m.starts_with("P ") {
            "plant"
        } else if m.starts_with("E ") {
            "grasp"
        } else {
            "truth"
        };
        println!(
            "{:>8.1} ms  ** {who}: {}",
            t_ms(f.ts),
            m.get(2..).unwrap_or(m).trim_start_matches("UTH ")
        );
    } else {
        println!("{}", log::show(f));
    }
}

/// Prints the final comparison: estimate vs truth.
pub fn summary(frames: &[Frame], status: i32) {
    println!("\n=== result ===");
    if let Some(e) = log::last(frames, "E Estimated") {
        let m = &e.msg;
        let located = m
            .split("located: ")
            .nth(1)
            .and_then(|r| r.split(',').next())
            .unwrap_or("?");
        println!("estimate : contact {located}");
        if let Some(k2) = int(m, "k2_um") {
            println!("           k̂2   = {:.2} mm from O2", k2 as f64 / 1000.0);
        }
        if let Some(kc) = int(m, "kc_hat_unm_per_rad") {
            println!("           K̂c   = {:.4} N·m/rad", kc as f64 * 1e-6);
        }
        if let (Some(d), Some(t)) = (int(m, "delta_ta_unm"), int(m, "delta_theta_a_urad")) {
            println!(
                "           ΔT_a = {:.4} N·m, Δθa = {:.5} rad",
                d as f64 * 1e-6,
                t as f64 * 1e-6
            );
        }
    } else {
        println!("estimate : none");
    }
    if let Some(c) = log::first(frames, "P first_contact") {
        println!(
            "truth    : first contact on the {} phalanx at k = {:.2} mm",
            word(&c.msg, "phalanx").unwrap_or("?"),
            int(&c.msg, "k_um").unwrap_or(0) as f64 / 1000.0
        );
    }
    if let Some(t) = log::first(frames, "TRUTH at=settled") {
        println!(
            "           at the settled step: contact {} at k = {:.2} mm",
            word(&t.msg, "contact").unwrap_or("?"),
            int(&t.msg, "k_um").unwrap_or(0) as f64 / 1000.0
        );
    }
    if let Some(e) = log::last(frames, "END") {
        println!(
            "end      : state {} , bridge safe {}, {} control ticks ({:.1} s simulated)",
            word(&e.msg, "state").unwrap_or("?"),
            word(&e.msg, "bridge_safe").unwrap_or("?"),
            int(&e.msg, "ticks").unwrap_or(0),
            int(&e.msg, "ticks").unwrap_or(0) as f64 * 1e-4
        );
    }
    if let (Some(e), Ok(per)) = (log::last(frames, "END"), crate::ci::instr_per_stamp(frames)) {
        let w = int(&e.msg, "work_max").unwrap_or(0) as f64 * per;
        let m = int(&e.msg, "work_mean_x100").unwrap_or(0) as f64 * 0.01 * per;
        let est = int(&e.msg, "est_work_max").unwrap_or(0) as f64 * per;
        let sup = int(&e.msg, "sup_work_max").unwrap_or(0) as f64 * per;
        println!(
            "work     : sampling task max {w:.0} / mean {m:.0} instructions per tick (Cortex-M4, ±40; of 10 000 per 100 µs at 100 MHz), state machine max {sup:.0} per run, estimate {est:.0} instructions"
        );
    }
    println!("firmware exit status {status}");
}

/// `cargo xtask demo`.
pub fn main(args: &[String]) -> Res<i32> {
    let scene = scene_from_args(args)?;
    qemu::ensure_qemu()?;
    let elf = qemu::build(&scene)?;
    let run = qemu::run(&elf, &mut live)?;
    summary(&run.frames, run.status);
    println!("(QEMU wall time {:.1} s)", run.wall.as_secs_f64());
    Ok(run.status)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scene_argument() {
        let a = |v: &[&str]| scene_from_args(&v.iter().map(|s| s.to_string()).collect::<Vec<_>>());
        assert_eq!(a(&[]).unwrap(), "table2");
        assert_eq!(a(&["--scene", "free"]).unwrap(), "free");
        assert_eq!(a(&["--scene=vertex_k2_30"]).unwrap(), "vertex_k2_30");
        assert!(a(&["--scene"]).is_err());
        assert!(a(&["--bogus"]).is_err());
    }
}
