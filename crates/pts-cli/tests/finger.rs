//! The finger file gets one verdict everywhere: `pts finger` refuses what the controller (and so
//! the firmware's build) refuses, naming the key and the allowed range.

use std::process::Command;

fn pts(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_pts"))
        .args(args)
        .output()
        .expect("run pts")
}

fn write(name: &str, text: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("pts-finger-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn a_current_limit_beyond_the_sensor_is_refused_by_pts_finger() {
    // The paper's current sense sees ±0.33 A; this limit passes the file's own range checks
    // but an over-current could never be detected.
    let f = write("imax.toml", "[motor]\nmax_current_a = 0.45\n");
    let out = pts(&["finger", "--finger", f.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "accepted: {err}");
    assert!(
        err.contains("motor.max_current_a") && err.contains("0.3298"),
        "{err}"
    );
}

#[test]
fn the_shipped_finger_files_are_accepted() {
    for f in ["fingers/paper.toml", "fingers/long_stiff.toml"] {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(f);
        let out = pts(&["finger", "--finger", path.to_str().unwrap()]);
        assert!(
            out.status.success(),
            "{f}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

/// A finger whose springs or linkage the estimators' tables cannot hold is refused when the
/// file is checked, naming the key and the range (it used to pass, and the firmware built from
/// it never estimated).
#[test]
fn a_finger_the_estimators_cannot_model_is_refused_by_pts_finger() {
    for (name, text, key, range) in [
        (
            "k2.toml",
            "[springs]\nk2_nm_per_rad = 150.0\n",
            "springs.k2_nm_per_rad",
            "(0, 100)",
        ),
        (
            "k1.toml",
            "[springs]\nk1_nm_per_rad = 0.0\n",
            "springs.k1_nm_per_rad",
            "(0, 100)",
        ),
        ("long.toml", "[geometry]\nl2_m = 0.35\n", "geometry", "4·l1"),
    ] {
        let f = write(name, text);
        let out = pts(&["finger", "--finger", f.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{name} accepted");
        assert!(err.contains(key) && err.contains(range), "{name}: {err}");
    }
}

/// `pts finger` prints the file and, as comments, what the firmware's build derives from it;
/// the printout reads back as the same finger. For the paper's finger the rest check's stop is
/// the hand-written prototype's (81.53 mrad below rest, 0.0444 N·m of spring there: MODEL.md's
/// geometry through `grasp::RestCheck::PAPER`), and the detection's margins are printed.
#[test]
fn pts_finger_prints_what_the_build_derives() {
    let out = pts(&["finger"]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    let back = pts::config::FingerFile::from_toml_str(&text).expect("reads back");
    assert_eq!(back, pts::config::FingerFile::paper());
    let stop = text
        .lines()
        .find(|l| l.starts_with("#   rest pose"))
        .unwrap_or_else(|| panic!("{text}"));
    assert!(
        stop.contains("open stop -0.08153 rad") && stop.contains("holding 0.0444 N·m"),
        "{stop}"
    );
    let det = text
        .lines()
        .find(|l| l.starts_with("#   contact detection at 1.5 N·m/rad"))
        .unwrap_or_else(|| panic!("{text}"));
    assert!(det.contains("(allowed: up to 0.750)"), "{det}");
    assert!(det.contains("a proximal contact"), "{det}");
}
