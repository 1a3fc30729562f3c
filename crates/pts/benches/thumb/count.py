#!/usr/bin/env python3
"""Counts the instructions of the pts solver variants and of grasp's per-sample tick in the
compiled thumbv7em-none-eabihf / thumbv6m-none-eabi harness (src/main.rs), by running the
ELF in the unicorn emulator (Cortex-M4 / Cortex-M0) with a basic-block hook. Deterministic:
the same ELF and inputs give the same counts. Also measures each variant's error against
the f64 variant run in the same emulator, over a grid of quasi-static contacts.

Driven by `cargo xtask bench` (which builds the ELFs and installs unicorn when missing).
"""
import argparse
import json
import math
import os
import struct
import sys

from unicorn import Uc, UC_ARCH_ARM, UC_MODE_THUMB, UC_MODE_MCLASS, UC_HOOK_BLOCK, UcError
from unicorn import arm_const as A

FLASH, FLASH_LEN = 0x0000_0000, 0x10_0000
RAM, RAM_LEN = 0x2000_0000, 0x4_0000
STACK_TOP = RAM + RAM_LEN - 16
INP, OUT = RAM + 0x3_0000, RAM + 0x3_1000
RET = FLASH + FLASH_LEN - 0x100  # never code: the call returns here
L2 = 0.075

VARIANTS = [  # (name, estimate id, free-motion id, encoding)
    ("f64", 1, 11, "f64"),
    ("f32", 2, 12, "f32"),
    ("Fx32", 3, 13, "fx32"),
    ("Fx24", 9, 19, "fx24"),
    ("Fx16", 4, 14, "fx16"),
    ("table+f64", 5, 15, "f64"),
    ("table+f32", 6, 16, "f32"),
    ("table+Fx32", 7, 17, "fx32"),
    ("table+Fx24", 10, 20, "fx24"),
    ("table+Fx16", 8, 18, "fx16"),
]
STATES = ["Init", "Calibrating", "Approach", "Seating", "Step", "Settling", "Estimating",
          "Holding", "Releasing", "Done", "Fault"]


def enc(x, kind):
    if kind == "f64":
        return struct.pack("<d", x)
    if kind == "f32":
        return struct.pack("<f", x) + b"\0" * 4
    if kind == "fx32":
        return struct.pack("<q", max(-(2**63), min(2**63 - 1, round(x * 2**32))))
    frac = 24 if kind == "fx24" else 16
    return struct.pack("<i", max(-(2**31), min(2**31 - 1, round(x * 2**frac)))) + b"\0" * 4


def dec(b, kind):
    if kind == "f64":
        return struct.unpack("<d", b[:8])[0]
    if kind == "f32":
        return struct.unpack("<f", b[:4])[0]
    if kind == "fx32":
        return struct.unpack("<q", b[:8])[0] / 2**32
    return struct.unpack("<i", b[:4])[0] / 2**(24 if kind == "fx24" else 16)


class Elf:
    """Just enough ELF32 little-endian: loadable segments and the symbol table."""

    def __init__(self, path):
        with open(path, "rb") as f:
            self.data = f.read()
        d = self.data
        if d[:4] != b"\x7fELF" or d[4] != 1 or d[5] != 1:
            raise SystemExit(f"{path}: not a 32-bit little-endian ELF")
        (self.entry, phoff, shoff) = struct.unpack_from("<III", d, 24)
        (phentsize, phnum, shentsize, shnum) = struct.unpack_from("<HHHH", d, 42)
        self.segments = []
        for i in range(phnum):
            (ptype, off, vaddr, _paddr, filesz, memsz) = struct.unpack_from("<IIIIII", d, phoff + i * phentsize)
            if ptype == 1 and memsz:
                self.segments.append((vaddr, d[off:off + filesz], memsz))
        secs = [struct.unpack_from("<IIIIIIIIII", d, shoff + i * shentsize) for i in range(shnum)]
        self.symbols = {}
        for s in secs:
            if s[1] != 2:  # SHT_SYMTAB
                continue
            strtab = secs[s[6]]
            for j in range(s[5] // 16):
                (name, value, size, info, _o, _sh) = struct.unpack_from("<IIIBBH", d, s[4] + j * 16)
                if info & 0xF != 2:  # STT_FUNC
                    continue
                o = strtab[4] + name
                n = d[o:d.index(b"\0", o)].decode("latin-1")
                self.symbols[n] = (value & ~1, size)

    def sym(self, name):
        if name not in self.symbols:
            raise SystemExit(f"symbol {name} missing from the harness ELF")
        return self.symbols[name][0]


class Target:
    def __init__(self, elf_path, m4):
        self.elf = Elf(elf_path)
        self.uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        self.uc.ctl_set_cpu_model(A.UC_CPU_ARM_CORTEX_M4 if m4 else A.UC_CPU_ARM_CORTEX_M0)
        self.uc.mem_map(FLASH, FLASH_LEN)
        self.uc.mem_map(RAM, RAM_LEN)
        for vaddr, blob, _memsz in self.elf.segments:
            self.uc.mem_write(vaddr, blob)
        self.init = self.elf.sym("bench_init")
        self.run_fn = self.elf.sym("bench_run")
        # Instructions inside the mock board are not the controller's: excluded.
        self.mock = sorted((a, a + n) for name, (a, n) in self.elf.symbols.items() if "Mock" in name and n)
        self.sizes = {}
        self.count = 0
        self.exclude_until = None
        self.counting = False
        # Counting one function only: its entry address, and the return address once inside.
        self.fn_entry = None
        self.fn_ret = None
        self.uc.hook_add(UC_HOOK_BLOCK, self._block)

    def function(self, part):
        """The one function symbol whose name contains `part` (its address)."""
        hits = [(n, a) for n, (a, size) in self.elf.symbols.items() if part in n and size]
        if len(hits) != 1:
            raise SystemExit(f"{len(hits)} function symbols contain {part!r}: {[h[0] for h in hits]}")
        return hits[0]

    def _insns(self, addr, size):
        key = (addr, size)
        n = self.sizes.get(key)
        if n is None:
            code = bytes(self.uc.mem_read(addr, size))
            n = i = 0
            while i < size:
                hw = code[i] | (code[i + 1] << 8) if i + 1 < size else 0
                i += 4 if (hw >> 11) in (0x1D, 0x1E, 0x1F) else 2
                n += 1
            self.sizes[key] = n
        return n

    def _block(self, uc, addr, size, _user):
        if not self.counting:
            return
        if self.fn_entry is not None:
            # Only the instructions of one call of the function (callees included).
            if self.fn_ret is None:
                if addr != self.fn_entry:
                    return
                self.fn_ret = uc.reg_read(A.UC_ARM_REG_LR) & ~1
            elif addr == self.fn_ret:
                self.fn_entry = None
                self.counting = False
                return
            self.count += self._insns(addr, size)
            return
        if self.exclude_until is not None:
            if addr != self.exclude_until:
                return
            self.exclude_until = None
        elif self.mock and any(lo <= addr < hi for lo, hi in self.mock):
            self.exclude_until = uc.reg_read(A.UC_ARM_REG_LR) & ~1
            return
        self.count += self._insns(addr, size)

    def call(self, fn, args=(), count=False, limit=400_000_000):
        uc = self.uc
        for r, v in zip((A.UC_ARM_REG_R0, A.UC_ARM_REG_R1, A.UC_ARM_REG_R2), args):
            uc.reg_write(r, v & 0xFFFF_FFFF)
        uc.reg_write(A.UC_ARM_REG_SP, STACK_TOP)
        uc.reg_write(A.UC_ARM_REG_LR, RET | 1)
        self.count, self.exclude_until, self.counting = 0, None, count
        try:
            uc.emu_start(fn | 1, RET, count=limit)
        except UcError as e:
            raise SystemExit(f"emulation failed at pc={uc.reg_read(A.UC_ARM_REG_PC):#x}: {e}")
        if uc.reg_read(A.UC_ARM_REG_PC) != RET:
            raise SystemExit(f"call did not return (panic or runaway) at pc={uc.reg_read(A.UC_ARM_REG_PC):#x}")
        self.counting = False
        r = uc.reg_read(A.UC_ARM_REG_R0)
        return r - (1 << 32) if r & 0x8000_0000 else r, self.count

    def run(self, op, values=(), kind="f64", count=False):
        if values:
            self.uc.mem_write(INP, b"".join(enc(v, kind) for v in values))
        code, n = self.call(self.run_fn, (op, INP, OUT), count)
        return code, n, bytes(self.uc.mem_read(OUT, 16))

    def run_function(self, op, entry):
        """Runs `op` and counts only the instructions of the call of the function at
        `entry` it makes (0 when it made none)."""
        self.uc.mem_write(OUT, b"\0" * 32)
        self.fn_entry, self.fn_ret = entry, None
        code, _ = self.call(self.run_fn, (op, INP, OUT), count=True)
        entered = self.fn_ret is not None
        self.fn_entry, self.fn_ret = None, None
        return code, (self.count if entered else 0), bytes(self.uc.mem_read(OUT, 32))


def linspace(a, b, n):
    return [a + (b - a) * i / (n - 1) for i in range(n)]


def measure(elf, m4, quick):
    t = Target(elf, m4)
    code, _ = t.call(t.init)
    if code != 0:
        raise SystemExit(f"bench_init failed with code {code}")
    _, overhead, _ = t.run(0, count=True)
    # Quasi-static contacts over the working range (f64 model in the emulator).
    nt, nk = (7, 7) if quick else (11, 11)
    points = []
    for ta_c in linspace(0.0, 1.5, nt):
        for kf in linspace(0.02, 0.97, nk):
            for dta in (0.2, 0.8):
                c, _, out = t.run(30, (ta_c, kf * L2, dta, 0.0), "f64")
                if c == 0:
                    th_c, th = struct.unpack("<dd", out)
                    points.append((th_c, ta_c, th, ta_c + dta))
    counted = points[:: max(1, len(points) // (6 if quick else 12))]
    res = {"overhead": overhead, "variants": {}}
    ref = {}
    for name, op, fop, kind in VARIANTS:
        outs = []
        for p in points:
            c, _, out = t.run(op, p, kind)
            outs.append((c, dec(out[:8], kind), dec(out[8:], kind)))
        if name == "f64":
            ref = outs
        counts = [t.run(op, p, kind, count=True)[1] - overhead for p in counted]
        fcounts = [t.run(fop, (p[0],), kind, count=True)[1] - overhead for p in counted]
        ek, ec, mism = [], [], 0
        for (c0, k0, kc0), (c1, k1, kc1) in zip(ref, outs):
            if c0 != c1:
                mism += 1
            elif c0 == 0:
                ek.append(abs(k1 - k0) / L2)
                ec.append(abs(kc1 - kc0) / abs(kc0))
        res["variants"][name] = {
            "estimate_max": max(counts),
            "estimate_mean": sum(counts) / len(counts),
            "free_max": max(fcounts),
            "points": len(points),
            "distal": len(ek),
            "mismatch": mism,
            "k2_max": max(ek) if ek else math.nan,
            "k2_rms": math.sqrt(sum(e * e for e in ek) / len(ek)) if ek else math.nan,
            "kc_max": max(ec) if ec else math.nan,
            "kc_rms": math.sqrt(sum(e * e for e in ec) / len(ec)) if ec else math.nan,
        }
    # The control task as the firmware runs it: grasp's ControlLoop::tick (loop_tick_dyn, the
    # sampling task, every tick) and Supervisor::service (supervise_dyn, the state machine in
    # the task below it, counted apart), on the mock board from power-up to holding.
    t.run(42)
    ticks, steps, state, served = [], [], 0, 0
    # A grasp from power-up to holding is ≈ 32,000 ticks. --quick (the budget check) runs it
    # whole on the Cortex-M4 (where the budget is) and only its first 3,000 ticks on the M0.
    for _ in range(3_000 if (quick and not m4) else 60_000):
        ready, n, _ = t.run(40, count=True)
        ticks.append(n - overhead)
        code, n, _ = t.run(44, count=True)
        if ready:
            steps.append(n - overhead)
        state = code >> 1
        if code & 1:
            served += t.run(41)[0]
        if STATES[min(state, 10)] in ("Holding", "Done", "Fault"):
            break
    ticks_sorted = sorted(ticks)
    steps_sorted = sorted(steps) or [0]
    res["tick"] = {
        "max": ticks_sorted[-1],
        "median": ticks_sorted[len(ticks) // 2],
        "mean": sum(ticks) / len(ticks),
        "n": len(ticks),
        "step_max": steps_sorted[-1],
        "step_median": steps_sorted[len(steps_sorted) // 2],
        "steps": len(steps),
        "final_state": STATES[min(state, 10)],
        "estimates_served": served,
    }
    return res


# The firmware's estimate entries (grasp::estimate), counted on the request cases: (label,
# op, symbol part, budget, guard in instructions, host result key in the case file). A count
# above the budget but within the guard is printed as NOT MET; above the guard it fails. Both
# are hard gates (guard = budget) on every request, the unseated controller's included.
ENTRIES = [
    ("two-point estimate task (grasp::estimate::two_point_fw)", 51, "5grasp8estimate12two_point_fw", 5_000,
     5_000, "host_two_point"),
    ("path-fit estimate task (grasp::estimate::path_fit_fw)", 52, "5grasp8estimate11path_fit_fw", 100_000,
     100_000, "host_path_fit"),
]

def load_case(path):
    """A request case (tests/estimate_cases.rs writes them): the input words for op 50 and
    the host's results by key."""
    params, fixed, pre, path_s, host = None, {}, [], [], {}
    with open(path) as f:
        for line in f:
            w = line.split()
            if not w or w[0].startswith("#"):
                continue
            if w[0] == "params":
                params = [int(x) for x in w[1:6]]
            elif w[0] in ("contact", "seat", "seat2", "end"):
                fixed[w[0]] = [int(x) for x in w[1:5]]
            elif w[0] == "pre":
                pre.append([int(x) for x in w[1:5]])
            elif w[0] == "path":
                path_s.append([int(x) for x in w[1:5]])
            else:
                host[w[0]] = w[1:]
    words = params + [len(pre), len(path_s)]
    for k in ("contact", "seat", "seat2", "end"):
        words += fixed[k]
    for smp in pre + path_s:
        words += smp
    return struct.pack(f"<{len(words)}i", *words), host


def decode_result(code, out):
    if code == 0:
        v = struct.unpack("<5i", out[:20])
        return ["ok"] + [str(x) for x in v]
    return ["err", out.split(b"\0")[0].decode("latin-1")]


def measure_requests(elf, cases):
    """Counts the firmware's estimate entries on thumbv7em on each request case and
    compares each result with the host's (the same function on the host: bit for bit)."""
    t = Target(elf, True)
    code, _ = t.call(t.init)
    if code != 0:
        raise SystemExit(f"bench_init failed with code {code}")
    rows = []
    for label, op, part, budget, guard, key in ENTRIES:
        name, entry = t.function(part)
        for c in cases:
            words, host = load_case(c)
            t.uc.mem_write(INP, words)
            lc, _, _ = t.run(50)
            if lc != 0:
                raise SystemExit(f"{c}: the harness refused the request (code {lc})")
            rc, n, out = t.run_function(op, entry)
            got = decode_result(rc, out)
            rows.append({"entry": label, "symbol": name, "case": os.path.basename(c), "instructions": n,
                         "budget": budget, "guard": guard, "target": got,
                         "host": host.get(key)})
    return rows


def criterion_median_ns(crit_dir, name):
    p = os.path.join(crit_dir, "estimate", name.replace("+", "_"), "new", "estimates.json")
    try:
        with open(p) as f:
            return json.load(f)["median"]["point_estimate"]
    except (OSError, KeyError, ValueError):
        return None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--v7em", required=True)
    ap.add_argument("--v6m", required=True)
    ap.add_argument("--criterion", help="criterion output dir (target/criterion)")
    ap.add_argument("--check", action="store_true", help="check the firmware variant's budgets")
    ap.add_argument("--firmware-v7em", default="table+Fx32",
                    help="the firmware's variant on thumbv7em-none-eabihf (table + FirmwareReal = Fx32)")
    ap.add_argument("--firmware-v6m", default="table+Fx32",
                    help="the firmware's variant on thumbv6m-none-eabi (table + FirmwareReal = Fx32)")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--requests", nargs="*", default=[], help="request cases (*.req) for the estimate entries")
    ap.add_argument("--json", help="write the raw results here")
    a = ap.parse_args()

    r7 = measure(a.v7em, True, a.quick)
    r6 = measure(a.v6m, False, a.quick)
    req_rows = measure_requests(a.v7em, a.requests) if a.requests else []
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"thumbv7em": r7, "thumbv6m": r6, "estimate_entries": req_rows}, f, indent=1)
    if req_rows:
        print("The firmware's estimate entries on thumbv7em-none-eabihf (the functions the estimate task")
        print("calls, counted from entry to return on the committed request cases):\n")
        print("| entry | case | instructions | budget | target result | = host |")
        print("|---|---|---|---|---|---|")
        for r in req_rows:
            same = r["target"] == r["host"]
            print(f"| {r['entry']} | {r['case']} | {r['instructions']:,} | {r['budget']:,} "
                  f"| {' '.join(r['target'])} | {'yes' if same else 'NO: host ' + ' '.join(r['host'] or ['missing'])} |")
        print()

    print("Instructions per call, counted in the compiled target code under unicorn (block hook,")
    print("dispatch overhead subtracted); error against the f64 variant over "
          f"{r7['variants']['f64']['points']} quasi-static contacts")
    print("(T_a,c 0..1.5 N·m, k2 0.02..0.97 l2, ΔT_a 0.2 and 0.8 N·m).\n")
    hdr = ("| variant | estimate v7em max (mean) | estimate v6m max (mean) | free-motion cfg v7em / v6m "
           "| host ns/estimate (median) | k2 err max / RMS (% l2) | K̂c rel err max / RMS | class mismatches |")
    print(hdr)
    print("|" + "---|" * 8)
    for name, *_ in VARIANTS:
        v7, v6 = r7["variants"][name], r6["variants"][name]
        ns = criterion_median_ns(a.criterion, name) if a.criterion else None
        print(f"| {name} | {v7['estimate_max']:,} ({v7['estimate_mean']:,.0f}) "
              f"| {v6['estimate_max']:,} ({v6['estimate_mean']:,.0f}) "
              f"| {v7['free_max']:,} / {v6['free_max']:,} "
              f"| {'%.0f' % ns if ns else 'n/a'} "
              f"| {100 * v7['k2_max']:.2e} / {100 * v7['k2_rms']:.2e} "
              f"| {v7['kc_max']:.1e} / {v7['kc_rms']:.1e} | {v7['mismatch']}/{v7['points']} |")
    for tgt, r in (("thumbv7em-none-eabihf", r7), ("thumbv6m-none-eabi", r6)):
        k = r["tick"]
        print(f"\nper-sample work (grasp ControlLoop::tick via loop_tick_dyn: the sampling task, mock "
              f"board excluded), {tgt}: max {k['max']}, median {k['median']}, mean {k['mean']:.0f} "
              f"instructions over {k['n']} ticks (power-up to {k['final_state']}, "
              f"{k['estimates_served']} estimate served)")
        print(f"  state-machine step (Supervisor::service via supervise_dyn, once per sample, task "
              f"below the loop): max {k['step_max']}, median {k['step_median']} over {k['steps']} samples")
        if k["final_state"] == "Fault" or k["estimates_served"] == 0 and k["n"] >= 30_000:
            print("  (the mock grasp did not complete: the tick count covers only part of a grasp)")

    if a.check:
        fw7, fw6 = r7["variants"][a.firmware_v7em], r6["variants"][a.firmware_v6m]
        # Issue 6's budgets: (name, measured, budget, guard); CI fails above the guard. The
        # estimate budgets are met and are hard gates (guard = budget); a budget not met yet
        # is printed as such and guarded against regression near the measured value.
        # Accuracy and classification are hard gates.
        budgets = [
            ("estimate on thumbv7em", fw7["estimate_max"], 2000, 2000),
            ("estimate on thumbv6m", fw6["estimate_max"], 8000, 8000),
            # Built with the firmware's profile (opt-level "s"); the worst tick is a
            # sample-ready one (the interval's sums into the link).
            ("ControlLoop::tick (sampling task) max on thumbv7em", r7["tick"]["max"], 400, 400),
        ]
        fails = []
        print()
        for name, got, budget, guard in budgets:
            if got <= budget:
                print(f"budget met:     {name} {got:,} <= {budget:,}")
            else:
                gate = "hard gate" if guard <= budget else "regression guard"
                print(f"budget NOT MET: {name} {got:,} > {budget:,} (issue 6; {gate} {guard:,})")
                if got > guard:
                    fails.append(f"{name} {got:,} > {gate} {guard:,}")
        for r in req_rows:
            if r["instructions"] == 0:
                fails.append(f"{r['entry']} on {r['case']}: the function was not called")
            elif r["instructions"] > r["guard"]:
                fails.append(f"{r['entry']} on {r['case']}: {r['instructions']:,} > guard {r['guard']:,}")
            elif r["instructions"] > r["budget"]:
                print(f"budget NOT MET: {r['entry']} on {r['case']}: {r['instructions']:,} > {r['budget']:,} "
                      f"(regression guard {r['guard']:,})")
            if r["target"] != r["host"]:
                fails.append(f"{r['entry']} on {r['case']}: target {r['target']} != host {r['host']}")
        if not req_rows:
            fails.append("no request cases: the estimate entries were not measured")
        for label, _op, _part, budget, _guard, _key in ENTRIES:
            counts = [r["instructions"] for r in req_rows if r["entry"] == label]
            if counts:
                print(f"estimate entry: {label} max {max(counts):,} instructions over {len(counts)} "
                      f"requests (budget {budget:,})")
        if not fw7["k2_max"] <= 1e-4:
            fails.append(f"{a.firmware_v7em} k2 error {fw7['k2_max']:.2e}·l2 > 1e-4·l2")
        if not r7["variants"][a.firmware_v6m]["k2_max"] <= 1e-4:
            fails.append(f"{a.firmware_v6m} k2 error > 1e-4·l2")
        if fw7["mismatch"]:
            fails.append(f"{a.firmware_v7em} classifies {fw7['mismatch']} contacts unlike f64")
        if fw7["distal"] < fw7["points"] // 2:
            fails.append(f"only {fw7['distal']} of {fw7['points']} contacts located: grid broken")
        print(f"accuracy: {a.firmware_v7em} k2 error {fw7['k2_max']:.1e}·l2 (<= 1e-4)")
        for f in fails:
            print("CHECK FAIL:", f)
        print(f"{len(fails)} check(s) failed" if fails else "accuracy gates and regression guards pass")
        sys.exit(1 if fails else 0)

if __name__ == "__main__":
    main()
