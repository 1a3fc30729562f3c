//! `pts sim` says by its exit status whether the grasp produced an estimate, and its defaults
//! produce one (the default ΔT_a is the firmware's, above the realistic drive's stiction).

use std::process::Command;

fn pts(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_pts"))
        .args(args)
        .output()
        .expect("run pts")
}

#[test]
fn plain_pts_sim_ends_with_an_estimate_and_exit_0() {
    let out = pts(&["sim"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("estimate: distal, k2 ="), "{text}");
}

#[test]
fn a_fault_is_reported_and_exits_non_zero() {
    let out = pts(&["sim", "--scene", "fault_encoder_stuck"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("fault") && err.contains("no estimate"),
        "{err}"
    );
}

fn json(args: &[&str]) -> serde_json::Value {
    let out = pts(args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("one JSON object")
}

/// The time to know is the first contact's plant time to the estimate's controller time, read
/// here from the run's own event list; a step gets there sooner than the default ramp
/// (1 N·m/s, 0.8 s for ΔT_a = 0.8 N·m), and the sweep reports the same figure per cell.
#[test]
fn time_to_know_from_the_events_and_shorter_with_a_step() {
    let run = |ramp: &str| {
        let v = json(&["sim", "--scene", "table2", "--step-ramp", ramp, "--json"]);
        let at = |source: &str, name: &str| {
            v["events"]
                .as_array()
                .unwrap()
                .iter()
                .find(|e| e["source"] == source && e["event"] == name)
                .and_then(|e| e["t_s"].as_f64())
                .unwrap_or_else(|| panic!("no {source} {name} in {v}"))
        };
        let by_events = at("ctl", "estimated") - at("plant", "first_contact");
        let reported = v["time_to_know_s"].as_f64().expect("time_to_know_s");
        assert!(
            (reported - by_events).abs() < 1e-9,
            "{reported} vs {by_events}"
        );
        assert!(reported > 0.0 && reported < 10.0, "{reported}");
        reported
    };
    let (ramp, step) = (run("1"), run("0"));
    assert!(step + 0.2 < ramp, "step {step} s, ramp {ramp} s");

    let sweep = json(&[
        "sim",
        "--sweep",
        "--radii-cm",
        "5",
        "--k2-pct",
        "50",
        "--dta",
        "0.8",
        "--step-ramp",
        "1,0",
        "--json",
    ]);
    let cells = sweep["cells"].as_array().unwrap();
    assert_eq!(cells.len(), 2, "{sweep}");
    let t: Vec<f64> = cells
        .iter()
        .map(|c| c["time_to_know_s"].as_f64().expect("time to know"))
        .collect();
    assert_eq!(cells[1]["step"], "step", "{sweep}");
    assert!(t[1] + 0.2 < t[0], "{t:?}");
}

#[test]
fn a_bad_step_ramp_is_refused_with_its_range() {
    let out = pts(&["sim", "--step-ramp=-1"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--step-ramp -1: a ramp rate in 0..=1000 N·m/s"),
        "{err}"
    );
}
