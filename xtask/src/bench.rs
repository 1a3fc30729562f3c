//! `cargo xtask bench [--check] [--quick] [--no-criterion]`: the solver variants' run time
//! against their error, and the firmware's estimate entries.
//!
//! Builds the instruction-count harness (`crates/pts/benches/thumb`, the firmware's release
//! profile) for thumbv7em-none-eabihf and thumbv6m-none-eabi, runs it in the unicorn emulator
//! (`count.py`; `pip install unicorn` when missing) and prints: instructions of the firmware's
//! estimate entries (`grasp::estimate::two_point_fw`, `path_fit_fw`: request to result, counted
//! from entry to return) on the committed requests (`requests/*.req`), the solver variants
//! per estimate and per free-motion lookup, grasp's `Controller::tick`, host time per estimate
//! (criterion, `cargo bench -p pts --bench solvers`) and each variant's error against f64.
//!
//! `--check` (called by `cargo xtask test`) skips criterion and uses a coarser grid. It fails
//! when an estimate entry exceeds its budget (two-point task ≤ 5,000 instructions; the path-fit
//! task ≤ 100,000, guarded above its measured worst case) or its result on the target differs
//! from the host's, when a budget not met regresses past its guard, or when the table+Fx32
//! variant leaves 1e-4·l2 of f64. It then checks on each firmware build's call graph that the
//! estimate task calls the very function counted and reaches no soft-float routine.
//!
//! The counts the README cites (the estimate entries and the loop: deterministic for the
//! pinned toolchain) are written to `docs/BENCH.md`; `--check` fails when that file differs
//! from what it counted, so the document cannot go stale.

use std::path::{Path, PathBuf};
use std::process::Command;

const TARGETS: [&str; 2] = ["thumbv7em-none-eabihf", "thumbv6m-none-eabi"];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from("."))
}

fn status(cmd: &mut Command) -> Result<(), String> {
    let st = cmd.status().map_err(|e| format!("{cmd:?}: {e}"))?;
    if st.success() {
        Ok(())
    } else {
        Err(format!("{cmd:?} failed with {st}"))
    }
}

/// `python3` with unicorn importable, installing it with pip when missing.
pub fn ensure_unicorn() -> Result<(), String> {
    let ok = |c: &mut Command| c.status().map(|s| s.success()).unwrap_or(false);
    if !ok(Command::new("python3")
        .arg("--version")
        .stdout(std::process::Stdio::null()))
    {
        return Err(
            "python3 not found: install it (apt-get install -y python3 python3-pip)".into(),
        );
    }
    if ok(Command::new("python3").args(["-c", "import unicorn"])) {
        return Ok(());
    }
    eprintln!("bench: installing the unicorn emulator (pip install unicorn)");
    let pip = |extra: &[&str]| {
        let mut c = Command::new("python3");
        c.args(["-m", "pip", "install", "--quiet", "unicorn"])
            .args(extra);
        ok(&mut c)
    };
    if !(pip(&[]) || pip(&["--break-system-packages"]) || pip(&["--user"])) {
        // A Debian python3 without pip.
        let _ = Command::new("apt-get")
            .args(["install", "-y", "python3-pip"])
            .status();
        if !pip(&["--break-system-packages"]) {
            return Err("could not `pip install unicorn` (needed to count instructions)".into());
        }
    }
    if ok(Command::new("python3").args(["-c", "import unicorn"])) {
        Ok(())
    } else {
        Err("unicorn installed but not importable by python3".into())
    }
}

/// Where the instruction-count harnesses are built from: a symlink to this checkout at one
/// fixed path. The harnesses are workspaces of their own, so the crates they count are path
/// dependencies outside the workspace being built, and Cargo hashes such a dependency's
/// absolute path into its symbol names. A codegen unit's functions are ordered by those names,
/// and the order moves register allocation: built from another checkout path, the same code
/// counts a few instructions more or less per call. Through one path every checkout counts
/// the same, and `docs/BENCH.md` can be compared exactly.
const STABLE_ROOT: &str = "/tmp/pts-finger-bench/root";

/// [`STABLE_ROOT`] pointed at `root`, with the lock that keeps another checkout from
/// re-pointing it until this one's builds are done (unlocked when dropped).
fn stable_root(root: &Path) -> Result<(PathBuf, std::fs::File), String> {
    let link = PathBuf::from(STABLE_ROOT);
    let dir = link.parent().ok_or("STABLE_ROOT has no parent")?;
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let lock_path = dir.join("lock");
    let lock = std::fs::File::options()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&lock_path)
        .map_err(|e| format!("{}: {e}", lock_path.display()))?;
    lock.lock()
        .map_err(|e| format!("{}: {e}", lock_path.display()))?;
    // A fresh link renamed over the old one: the path always names a checkout.
    let tmp = dir.join(format!("root.{}", std::process::id()));
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(root, &tmp).map_err(|e| format!("{}: {e}", tmp.display()))?;
    std::fs::rename(&tmp, &link).map_err(|e| {
        format!(
            "{} -> {}: {e} (remove {} if it is not a symlink)",
            tmp.display(),
            link.display(),
            link.display()
        )
    })?;
    Ok((link, lock))
}

/// Builds the harness for both targets; returns the two ELF paths.
fn build_harness(root: &Path) -> Result<Vec<PathBuf>, String> {
    let dir = root.join("crates/pts/benches/thumb");
    let (stable, _lock) = stable_root(root)?;
    let target_dir = root.join("target/bench-thumb");
    let mut elfs = Vec::new();
    for t in TARGETS {
        status(
            Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
                .args(["build", "--quiet", "--release", "--target", t])
                .arg("--manifest-path")
                .arg(stable.join("crates/pts/benches/thumb/Cargo.toml"))
                .current_dir(&dir)
                // The harness brings its own linker script; ignore any target rustflags.
                .env("RUSTFLAGS", "")
                // Their own link scripts have no MEMORY.RAM: the firmware's flip-link
                // (.cargo/config.toml) does not apply to them.
                .env("CARGO_TARGET_THUMBV7EM_NONE_EABIHF_LINKER", "rust-lld")
                .env("CARGO_TARGET_DIR", &target_dir),
        )?;
        elfs.push(target_dir.join(t).join("release/pts-bench-thumb"));
    }
    Ok(elfs)
}

pub fn main(args: &[String]) -> Result<i32, String> {
    let has = |f: &str| args.iter().any(|a| a == f);
    let (check, quick) = (has("--check"), has("--quick") || has("--check"));
    let criterion = !(check || has("--no-criterion"));
    let root = root();
    ensure_unicorn()?;
    let elfs = build_harness(&root)?;
    if criterion {
        status(
            Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
                .args(["bench", "-p", "pts", "--bench", "solvers", "--", "--noplot"])
                .current_dir(&root),
        )?;
    }
    let script = root.join("crates/pts/benches/thumb/count.py");
    let mut cmd = Command::new("python3");
    cmd.arg(&script)
        .arg("--v7em")
        .arg(&elfs[0])
        .arg("--v6m")
        .arg(&elfs[1])
        .arg("--json")
        .arg(root.join("target/bench-thumb/bench.json"));
    if criterion {
        cmd.arg("--criterion").arg(root.join("target/criterion"));
    }
    if check {
        cmd.arg("--check");
    }
    if quick {
        cmd.arg("--quick");
    }
    cmd.arg("--requests").args(request_cases(&root)?);
    let st = cmd.status().map_err(|e| format!("{script:?}: {e}"))?;
    let table = match bench_table(&root.join("target/bench-thumb/bench.json")) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("CHECK FAIL: {e}");
            return Ok(1);
        }
    };
    let doc = root.join(BENCH_DOC);
    if check {
        let committed = std::fs::read_to_string(&doc).unwrap_or_default();
        if committed != table {
            eprintln!(
                "CHECK FAIL: {BENCH_DOC} differs from the counts just measured; run `cargo xtask bench` and commit it"
            );
            return Ok(1);
        }
    } else {
        std::fs::write(&doc, &table).map_err(|e| format!("{}: {e}", doc.display()))?;
        println!("wrote {BENCH_DOC}");
    }
    let path_fit = pathfit_check(&root)?;
    let entries = if check {
        match firmware_entry_check(&root) {
            Ok(()) => 0,
            Err(e) => {
                eprintln!("CHECK FAIL: {e}");
                1
            }
        }
    } else {
        0
    };
    Ok(match st.code() {
        Some(0) if path_fit == 0 => entries,
        Some(0) => path_fit,
        other => other.unwrap_or(1),
    })
}

/// The generated table of instruction counts (repository-relative).
pub const BENCH_DOC: &str = "docs/BENCH.md";

/// `docs/BENCH.md` from count.py's JSON: the firmware's estimate entries per committed request
/// and the control loop's tick, with their budgets.
pub fn bench_table(json: &Path) -> Result<String, String> {
    let text = std::fs::read_to_string(json).map_err(|e| format!("{}: {e}", json.display()))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| format!("{}: {e}", json.display()))?;
    let thousands = crate::size::grouped;
    let mut t = String::from(
        "# Instruction counts on the Cortex-M4\n\n\
         Generated by `cargo xtask bench` from the unicorn counts of the firmware's own functions\n\
         (thumbv7em-none-eabihf, the firmware's release profile); `cargo xtask test` fails when this\n\
         file differs from what the code counts now. Counts are deterministic for the pinned\n\
         toolchain; the harness is built through one fixed path, so they do not depend on where the\n\
         repository is checked out.\n\n## The estimate entry, per committed request\n\n\
         Request to result, contact point included (`crates/pts/benches/thumb/requests/`). The\n\
         `_unseated` requests come from the controller without seating (a 4 N·m/s ramp from\n\
         T_a,c, the whole loading path: a grasp shaped like a recording no seating controller\n\
         made). Every count is a hard gate at its budget.\n\n\
         | entry | request | instructions | budget |\n|---|---|---|---|\n",
    );
    let entries = v["estimate_entries"]
        .as_array()
        .ok_or("bench.json has no estimate_entries")?;
    for e in entries {
        let (Some(name), Some(case), Some(n), Some(budget)) = (
            e["entry"].as_str(),
            e["case"].as_str(),
            e["instructions"].as_u64(),
            e["budget"].as_u64(),
        ) else {
            return Err(format!("bench.json: incomplete estimate entry {e}"));
        };
        // The label's parenthesised function path is the entry's name.
        let name = name
            .split_once('(')
            .map_or(name, |(_, rest)| rest.trim_end_matches(')'));
        t += &format!(
            "| `{name}` | {} | {} | {} |\n",
            case.trim_end_matches(".req"),
            thousands(n),
            thousands(budget)
        );
    }
    let tick = &v["thumbv7em"]["tick"];
    let (Some(max), Some(median), Some(n), Some(step_max), Some(step_median)) = (
        tick["max"].as_u64(),
        tick["median"].as_u64(),
        tick["n"].as_u64(),
        tick["step_max"].as_u64(),
        tick["step_median"].as_u64(),
    ) else {
        return Err("bench.json has no thumbv7em tick counts".into());
    };
    t += &format!(
        "\n## The 10 kHz control loop\n\n`grasp::ControlLoop::tick`, the sampling task's work \
         (mock board excluded), from power-up to Holding on the plant. The state machine \
         (`Supervisor::service`) runs apart, once per sample, in the task below it.\n\n\
         | loop: worst tick | median | ticks | budget | state machine: worst step | median |\n\
         |---|---|---|---|---|---|\n| {} | {} | {} | 400 | {} | {} |\n",
        thousands(max),
        thousands(median),
        thousands(n),
        thousands(step_max),
        thousands(step_median)
    );
    Ok(t)
}

/// The firmware's estimate entries: (estimator build, the entry's legacy-mangled path).
pub const ENTRIES: &[(&str, &str)] = &[
    ("two-point", "_ZN5grasp8estimate12two_point_fw"),
    ("path-fit", "_ZN5grasp8estimate11path_fit_fw"),
];

/// What the firmware's call graph says about one estimate entry.
#[derive(Debug)]
pub struct EntryFacts {
    /// The entry's symbol in the firmware.
    pub symbol: String,
    /// The task entry points (interrupts, dispatchers) that reach it.
    pub roots: Vec<String>,
    /// Soft-float routines reachable from the entry, and from the task that calls it.
    pub soft_float_in_entry: Vec<String>,
    pub soft_float_in_task: Vec<String>,
}

/// The call graph facts of the entry named `path` (hash stripped) in a firmware's assembly.
pub fn entry_facts(asm: &str, path: &str, roots: &[&str]) -> Result<EntryFacts, String> {
    use crate::callgraph::{call_graph, is_soft_float, reachable, without_hash};
    let g = call_graph(asm);
    let hits: Vec<&String> = g.keys().filter(|k| without_hash(k) == path).collect();
    let [symbol] = hits[..] else {
        return Err(format!(
            "{} functions named {path} in the firmware: {hits:?}",
            hits.len()
        ));
    };
    let soft = |f: &str| -> Vec<String> {
        reachable(&g, f)
            .into_iter()
            .filter(|s| is_soft_float(s))
            .collect()
    };
    let reaching: Vec<String> = roots
        .iter()
        .filter(|r| reachable(&g, r).contains(symbol))
        .map(|r| r.to_string())
        .collect();
    let soft_float_in_task = reaching.iter().flat_map(|r| soft(r)).collect();
    Ok(EntryFacts {
        symbol: symbol.clone(),
        roots: reaching,
        soft_float_in_entry: soft(symbol),
        soft_float_in_task,
    })
}

/// The gate measures what ships: in each firmware build (board, release, the assembly of the
/// whole LTO program), exactly one task dispatcher (not the sampling interrupt) reaches the
/// build's estimate entry, neither the entry nor that task reaches a soft-float routine, and
/// the function count.py counted in the harness ELF (target/bench-thumb/bench.json) is that
/// same function of grasp (same path, hash aside: the crates' features differ).
fn firmware_entry_check(root: &Path) -> Result<(), String> {
    use crate::callgraph::without_hash;
    let json = std::fs::read_to_string(root.join("target/bench-thumb/bench.json"))
        .map_err(|e| format!("bench.json: {e}"))?;
    let mut errs = Vec::new();
    for (estimator, path) in ENTRIES {
        let counted = json
            .split("\"symbol\": \"")
            .skip(1)
            .filter_map(|s| s.split('"').next())
            .any(|s| without_hash(s) == *path);
        if !counted {
            errs.push(format!("the bench did not count {path}"));
        }
        let asm_path = crate::panics::build_asm(&[], estimator)?;
        let asm = std::fs::read_to_string(&asm_path)
            .map_err(|e| format!("{}: {e}", asm_path.display()))?;
        let f = entry_facts(&asm, path, crate::panics::BOARD_ROOTS)?;
        println!(
            "firmware ({estimator}): {} reached from {:?}; soft float reachable from it: {:?}, from its task: {:?}",
            f.symbol, f.roots, f.soft_float_in_entry, f.soft_float_in_task
        );
        if f.roots.len() != 1 || f.roots.iter().any(|r| r == "ADC") {
            errs.push(format!(
                "{estimator}: {path} must be reached from exactly one task dispatcher, is from {:?}",
                f.roots
            ));
        }
        if !f.soft_float_in_entry.is_empty() || !f.soft_float_in_task.is_empty() {
            errs.push(format!(
                "{estimator}: soft float reachable from the estimate task: {:?} {:?}",
                f.soft_float_in_entry, f.soft_float_in_task
            ));
        }
    }
    if errs.is_empty() {
        Ok(())
    } else {
        Err(errs.join("; "))
    }
}

/// The committed estimate requests (`crates/pts/benches/thumb/requests/*.req`, written by
/// `tests/estimate_cases.rs`), sorted.
fn request_cases(root: &Path) -> Result<Vec<PathBuf>, String> {
    let dir = root.join("crates/pts/benches/thumb/requests");
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "req"))
        .collect();
    v.sort();
    if v.is_empty() {
        return Err(format!("no request cases in {}", dir.display()));
    }
    Ok(v)
}

/// Issue 7's gate: the firmware's integer path fit on the committed cases within its
/// instruction budget on thumbv7em and within σ/2 of the FPU fit (`crates/pathfit/benches/icount/check.py`).
fn pathfit_check(root: &Path) -> Result<i32, String> {
    let dir = root.join("crates/pathfit/benches/icount");
    let (stable, lock) = stable_root(root)?;
    status(
        Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
            .args([
                "build",
                "--quiet",
                "--release",
                "--target",
                "thumbv7em-none-eabihf",
            ])
            .arg("--manifest-path")
            .arg(stable.join("crates/pathfit/benches/icount/Cargo.toml"))
            .env("CARGO_TARGET_DIR", root.join("target/bench-pathfit"))
            .env("RUSTFLAGS", "")
            // Their own link scripts have no MEMORY.RAM: the firmware's flip-link
            // (.cargo/config.toml) does not apply to them.
            .env("CARGO_TARGET_THUMBV7EM_NONE_EABIHF_LINKER", "rust-lld")
            .current_dir(root),
    )?;
    drop(lock);
    let elf = root.join("target/bench-pathfit/thumbv7em-none-eabihf/release/pathfit-icount");
    let mut cases: Vec<PathBuf> = std::fs::read_dir(dir.join("cases"))
        .map_err(|e| format!("{:?}: {e}", dir.join("cases")))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "txt"))
        .collect();
    cases.sort();
    let st = Command::new("python3")
        .arg(dir.join("check.py"))
        .arg(&elf)
        .args(&cases)
        .current_dir(&dir)
        .status()
        .map_err(|e| format!("check.py: {e}"))?;
    Ok(st.code().unwrap_or(1))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A planted firmware: the sampling interrupt, a dispatcher calling an entry that uses
    /// f64 through a helper, another dispatcher that does not reach it.
    const ASM: &str = "ADC:\n\tbl loop_tick\n\tbx lr\nloop_tick:\n\tbx lr\n\
SPI2:\n\tbl _ZN5grasp8estimate12two_point_fw17h0123456789abcdefE\n\tbx lr\n\
SPI3:\n\tbl telemetry\n\tbx lr\ntelemetry:\n\tbx lr\n\
_ZN5grasp8estimate12two_point_fw17h0123456789abcdefE:\n\tbl helper\n\tbx lr\n\
helper:\n\tbl __aeabi_dmul\n\tbx lr\n";

    #[test]
    fn the_entry_check_finds_the_task_and_the_soft_float_it_reaches() {
        let f = entry_facts(ASM, ENTRIES[0].1, &["ADC", "SPI2", "SPI3"]).unwrap();
        assert_eq!(f.roots, ["SPI2"]);
        assert_eq!(f.soft_float_in_entry, ["__aeabi_dmul"]);
        assert_eq!(f.soft_float_in_task, ["__aeabi_dmul"]);
        // Not in the program: an error, not a pass.
        assert!(entry_facts(ASM, ENTRIES[1].1, &["SPI2"]).is_err());
        // Without the f64 helper the entry is clean.
        let clean = ASM.replace("\tbl __aeabi_dmul\n", "");
        let f = entry_facts(&clean, ENTRIES[0].1, &["ADC", "SPI2", "SPI3"]).unwrap();
        assert!(f.soft_float_in_entry.is_empty() && f.soft_float_in_task.is_empty());
    }
}
