//! Flash and static RAM of the release board firmware, from its ELF sections, and the stack:
//! its size on the board (flip-link puts it below the statics) and its high-water mark,
//! measured in QEMU (the stack is painted at reset and read back at the end of the run).

use object::{Object, ObjectSection, SectionFlags};

use crate::util::{self, Res};

/// Flash budget of the board firmware (bytes): a quarter of the STM32F411CE's 512 KiB, room
/// for both estimators, the protocol and USB, with the settings store's sectors apart.
pub const FLASH_BUDGET: u64 = 128 * 1024;
/// Static RAM budget (bytes): .data + .bss + .uninit, without the stack.
pub const RAM_BUDGET: u64 = 32 * 1024;

/// Sizes of one ELF.
#[derive(Clone, Copy, Debug)]
pub struct Sizes {
    /// Bytes stored in flash: vector table, code, read-only data and the .data image.
    pub flash: u64,
    /// Bytes of static RAM: .data + .bss + .uninit.
    pub ram: u64,
    /// Panic-location paths of registry crates in .rodata still under cargo's home (0 when
    /// xtask's remap applied): the flash grows by this many bytes per character of a longer
    /// `CARGO_HOME`.
    pub registry_paths: u64,
}

/// Measures an ELF.
pub fn measure(elf: &std::path::Path) -> Res<Sizes> {
    let bytes = std::fs::read(elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    let file = object::File::parse(&*bytes).map_err(|e| format!("{}: {e}", elf.display()))?;
    let mut s = Sizes {
        flash: 0,
        ram: 0,
        registry_paths: 0,
    };
    for sec in file.sections() {
        let name = sec.name().unwrap_or("");
        let alloc = match sec.flags() {
            SectionFlags::Elf { sh_flags } => sh_flags & u64::from(object::elf::SHF_ALLOC) != 0,
            _ => false,
        };
        if !alloc {
            continue;
        }
        match name {
            ".vector_table" | ".text" => s.flash += sec.size(),
            ".rodata" => {
                s.flash += sec.size();
                let data = sec.data().unwrap_or(&[]);
                if let Some(home) = util::cargo_home() {
                    let marker = home.join("registry").join("src");
                    let marker = marker.to_string_lossy();
                    let marker = marker.as_bytes();
                    s.registry_paths =
                        data.windows(marker.len()).filter(|w| w == &marker).count() as u64;
                }
            }
            ".data" => {
                s.flash += sec.size();
                s.ram += sec.size();
            }
            ".bss" | ".uninit" => s.ram += sec.size(),
            _ => {}
        }
    }
    Ok(s)
}

/// Builds the release board firmware (the power-up grasp); returns its ELF.
pub fn build_board() -> Res<std::path::PathBuf> {
    build_board_with(&[], None)
}

/// What `cargo build` / `cargo run` take for the release board firmware.
const BOARD_ARGS: [&str; 5] = [
    "--release",
    "-p",
    "finger-fw",
    "--target",
    crate::qemu::TARGET,
];

/// `cargo xtask board` (`cargo board`): `cargo run` of the release board firmware with the
/// same flags as [`build_board`], so what is flashed is what the size budgets measured; the
/// runner's exit status.
pub fn board(args: &[String]) -> Res<i32> {
    let mut cmd = util::cargo();
    cmd.arg("run").args(BOARD_ARGS).args(args);
    eprintln!("$ {}", util::show(&cmd));
    let status = cmd
        .status()
        .map_err(|e| format!("{}: {e}", util::show(&cmd)))?;
    Ok(status.code().unwrap_or(1))
}

/// Cargo features of the board's device-mode build: USB CDC-ACM, the protocol, the settings
/// store, the two-point estimator (what `cargo board --features device` flashes).
pub const DEVICE_FEATURES: &str = "board,device";
/// The same with both estimators at run time (`path-fit` builds in the path fit's table and
/// keeps the two-point method): the largest board build, held to the same budgets.
pub const DEVICE_BOTH_FEATURES: &str = "board,device,path-fit";

/// Builds the release board firmware in device mode with `features` (one of the two above);
/// returns its ELF (kept apart: the next build overwrites the one in place).
pub fn build_board_device(features: &str) -> Res<std::path::PathBuf> {
    // Without the feature the estimator is the two-point method, chosen explicitly: the
    // firmware's default is the path fit.
    let estimator = if features.contains("path-fit") {
        "path-fit"
    } else {
        "two-point"
    };
    let elf = build_board_with(
        &["--no-default-features", "--features", features],
        Some(estimator),
    )?;
    let kept = elf.with_file_name(format!("finger-fw-{}", features.replace(',', "-")));
    std::fs::copy(&elf, &kept).map_err(|e| format!("{}: {e}", kept.display()))?;
    Ok(kept)
}

/// `estimator`: `FINGER_FW_ESTIMATOR` for the build; `None` keeps the caller's environment.
fn build_board_with(extra: &[&str], estimator: Option<&str>) -> Res<std::path::PathBuf> {
    let mut cmd = util::cargo();
    cmd.arg("build").args(BOARD_ARGS).args(extra);
    if let Some(e) = estimator {
        cmd.env("FINGER_FW_ESTIMATOR", e);
    }
    util::run(&mut cmd)?;
    Ok(util::root()
        .join("target")
        .join(crate::qemu::TARGET)
        .join("release")
        .join("finger-fw"))
}

/// Prints both numbers of the build `label` against the budgets; `Err` when over.
pub fn report(label: &str, s: Sizes) -> Res {
    println!(
        "board firmware ({label}): flash {} B ({:.1} KiB) of {} KiB, static RAM {} B ({:.1} KiB) of {} KiB",
        s.flash,
        s.flash as f64 / 1024.0,
        FLASH_BUDGET / 1024,
        s.ram,
        s.ram as f64 / 1024.0,
        RAM_BUDGET / 1024
    );
    let mut errs = Vec::new();
    if s.flash > FLASH_BUDGET {
        errs.push(format!(
            "flash {} B over the {} B budget",
            s.flash, FLASH_BUDGET
        ));
    }
    if s.ram > RAM_BUDGET {
        errs.push(format!(
            "static RAM {} B over the {} B budget",
            s.ram, RAM_BUDGET
        ));
    }
    if errs.is_empty() {
        Ok(())
    } else {
        Err(errs.join("; "))
    }
}

/// The documents that quote each board build's flash and static RAM.
const SIZE_DOCS: [&str; 2] = ["README.md", "docs/RESULTS.md"];
/// The document that quotes the stack's high-water mark of the Table 2 scene.
const STACK_DOC: &str = "docs/SAFETY.md";

/// `n` as the documents write bytes: thousands separated by commas (130904 → "130,904").
pub fn grouped(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// Each `(name, text)` of `docs` that does not state `value` bytes (grouped, not part of a
/// longer number), as a message naming the document, `what` and the value.
fn unstated(docs: &[(&str, String)], what: &str, value: u64) -> Vec<String> {
    let want = grouped(value);
    let states = |text: &str| {
        text.match_indices(&want).any(|(i, _)| {
            let before = text[..i].chars().next_back();
            let after = text[i + want.len()..].chars().next();
            !before.is_some_and(|c| c.is_ascii_digit() || c == ',')
                && !after.is_some_and(|c| c.is_ascii_digit() || c == ',' || c == '.')
        })
    };
    docs.iter()
        .filter(|(_, text)| !states(text))
        .map(|(name, _)| format!("{name} does not state {what} ({want} B, measured)"))
        .collect()
}

fn read_docs(names: &[&'static str]) -> Res<Vec<(&'static str, String)>> {
    names
        .iter()
        .map(|n| {
            std::fs::read_to_string(util::root().join(n))
                .map(|t| (*n, t))
                .map_err(|e| format!("{n}: {e}"))
        })
        .collect()
}

/// `Err` naming each document (README, RESULTS) that does not quote this build's measured
/// flash and static RAM (the sizes the documents give are the ones `cargo xtask size` prints),
/// or when the build embeds cargo's home: its size would then depend on the machine.
pub fn documented(label: &str, s: Sizes) -> Res {
    let docs = read_docs(&SIZE_DOCS)?;
    let mut errs = unstated(&docs, &format!("the flash of the {label} build"), s.flash);
    errs.extend(unstated(
        &docs,
        &format!("the static RAM of the {label} build"),
        s.ram,
    ));
    if !errs.is_empty() {
        errs.push("update the size rows".to_string());
    }
    if s.registry_paths > 0 {
        errs.push(format!(
            "the {label} build holds {} panic-location paths under cargo's home, so its flash \
             depends on that path's length: xtask remaps them ({}, from `util::thumb_rustflags`) \
             unless that variable is set already or cargo's home holds a space",
            s.registry_paths,
            util::THUMB_RUSTFLAGS
        ));
    }
    if errs.is_empty() {
        Ok(())
    } else {
        Err(errs.join("; "))
    }
}

/// `Err` when SAFETY.md does not quote the Table 2 scene's stack high-water mark `used` (B)
/// of the `estimator` build.
pub fn stack_documented(estimator: &str, used: u64) -> Res {
    let docs = read_docs(&[STACK_DOC])?;
    let errs = unstated(
        &docs,
        &format!("the {estimator} build's stack high-water mark"),
        used,
    );
    if errs.is_empty() {
        Ok(())
    } else {
        Err(errs.join("; "))
    }
}

/// The board's RAM (STM32F411CE).
const BOARD_RAM: u64 = 128 * 1024;
/// The stack may use at most this share of what the board leaves it.
const STACK_MAX_SHARE: f64 = 0.5;

/// Installs flip-link (the thumb builds' linker, .cargo/config.toml) when it is missing.
pub fn ensure_flip_link() -> Res {
    let found = std::env::var_os("PATH")
        .is_some_and(|paths| std::env::split_paths(&paths).any(|d| d.join("flip-link").is_file()));
    if found {
        return Ok(());
    }
    eprintln!("flip-link (the firmware's linker) is missing: installing it");
    util::run(
        std::process::Command::new(std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into()))
            .args(["install", "flip-link", "--locked"]),
    )
}

/// The stack line of a QEMU run checked against the board: the high-water mark must fit in
/// half of the board's RAM left after the static budget.
pub fn stack_check(frames: &[crate::qemu::Frame]) -> Res<String> {
    let used = stack_used(frames)?;
    let avail = BOARD_RAM - RAM_BUDGET;
    let max = (avail as f64 * STACK_MAX_SHARE) as u64;
    let text = format!(
        "stack high-water {used} B (QEMU, the simulated plant included), board stack {avail} B (RAM less the static budget): margin {} B; limit {max} B",
        avail.saturating_sub(used)
    );
    if used > max {
        Err(format!("stack too deep: {text}"))
    } else {
        Ok(text)
    }
}

/// The stack's high-water mark (B) of a QEMU run's log.
pub fn stack_used(frames: &[crate::qemu::Frame]) -> Res<u64> {
    let line = crate::log::first(frames, "STACK").ok_or("no STACK line in the log")?;
    Ok(crate::log::int(&line.msg, "used").ok_or("STACK without used")? as u64)
}

/// `cargo xtask size`: flash and static RAM of the board builds (power-up grasp; device mode
/// with USB, with one and with both estimators), then the stack's high-water mark of the
/// Table 2 scene in QEMU for both estimators.
pub fn main(_args: &[String]) -> Res {
    let checked = |label: &str, s: Sizes| report(label, s).and(documented(label, s));
    let mut sized = vec![build_board().and_then(|elf| checked("power-up grasp", measure(&elf)?))];
    for features in [DEVICE_FEATURES, DEVICE_BOTH_FEATURES] {
        sized.push(
            build_board_device(features)
                .and_then(|elf| checked(&format!("device mode, USB, {features}"), measure(&elf)?)),
        );
    }
    let sized: Vec<String> = sized.into_iter().filter_map(Result::err).collect();
    let sized = if sized.is_empty() {
        Ok(())
    } else {
        Err(sized.join("\n"))
    };
    let mut errs = Vec::new();
    for est in ["two-point", "path-fit"] {
        std::env::set_var("FINGER_FW_ESTIMATOR", est);
        let r = crate::qemu::build("table2")
            .and_then(|elf| crate::qemu::run(&elf, &mut |_| {}))
            .and_then(|run| {
                stack_documented(est, stack_used(&run.frames)?)?;
                stack_check(&run.frames)
            });
        std::env::remove_var("FINGER_FW_ESTIMATOR");
        match r {
            Ok(t) => println!("{est}: {t}"),
            Err(e) => errs.push(format!("{est}: {e}")),
        }
    }
    sized?;
    if errs.is_empty() {
        Ok(())
    } else {
        Err(errs.join("\n"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_build_over_either_budget_fails_and_says_which() {
        let s = |flash, ram| Sizes {
            flash,
            ram,
            registry_paths: 0,
        };
        assert!(report("t", s(FLASH_BUDGET, RAM_BUDGET)).is_ok());
        let e = report("t", s(FLASH_BUDGET + 1, RAM_BUDGET)).unwrap_err();
        assert!(e.contains("flash") && !e.contains("static RAM"), "{e}");
        let e = report("t", s(FLASH_BUDGET, RAM_BUDGET + 1)).unwrap_err();
        assert!(e.contains("static RAM") && !e.contains("flash"), "{e}");
    }

    #[test]
    fn a_size_the_documents_do_not_state_is_named_with_the_document() {
        assert_eq!(grouped(0), "0");
        assert_eq!(grouped(999), "999");
        assert_eq!(grouped(90_248), "90,248");
        assert_eq!(grouped(130_904), "130,904");
        assert_eq!(grouped(1_334_133), "1,334,133");
        let docs = [
            ("A.md", "flash 100,056 / 130,904 B".to_string()),
            (
                "B.md",
                "flash 1,130,904 B and 130,9041 B and 130,904.5 B".to_string(),
            ),
        ];
        assert!(unstated(&docs[..1], "x", 130_904).is_empty());
        assert!(unstated(&docs[..1], "x", 100_056).is_empty());
        let e = unstated(&docs, "the flash of t", 130_904);
        assert_eq!(e.len(), 1, "{e:?}");
        assert!(e[0].contains("B.md") && e[0].contains("130,904"), "{e:?}");
        assert_eq!(unstated(&docs, "x", 130_905).len(), 2);
    }
}
