//! Flash and static RAM of the release board firmware, from its ELF sections.

use object::{Object, ObjectSection, SectionFlags};

use crate::util::{self, Res};

/// Flash budget of the board firmware (bytes).
pub const FLASH_BUDGET: u64 = 64 * 1024;
/// Static RAM budget (bytes): .data + .bss + .uninit, without the stack.
pub const RAM_BUDGET: u64 = 16 * 1024;

/// Sizes of one ELF.
#[derive(Clone, Copy, Debug)]
pub struct Sizes {
    /// Bytes stored in flash: vector table, code, read-only data and the .data image.
    pub flash: u64,
    /// Bytes of static RAM: .data + .bss + .uninit.
    pub ram: u64,
}

/// Measures an ELF.
pub fn measure(elf: &std::path::Path) -> Res<Sizes> {
    let bytes = std::fs::read(elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    let file = object::File::parse(&*bytes).map_err(|e| format!("{}: {e}", elf.display()))?;
    let mut s = Sizes { flash: 0, ram: 0 };
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
            ".vector_table" | ".text" | ".rodata" => s.flash += sec.size(),
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

/// Builds the release board firmware; returns its ELF.
pub fn build_board() -> Res<std::path::PathBuf> {
    util::run(util::cargo().args([
        "build",
        "--release",
        "-p",
        "finger-fw",
        "--target",
        crate::qemu::TARGET,
    ]))?;
    Ok(util::root()
        .join("target")
        .join(crate::qemu::TARGET)
        .join("release")
        .join("finger-fw"))
}

/// Prints both numbers against the budgets; `Err` when over.
pub fn report(s: Sizes) -> Res {
    println!(
        "board firmware: flash {} B ({:.1} KiB) of {} KiB, static RAM {} B ({:.1} KiB) of {} KiB",
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

/// `cargo xtask size`.
pub fn main(_args: &[String]) -> Res {
    let elf = build_board()?;
    report(measure(&elf)?)
}
