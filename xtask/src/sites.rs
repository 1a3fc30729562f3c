//! Where each panic call of a linked firmware lies in the source: every Thumb branch to a panic
//! entry point in the ELF's code, with the chain of inlined frames at it (the DWARF line tables),
//! and whose code the innermost frame outside the standard library is. `cargo xtask panics`
//! uses it to hold the one task whose panics are known open to sites in crates this project
//! does not own: a panic site in the workspace's own code fails there too.

use std::borrow::Cow;
use std::path::Path;

use object::{Object, ObjectSection, ObjectSymbol, SymbolKind};

use crate::callgraph::is_panic;
use crate::util::Res;

/// One source frame at a call site, innermost first in [`Site::frames`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame {
    /// Demangled function name, when the DWARF names it.
    pub function: Option<String>,
    /// Source file (absolute, as the compiler recorded it).
    pub file: Option<String>,
    /// Line; `None` for a call the compiler merged from several places (line 0).
    pub line: Option<u32>,
}

/// A branch, in the linked code, to a panic entry point or to one of core's functions.
#[derive(Clone, Debug)]
pub struct Site {
    /// The function (symbol) the branch lies in.
    pub caller: String,
    /// The panic entry point (or core's function) it branches to.
    pub callee: String,
    /// Address of the branch instruction.
    pub addr: u64,
    /// The inlined frames at the branch, innermost first.
    pub frames: Vec<Frame>,
}

/// Whose code a call site is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Owner {
    /// The workspace's own code (the file under the workspace root).
    Own(Frame),
    /// A dependency from the registry: its `name-version` directory and the frame.
    Crate(String, Frame),
    /// Only the standard library's frames (or none): core's own internal checks.
    Std,
}

/// A function that may be core's: its path or its impl's self type names core (legacy or v0
/// mangling: `4core`, `core..`). Broad on purpose: a call recorded into a function that is not
/// core's costs a lookup, a call missed would leave a panic in core unattributed.
pub fn is_core(sym: &str) -> bool {
    sym.contains("4core") || sym.contains("core..")
}

impl Owner {
    /// Where the call lies, for a report: `file:line` in this project, `crate file:line` in a
    /// dependency, `core` when only the standard library's frames are known.
    pub fn place(&self, root: &Path) -> String {
        match self {
            Owner::Own(f) => Site::place(f, root),
            Owner::Crate(k, f) => format!("{k} {}", Site::place(f, root)),
            Owner::Std => "core".to_string(),
        }
    }
}

/// The standard library's sources as rustc records them (remapped to `/rustc/<commit>/`).
fn is_std(file: &str) -> bool {
    file.starts_with("/rustc/") || file.contains("/library/core/src/")
}

impl Site {
    /// The innermost frame outside the standard library decides: a bounds check written in a
    /// crate's code is inlined from core's `Index`, so the frame just outside core is the code
    /// that indexed.
    pub fn owner(&self, root: &Path) -> Owner {
        let Some(f) = self
            .frames
            .iter()
            .find(|f| f.file.as_deref().is_some_and(|p| !is_std(p)))
        else {
            return Owner::Std;
        };
        let file = f.file.as_deref().unwrap_or("");
        if Path::new(file).starts_with(root) {
            return Owner::Own(f.clone());
        }
        // …/registry/src/<index>/<name-version>/src/…
        let krate = file
            .split_once("/registry/src/")
            .and_then(|(_, rest)| rest.split('/').nth(1))
            .unwrap_or(file);
        Owner::Crate(krate.to_string(), f.clone())
    }

    /// `file:line` of a frame (relative to `root`, or to a registry crate's directory), `?`
    /// for a merged call's line.
    pub fn place(f: &Frame, root: &Path) -> String {
        let file = f.file.as_deref().unwrap_or("?");
        let file = match Path::new(file).strip_prefix(root) {
            Ok(p) => p.display().to_string(),
            Err(_) => file
                .split_once("/registry/src/")
                .and_then(|(_, rest)| rest.splitn(3, '/').nth(2))
                .unwrap_or(file)
                .to_string(),
        };
        match f.line {
            Some(l) => format!("{file}:{l}"),
            None => format!("{file}:?"),
        }
    }
}

/// The target of a Thumb-2 branch at `addr` whose first halfword is `h1` (and next `h2`): BL,
/// B.W and conditional B.W (32-bit), B and conditional B (16-bit). `None` for anything else.
pub fn branch_target(addr: u64, h1: u16, h2: u16) -> Option<u64> {
    let pc = addr.wrapping_add(4) as i64;
    let (h1, h2) = (u32::from(h1), u32::from(h2));
    let target = if h1 & 0xF800 == 0xF000 && h2 & 0x8000 != 0 {
        let s = (h1 >> 10) & 1;
        let (j1, j2) = ((h2 >> 13) & 1, (h2 >> 11) & 1);
        match h2 & 0x5000 {
            // BL (T1) and B.W (T4): S:I1:I2:imm10:imm11:0, I = !(J ^ S).
            0x5000 | 0x1000 => {
                let (i1, i2) = (!(j1 ^ s) & 1, !(j2 ^ s) & 1);
                let imm = (s << 24)
                    | (i1 << 23)
                    | (i2 << 22)
                    | ((h1 & 0x3FF) << 12)
                    | ((h2 & 0x7FF) << 1);
                pc + sign_extend(imm, 25)
            }
            // Conditional B.W (T3): S:J2:J1:imm6:imm11:0 (cond 111x is another instruction).
            0x0000 if (h1 >> 7) & 0x7 != 0x7 => {
                let imm =
                    (s << 20) | (j2 << 19) | (j1 << 18) | ((h1 & 0x3F) << 12) | ((h2 & 0x7FF) << 1);
                pc + sign_extend(imm, 21)
            }
            // BLX to Arm state, and the control instructions: no Thumb target.
            _ => return None,
        }
    } else if h1 & 0xF800 == 0xE000 {
        // B (T2, 16-bit).
        pc + sign_extend((h1 & 0x7FF) << 1, 12)
    } else if h1 & 0xF000 == 0xD000 && (h1 >> 8) & 0xF < 0xE {
        // B<cond> (T1, 16-bit).
        pc + sign_extend((h1 & 0xFF) << 1, 9)
    } else {
        return None;
    };
    Some(target as u64)
}

fn sign_extend(v: u32, bits: u32) -> i64 {
    let shift = 64 - bits;
    (i64::from(v) << shift) >> shift
}

/// Every branch to a panic entry point in the ELF's functions, and to a function of core's
/// that was not inlined (a panic inside one is judged by who called it), with the source
/// frames at it. Every halfword of each function is tried as the start of a branch, so a
/// branch is never missed whatever sits between instructions; data that happens to encode a
/// branch to one of these can add a site, never hide one.
pub fn panic_sites(elf: &[u8]) -> Res<Vec<Site>> {
    let obj = object::File::parse(elf).map_err(|e| format!("ELF: {e}"))?;
    let mut funcs: Vec<(u64, u64, String)> = Vec::new();
    let mut panics: std::collections::BTreeMap<u64, String> = Default::default();
    for sym in obj.symbols() {
        if sym.kind() != SymbolKind::Text || sym.size() == 0 {
            continue;
        }
        let Ok(name) = sym.name() else { continue };
        let addr = sym.address() & !1;
        if is_panic(name) || is_core(name) {
            panics.insert(addr, name.to_string());
        }
        funcs.push((addr, sym.size(), name.to_string()));
    }
    let load = |id: gimli::SectionId| -> Result<Cow<'_, [u8]>, gimli::Error> {
        Ok(obj
            .section_by_name(id.name())
            .and_then(|s| s.uncompressed_data().ok())
            .unwrap_or(Cow::Borrowed(&[])))
    };
    let sections = gimli::DwarfSections::load(load).map_err(|e| format!("DWARF: {e}"))?;
    let dwarf = sections.borrow(|s| gimli::EndianSlice::new(s, gimli::RunTimeEndian::Little));
    let ctx = addr2line::Context::from_dwarf(dwarf).map_err(|e| format!("DWARF: {e}"))?;
    let mut sites = Vec::new();
    for (start, size, name) in &funcs {
        if is_panic(name) {
            continue;
        }
        let Some(code) = bytes_at(&obj, *start, *size) else {
            continue;
        };
        let half = |i: usize| -> u16 {
            u16::from_le_bytes([code[i], code.get(i + 1).copied().unwrap_or(0)])
        };
        let mut i = 0;
        while i + 1 < code.len() {
            let addr = start + i as u64;
            let h2 = if i + 3 < code.len() { half(i + 2) } else { 0 };
            if let Some(callee) = branch_target(addr, half(i), h2).and_then(|t| panics.get(&t)) {
                sites.push(Site {
                    caller: name.clone(),
                    callee: callee.clone(),
                    addr,
                    frames: frames_at(&ctx, addr)?,
                });
            }
            i += 2;
        }
    }
    Ok(sites)
}

type Reader<'a> = gimli::EndianSlice<'a, gimli::RunTimeEndian>;

fn frames_at(ctx: &addr2line::Context<Reader<'_>>, addr: u64) -> Res<Vec<Frame>> {
    let mut out = Vec::new();
    let mut it = ctx
        .find_frames(addr)
        .skip_all_loads()
        .map_err(|e| format!("DWARF at {addr:#x}: {e}"))?;
    while let Some(f) = it.next().map_err(|e| format!("DWARF at {addr:#x}: {e}"))? {
        out.push(Frame {
            function: f
                .function
                .as_ref()
                .and_then(|n| n.demangle().ok())
                .map(|n| n.into_owned()),
            file: f.location.as_ref().and_then(|l| l.file).map(str::to_string),
            line: f.location.as_ref().and_then(|l| l.line).filter(|&l| l > 0),
        });
    }
    Ok(out)
}

/// The bytes of `size` at `addr` in whichever section holds them.
fn bytes_at<'a>(obj: &'a object::File<'a>, addr: u64, size: u64) -> Option<&'a [u8]> {
    obj.sections().find_map(|s| {
        let (a, n) = (s.address(), s.size());
        if addr < a || addr + size > a + n {
            return None;
        }
        let data = s.data().ok()?;
        data.get((addr - a) as usize..(addr - a + size) as usize)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A registry crate's frame is told from the workspace's whether or not xtask remapped
    /// cargo's home out of its path (`util::thumb_rustflags`).
    #[test]
    fn a_registry_crate_s_call_is_its_crate_s_remapped_or_not() {
        let root = Path::new("/work/main");
        let site = |file: &str| Site {
            caller: "c".into(),
            callee: "p".into(),
            addr: 0,
            frames: vec![Frame {
                function: Some("f".into()),
                file: Some(file.into()),
                line: Some(706),
            }],
        };
        // The path as xtask's remap (util::thumb_rustflags) rewrites it, for a home made here.
        let home = std::env::temp_dir().join(format!("xtask-sites-home-{}", std::process::id()));
        let index = home.join("registry/src/index.crates.io-1949cf8c6b5b557f");
        std::fs::create_dir_all(&index).unwrap();
        let flags = crate::util::thumb_rustflags(&home).expect("remap flags");
        std::fs::remove_dir_all(&home).unwrap();
        let (from, to) = flags
            .strip_prefix("--remap-path-prefix=")
            .and_then(|f| f.split_once('='))
            .expect("one FROM=TO");
        assert_eq!(Path::new(from), index);
        let remapped = format!("{to}/synopsys-usb-otg-0.4.0/src/bus.rs");
        for file in [
            remapped.as_str(),
            "/root/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/synopsys-usb-otg-0.4.0/src/bus.rs",
        ] {
            let owner = site(file).owner(root);
            assert!(
                matches!(&owner, Owner::Crate(k, _) if k == "synopsys-usb-otg-0.4.0"),
                "{file}: {owner:?}"
            );
            assert_eq!(owner.place(root), "synopsys-usb-otg-0.4.0 src/bus.rs:706");
        }
        let own = site("/work/main/src/app_device.rs").owner(root);
        assert!(matches!(own, Owner::Own(_)), "{own:?}");
        assert_eq!(own.place(root), "src/app_device.rs:706");
    }

    #[test]
    fn branch_encodings_decode_to_their_targets() {
        // From arm-none-eabi-objdump of a firmware build.
        // 2028e: f000 f94b  bl 20528
        assert_eq!(branch_target(0x2028e, 0xf000, 0xf94b), Some(0x20528));
        // 202a6: f000 f934  bl 20512
        assert_eq!(branch_target(0x202a6, 0xf000, 0xf934), Some(0x20512));
        // Backwards BL: 0x1000: f7ff fffe  bl 0x1000 (a call to itself).
        assert_eq!(branch_target(0x1000, 0xf7ff, 0xfffe), Some(0x1000));
        // B.W (T4) forward by 0x100: 0x2000: f000 b87e  b.w 0x2100.
        assert_eq!(branch_target(0x2000, 0xf000, 0xb87e), Some(0x2100));
        // BNE.W (T3) forward by 0x40: 0x3000: f040 8020  bne.w 0x3044.
        assert_eq!(branch_target(0x3000, 0xf040, 0x8020), Some(0x3044));
        // 16-bit B: 0x4000: e7fe  b 0x4000.
        assert_eq!(branch_target(0x4000, 0xe7fe, 0), Some(0x4000));
        // 16-bit BEQ forward: 0x5000: d002  beq 0x5008.
        assert_eq!(branch_target(0x5000, 0xd002, 0), Some(0x5008));
        // Not branches: svc (df00), udf (de00), movw, a plain mov.
        for (h1, h2) in [(0xdf00, 0), (0xde00, 0), (0xf240, 0x104c), (0x461a, 0)] {
            assert_eq!(branch_target(0x6000, h1, h2), None, "{h1:04x} {h2:04x}");
        }
    }
}
