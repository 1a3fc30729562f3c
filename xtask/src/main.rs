//! Project automation: `cargo xtask <command>`; `cargo xtask <command> --help` for details.
//!
//! * `demo [--scene NAME|FILE]`: the QEMU firmware with the simulated finger: three grasps over
//!   the host protocol (or one power-up grasp of a scene), live, then estimates vs truth.
//! * `test`: every check the project has (the CI entry point, see .ci/run).
//! * `size`: flash and static RAM of the board firmware against the budgets.
//! * `bench [--check] [--quick] [--no-criterion]`: solver cost against error.
//! * `fuzz [--seconds N] [--target NAME]`: the cargo-fuzz targets.
//! * `qemu ELF`: run a firmware ELF in QEMU and print its decoded defmt log.
//! * `device [--port PORT]`: the device-mode firmware in QEMU for `pts board`.
//! * `figures [--check]`: draw the documentation's figures (or check they are current).
//!
//! The overview, each command's `--help` and the dispatch all come from one table
//! ([`COMMANDS`]), so a command cannot be added without its help.

mod bench;
mod callgraph;
mod ci;
mod demo;
mod demo_device;
mod device;
mod figures;
mod fuzz;
#[cfg(test)]
mod links;
mod log;
mod panics;
mod qemu;
mod serve;
mod sites;
mod size;
mod util;

use std::process::ExitCode;

/// One subcommand.
struct Cmd {
    /// The word after `cargo xtask`.
    name: &'static str,
    /// Its arguments, as in a usage line.
    args: &'static str,
    /// One line for the overview.
    summary: &'static str,
    /// What `--help` prints after the usage line.
    help: &'static str,
    /// Runs it; the value is the exit status.
    run: fn(&[String]) -> Result<i32, String>,
}

/// Every subcommand, in the order the overview lists them.
const COMMANDS: &[Cmd] = &[
    Cmd {
        name: "demo",
        args: "[--scene NAME|FILE]",
        summary: "the QEMU firmware and simulated finger: grasps live, then vs truth",
        help: "\
Without options: builds the device-mode firmware for QEMU's mps2-an386 (Cortex-M4) with the
simulated finger inside it and drives it over its host protocol, as a robot drives the board:
one power-up, three grasps on different objects and torque steps (table2 at 0.8 N·m,
cyl10_k2_20 at 0.6, vertex_k2_30 at 1.0), each with the path fit, shown live by
`pts board watch --grasp` (a terminal UI on a terminal, summary lines otherwise) and released
before the next. Ends with a table: k2 ± σ, the paper's two-point k2 beside it, the plant's
first contact and the error. The first run compiles the firmware, which takes a few minutes.

options:
  --scene NAME|FILE     instead, the power-up build: the firmware grasps once at power-up with
                        the build's settings, its decoded log shown live, then the estimate
                        next to the truth. A built-in scene (the file stems of
                        crates/plant/scenes/*.toml, e.g. table2, vertex_k2_30,
                        fault_encoder_stuck) or a scene TOML file
  -h, --help            print this help and exit

environment (read when the --scene firmware is built):
  FINGER_FW_ESTIMATOR   path-fit (default) or two-point (the paper's method only)
  FINGER_FW_DELTA_TA_NM the torque step ΔT_a after contact, in N·m (default 0.8)
  FINGER_TOML           a finger file (default: the paper's prototype,
                        crates/pts-cli/fingers/paper.toml)

exit status: 0 every grasp gave an estimate; 2 the controller faulted and switched the bridge
off; with --scene also 101 / 102 a panic / HardFault (bridge off); 1 the demo itself failed.
",
        run: demo::main,
    },
    Cmd {
        name: "test",
        args: "[STAGE | --lane host|firmware]",
        summary: "every check (the CI command); ends with `N passed, M failed`",
        help: "\
Runs every check of the project (the command .ci/run runs): the toolchain's thumb targets,
qemu-system-arm, cargo fmt --check, clippy -D warnings, cargo test --workspace, clippy of the
firmware for QEMU and for the board, the board firmware's flash/RAM budgets, QEMU scenes (three
estimates checked against the host, a fault scene, the path-fit build, a non-paper finger file,
injected panic and HardFault) and `cargo xtask bench --check`. Every stage runs even when an
earlier one failed; the last line is `N passed, M failed`. Installs what it needs (targets,
qemu-system-arm).

Without arguments the stages run in two lanes side by side: the host's in this process, the
firmware's (its builds and every QEMU run) in a child process whose lines start with `fw| `.

arguments:
  STAGE                 run only the stages whose name contains STAGE (case-insensitive),
                        one after the other, e.g. `cargo xtask test 'non-paper finger'`; no
                        match is an error

options:
  --lane host|firmware  run one lane's stages only, one after the other
  -h, --help            print this help and exit

exit status: 0 when every stage passed, 1 otherwise.
",
        run: ci::main,
    },
    Cmd {
        name: "device",
        args: "[--port PORT]",
        summary: "the device-mode firmware in QEMU, its UART on a socket for `pts board`",
        help: "\
Builds the device-mode firmware for QEMU (features qemu,device; a path-fit build, so both
estimators can be chosen per grasp), starts it with its UART on the TCP socket
127.0.0.1:PORT and shows its log live until Ctrl-C. Drive it from another terminal with
`pts board --connect 127.0.0.1:PORT hello|status|get|set|grasp|release|stop`; between grasps
`pts board set scene NAME` selects the simulated object.

options:
  --port PORT           the TCP port of the UART (default 4321, pts board's default)
  -h, --help            print this help and exit

exit status: QEMU's when it ends; 1 when the build or QEMU cannot start.
",
        run: serve::main,
    },
    Cmd {
        name: "figures",
        args: "[--check]",
        summary: "draw the docs' figures (docs/figures/) or check they are current",
        help: "\
Builds `pts` (profile `host`) and draws every figure the documentation shows (docs/figures/*.svg):
K_c(k2), the Table 2 grasp with the two-point and the path-fit estimate, and the heat maps of
the closed-loop sweeps. Each figure's recipe (the `pts` commands) is in xtask/src/figures.rs.

options:
  --check               draw into a scratch directory and compare with the committed files
                        byte for byte (a stage of `cargo xtask test`)
  -h, --help            print this help and exit

exit status: 0 when drawn (or all current), 1 when a figure is stale or a step failed.
",
        run: figures::main,
    },
    Cmd {
        name: "size",
        args: "",
        summary: "flash / static RAM of the board firmware against the budgets",
        help: "\
Builds the release firmware for the board (STM32F411, thumbv7em-none-eabihf): the power-up
build and the device-mode builds with one and with both estimators, and prints their flash and
static RAM (.data + .bss + .uninit, without the stack) against the budgets of 128 KiB and 32 KiB;
then the stack's high-water mark in QEMU.

options:
  -h, --help            print this help and exit

environment: FINGER_FW_ESTIMATOR, FINGER_FW_DELTA_TA_NM and FINGER_TOML as for `demo`
(e.g. FINGER_FW_ESTIMATOR=two-point cargo xtask size measures the two-point build).

exit status: 0 within both budgets, 1 over either or when the build fails.
",
        run: |args| size::main(args).map(|()| 0),
    },
    Cmd {
        name: "board",
        args: "[CARGO OPTIONS]",
        summary: "build the board firmware as `size` measures it, flash it, stream its log",
        help: "\
Builds the release firmware for the board (STM32F411, thumbv7em-none-eabihf) the way
`cargo xtask size` measures it (registry paths remapped, so the flash is the same on every
machine), then flashes it and streams its defmt log with the runner of .cargo/config.toml
(`probe-rs run --chip STM32F411CEUx`; needs probe-rs-tools and a probe). `cargo board` is
this command. Options go to `cargo run`, e.g. `cargo board --features device`.

options:
  -h, --help            print this help and exit

environment: FINGER_TOML, FINGER_FW_ESTIMATOR and FINGER_FW_DELTA_TA_NM as for `demo`.

exit status: the runner's (probe-rs's); 127 when probe-rs is missing; 1 when the build fails.
",
        run: size::board,
    },
    Cmd {
        name: "bench",
        args: "[--check] [--quick] [--no-criterion]",
        summary: "instructions per estimate (unicorn) and error of each solver variant",
        help: "\
Builds the instruction-count harness (crates/pts/benches/thumb) for thumbv7em and thumbv6m, runs
it in the unicorn emulator (python3; `pip install unicorn` when missing) and prints, per solver
variant, instructions per estimate on both targets, the controller's per-sample work, host time
(criterion) and the error against the f64 reference. Also counts the firmware's integer path fit
on the committed cases (crates/pathfit/benches/icount/cases). Counts are emulated instructions,
so they do not depend on the machine. The full run takes several minutes.

options:
  --check               what `cargo xtask test` runs: a coarser grid, no criterion, and a
                        failure when the firmware estimate's instruction budgets (2,000 on
                        thumbv7em, 8,000 on thumbv6m; 400 per control tick) or its accuracy
                        against f64 (1e-4·l2) are not met
  --quick               the coarser grid only
  --no-criterion        skip the host timing (cargo bench -p pts --bench solvers)
  -h, --help            print this help and exit

exit status: 0 on success; 1 when a gate fails (the path-fit gate: 100,000 instructions and
within σ/2 of the FPU fit, on every run; the estimate gates with --check) or a step cannot run.
",
        run: bench::main,
    },
    Cmd {
        name: "fuzz",
        args: "[--seconds N] [--target solver|parsers|settings|proto]",
        summary: "the cargo-fuzz targets (nightly, libFuzzer), N seconds each",
        help: "\
Runs the cargo-fuzz targets of fuzz/ (the solver on arbitrary inputs; the parsers of scene TOML,
finger TOML and trace CSV; the settings store's load on arbitrary flash contents; the host
protocol's frame decoder on arbitrary byte streams) and reports, per target, how long it ran
clean and how many inputs it executed. Installs the nightly toolchain and cargo-fuzz when
missing (host only).

options:
  --seconds N           how long each target runs (default 60)
  --target NAME         only this target: solver, parsers, settings or proto
  -h, --help            print this help and exit

exit status: 0 when no target found anything; 1 on a finding (the input that triggered it is
left in fuzz/artifacts/<target>/).
",
        run: fuzz::main,
    },
    Cmd {
        name: "panics",
        args: "",
        summary: "no panic reachable from any firmware task (whole-program call graph)",
        help: "\
Builds the board firmware (two-point and path-fit estimators) as one LTO assembly file and walks
the call graph from the sampling interrupt and the task dispatchers. Any reachable core panic
entry point (unwrap, expect, slice index, bounds check, division, panic_fmt, ...) that is not on
the list of accepted sites fails the check, with its call path and source line. Only device
mode's USB interrupt is known open, per call site: each panic call it reaches must lie in a
crate this project does not own (by the linked ELF's line tables) or be listed with its reason;
those are reported with their crate, file and line, not failed.

options:
  -h, --help            print this help and exit

exit status: 0 when nothing new is reachable; 1 otherwise.
",
        run: |a| panics::main(a).map(|()| 0),
    },
    Cmd {
        name: "qemu",
        args: "ELF",
        summary: "run a firmware ELF in QEMU and print its decoded defmt log",
        help: "\
Runs a firmware ELF built for QEMU (cargo build --release -p finger-fw --target
thumbv7em-none-eabihf --no-default-features --features qemu) in qemu-system-arm and prints its
defmt log, decoded with the ELF's own string table. Killed as hung after 600 s of wall time.

arguments:
  ELF                   path of the firmware ELF

options:
  -h, --help            print this help and exit

exit status: the firmware's (see `cargo xtask demo --help`); 1 when QEMU cannot run it.
",
        run: run_qemu,
    },
];

/// `cargo xtask qemu ELF`.
fn run_qemu(args: &[String]) -> Result<i32, String> {
    match args {
        [elf] => qemu::run(std::path::Path::new(elf), &mut |f| {
            println!("{}", log::show(f))
        })
        .map(|r| r.status),
        _ => Err("usage: cargo xtask qemu ELF (see cargo xtask qemu --help)".into()),
    }
}

fn find(name: &str) -> Option<&'static Cmd> {
    COMMANDS.iter().find(|c| c.name == name)
}

fn is_help(arg: &str) -> bool {
    matches!(arg, "--help" | "-h")
}

/// The usage line of one command.
fn usage_line(c: &Cmd) -> String {
    if c.args.is_empty() {
        format!("usage: cargo xtask {}", c.name)
    } else {
        format!("usage: cargo xtask {} {}", c.name, c.args)
    }
}

/// The full help of one command.
fn command_help(c: &Cmd) -> String {
    format!("{}\n\n{}", usage_line(c), c.help)
}

/// The overview: every command with its one-line summary.
fn overview() -> String {
    const COL: usize = 28;
    let mut s = String::from(
        "usage: cargo xtask <command> [options]\n\
         \x20      cargo xtask <command> --help    what one command does, its options and exit status\n\
         \ncommands:\n",
    );
    for c in COMMANDS {
        let head = format!("  {} {}", c.name, c.args);
        let head = head.trim_end();
        // The summary on the same line when it fits, else on the next one.
        if head.chars().count() < COL {
            s += &format!("{head:<COL$}{}\n", c.summary);
        } else {
            s += &format!("{head}\n{:COL$}{}\n", "", c.summary);
        }
    }
    s
}

/// What to print when the arguments ask for help, or `None` when they ask for work.
///
/// `help`, `--help`, `-h` or no arguments give the overview; `help CMD` or `CMD ... --help`
/// (or `-h`) anywhere after a known command give that command's help, without running it.
fn help_request(args: &[String]) -> Option<String> {
    match args.first().map(String::as_str) {
        None => Some(overview()),
        Some("help") => Some(match args.get(1).and_then(|n| find(n)) {
            Some(c) => command_help(c),
            None => overview(),
        }),
        Some(a) if is_help(a) => Some(overview()),
        Some(name) => {
            let c = find(name)?;
            args[1..]
                .iter()
                .any(|a| is_help(a))
                .then(|| command_help(c))
        }
    }
}

fn run(args: &[String]) -> Result<i32, String> {
    if let Some(text) = help_request(args) {
        print!("{text}");
        return Ok(0);
    }
    let name = args.first().map(String::as_str).unwrap_or_default();
    match find(name) {
        Some(c) => {
            // The thumb builds link with flip-link (stack overflow caught by the hardware).
            size::ensure_flip_link()?;
            (c.run)(&args[1..])
        }
        None => Err(format!("unknown command `{name}`\n{}", overview())),
    }
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match run(&args) {
        Ok(code) => ExitCode::from(u8::try_from(code.clamp(0, 255)).unwrap_or(1)),
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn fuzz_help_names_every_fuzz_target() {
        let c = COMMANDS.iter().find(|c| c.name == "fuzz").unwrap();
        for t in fuzz::TARGETS {
            assert!(c.args.contains(t), "usage omits the {t} target: {}", c.args);
            assert!(c.help.contains(t), "help omits the {t} target");
        }
    }

    #[test]
    fn every_command_answers_help_without_running() {
        for c in COMMANDS {
            for flag in ["--help", "-h"] {
                // Alone, and after other arguments (`demo --scene x --help`).
                for a in [args(&[c.name, flag]), args(&[c.name, "x", flag])] {
                    let text = help_request(&a)
                        .unwrap_or_else(|| panic!("`{}` is not treated as help", a.join(" ")));
                    assert!(text.starts_with(&usage_line(c)), "{text}");
                    assert!(text.contains("exit status"), "{}: no exit status", c.name);
                    assert!(text.contains("-h, --help"), "{}: --help not listed", c.name);
                }
            }
            assert_eq!(
                help_request(&args(&["help", c.name])),
                Some(command_help(c))
            );
        }
    }

    #[test]
    fn overview_lists_every_command() {
        let o = overview();
        for c in COMMANDS {
            assert!(
                o.lines()
                    .any(|l| l.starts_with(&format!("  {} ", c.name))
                        || l == format!("  {}", c.name)),
                "`{}` missing from the overview:\n{o}",
                c.name
            );
        }
        let cases: [&[&str]; 5] = [&[], &["help"], &["--help"], &["-h"], &["help", "nosuch"]];
        for a in cases {
            assert_eq!(help_request(&args(a)), Some(o.clone()));
        }
    }

    #[test]
    fn work_and_unknown_commands_are_not_help() {
        assert_eq!(help_request(&args(&["demo", "--scene", "free"])), None);
        assert_eq!(help_request(&args(&["test"])), None);
        // An unknown command is an error, even with --help after it.
        assert_eq!(help_request(&args(&["nosuch", "--help"])), None);
        assert!(run(&args(&["nosuch"])).is_err());
    }

    #[test]
    fn names_are_unique_and_lines_fit_100_columns() {
        for (i, c) in COMMANDS.iter().enumerate() {
            assert!(COMMANDS[..i].iter().all(|d| d.name != c.name), "{}", c.name);
            for l in command_help(c).lines() {
                assert!(l.chars().count() <= 100, "{}: line too long: {l}", c.name);
            }
        }
        for l in overview().lines() {
            assert!(l.chars().count() <= 100, "overview line too long: {l}");
        }
    }
}
