"""Counts the thumbv7em instructions of one pts::pathfit::fit_path call (harness `src/main.rs`)
with unicorn: loads the ELF's PT_LOAD segments, writes the case into INPUT/INPUT_F32/N, runs the
entry (`run` = Fx32, `run_f32` = f32 on the FPU) to a sentinel return address and counts every
executed instruction; also reports the peak stack. Usage: count.py ELF CASE [ENTRY]."""
import struct, subprocess, sys
from unicorn import Uc, UC_ARCH_ARM, UC_MODE_THUMB, UC_MODE_MCLASS, UC_HOOK_CODE
from unicorn.arm_const import UC_ARM_REG_SP, UC_ARM_REG_LR, UC_ARM_REG_R0, UC_ARM_REG_PC

elf_path = sys.argv[1]
case = sys.argv[2]
data = open(elf_path, 'rb').read()
e_phoff, = struct.unpack_from('<I', data, 28)
e_phentsize, e_phnum = struct.unpack_from('<HH', data, 42)
syms = {}
for line in subprocess.check_output(['nm', '-S', elf_path]).decode().splitlines():
    parts = line.split()
    if len(parts) >= 3:
        syms[parts[-1]] = (int(parts[0], 16), int(parts[1], 16) if len(parts) == 4 else 0)

uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
RAM, RAMSZ = 0x20000000, 8 << 20
uc.mem_map(RAM, RAMSZ)
for i in range(e_phnum):
    p_type, p_offset, p_vaddr, p_paddr, p_filesz, p_memsz = struct.unpack_from('<IIIIII', data, e_phoff + i * e_phentsize)
    if p_type == 1 and p_memsz:
        uc.mem_write(p_vaddr, data[p_offset:p_offset + p_filesz] + b'\0' * (p_memsz - p_filesz))

def fx(v):
    return int(round(float(v) * (1 << 32)))
lines = open(case).read().split('\n')
th_c, ta_c = lines[0].split()
vals = [fx(th_c), fx(ta_c)]
n = 0
for l in lines[1:]:
    if l.strip():
        vals += [fx(x) for x in l.split()]
        n += 1
uc.mem_write(syms['INPUT'][0], struct.pack('<%dq' % len(vals), *vals))
uc.mem_write(syms['N'][0], struct.pack('<I', n))
fl = [float(th_c), float(ta_c)] + [float(x) for l in lines[1:] if l.strip() for x in l.split()]
uc.mem_write(syms['INPUT_F32'][0], struct.pack('<%df' % len(fl), *fl))

STACK_TOP = RAM + RAMSZ - 16
SENTINEL = 0x20700000
uc.mem_write(SENTINEL, b'\x00\xbf\x00\xbf')  # nop; nop
uc.reg_write(UC_ARM_REG_SP, STACK_TOP)
uc.reg_write(UC_ARM_REG_LR, SENTINEL | 1)
count = [0]
min_sp = [STACK_TOP]
def hook(uc, addr, size, user):
    count[0] += 1
    sp = uc.reg_read(UC_ARM_REG_SP)
    if sp < min_sp[0]:
        min_sp[0] = sp
uc.hook_add(UC_HOOK_CODE, hook)
entry = syms[sys.argv[3] if len(sys.argv) > 3 else 'run'][0]
uc.emu_start(entry | 1, SENTINEL, count=50_000_000)
r0 = uc.reg_read(UC_ARM_REG_R0)
out = struct.unpack('<4q', uc.mem_read(syms['OUT'][0], 32))
print(f"samples {n}: status {r0}, k2 {out[0] / 2**32:.6f} m, sigma {out[1] / 2**32:.6f} m, path evals {out[3]}")
print(f"instructions {count[0]}, peak stack {STACK_TOP - min_sp[0]} bytes")
