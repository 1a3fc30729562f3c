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
