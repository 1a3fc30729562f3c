//! Project automation: `cargo xtask <command>`.
//!
//! * `demo [--scene NAME|FILE]`: the QEMU firmware with the simulated finger, decoded live.
//! * `test`: every check the project has (the CI entry point, see .ci/run).
//! * `size`: flash and static RAM of the board firmware against the budgets.
//! * `qemu ELF`: run a firmware ELF in QEMU and print its decoded defmt log.
//! * `panics`: no panic reachable from any firmware task (whole-program call graph).

mod bench;
mod ci;
mod demo;
mod fuzz;
mod log;
mod panics;
mod qemu;
mod size;
mod util;

use std::process::ExitCode;

const USAGE: &str = "\
usage: cargo xtask <command>
  demo [--scene NAME|FILE]   build the QEMU firmware for a scene (default table2), run it,
                             show the grasp live and the estimate against the plant's truth
  test                       run every test (fmt, clippy, unit/integration tests, target
                             builds, size budgets, QEMU scenes) and print `N passed, M failed`
  size                       flash / static RAM of the release board firmware vs the budgets,
                             and the stack's high-water mark (QEMU) against the board's stack
  qemu ELF                   run a firmware ELF in QEMU and print its decoded defmt log
  panics                     no panic reachable from any firmware task (board builds)
";

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let rest = args.get(1..).unwrap_or(&[]);
    let builds = !matches!(
        args.first().map(String::as_str),
        None | Some("help" | "--help" | "-h")
    );
    if builds {
        if let Err(e) = size::ensure_flip_link() {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
    }
    let result: Result<i32, String> = match args.first().map(String::as_str) {
        Some("demo") => demo::main(rest),
        Some("test") => ci::main(rest),
        Some("size") => size::main(rest).map(|_| 0),
        Some("panics") => panics::main(rest).map(|_| 0),
        Some("qemu") => match rest.first() {
            Some(elf) => qemu::run(std::path::Path::new(elf), &mut |f| {
                println!("{}", log::show(f))
            })
            .map(|r| r.status),
            None => Err("usage: cargo xtask qemu ELF".into()),
        },
        // Subcommands of the numerics owner (xtask/src/bench.rs, xtask/src/fuzz.rs) go here.
        Some("bench") => bench::main(rest),
        Some("fuzz") => fuzz::main(rest),
        Some("help" | "--help" | "-h") | None => {
            print!("{USAGE}");
            Ok(0)
        }
        Some(other) => Err(format!("unknown command `{other}`\n{USAGE}")),
    };
    match result {
        Ok(code) => ExitCode::from(u8::try_from(code.clamp(0, 255)).unwrap_or(1)),
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
