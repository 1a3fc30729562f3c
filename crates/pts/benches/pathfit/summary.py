"""Instruction counts of pts::pathfit::fit_path over many case files (the ELF parsed
once, a fresh emulator per run): min / median / max over the successful fits and how many stay within
the issue-7 budget. Usage: summary.py ELF CASE... (`count.sh --summary CASE...` runs it)."""
import struct, subprocess, sys, statistics
from unicorn import Uc, UC_ARCH_ARM, UC_MODE_THUMB, UC_MODE_MCLASS, UC_HOOK_CODE
from unicorn.arm_const import UC_ARM_REG_SP, UC_ARM_REG_LR, UC_ARM_REG_R0

BUDGET = 100_000
elf_path, cases = sys.argv[1], sys.argv[2:]
data = open(elf_path, 'rb').read()
e_phoff, = struct.unpack_from('<I', data, 28)
e_phentsize, e_phnum = struct.unpack_from('<HH', data, 42)
syms = {}
for line in subprocess.check_output(['nm', '-S', elf_path]).decode().splitlines():
    parts = line.split()
    if len(parts) >= 3:
        syms[parts[-1]] = int(parts[0], 16)
RAM, RAMSZ = 0x20000000, 8 << 20
STACK_TOP, SENTINEL = RAM + RAMSZ - 16, 0x20700000
segments = []
for i in range(e_phnum):
    p_type, p_offset, p_vaddr, _, p_filesz, p_memsz = struct.unpack_from('<IIIIII', data, e_phoff + i * e_phentsize)
    if p_type == 1 and p_memsz:
        segments.append((p_vaddr, data[p_offset:p_offset + p_filesz] + b'\0' * (p_memsz - p_filesz)))

def run(entry, case):
    uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
    uc.mem_map(RAM, RAMSZ)
    for addr, blob in segments:
        uc.mem_write(addr, blob)
    lines = [l for l in open(case).read().split('\n') if l.strip()]
    head = [float(x) for x in lines[0].split()]
    rows = [[float(x) for x in l.split()] for l in lines[1:]][:256]
    flat = head + [x for r in rows for x in r]
    uc.mem_write(syms['INPUT'], struct.pack('<%dq' % len(flat), *[int(round(v * 2**32)) for v in flat]))
    uc.mem_write(syms['INPUT_F32'], struct.pack('<%df' % len(flat), *flat))
    uc.mem_write(syms['N'], struct.pack('<I', len(rows)))
    uc.mem_write(SENTINEL, b'\x00\xbf\x00\xbf')
    uc.reg_write(UC_ARM_REG_SP, STACK_TOP)
    uc.reg_write(UC_ARM_REG_LR, SENTINEL | 1)
    n = [0, STACK_TOP]
    def hook(uc, addr, size, user):
        n[0] += 1
    uc.hook_add(UC_HOOK_CODE, hook)
    uc.emu_start(syms[entry] | 1, SENTINEL, count=50_000_000)
    evals = struct.unpack('<4q', uc.mem_read(syms['OUT'], 32))[3]
    return uc.reg_read(UC_ARM_REG_R0), n[0], evals

for entry, label in (('run_f32', 'f32 (FPU)'), ('run', 'Fx32')):
    ok, refused, over = [], 0, []
    for i, c in enumerate(cases):
        status, count, evals = run(entry, c)
        if status == 0:
            ok.append(count)
            if count > BUDGET:
                over.append(evals)
        else:
            refused += 1
        print(f"\r{label}: {i + 1}/{len(cases)}", end='', file=sys.stderr, flush=True)
    print(file=sys.stderr)
    if ok:
        within = sum(1 for x in ok if x <= BUDGET)
        print(f"{label}: {len(ok)} fits ({refused} refused): instructions min {min(ok):,} / median "
              f"{int(statistics.median(ok)):,} / max {max(ok):,}; within {BUDGET:,}: {within}/{len(ok)}"
              + (f" (path evaluations of the others: {min(over)}–{max(over)})" if over else ""))
