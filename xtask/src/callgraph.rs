//! The call graph of a GNU assembly listing and the names of Rust's panic entry points: shared
//! by `cargo xtask panics` and grasp's no-float test (included there with `#[path]`), so the
//! two checks cannot drift apart. Plain std, no crate of ours.

use std::collections::{BTreeMap, BTreeSet};

/// Whether a symbol (mangled legacy `_ZN…`, v0 `_R…` or plain) is a core panic entry point or
/// the panic handler. Matching is on the identifier words, so every mangling is covered.
pub fn is_panic(sym: &str) -> bool {
    let s = sym.to_ascii_lowercase();
    const WORDS: &[&str] = &[
        "panic", // core::panicking::*, panic_fmt, panic_bounds_check, panic_const_*, begin_panic
        "unwrap_failed",
        "expect_failed",
        "_fail", // slice_index_fail, slice_{start,end}_index_len_fail, slice_index_order_fail, str_index_overflow_fail, assert_failed
        "rust_begin_unwind",
        "unreachable_display",
        "handle_alloc_error",
    ];
    WORDS.iter().any(|w| s.contains(w))
}

/// Whether a symbol is a soft-float routine of compiler-builtins: the ARM EABI helpers
/// (`__aeabi_fadd`, `__aeabi_dmul`, `__aeabi_i2f`, `__aeabi_f2d`, `__aeabi_l2d`, …) and the
/// generic names (`__addsf3`, `__muldf3`, `__floatsisf`, `__fixdfsi`, `__extendsfdf2`, …).
pub fn is_soft_float(sym: &str) -> bool {
    let s = sym.trim_start_matches('_');
    if let Some(rest) = sym.strip_prefix("__aeabi_") {
        return rest.starts_with('f')
            || rest.starts_with('d')
            || rest.contains("2f")
            || rest.contains("2d");
    }
    s.ends_with("sf3")
        || s.ends_with("df3")
        || s.ends_with("sf2")
        || s.ends_with("df2")
        || s.starts_with("float")
        || s.starts_with("fix")
        || s.starts_with("extendsfdf")
        || s.starts_with("truncdfsf")
}

/// Every function reachable from `root` through direct calls, `root` included.
pub fn reachable(g: &BTreeMap<String, BTreeSet<String>>, root: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut stack = vec![root.to_string()];
    while let Some(f) = stack.pop() {
        if seen.insert(f.clone()) {
            stack.extend(g.get(&f).into_iter().flatten().cloned());
        }
    }
    seen
}

/// A legacy-mangled Rust symbol without its hash (`_ZN5grasp8estimate12two_point_fw17h…E`
/// → `_ZN5grasp8estimate12two_point_fw`): the same function's name in two builds.
pub fn without_hash(sym: &str) -> &str {
    match sym.rfind("17h") {
        Some(i) if sym.ends_with('E') && sym.len() == i + 3 + 16 + 1 => &sym[..i],
        _ => sym,
    }
}

/// True for a Thumb branch mnemonic that can leave the function: b, bl, blx, `b<cond>`, with
/// an optional .w/.n width (not bfc, bfi, bic, bkpt, ...).
pub fn is_branch(op: &str) -> bool {
    let op = op
        .strip_suffix(".w")
        .or_else(|| op.strip_suffix(".n"))
        .unwrap_or(op);
    const CONDS: &[&str] = &[
        "eq", "ne", "cs", "hs", "cc", "lo", "mi", "pl", "vs", "vc", "hi", "ls", "ge", "lt", "gt",
        "le", "al",
    ];
    match op {
        "b" | "bl" | "blx" => true,
        _ => op.strip_prefix('b').is_some_and(|c| CONDS.contains(&c)),
    }
}

/// Function label → symbols it branches to, from GNU assembly.
pub fn call_graph(asm: &str) -> BTreeMap<String, BTreeSet<String>> {
    let mut g: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    let mut cur: Option<String> = None;
    for line in asm.lines() {
        let t = line.trim();
        if let Some(label) = t.strip_suffix(':') {
            if !label.starts_with('.') && !label.contains(' ') && !label.starts_with('$') {
                let l = label.trim_matches('"').to_string();
                g.entry(l.clone()).or_default();
                cur = Some(l);
            }
            continue;
        }
        let mut parts = t.split_whitespace();
        let Some(op) = parts.next() else { continue };
        let rest: Vec<&str> = parts.collect();
        let target = if is_branch(op) {
            rest.first().copied()
        } else if matches!(op, "cbz" | "cbnz") {
            rest.get(1).copied()
        } else {
            None
        };
        let Some(target) = target else { continue };
        let target = target.trim_end_matches(',').trim_matches('"');
        if target.starts_with(".L")
            || target.starts_with('r') && target.len() <= 3
            || target == "lr"
        {
            continue;
        }
        if let Some(c) = &cur {
            g.entry(c.clone()).or_default().insert(target.to_string());
        }
    }
    g
}
