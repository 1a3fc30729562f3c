# Per-function instruction profile of one case: prof.py ELF CASE ENTRY (run from this directory).
import subprocess, sys, collections, bisect
exec(open('count.py').read().split("uc.hook_add")[0])
funcs = []
for line in subprocess.check_output(['nm', '-S', '--demangle', elf_path]).decode().splitlines():
    parts = line.split(None, 3)
    if len(parts) == 4 and parts[2] in 'tT':
        funcs.append((int(parts[0], 16) & ~1, int(parts[1], 16), parts[3]))
funcs.sort()
starts = [f[0] for f in funcs]
hist = collections.Counter()
def hook2(uc, addr, size, user):
    i = bisect.bisect_right(starts, addr) - 1
    hist[funcs[i][2] if i >= 0 and addr < funcs[i][0] + funcs[i][1] else '?'] += 1
uc.reg_write(UC_ARM_REG_SP, STACK_TOP)
uc.reg_write(UC_ARM_REG_LR, SENTINEL | 1)
uc.hook_add(UC_HOOK_CODE, hook2)
entry = syms[sys.argv[3] if len(sys.argv) > 3 else "run"][0]
uc.emu_start(entry | 1, SENTINEL, count=50_000_000)
tot = sum(hist.values())
for name, c in hist.most_common(25):
    print(f"{c:9d} {100*c/tot:5.1f}% {name[:150]}")
