//! `cargo xtask panics`: no panic reachable from any firmware task on thumbv7em.
//!
//! The release firmware is built with fat LTO and `--emit=asm`, which gives the whole
//! program (firmware, grasp, pts, core, the HAL) as one assembly file. Its direct call graph
//! (every `bl`/`blx`/`b`/conditional branch/`cbz` to a symbol) is walked from the task entry
//! points: the sampling interrupt and the RTIC dispatchers that run `supervise`, `estimate`
//! and `telemetry`. A function is a panic path if its (mangled or demangled) name names a
//! core panic entry point ([`is_panic`]) or it is the panic handler itself
//! (`rust_begin_unwind`, which every panic reaches). Indirect calls (function pointers,
//! trait objects) are not followed; the tasks use none on their control path.
//!
//! The build carries line tables (`-C debuginfo=line-tables-only`, which leaves the code as
//! it is), so each panic call in the linked ELF is attributed to a source file
//! ([`crate::sites`]). That decides for the one task whose panics are known open, the USB
//! interrupt: a call in this project's files fails it unless listed with its reason.
//!
//! The checker is tested on planted functions (an `unwrap`, a slice index, a range index,
//! a division, an `expect`, a call into core's sort) compiled for the same target.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

pub use crate::callgraph::{call_graph, is_panic};
use std::path::{Path, PathBuf};

use crate::sites::{panic_sites, Frame, Owner, Site};
use crate::util::{self, Res};

/// The builds checked: (label, cargo features, estimator, task entry points, entry points whose
/// panic paths are known open: reported, not failed).
type Build = (
    &'static str,
    &'static [&'static str],
    &'static str,
    &'static [&'static str],
    &'static [&'static str],
);
const BUILDS: &[Build] = &[
    ("board, two-point", &[], "two-point", BOARD_ROOTS, &[]),
    ("board, path fit", &[], "path-fit", BOARD_ROOTS, &[]),
    // Device mode: the loop, the supervisor, the estimate and the host task are held to the
    // same rule; the USB interrupt, the one task that touches the link, is an allowance
    // (DEVICE_OPEN_ROOTS).
    (
        "board, device mode (USB), path fit",
        &["board", "device"],
        "path-fit",
        DEVICE_ROOTS,
        DEVICE_OPEN_ROOTS,
    ),
];

/// The board's task entry points: the sampling interrupt and the three dispatchers.
pub const BOARD_ROOTS: &[&str] = &["ADC", "SPI2", "SPI3", "SPI4"];
/// Device mode's on the board: those and the host link's USB interrupt.
pub const DEVICE_ROOTS: &[&str] = &["ADC", "SPI2", "SPI3", "SPI4", "OTG_FS"];
/// Device mode's task whose panic paths are known open: the USB interrupt, the one task that
/// encodes and touches the link (the host task only queues messages for it, and is held to
/// the rule). Its panic calls lie in the USB stack (usb-device, usbd-serial,
/// synopsys-usb-otg), stm32f4xx-hal's flash write, cobs and postcard, which fat LTO inlines
/// into our functions, so the call graph cannot tell whose code a call is. The allowance is
/// therefore per call site, by the linked ELF's line tables ([`crate::sites`]): each call must
/// lie in a crate this project does not own, or be one of [`ACCEPTED_OWN_SITES`]; a panic
/// call in the workspace's own code fails this task like any other.
const DEVICE_OPEN_ROOTS: &[&str] = &["OTG_FS"];

/// The panic paths reachable from `root`: every call from a reachable function into a panic
/// function, each with the call chain from the root to it (shortest, breadth-first).
pub fn panic_paths(g: &BTreeMap<String, BTreeSet<String>>, root: &str) -> Vec<Vec<String>> {
    let mut parent: BTreeMap<String, String> = BTreeMap::new();
    let mut seen = BTreeSet::from([root.to_string()]);
    let mut queue = VecDeque::from([root.to_string()]);
    let mut found = Vec::new();
    let chain_to = |parent: &BTreeMap<String, String>, f: &str| {
        let mut chain = vec![f.to_string()];
        let mut at = f.to_string();
        while let Some(p) = parent.get(&at) {
            chain.push(p.clone());
            at = p.clone();
        }
        chain.reverse();
        chain
    };
    if is_panic(root) {
        return vec![vec![root.to_string()]];
    }
    while let Some(f) = queue.pop_front() {
        for c in g.get(&f).into_iter().flatten() {
            if is_panic(c) {
                // Not into the panic machinery itself: the edge is the finding.
                let mut chain = chain_to(&parent, &f);
                chain.push(c.clone());
                found.push(chain);
            } else if seen.insert(c.clone()) {
                parent.insert(c.clone(), f.clone());
                queue.push_back(c.clone());
            }
        }
    }
    found
}

/// Panic edges accepted, with why: (caller, panic function) substrings.
const ACCEPTED: &[(&str, &str, &str)] = &[
    (
        "_defmt_release",
        "panic_fmt",
        "defmt-rtt's check that release follows acquire: every defmt macro pairs them",
    ),
    (
        "_defmt_acquire",
        "panic_fmt",
        "defmt-rtt's re-entrance check: acquire runs inside its critical section",
    ),
    (
        "",
        "panic_const_async_fn_resumed",
        "the compiler's guard against polling a finished async task: RTIC's executor never does",
    ),
];

fn matches_edge(chain: &[String], caller: &str, callee: &str) -> bool {
    let n = chain.len();
    n >= 1
        && chain[n - 1].contains(callee)
        && (caller.is_empty() || n >= 2 && chain[n - 2].contains(caller))
}

/// Builds one firmware with `--emit=asm` (own target directory); returns the assembly path.
pub fn build_asm(features: &[&str], estimator: &str) -> Res<PathBuf> {
    build(features, estimator, "0")
}

/// Builds one firmware with `--emit=asm,link` and `-C debuginfo=<debuginfo>`; returns the
/// assembly path (the linked ELF is the same path without `.s`). Debug information does not
/// change the code LLVM generates, so the line tables describe the build the board gets.
fn build(features: &[&str], estimator: &str, debuginfo: &str) -> Res<PathBuf> {
    // The workspace's target directory: the flags after `--` reach the firmware crate only,
    // so its dependencies are the ones the board builds (`cargo xtask size`) compile, once.
    let target_dir = util::root().join("target");
    // The assembly is written only when the firmware compiles: a build that cargo finds fresh
    // (the same features as a previous run) would leave another build's file the newest. So
    // the old files go and the firmware is marked changed, and this build writes its own.
    let deps = target_dir
        .join(crate::qemu::TARGET)
        .join("release")
        .join("deps");
    if let Ok(dir) = std::fs::read_dir(&deps) {
        for p in dir.filter_map(Result::ok).map(|e| e.path()) {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            if name.starts_with("finger_fw-") && name.ends_with(".s") {
                let _ = std::fs::remove_file(&p);
            }
        }
    }
    let main_rs = util::root().join("src").join("main.rs");
    std::fs::File::options()
        .write(true)
        .open(&main_rs)
        .and_then(|f| f.set_modified(std::time::SystemTime::now()))
        .map_err(|e| format!("{}: {e}", main_rs.display()))?;
    let mut cmd = util::cargo();
    cmd.args([
        "rustc",
        "--release",
        "-p",
        "finger-fw",
        "--bin",
        "finger-fw",
        "--target",
        crate::qemu::TARGET,
    ])
    .arg("--target-dir")
    .arg(&target_dir)
    .env("FINGER_FW_ESTIMATOR", estimator);
    if !features.is_empty() {
        cmd.args(["--no-default-features", "--features", &features.join(",")]);
    }
    cmd.arg("--")
        .arg("--emit=asm,link")
        .arg("-C")
        .arg(format!("debuginfo={debuginfo}"));
    util::run(&mut cmd)?;
    newest_asm(
        &target_dir
            .join(crate::qemu::TARGET)
            .join("release")
            .join("deps"),
        "finger_fw-",
    )
}

fn newest_asm(dir: &Path, prefix: &str) -> Res<PathBuf> {
    std::fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            p.extension().is_some_and(|e| e == "s")
                && p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with(prefix))
        })
        .max_by_key(|p| p.metadata().and_then(|m| m.modified()).ok())
        .ok_or_else(|| format!("no {prefix}*.s in {}", dir.display()))
}

/// Calls in the workspace's own files that the known-open task may reach, with why: (file
/// under the workspace root, the frame's function (substring; empty: any), whether only a
/// merged call (no line) matches, why).
const ACCEPTED_OWN_SITES: &[(&str, &str, bool, &str)] = &[
    (
        "crates/proto/src/lib.rs",
        "Serialize for proto::DeviceMsg",
        false,
        "code that serde's derive generates (it indexes nothing); the bounds checks of \
         postcard's varint writer inlined into it keep the derive's line when merged",
    ),
    (
        "src/board/usb.rs",
        "",
        true,
        "a call the compiler merged from several inlined places, without a line, in the USB \
         read, whose own code indexes with `get`; the code inlined there is usbd-serial's \
         `SerialPort::read` and usb-device's poll with the Synopsys driver",
    ),
];

/// For a panic inside a function of core's on path `p` (root … caller, core function, panic):
/// the places of the calls into core from the first function up the path that is not core's,
/// when they all lie outside this project's code (or are accepted); else why not.
fn std_caller(p: &[String], sites: &[Site], root: &Path) -> Result<String, String> {
    let mut callee = p.len().checked_sub(2).ok_or("no caller")?;
    loop {
        let Some(caller) = callee.checked_sub(1) else {
            return Err(format!(
                "the task's entry calls core's {} directly",
                p[callee]
            ));
        };
        let owners: Vec<Owner> = sites
            .iter()
            .filter(|c| c.caller == p[caller] && c.callee == p[callee])
            .map(|c| c.owner(root))
            .collect();
        if owners.is_empty() {
            return Err(format!(
                "the call from {} into core's {} is not in the linked ELF, so it cannot be \
                 attributed",
                p[caller], p[callee]
            ));
        }
        if owners.iter().all(|o| *o == Owner::Std) {
            callee = caller;
            continue;
        }
        let mut places = Vec::new();
        for o in owners {
            match o {
                Owner::Own(f) if accepted_own(&f, root).is_none() => {
                    return Err(format!(
                        "own code at {} calls core's {}, which panics",
                        Site::place(&f, root),
                        p[callee]
                    ))
                }
                Owner::Std => {}
                o => places.push(o.place(root)),
            }
        }
        return Ok(places.join(", "));
    }
}

fn accepted_own(f: &Frame, root: &Path) -> Option<&'static str> {
    let file = Path::new(f.file.as_deref()?);
    ACCEPTED_OWN_SITES
        .iter()
        .find(|(path, func, merged_only, _)| {
            file == root.join(path)
                && f.function.as_deref().unwrap_or("").contains(func)
                && (!merged_only || f.line.is_none())
        })
        .map(|a| a.3)
}

/// Checks one build: every root present, no panic path from any of them except the accepted
/// ones; from an `open_roots` entry, every call site of a panic path must lie in a crate this
/// project does not own (by the ELF's line tables; `sites` and the workspace root), and is
/// reported as known open. Returns the report lines, or the panic chains as the error.
pub fn check(
    asm: &str,
    sites: Option<(&[Site], &Path)>,
    roots: &[&str],
    open_roots: &[&str],
) -> Res<Vec<String>> {
    let g = call_graph(asm);
    let mut lines = Vec::new();
    let mut bad = Vec::new();
    for root in roots {
        if !g.contains_key(*root) {
            return Err(format!(
                "task entry {root} not in the assembly: checker broken"
            ));
        }
        let paths = panic_paths(&g, root);
        let mut accepted = 0;
        let mut open = BTreeMap::<String, usize>::new();
        let mut own_accepted = 0;
        for p in paths {
            if ACCEPTED.iter().any(|(a, b, _)| matches_edge(&p, a, b)) {
                accepted += 1;
                continue;
            }
            let chain = p.join(" -> ");
            let at: Vec<&Site> = match (sites, p.len()) {
                (Some((all, _)), n) if n >= 2 => all
                    .iter()
                    .filter(|s| s.caller == p[n - 2] && s.callee == p[n - 1])
                    .collect(),
                _ => Vec::new(),
            };
            if !open_roots.contains(root) {
                let wher: Vec<String> = match sites {
                    Some((_, dir)) => at.iter().map(|s| s.owner(dir).place(dir)).collect(),
                    None => Vec::new(),
                };
                bad.push(format!("{root}: {chain} (at {})", wher.join(", ")));
                continue;
            }
            let Some((all, dir)) = sites else {
                bad.push(format!("{root}: {chain}: no line tables to attribute it"));
                continue;
            };
            if at.is_empty() {
                bad.push(format!(
                    "{root}: {chain}: no such call in the linked ELF, so it cannot be attributed"
                ));
            }
            for s in at {
                match s.owner(dir) {
                    Owner::Own(f) => match accepted_own(&f, dir) {
                        Some(why) => {
                            own_accepted += 1;
                            lines.push(format!(
                                "  KNOWN OPEN {root}: accepted at {} ({}): {why}",
                                Site::place(&f, dir),
                                f.function.as_deref().unwrap_or("?")
                            ));
                        }
                        None => bad.push(format!(
                            "{root}: own code at {} ({}, call at {:#x}): {chain}",
                            Site::place(&f, dir),
                            f.function.as_deref().unwrap_or("?"),
                            s.addr
                        )),
                    },
                    Owner::Crate(k, f) => {
                        lines.push(format!("  KNOWN OPEN {root}: {k} {}", Site::place(&f, dir)));
                        *open.entry(k).or_default() += 1;
                    }
                    // Inside a core function that was not inlined: the calls into it decide,
                    // by their own line tables, walking up the path while they are core's too.
                    Owner::Std => match std_caller(&p, all, dir) {
                        Ok(places) => {
                            lines.push(format!(
                                "  KNOWN OPEN {root}: core, in {} reached from {places}",
                                p[p.len() - 2]
                            ));
                            *open.entry("core".into()).or_default() += 1;
                        }
                        Err(why) => bad.push(format!("{root}: {why}: {chain}")),
                    },
                }
            }
        }
        lines.push(format!("{root}: {accepted} accepted panic edge(s)"));
        if !open.is_empty() || own_accepted > 0 {
            let by: Vec<String> = open.iter().map(|(k, n)| format!("{k} {n}")).collect();
            lines.push(format!(
                "{root}: known-open panic calls by crate: {}; in this project's files: \
                 {own_accepted}, each listed with its reason (ACCEPTED_OWN_SITES)",
                by.join(", ")
            ));
        }
    }
    if bad.is_empty() {
        Ok(lines)
    } else {
        Err(format!(
            "panic reachable from a firmware task:\n  {}",
            bad.join("\n  ")
        ))
    }
}

/// `cargo xtask panics`.
pub fn main(_args: &[String]) -> Res<()> {
    let mut errs = Vec::new();
    let root = util::root();
    for (label, features, estimator, roots, open_roots) in BUILDS {
        let asm_path = build(features, estimator, "line-tables-only")?;
        let asm = std::fs::read_to_string(&asm_path)
            .map_err(|e| format!("{}: {e}", asm_path.display()))?;
        let elf_path = asm_path.with_extension("");
        let elf = std::fs::read(&elf_path).map_err(|e| format!("{}: {e}", elf_path.display()))?;
        let sites = panic_sites(&elf)?;
        match check(&asm, Some((&sites, &root)), roots, open_roots) {
            Ok(lines) => println!(
                "{label}: no unaccepted panic reachable\n{}",
                lines.join("\n")
            ),
            Err(e) => errs.push(format!("{label}: {e}")),
        }
    }
    if errs.is_empty() {
        Ok(())
    } else {
        Err(errs.join("\n"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::callgraph::is_branch;

    /// Planted panics, compiled for the firmware's target: the checker must flag each one and
    /// pass the clean function.
    const PLANTED: &str = r#"
#![no_std]
#[panic_handler]
fn ph(_: &core::panic::PanicInfo) -> ! { loop {} }
#[no_mangle] #[inline(never)] pub fn planted_unwrap(x: Option<u32>) -> u32 { x.unwrap() }
#[no_mangle] #[inline(never)] pub fn planted_result(x: Result<u32, u8>) -> u32 { x.unwrap() }
#[no_mangle] #[inline(never)] pub fn planted_expect(x: Option<u32>) -> u32 { x.expect("x") }
#[no_mangle] #[inline(never)] pub fn planted_index(s: &[u32], i: usize) -> u32 { s[i] }
#[no_mangle] #[inline(never)] pub fn planted_range(s: &[u32], n: usize) -> u32 { s[..n].iter().sum() }
#[no_mangle] #[inline(never)] pub fn planted_div(a: u32, b: u32) -> u32 { a / b }
#[no_mangle] #[inline(never)] pub fn planted_deep(s: &[u32], i: usize) -> u32 { planted_index(s, i) + 1 }
#[export_name = "_ZN7pathfit1q7bin_raw17h0123456789abcdefE"] #[inline(never)] pub fn planted_pathfit(s: &[u32], i: usize) -> u32 { s[i] }
#[no_mangle] #[inline(never)] pub fn planted_estimate(s: &[u32], i: usize) -> u32 { planted_pathfit(s, i) + 1 }
#[no_mangle] #[inline(never)] pub fn planted_clean(s: &[u32], i: usize) -> u32 { s.get(i).copied().unwrap_or(0) / 3 }
#[no_mangle] #[inline(never)] pub fn planted_sort(s: &mut [u32]) { s.sort_unstable() }
"#;

    /// The planted functions built for the firmware's target: as a library (`elf` false:
    /// assembly only), or linked with line tables (`elf` true: the assembly and the ELF, in
    /// `dir`, which the caller removes).
    fn planted_build(dir: &Path, elf: bool) -> (String, Option<Vec<u8>>) {
        std::fs::create_dir_all(dir).unwrap();
        let src = dir.join("planted.rs");
        let text = if elf {
            // Linked: an entry point, and every planted function kept.
            PLANTED.replace("#![no_std]", "#![no_std]\n#![no_main]")
                + "#[no_mangle] pub extern \"C\" fn _start() {}\n"
        } else {
            PLANTED.to_string()
        };
        std::fs::write(&src, text).unwrap();
        let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
        let mut cmd = std::process::Command::new(rustc);
        cmd.current_dir(util::root()).args([
            "--edition",
            "2021",
            "--target",
            crate::qemu::TARGET,
            "-C",
            "opt-level=s",
            "-C",
            "panic=abort",
        ]);
        cmd.arg(if elf { "--emit=asm,link" } else { "--emit=asm" });
        if elf {
            cmd.args([
                "--crate-type",
                "bin",
                "-C",
                "debuginfo=line-tables-only",
                "-C",
                "link-dead-code=yes",
            ]);
        } else {
            cmd.args(["--crate-type", "lib"]);
        }
        let st = cmd
            .arg("-o")
            // One output type takes the name as given; two derive theirs from it.
            .arg(dir.join(if elf { "planted" } else { "planted.s" }))
            .arg(&src)
            .status()
            .expect("rustc");
        assert!(st.success());
        let asm = std::fs::read_to_string(dir.join("planted.s")).unwrap();
        let bin = elf.then(|| std::fs::read(dir.join("planted")).unwrap());
        (asm, bin)
    }

    fn planted_asm() -> String {
        let dir = std::env::temp_dir().join(format!("xtask-planted-{}", std::process::id()));
        let (asm, _) = planted_build(&dir, false);
        let _ = std::fs::remove_dir_all(&dir);
        asm
    }

    /// The known-open task's allowance is per call site, by the ELF's line tables: a planted
    /// panic is attributed to its own line of planted.rs (through core's inlined `Index`),
    /// fails the open task when planted.rs lies under the workspace root given, and is
    /// reported as known open when it does not.
    #[test]
    fn a_panic_site_is_attributed_to_its_line_and_fails_an_open_task_in_own_code() {
        let dir = std::env::temp_dir().join(format!("xtask-planted-elf-{}", std::process::id()));
        let (asm, elf) = planted_build(&dir, true);
        let sites = panic_sites(&elf.unwrap()).unwrap();
        let src = std::fs::read_to_string(dir.join("planted.rs")).unwrap();
        let elsewhere = dir.join("not-the-workspace");
        for f in [
            "planted_unwrap",
            "planted_index",
            "planted_range",
            "planted_div",
        ] {
            let line = src
                .lines()
                .position(|l| l.contains(&format!("fn {f}(")))
                .unwrap() as u32
                + 1;
            let at: Vec<&Site> = sites.iter().filter(|s| s.caller == f).collect();
            assert!(!at.is_empty(), "{f}: no panic call found in the ELF");
            for s in &at {
                match s.owner(&dir) {
                    Owner::Own(fr) => {
                        assert!(fr.file.as_deref().unwrap().ends_with("planted.rs"));
                        assert_eq!(fr.line, Some(line), "{f}: {:?}", s.frames);
                    }
                    o => panic!("{f}: {o:?}"),
                }
                assert!(matches!(s.owner(&elsewhere), Owner::Crate(..)));
            }
            let e = check(&asm, Some((&sites, &dir)), &[f], &[f]).unwrap_err();
            assert!(e.contains(&format!("planted.rs:{line}")), "{f}: {e}");
            let ok = check(&asm, Some((&sites, &elsewhere)), &[f], &[f]).unwrap();
            assert!(
                ok.iter()
                    .any(|l| l.contains("KNOWN OPEN") && l.contains(&format!(":{line}"))),
                "{f}: {ok:?}"
            );
            assert!(check(&asm, Some((&sites, &elsewhere)), &[f], &[]).is_err());
        }
        // No panic call in the clean function; the entry point reaches none.
        assert!(sites.iter().all(|s| s.caller != "planted_clean"));
        // A panic inside core's own (not inlined) functions is judged by the call into them.
        let f = "planted_sort";
        let line = src
            .lines()
            .position(|l| l.contains("fn planted_sort("))
            .unwrap()
            + 1;
        let e = check(&asm, Some((&sites, &dir)), &[f], &[f]).unwrap_err();
        assert!(
            e.contains("calls core's") && e.contains(&format!("planted.rs:{line}")),
            "{e}"
        );
        let ok = check(&asm, Some((&sites, &elsewhere)), &[f], &[f]).unwrap();
        assert!(
            ok.iter()
                .any(|l| l.contains("KNOWN OPEN") && l.contains("core, in")),
            "{ok:?}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_merged_call_in_own_code_is_accepted_only_where_listed() {
        let root = Path::new("/ws");
        let frame = |file: &str, function: &str, line: Option<u32>| Frame {
            function: Some(function.into()),
            file: Some(file.into()),
            line,
        };
        assert!(accepted_own(&frame("/ws/src/board/usb.rs", "read", None), root).is_some());
        // A line of our own in the same file is not a merged call.
        assert!(accepted_own(&frame("/ws/src/board/usb.rs", "read", Some(82)), root).is_none());
        let derive = "proto::_::<impl serde_core::ser::Serialize for proto::DeviceMsg>::serialize";
        assert!(accepted_own(
            &frame("/ws/crates/proto/src/lib.rs", derive, Some(344)),
            root
        )
        .is_some());
        assert!(accepted_own(
            &frame("/ws/crates/proto/src/lib.rs", "proto::Drive::new", Some(1)),
            root
        )
        .is_none());
        assert!(accepted_own(&frame("/ws/src/device.rs", "flush", None), root).is_none());
    }

    #[test]
    fn the_checker_flags_every_planted_panic_and_passes_the_clean_function() {
        let asm = planted_asm();
        let g = call_graph(&asm);
        for f in [
            "planted_unwrap",
            "planted_result",
            "planted_expect",
            "planted_index",
            "planted_range",
            "planted_div",
            "planted_deep",
        ] {
            assert!(g.contains_key(f), "{f} not in the planted assembly");
            let p = panic_paths(&g, f);
            assert!(
                !p.is_empty(),
                "{f}: panic not found; callees {:?}",
                g.get(f)
            );
            assert!(check(&asm, None, &[f], &[]).is_err());
            // An open task cannot be judged without the ELF's line tables.
            assert!(check(&asm, None, &[f], &[f]).is_err());
        }
        // The path fit's kernel is no longer excused: its panic fails the estimate task.
        assert!(check(&asm, None, &["planted_estimate"], &[]).is_err());
        assert!(panic_paths(&g, "planted_clean").is_empty());
        assert!(check(&asm, None, &["planted_clean"], &[]).is_ok());
        assert!(check(&asm, None, &["no_such_task"], &[]).is_err());
    }

    #[test]
    fn names_of_core_panic_entry_points_are_recognised_in_every_mangling() {
        for s in [
            "_ZN4core9panicking9panic_fmt17h0123456789abcdefE",
            "_ZN4core9panicking18panic_bounds_check17h0123456789abcdefE",
            "_ZN4core6option13unwrap_failed17h0123456789abcdefE",
            "_ZN4core6result13unwrap_failed17h0123456789abcdefE",
            "_ZN4core6option13expect_failed17h0123456789abcdefE",
            "_ZN4core5slice5index16slice_index_fail17h0123456789abcdefE",
            "_ZN4core5slice5index24slice_end_index_len_fail17h0123456789abcdefE",
            "_ZN4core5slice5index26slice_start_index_len_fail17h0123456789abcdefE",
            "_ZN4core5slice5index22slice_index_order_fail17h0123456789abcdefE",
            "_RNvNtCs7ldSeZOOJos_4core9panicking5panic",
            "_RNvNtNtCs7ldSeZOOJos_4core9panicking11panic_const23panic_const_div_by_zero",
            "_RNvCsfLfy6EI15iL_7___rustc17rust_begin_unwind",
            "core::panicking::assert_failed",
        ] {
            assert!(is_panic(s), "{s}");
        }
        for s in ["__aeabi_memcpy", "_ZN5grasp8estimate9back_date17hE", "ADC"] {
            assert!(!is_panic(s), "{s}");
        }
        for op in ["b", "bl", "blx", "b.w", "bhs.w", "bne", "beq.n"] {
            assert!(is_branch(op), "{op}");
        }
        for op in ["bfc", "bics.w", "bic", "bfi", "bkpt", "bx"] {
            assert!(!is_branch(op), "{op}");
        }
    }
}
