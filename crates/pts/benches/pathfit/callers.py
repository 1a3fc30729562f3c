# Who calls the named functions: callers.py ELF CASE ENTRY name1,name2 (run from this directory).
import subprocess, sys, collections, bisect
exec(open('count.py').read().split("uc.hook_add")[0])
funcs = []
for line in subprocess.check_output(['nm', '-S', '--demangle', elf_path]).decode().splitlines():
    parts = line.split(None, 3)
    if len(parts) == 4 and parts[2] in 'tT':
        funcs.append((int(parts[0], 16) & ~1, int(parts[1], 16), parts[3]))
funcs.sort()
starts = [f[0] for f in funcs]
def name(addr):
    i = bisect.bisect_right(starts, addr) - 1
    return funcs[i][2] if i >= 0 else '?'
targets = {f[0]: f[2] for f in funcs if any(k in f[2] for k in sys.argv[4].split(','))}
hist = collections.Counter()
def hook2(uc, addr, size, user):
    if addr in targets:
        lr = uc.reg_read(UC_ARM_REG_LR) & ~1
        hist[(targets[addr][:40], name(lr)[:100], hex(lr))] += 1
entry = syms[sys.argv[3]][0]
uc.reg_write(UC_ARM_REG_SP, STACK_TOP)
uc.reg_write(UC_ARM_REG_LR, SENTINEL | 1)
uc.hook_add(UC_HOOK_CODE, hook2)
uc.emu_start(entry | 1, SENTINEL, count=50_000_000)
for k, c in hist.most_common(15):
    print(c, k)
