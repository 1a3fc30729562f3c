"""Runs the plant-target-cost image in unicorn (Cortex-M4) and prints instructions per step."""
import struct, sys
from unicorn import *
from unicorn.arm_const import *

data = open(sys.argv[1], 'rb').read()
# ELF32 little-endian: program headers
e_entry, e_phoff = struct.unpack_from('<II', data, 0x18)
e_phentsize, e_phnum = struct.unpack_from('<HH', data, 0x2A)
mu = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
try:
    mu.ctl_set_cpu_model(UC_CPU_ARM_CORTEX_M4)
except Exception as ex:
    print("cpu model:", ex)
mu.mem_map(0x0, 0x100000)
mu.mem_map(0x20000000, 0x40000)
mu.mem_map(0xE0000000, 0x100000)
for i in range(e_phnum):
    p_type, p_offset, p_vaddr, p_paddr, p_filesz, p_memsz = struct.unpack_from('<IIIIII', data, e_phoff + i * e_phentsize)
    if p_type == 1 and p_filesz:
        mu.mem_write(p_paddr, data[p_offset:p_offset + p_filesz])
mu.reg_write(UC_ARM_REG_SP, 0x2002F000)
count = [0]
marks = []
def hook_code(uc, addr, size, ud):
    count[0] += 1
def hook_mem(uc, access, addr, size, value, ud):
    if addr == 0x20030000:
        marks.append((value, count[0]))
        if value in (4, 0xDEAD, 0xBAD):
            uc.emu_stop()
mu.hook_add(UC_HOOK_CODE, hook_code)
mu.hook_add(UC_HOOK_MEM_WRITE, hook_mem, begin=0x20030000, end=0x20030003)
try:
    mu.emu_start(e_entry | 1, 0xFFFFFFF0, count=400_000_000)
except UcError as ex:
    print("stopped:", ex, hex(mu.reg_read(UC_ARM_REG_PC)))
print("marks:", len(marks), "last", marks[-1] if marks else None)
vals = [m for m in marks]
new = [c for v, c in vals if v == 2]
one = [c for v, c in vals if v == 1]
if one and new:
    print("Plant::new: %d instructions" % (new[0] - one[0]))
steps = [(v, c) for v, c in vals if v >= 100 and v < 200]
prev = new[0] if new else 0
per = {}
for v, c in steps:
    per.setdefault(v - 100, []).append(c - prev)
    prev = c
names = {0: 'free', 1: 'proximal', 2: 'distal', 3: 'limit', 4: 'locked'}
for k, l in per.items():
    l2 = sorted(l)
    print("%-8s steps %4d  median %7d  max %8d instructions/step" % (names.get(k, k), len(l), l2[len(l2)//2], l2[-1]))

m = dict((v, c) for v, c in vals if v in (10, 11, 12, 13))
print("linkage: %d instr/call; drive.advance (default substeps): %d instr/call; adc+normal: %d instr/sample" % ((m[11]-m[10])/100, (m[12]-m[11])/100, (m[13]-m[12])/100))
