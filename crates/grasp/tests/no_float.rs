//! The per-tick path does no floating point: grasp is compiled for thumbv6m-none-eabi (no FPU,
//! every float operation is a call into compiler-builtins) and the call graph of
//! `grasp::tick_dyn`, `grasp::loop_tick_dyn` (the sampling task) and `grasp::supervise_dyn` in
//! the emitted assembly must not reach a soft-float routine or a panic; the sampling task
//! must not reach a division either.
//!
//! Uses its own target directory (`target/grasp-thumbv6m`) so it never waits on the outer
//! build lock. Needs the thumbv6m-none-eabi target (rust-toolchain.toml installs it).
use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::process::Command;

fn workspace_root() -> PathBuf {
    let here = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    here.parent()
        .and_then(|p| p.parent())
        .map(PathBuf::from)
        .unwrap_or(here)
}

// The panic names and the call graph are `cargo xtask panics`' own (one source, two checks).
#[path = "../../../xtask/src/callgraph.rs"]
#[allow(dead_code)] // xtask's other checks use the rest
mod callgraph;
use callgraph::{call_graph, is_panic, is_soft_float};

#[test]
fn the_panic_filter_cannot_miss_the_core_entry_points() {
    for s in [
        "_ZN4core9panicking9panic_fmt17h0123456789abcdefE",
        "_ZN4core9panicking18panic_bounds_check17h0123456789abcdefE",
        "_ZN4core6option13unwrap_failed17h0123456789abcdefE",
        "_ZN4core6result13unwrap_failed17h0123456789abcdefE",
        "_ZN4core6option13expect_failed17h0123456789abcdefE",
        "_ZN4core5slice5index16slice_index_fail17h0123456789abcdefE",
        "_ZN4core5slice5index24slice_end_index_len_fail17h0123456789abcdefE",
        "_ZN4core5slice5index22slice_index_order_fail17h0123456789abcdefE",
        "_RNvNtCs7ldSeZOOJos_4core9panicking5panic",
    ] {
        assert!(is_panic(s), "{s}");
    }
    assert!(!is_panic("__aeabi_memcpy") && !is_panic("__aeabi_uidiv"));
    // A conditional tail branch to a panic is an edge; bfc/bics are not branches.
    let g = call_graph(
        "f:\n\tbics.w r1, r4, r1\n\tbhs.w _ZN4core9panicking18panic_bounds_check17hE\n\tbx lr\n",
    );
    assert_eq!(
        g["f"].iter().collect::<Vec<_>>(),
        ["_ZN4core9panicking18panic_bounds_check17hE"]
    );
}

#[test]
fn tick_path_calls_no_soft_float_on_thumbv6m() {
    let root = workspace_root();
    let target_dir = root.join("target").join("grasp-thumbv6m");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let status = Command::new(&cargo)
        .current_dir(&root)
        .args([
            "rustc",
            "-q",
            "-p",
            "grasp",
            "--lib",
            "--release",
            "--target",
            "thumbv6m-none-eabi",
            "--target-dir",
        ])
        .arg(&target_dir)
        .args([
            "--",
            "--emit=asm",
            "-C",
            "codegen-units=1",
            "-C",
            "debuginfo=0",
        ])
        .status()
        .expect("run cargo");
    assert!(
        status.success(),
        "cargo rustc for thumbv6m-none-eabi failed"
    );
    let deps = target_dir.join("thumbv6m-none-eabi/release/deps");
    let asm_path = std::fs::read_dir(&deps)
        .expect("deps dir")
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            p.extension().is_some_and(|e| e == "s")
                && p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("grasp-"))
        })
        .max_by_key(|p| p.metadata().and_then(|m| m.modified()).ok())
        .expect("grasp-*.s emitted");
    let asm = std::fs::read_to_string(&asm_path).expect("read asm");
    let g = call_graph(&asm);
    // Sanity: the checker does see soft float where there is some (the config conversion).
    let all_soft: BTreeSet<&String> = g.values().flatten().filter(|s| is_soft_float(s)).collect();
    assert!(
        !all_soft.is_empty(),
        "the crate has float code (config); the checker must see it"
    );
    // The composed tick, the sampling task's loop tick and the supervisor's step.
    for (root_name, no_division) in [
        ("5grasp8tick_dyn", false),
        ("5grasp13loop_tick_dyn", true),
        ("5grasp13supervise_dyn", false),
    ] {
        let root_fn = g
            .keys()
            .find(|k| k.contains(root_name))
            .cloned()
            .unwrap_or_else(|| panic!("{root_name} in the assembly"));
        let (seen, external) = reachable_split(&g, &root_fn);
        let soft: Vec<&String> = seen.iter().filter(|s| is_soft_float(s)).collect();
        println!(
            "{root_name}: {} functions in grasp, external callees: {:?}",
            seen.len() - external.len(),
            external
        );
        assert!(
            soft.is_empty(),
            "soft-float routines reachable from {root_name}: {soft:?}"
        );
        // Nothing panics: no panic routine is reachable either (release build, so this is
        // about division by zero, bounds checks and explicit panics, not overflow checks).
        let panics: Vec<&String> = seen.iter().filter(|s| is_panic(s)).collect();
        assert!(
            panics.is_empty(),
            "panic paths reachable from {root_name}: {panics:?}"
        );
        if no_division {
            // The sampling task divides nothing (Armv6-M has no divider: every division
            // would be a library call of tens of instructions) except in the calibration's
            // end, once at power-up with the bridge off (kept out of line for this check).
            let calib = g
                .keys()
                .find(|k| k.contains("calib_finish"))
                .cloned()
                .expect("CurrentSense::calib_finish out of line");
            let (seen, _) = reachable_except(&g, &root_fn, &calib);
            assert!(seen.len() > 1, "{root_name} has no callees: checker broken");
            let div: Vec<&String> = seen.iter().filter(|s| s.contains("div")).collect();
            assert!(
                div.is_empty(),
                "division reachable from {root_name}: {div:?}"
            );
        }
    }
}

/// Functions reachable from `root` (defined in the crate) and the external callees.
fn reachable_split(
    g: &BTreeMap<String, BTreeSet<String>>,
    root: &str,
) -> (BTreeSet<String>, BTreeSet<String>) {
    reachable_except(g, root, "")
}

/// [`reachable_split`] without descending into `skip`.
fn reachable_except(
    g: &BTreeMap<String, BTreeSet<String>>,
    root: &str,
    skip: &str,
) -> (BTreeSet<String>, BTreeSet<String>) {
    let mut seen = BTreeSet::new();
    let mut stack = vec![root.to_string()];
    let mut external = BTreeSet::new();
    while let Some(f) = stack.pop() {
        if f == skip || !seen.insert(f.clone()) {
            continue;
        }
        match g.get(&f) {
            Some(callees) => stack.extend(callees.iter().cloned()),
            None => {
                external.insert(f);
            }
        }
    }
    (seen, external)
}
