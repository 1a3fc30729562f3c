//! `cargo xtask fuzz [--seconds N] [--target solver|parsers|settings|proto]`: runs the cargo-fuzz targets
//! of `fuzz/` (nightly + libFuzzer) for N seconds each (default 60) and reports, per target,
//! how long it ran clean and how many inputs it executed. Installs cargo-fuzz and the
//! nightly toolchain when missing. Exit status 1 on any finding (the crash input is left in
//! `fuzz/artifacts/<target>/`) or on a target that does not build.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

pub(crate) const TARGETS: [&str; 4] = ["solver", "parsers", "settings", "proto"];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from("."))
}

fn ok(c: &mut Command) -> bool {
    c.status().map(|s| s.success()).unwrap_or(false)
}

fn ensure_tools() -> Result<(), String> {
    if !ok(Command::new("rustup").args(["run", "nightly", "rustc", "--version"])) {
        eprintln!("fuzz: installing the nightly toolchain (fuzzing only)");
        if !ok(Command::new("rustup").args([
            "toolchain",
            "install",
            "nightly",
            "--profile",
            "minimal",
        ])) {
            return Err("could not install the nightly toolchain".into());
        }
    }
    if !ok(Command::new("cargo").args(["fuzz", "--version"])) {
        eprintln!("fuzz: installing cargo-fuzz (cargo install cargo-fuzz --locked)");
        if !ok(Command::new("cargo").args(["install", "cargo-fuzz", "--locked"])) {
            return Err("could not install cargo-fuzz".into());
        }
    }
    Ok(())
}

/// Seeds the parser corpus with the repository's own scenes, fingers and traces.
fn seed(root: &Path) {
    let dir = root.join("fuzz/corpus/parsers");
    let _ = std::fs::create_dir_all(&dir);
    for src in [
        "crates/plant/scenes",
        "crates/pts-cli/fingers",
        "crates/pts-cli/tests/data",
    ] {
        let Ok(rd) = std::fs::read_dir(root.join(src)) else {
            continue;
        };
        for e in rd.flatten() {
            let p = e.path();
            if matches!(p.extension().and_then(|x| x.to_str()), Some("toml" | "csv")) {
                if let Some(name) = p.file_name() {
                    let _ = std::fs::copy(&p, dir.join(name));
                }
            }
        }
    }
    let _ = std::fs::create_dir_all(root.join("fuzz/corpus/solver"));
    let _ = std::fs::create_dir_all(root.join("fuzz/corpus/settings"));
}

pub fn main(args: &[String]) -> Result<i32, String> {
    let mut seconds = 60u64;
    let mut only: Option<String> = None;
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--seconds" => {
                seconds = it
                    .next()
                    .and_then(|s| s.parse().ok())
                    .ok_or("--seconds needs a number")?
            }
            "--target" => only = it.next().cloned(),
            other => {
                return Err(format!(
                    "unknown argument `{other}` (--seconds N, --target NAME)"
                ))
            }
        }
    }
    let root = root();
    ensure_tools()?;
    seed(&root);
    let mut findings = 0;
    let mut report = Vec::new();
    for t in TARGETS
        .iter()
        .filter(|t| only.as_deref().is_none_or(|o| o == **t))
    {
        // A target that does not compile is not a finding of the fuzzer: say so, with the
        // compiler's own messages (inherited stderr).
        if !ok(Command::new("cargo")
            .args(["+nightly", "fuzz", "build", t])
            .current_dir(&root))
        {
            findings += 1;
            report.push(format!(
                "fuzz {t}: DOES NOT BUILD (the compiler's errors are above)"
            ));
            continue;
        }
        let start = Instant::now();
        let out = Command::new("cargo")
            .args(["+nightly", "fuzz", "run", t, "--"])
            .arg(format!("-max_total_time={seconds}"))
            // plant leaks each parsed scene's name once on purpose (&'static str): not a
            // finding, so LeakSanitizer is off; panics, overflows and bad Ok values are.
            .args(["-print_final_stats=1", "-max_len=4096", "-detect_leaks=0"])
            .env("ASAN_OPTIONS", "detect_leaks=0") // the same at exit
            .current_dir(&root)
            .output()
            .map_err(|e| format!("cargo fuzz run {t}: {e}"))?;
        let secs = start.elapsed().as_secs();
        let log = String::from_utf8_lossy(&out.stderr);
        let stat = |key: &str| {
            log.lines()
                .filter_map(|l| l.strip_prefix(key))
                .filter_map(|v| v.trim().parse::<u64>().ok())
                .next_back()
        };
        let execs = stat("stat::number_of_executed_units:");
        let clean = out.status.success();
        if !clean {
            findings += 1;
            let tail: Vec<&str> = log.lines().rev().take(40).collect();
            for l in tail.iter().rev() {
                eprintln!("{l}");
            }
        }
        report.push(format!(
            "fuzz {t}: {} after {secs} s (budget {seconds} s), {} executions",
            if clean { "clean" } else { "FINDING" },
            execs.map_or("?".into(), |n| n.to_string())
        ));
    }
    for r in &report {
        println!("{r}");
    }
    Ok(if findings == 0 { 0 } else { 1 })
}
