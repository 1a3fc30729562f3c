//! `cargo xtask demo [--scene NAME|FILE]`: the README's main command.
//!
//! Without options it runs [`crate::demo_device`]: grasps driven over the host protocol. With
//! `--scene` it builds the power-up firmware for that scene, runs it in qemu-system-arm
//! (installing it when missing), decodes the defmt stream live and ends with the estimate next
//! to the plant's truth, exiting with the firmware's status (0: estimate delivered; 2: the
//! controller faulted and switched the bridge off; 101/102: panic/HardFault). The words this
//! view gives events are shared with the device demo and `cargo xtask device`.

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

/// Width of the live view (columns).
const WIDTH: usize = 80;

/// `text` wrapped to [`WIDTH`] columns, continuation lines indented by `indent` spaces.
fn wrap(text: &str, indent: usize) -> String {
    let body = text.trim_start_matches(' ');
    let mut col = text.len() - body.len();
    let mut out = " ".repeat(col);
    let lead = col;
    for word in body.split(' ') {
        let w = word.chars().count();
        if col > indent.max(lead) && col + 1 + w > WIDTH {
            out.push('\n');
            out.push_str(&" ".repeat(indent));
            col = indent;
        } else if col > lead {
            out.push(' ');
            col += 1;
        }
        out.push_str(word);
        col += w;
    }
    out
}

/// The i-th identifier of a Rust Debug text (`Fault { tick: 1, reason: NoMotion { .. } }`:
/// 0 → "Fault", 2 → "NoMotion").
fn idents(msg: &str) -> Vec<&str> {
    msg.split(|c: char| !c.is_ascii_alphanumeric() && c != '_')
        .filter(|w| w.chars().next().is_some_and(|c| c.is_ascii_uppercase()))
        .collect()
}

/// A fault in words: what happened, the likely cause, what to try.
pub fn fault_words(name: &str) -> (&'static str, &'static str, &'static str) {
    match name {
        "EncoderJump" => (
            "the encoder count jumped further in one period than the motor can turn",
            "electrical noise on the encoder lines or a loose connector",
            "check the encoder wiring and its ground; shield the cable",
        ),
        "EncoderMismatch" => (
            "the encoder disagrees with the motor's back-EMF",
            "a stuck or slipping encoder, or a disconnected channel",
            "check the encoder cable and that its disc turns with the shaft",
        ),
        "AdcCode" | "AdcOffset" => (
            "the current sensor reads an impossible value with the bridge off",
            "a failed or unpowered current amplifier",
            "check the shunt amplifier's supply and its output at zero current (mid-scale)",
        ),
        "AdcRail" => (
            "the current reading sat at a rail while driving",
            "current beyond the sensor's range, or a failed sensor",
            "check the motor for a short; compare motor.max_current_a with the sensor's range",
        ),
        "OverCurrent" => (
            "the motor current stayed above its limit",
            "a shorted winding or a jammed gearhead",
            "turn the motor by hand with the power off; measure the winding resistance",
        ),
        "Stall" => (
            "the drive could not follow the torque reference (duty saturated)",
            "a jammed transmission or a bus voltage too low for the motor",
            "check the bus voltage and that the finger moves freely",
        ),
        "NoContact" => (
            "the approach reached its torque ceiling or the end of travel without a contact",
            "no object in reach",
            "place an object within the finger's range (or choose a scene with one)",
        ),
        "SettleTimeout" => (
            "the finger did not come to rest after the torque step",
            "a contact that keeps sliding, or vibration",
            "use a smaller ΔT_a or a firmer object",
        ),
        "EstimateTimeout" => (
            "the estimate was not delivered in time",
            "the estimate task was starved or stalled",
            "report it: this is a firmware fault",
        ),
        "SecondContact" => (
            "the stiffness became larger than any single contact allows",
            "the object touches both phalanges (or the tip) and locks the finger",
            "move the object so that it touches the distal phalanx only",
        ),
        "NoMotion" => (
            "the torque step did not move the finger enough to measure a stiffness",
            "ΔT_a inside the transmission's friction band",
            "raise ΔT_a (FINGER_FW_DELTA_TA_NM, e.g. 0.8 N·m)",
        ),
        "LossOfContact" => (
            "the finger moved further than a contact allows",
            "the object slipped away or was removed",
            "hold the object still, or grasp it nearer the phalanx's middle",
        ),
        "EstimateOutOfRange" => (
            "the estimator refused the measurement",
            "a stiffness no contact on this finger can produce (wrong finger file, or noise)",
            "check the finger file against the finger; repeat with a larger ΔT_a",
        ),
        "SupervisorStalled" => (
            "the control loop found its setpoint too old and stopped driving",
            "the supervise task stalled",
            "report it: this is a firmware fault",
        ),
        "RestNotFound" => (
            "the finger's open stop was not found before zeroing the encoder",
            "the finger is blocked, the encoder or motor does not work, or no stop within its range",
            "free the finger and check the motor and encoder, then power-cycle",
        ),
        _ => ("an unknown fault", "unknown", "read the raw log line above"),
    }
}

fn mm(um: i64) -> String {
    format!("{:.2} mm", um as f64 / 1000.0)
}

fn rad(urad: i64) -> String {
    format!("{:+.4} rad", urad as f64 * 1e-6)
}

fn nm(unm: i64) -> String {
    format!("{:.3} N·m", unm as f64 * 1e-6)
}

/// A controller event (`E …`) in words, or `None` for events the view leaves out.
pub fn event_words(msg: &str) -> Option<String> {
    let ids = idents(msg);
    let v = |k: &str| int(msg, k).unwrap_or(0);
    Some(match *ids.first()? {
        "Calibrated" => "current sensor zeroed with the bridge off; approaching the object".into(),
        "ContactDetected" => format!(
            "contact: θa,c = {}, T_a,c = {}; raising the torque to {}",
            rad(v("theta_a_urad")),
            nm(v("torque_unm")),
            nm(v("target_unm"))
        ),
        "Seated" => format!(
            "{}: θa = {}, T_a = {}",
            match v("stage") {
                0 => "impact at rest",
                1 => "first loading point",
                _ => "second loading point",
            },
            rad(v("theta_a_urad")),
            nm(v("torque_unm"))
        ),
        "StepDone" => "torque step complete; waiting for the finger to settle".into(),
        "Settled" => format!(
            "settled: θa = {}, T_a = {}; estimating from {} samples",
            rad(v("theta_a_urad")),
            nm(v("torque_unm")),
            v("path_len")
        ),
        "Estimated" => {
            let located = ids.get(2).copied().unwrap_or("?");
            let quality = ids.last().copied().unwrap_or("?").to_lowercase();
            let sigma = int(msg, "k2_sigma_um").map_or(String::new(), |s| format!(" ± {}", mm(s)));
            let radius =
                int(msg, "radius_um").map_or(String::new(), |r| format!(", R = {}", mm(r)));
            let reference = int(msg, "two_point_k2_um")
                .map_or(String::new(), |t| format!("; two-point method {}", mm(t)));
            match int(msg, "k2_um") {
                Some(k2) => format!(
                    "estimate: {} phalanx, k2 = {}{sigma} from O2{radius} (K_c = {:.3} N·m/rad, quality {quality}{reference})",
                    located.to_lowercase(),
                    mm(k2),
                    v("kc_hat_unm_per_rad") as f64 * 1e-6
                ),
                None => format!(
                    "estimate: contact on the {} phalanx (quality {quality})",
                    located.to_lowercase()
                ),
            }
        }
        "Holding" => "holding the object (bridge on)".into(),
        "Releasing" => "releasing".into(),
        "Released" => "released; bridge off".into(),
        "Fault" => {
            let name = ids.get(1).copied().unwrap_or("?");
            let (what, cause, try_) = fault_words(name);
            format!("FAULT, bridge off: {what}. Likely cause: {cause}. Try: {try_}.")
        }
        _ => return None,
    })
}

/// The finger's name in a BOOT line (it may contain spaces).
pub fn boot_finger(boot: &str) -> &str {
    boot.split("finger=")
        .nth(1)
        .and_then(|r| r.split(" l2_um=").next())
        .unwrap_or("?")
}

/// The live view: the build's settings, events in words, samples at a calm rate (one a second
/// during the approach, five a second after contact, and at every change of state).
#[derive(Default)]
pub struct View {
    last_sample: Option<u64>,
    last_state: String,
}

impl View {
    /// Prints what `f` adds to the view.
    pub fn show(&mut self, f: &Frame) {
        let m = &f.msg;
        let t = |ticks: Option<u64>| format!("{:>7.3} s", ticks.unwrap_or(0) as f64 * 1e-4);
        if m.starts_with("BOOT ") {
            println!(
                "finger     {} (l2 = {})",
                boot_finger(m),
                mm(int(m, "l2_um").unwrap_or(0))
            );
            println!(
                "scene      {} (simulated inside the firmware)",
                word(m, "scene").unwrap_or("?")
            );
            match word(m, "estimator") {
                Some(e) => println!(
                    "build      {e} estimator, ΔT_a = {}",
                    nm(int(m, "dta_unm").unwrap_or(0))
                ),
                None => println!("mode       device: each grasp takes its settings from the host"),
            }
            println!();
        } else if let Some(s) = proto::log::SampleLine::parse(m) {
            let st = s.state.split('(').next().unwrap_or(s.state).to_string();
            let tick = f.ts.unwrap_or(0);
            let every = if st == "Approach" { 10_000 } else { 2_000 };
            let due = self.last_sample.is_none_or(|l| tick >= l + every);
            if st != self.last_state || due {
                self.last_sample = Some(tick);
                self.last_state = st.clone();
                println!(
                    "{}  {:<11} θa {}   T_a {} (ref {})",
                    t(f.ts),
                    st.to_lowercase(),
                    rad(s.theta_a_urad.into()),
                    nm(s.torque_unm.into()),
                    nm(s.ref_unm.into())
                );
            }
        } else if m.starts_with("GRASP ") {
            println!(
                "\ngrasp {} on {}: ΔT_a = {}, {} estimator",
                m.split(' ').nth(1).unwrap_or("?"),
                word(m, "scene").unwrap_or("?"),
                nm(int(m, "dta_unm").unwrap_or(0)),
                word(m, "estimator").unwrap_or("?")
            );
        } else if let Some(e) = m.strip_prefix("E ") {
            if let Some(words) = event_words(e) {
                println!("{}", wrap(&format!("{}  ** {words}", t(f.ts)), 14));
            }
        } else if let Some(p) = m.strip_prefix("P ") {
            let kind = p.split(' ').next().unwrap_or("?").replace('_', " ");
            let where_ = match word(m, "phalanx") {
                Some(ph) if ph != "none" => format!(
                    " on the {ph} phalanx at k = {}",
                    mm(int(m, "k_um").unwrap_or(0))
                ),
                _ => String::new(),
            };
            println!(
                "{}",
                wrap(&format!("{}  (simulation: {kind}{where_})", t(f.ts)), 14)
            );
        } else if m.starts_with("TRUTH")
            || ["CAL ", "INIT ", "WDG ", "STACK "]
                .iter()
                .any(|p| m.starts_with(p))
        {
            // In the summary, or bookkeeping for the checks.
        } else if m.starts_with("RESET ") && word(m, "cause") == Some("power_on") {
        } else if !m.starts_with("END ") {
            println!("{}", log::show(f));
        }
    }
}

/// What the method's number means, for the summary.
fn meaning(estimator: &str) -> &'static str {
    if estimator == "path-fit" {
        "the path fit models the contact's path from the first contact to the settled step \
         and reports where the object first touched"
    } else {
        "the two-point method (the paper's) measures the stiffness between the contact and \
         the settled step; a contact that slides outward reads between its first and final \
         location (the paper's Table 2 shows the same bias); the default build's path fit \
         estimates the first contact"
    }
}

/// Prints the final comparison: estimate vs truth, what it means, how the run ended.
pub fn summary(frames: &[Frame], status: i32) {
    println!("\n{}", "=".repeat(WIDTH));
    let boot = log::first(frames, "BOOT ");
    let estimator = boot.and_then(|b| word(&b.msg, "estimator")).unwrap_or("?");
    let l2_um = boot.and_then(|b| int(&b.msg, "l2_um")).unwrap_or(0);
    let line = |label: &str, text: String| println!("{}", wrap(&format!("{label:<11}{text}"), 11));
    let estimate = log::last(frames, "E Estimated");
    let k2 = estimate.and_then(|e| int(&e.msg, "k2_um"));
    match estimate.and_then(|e| e.msg.strip_prefix("E ").and_then(event_words)) {
        Some(w) => line(
            "estimate",
            format!("{estimator}: {}", w.trim_start_matches("estimate: ")),
        ),
        None => line("estimate", "none".into()),
    }
    let first = log::first(frames, "P first_contact");
    if let Some(c) = first {
        let settled = log::first(frames, "TRUTH at=settled")
            .map(|t| {
                format!(
                    "; at the settled step {}",
                    mm(int(&t.msg, "k_um").unwrap_or(0))
                )
            })
            .unwrap_or_default();
        line(
            "truth",
            format!(
                "first contact on the {} phalanx at {}{settled}",
                word(&c.msg, "phalanx").unwrap_or("?"),
                mm(int(&c.msg, "k_um").unwrap_or(0))
            ),
        );
    }
    if let (Some(k2), Some(k)) = (k2, first.and_then(|c| int(&c.msg, "k_um"))) {
        let pct = if l2_um > 0 {
            (k2 - k) as f64 / l2_um as f64 * 100.0
        } else {
            f64::NAN
        };
        line(
            "error",
            format!(
                "{:+.2} mm = {pct:+.1} % of l2, against the first contact",
                (k2 - k) as f64 / 1000.0
            ),
        );
        line("meaning", meaning(estimator).into());
    }
    if let Some(f) = log::last(frames, "E Fault") {
        if let Some(w) = f.msg.strip_prefix("E ").and_then(event_words) {
            line(
                "fault",
                w.trim_start_matches("FAULT, bridge off: ").to_string(),
            );
        }
    }
    if let Some(e) = log::last(frames, "END") {
        let safe = word(&e.msg, "bridge_safe") == Some("true");
        line(
            "motor",
            if safe {
                "bridge off (safe)".into()
            } else {
                format!(
                    "bridge on, state {} (QEMU stops here; the board keeps holding until released)",
                    word(&e.msg, "state").unwrap_or("?").to_lowercase()
                )
            },
        );
        let ticks = int(&e.msg, "ticks").unwrap_or(0);
        line(
            "firmware",
            format!(
                "exit {status} ({}), {:.1} s simulated",
                match status {
                    0 => "estimate delivered",
                    2 => "the controller faulted and switched the bridge off",
                    101 => "panic, bridge off",
                    102 => "HardFault, bridge off",
                    _ => "see the log",
                },
                ticks as f64 * 1e-4
            ),
        );
    }
    if let (Some(e), Ok(per)) = (log::last(frames, "END"), crate::ci::instr_per_stamp(frames)) {
        let w = int(&e.msg, "work_max").unwrap_or(0) as f64 * per;
        let est = int(&e.msg, "est_work_max").unwrap_or(0) as f64 * per;
        let est = if est > 0.0 {
            format!("; estimate task {est:.0}")
        } else {
            String::new()
        };
        line(
            "work",
            format!(
                "sampling task ≤ {w:.0} of 10,000 instructions per 100 µs period at 100 MHz{est} \
                 (Cortex-M4 instructions, counted by QEMU)"
            ),
        );
    }
}

/// `cargo xtask demo`.
pub fn main(args: &[String]) -> Res<i32> {
    if args.is_empty() {
        return crate::demo_device::main();
    }
    let scene = scene_from_args(args)?;
    qemu::ensure_qemu()?;
    let elf = qemu::build(&scene)?;
    let mut view = View::default();
    let run = qemu::run(&elf, &mut |f| view.show(f))?;
    summary(&run.frames, run.status);
    println!("(QEMU wall time {:.1} s)", run.wall.as_secs_f64());
    Ok(run.status)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn events_read_in_words_within_80_columns() {
        let est = "Estimated { tick: 68120, result: EstimateResult { located: Distal, k2_um: Some(41993), kc_hat_unm_per_rad: 10152486, kc_proximal_unm_per_rad: 2627086, kc_tip_unm_per_rad: 30403645, delta_ta_unm: 803311, delta_theta_a_urad: 79125, theta_a_c_urad: -220697, ta_c_unm: 425269, quality: Good } }";
        let w = event_words(est).unwrap();
        assert!(w.contains("distal phalanx, k2 = 41.99 mm"), "{w}");
        assert!(
            w.contains("K_c = 10.152 N·m/rad") && w.contains("quality good"),
            "{w}"
        );
        let fit = "Estimated { tick: 1, result: EstimateResult { located: Distal, k2_um: Some(29719), k2_sigma_um: Some(1184), radius_um: None, two_point_k2_um: Some(41993), kc_hat_unm_per_rad: 7079086, quality: Good } }";
        let w = event_words(fit).unwrap();
        assert!(
            w.contains("k2 = 29.72 mm ± 1.18 mm from O2 (")
                && w.contains("two-point method 41.99 mm"),
            "{w}"
        );
        let fault = "Fault { tick: 5, reason: NoMotion { travel_urad: 12 } }";
        let w = event_words(fault).unwrap();
        assert!(
            w.starts_with("FAULT, bridge off") && w.contains("raise ΔT_a"),
            "{w}"
        );
        for line in wrap(&format!("  6.814 s  ** {w}"), 14).lines() {
            assert!(line.chars().count() <= WIDTH, "{line}");
        }
        assert_eq!(event_words("Unheard { tick: 1 }"), None);
        // Every fault the controller names has its own words.
        for name in [
            "EncoderJump",
            "EncoderMismatch",
            "AdcCode",
            "AdcOffset",
            "AdcRail",
            "OverCurrent",
            "Stall",
            "NoContact",
            "SettleTimeout",
            "EstimateTimeout",
            "SecondContact",
            "NoMotion",
            "LossOfContact",
            "EstimateOutOfRange",
            "SupervisorStalled",
            "RestNotFound",
        ] {
            assert_ne!(fault_words(name).0, "an unknown fault", "{name}");
        }
    }

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
