"""Who calls the named functions: callers.py ELF CASE ENTRY name1,name2 (see emu.py)."""
import sys, collections, bisect
from unicorn.arm_const import UC_ARM_REG_LR
from emu import Elf, run

elf = Elf(sys.argv[1])
starts = [f[0] for f in elf.funcs]


def name(addr):
    i = bisect.bisect_right(starts, addr) - 1
    return elf.funcs[i][2] if i >= 0 else '?'


targets = {f[0]: f[2] for f in elf.funcs if any(k in f[2] for k in sys.argv[4].split(','))}
hist = collections.Counter()


def hook(uc, addr, size, user):
    if addr in targets:
        lr = uc.reg_read(UC_ARM_REG_LR) & ~1
        hist[(targets[addr][:40], name(lr)[:100], hex(lr))] += 1


run(elf, sys.argv[2], sys.argv[3], hook)
for k, c in hist.most_common(15):
    print(c, k)
