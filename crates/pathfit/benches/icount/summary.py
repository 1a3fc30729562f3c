"""Instruction counts of every harness entry over many case files: min / median / max over the
successful fits and how many stay within the issue-7 budget (see emu.py).
Usage: summary.py ELF CASE... (`count.sh --summary CASE...` runs it)."""
import sys, statistics
from emu import Elf, run, ENTRIES

BUDGET = 100_000
elf, cases = Elf(sys.argv[1]), sys.argv[2:]
for entry, label in ENTRIES:
    ok, refused, over, stack, refused_max = [], 0, [], 0, 0
    for i, c in enumerate(cases):
        status, count, peak, out, _ = run(elf, c, entry)
        stack = max(stack, peak)
        if status == 0:
            ok.append(count)
            if count > BUDGET:
                over.append(out[3])
        else:
            refused += 1
            refused_max = max(refused_max, count)
        print(f"\r{label}: {i + 1}/{len(cases)}", end='', file=sys.stderr, flush=True)
    print(file=sys.stderr)
    if ok:
        within = sum(1 for x in ok if x <= BUDGET)
        print(f"{label}: {len(ok)} fits ({refused} refused, at most {refused_max:,}): instructions "
              f"min {min(ok):,} / median {int(statistics.median(ok)):,} / max {max(ok):,}; "
              f"within {BUDGET:,}: {within}/{len(ok)}; peak stack {stack} B"
              + (f" (path evaluations of the others: {min(over)}–{max(over)})" if over else ""))
