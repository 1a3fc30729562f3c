"""Issue 7's budget gate (`cargo xtask bench`, part of `cargo xtask test`): the firmware's integer
path fit (`run_q`) on every committed case (cases/*.txt: closed-loop requests of the realistic plant,
the slowest of the grid among them) must fit within BUDGET instructions on thumbv7em and land,
on the same target, within half its σ of the generic fit on the FPU (`run_f32`). A case named
refused_*.txt must be refused, by both back ends for the same reason, also within BUDGET (a
refusal is the most expensive path: it runs to the evaluation budget).
Usage: check.py ELF CASE... (see emu.py)."""
import os, sys
from emu import Elf, run

BUDGET = 100_000
elf, cases = Elf(sys.argv[1]), sys.argv[2:]
failed = 0
for c in cases:
    sq, nq, stack, oq, rows = run(elf, c, 'run_q')
    sf, _, _, of, _ = run(elf, c, 'run_f32')
    name = os.path.basename(c)
    if name.startswith('refused_'):
        ok = sq != 0 and sq == sf and nq <= BUDGET
        failed += not ok
        print(f"path fit {name} ({rows} samples): integer refused (status {sq}, FPU generic "
              f"{sf}) after {nq:,} instructions (budget {BUDGET:,}), stack {stack} B: "
              f"{'ok' if ok else 'FAILED'}")
        continue
    k2q, sig, k2f = oq[0] / 2**32, oq[1] / 2**32, of[0] / 2**32
    ok = sq == 0 and sf == 0 and nq <= BUDGET and abs(k2q - k2f) <= 0.5 * sig
    failed += not ok
    print(f"path fit {name} ({rows} samples): integer {nq:,} instructions "
          f"(budget {BUDGET:,}), stack {stack} B, k2 {k2q * 1e3:.3f} mm, FPU generic "
          f"{k2f * 1e3:.3f} mm, σ {sig * 1e3:.3f} mm: {'ok' if ok else 'FAILED'}")
sys.exit(1 if failed else 0)
