"""Per-function instruction profile of one harness entry on one case (see emu.py).
Usage: prof.py ELF CASE [ENTRY]."""
import sys, collections, bisect
from emu import Elf, run

elf = Elf(sys.argv[1])
starts = [f[0] for f in elf.funcs]
hist = collections.Counter()


def hook(uc, addr, size, user):
    i = bisect.bisect_right(starts, addr) - 1
    f = elf.funcs[i] if i >= 0 else None
    hist[f[2] if f and addr < f[0] + f[1] else '?'] += 1


run(elf, sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else 'run', hook)
tot = sum(hist.values())
for name, c in hist.most_common(25):
    print(f"{c:9d} {100*c/tot:5.1f}% {name[:150]}")
