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
    // Every event in words and SI units, none in the controller's Debug form; the seated
    // controller's events too.
    assert!(text.contains("back-dated to t ="), "{text}");
    assert!(!text.contains("{ tick"), "{text}");
    let seated = pts(&["sim", "--seating"]);
    let text = String::from_utf8_lossy(&seated.stdout);
    assert!(seated.status.success(), "{text}");
    assert!(text.contains("first loading point: θa ="), "{text}");
    assert!(!text.contains("{ tick"), "{text}");
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

/// A scene's open-loop `[command]` and `duration_s` are not silently dropped: `pts sim` says
/// that the controller drives the grasp instead, and `--list` says what they are for.
#[test]
fn the_scenes_open_loop_command_is_named_not_silently_ignored() {
    let out = pts(&["sim", "--scene", "large_cyl_second_contact"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("note: A scene's [command]") && err.contains("run_scene"),
        "{err}"
    );
    let list = pts(&["sim", "--list"]);
    let text = String::from_utf8_lossy(&list.stdout);
    assert!(
        text.contains("[command]") && text.contains("duration_s"),
        "{text}"
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

/// Issue 16's time to know, on the default controller: over the sweep's default grasps
/// (vertex, R 1 and 5 cm × k2,c 10–90 % of l2, the realistic plant) at ΔT_a 0.5 and 0.8 N·m,
/// every grasp answered, the median from the plant's first contact to the estimate within
/// 0.6 s and the mean error against the plant's contact within 1 % of l2 (measured 0.49 /
/// 0.52 s, 0.55 / 0.74 %).
#[test]
fn the_default_is_known_within_0_6_s_at_a_mean_error_within_1_percent() {
    let sweep = json(&["sim", "--sweep", "--dta", "0.5,0.8", "--json"]);
    let cells = sweep["cells"].as_array().unwrap();
    for dta in [0.5, 0.8] {
        let of: Vec<&serde_json::Value> = cells
            .iter()
            .filter(|c| c["dta"].as_f64() == Some(dta))
            .collect();
        assert_eq!(of.len(), 15, "{sweep}");
        let mut t: Vec<f64> = of
            .iter()
            .map(|c| c["time_to_know_s"].as_f64().expect("known"))
            .collect();
        let errs: Vec<f64> = of
            .iter()
            .map(|c| c["error_pct_l2"].as_f64().expect("answered").abs())
            .collect();
        t.sort_by(f64::total_cmp);
        let median = t[t.len() / 2];
        let mean = errs.iter().sum::<f64>() / errs.len() as f64;
        println!(
            "ΔT_a {dta} N·m: median time to know {median:.3} s, mean |error| {mean:.2} % of l2"
        );
        assert!(median <= 0.6, "ΔT_a {dta}: median {median} s");
        assert!(mean <= 1.0, "ΔT_a {dta}: mean {mean} % of l2");
    }
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

/// By default the controller steps from T_a,c at the detection: no `seated` event, the
/// estimate known within 0.6 s of the first contact (issue 16) and about a second sooner than
/// the seated controller's (`--seating`), still close to the plant's contact, and a trace
/// recorded that way replays (`pts estimate`, from its `# pts-sim` line) to the same answer.
#[test]
fn by_default_the_step_starts_at_the_detection() {
    let events = |v: &serde_json::Value| -> Vec<String> {
        v["events"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| e["event"].as_str().unwrap().to_string())
            .collect()
    };
    let seated = json(&["sim", "--scene", "table2", "--seating", "--json"]);
    let direct = json(&["sim", "--scene", "table2", "--json"]);
    let explicit = json(&["sim", "--scene", "table2", "--no-seating", "--json"]);
    assert_eq!(direct["estimate"], explicit["estimate"]);
    assert!(events(&seated).iter().any(|e| e == "seated"), "{seated}");
    assert!(!events(&direct).iter().any(|e| e == "seated"), "{direct}");
    let know = |v: &serde_json::Value| v["time_to_know_s"].as_f64().expect("time to know");
    assert!(know(&direct) < 0.6, "{}", know(&direct));
    // The seating stages take over a second on this scene.
    assert!(
        know(&direct) + 0.8 < know(&seated),
        "{} vs {}",
        know(&direct),
        know(&seated)
    );
    // Against the plant's own first contact (measured +1.06 %).
    let err = direct["error_pct_l2"]
        .as_f64()
        .expect("an error against the truth");
    assert!(err.abs() < 1.5, "{err} % of l2");
    // 0.5 N·m on the same ramp is known within 0.6 s too (measured 0.524 s, +0.91 % of l2).
    let fast = json(&["sim", "--scene", "table2", "--dta", "0.5", "--json"]);
    assert!(know(&fast) < 0.6, "{}", know(&fast));
    let err = fast["error_pct_l2"]
        .as_f64()
        .expect("an error against the truth");
    assert!(err.abs() < 1.5, "{err} % of l2");

    let dir = std::env::temp_dir().join(format!("pts-no-seating-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let csv = dir.join("direct.csv");
    let out = pts(&["sim", "--scene", "table2", "--csv", csv.to_str().unwrap()]);
    assert!(out.status.success());
    let replay = json(&["estimate", "--trace", csv.to_str().unwrap(), "--json"]);
    assert_eq!(replay["exact_replay"], true, "{replay}");
    assert_eq!(
        replay["contacts"][0]["k2"], direct["estimate"]["k2"],
        "{replay}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A fast step on a soft contact (10 % of l2) holds the duty at its limit through the motor's
/// back-EMF while the finger travels: the motor turns, so it is not a stall (the grasp's stall
/// check counted saturated ticks alone and ended this grasp in `stall`).
#[test]
fn a_saturated_duty_while_the_motor_turns_is_not_a_stall() {
    let v = json(&[
        "sim",
        "--sweep",
        "--radii-cm",
        "0",
        "--k2-pct",
        "10",
        "--dta",
        "0.8",
        "--step-ramp",
        "8",
        "--no-seating",
        "--json",
    ]);
    let cell = &v["cells"][0];
    assert_eq!(cell["outcome"], "ok", "{v}");
    let err = cell["error_pct_l2"]
        .as_f64()
        .expect("an error against the truth");
    assert!(err.abs() < 1.0, "{err} % of l2");
}

/// A value out of range is refused with the value and the range in the message, before any
/// simulation runs.
#[test]
fn out_of_range_options_name_the_value_and_the_range() {
    for (args, value, range) in [
        (&["sim", "--dta", "0.5,7"][..], "7 N·m", "(0, 2] N·m"),
        (&["sim", "--max-s", "1000"][..], "1000 s", "(0, 600] s"),
    ] {
        let out = pts(args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.contains(value) && err.contains(range),
            "{args:?}: {err}"
        );
    }
}
