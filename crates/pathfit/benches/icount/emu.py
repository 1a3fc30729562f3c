"""Runs one entry of the pathfit-icount harness (src/main.rs) on a case under unicorn (thumbv7em)
and counts every executed instruction: the one loader behind count.py, summary.py, prof.py and
callers.py. A case file is `θa,c T_a,c` then `t θa T_a` per sample (SI); the harness gets it as
Fx32 bits (INPUT), f32 (INPUT_F32) and the controller's integers (INPUT_RAW: tick of 100 µs, µrad,
µN·m). Entries: `run` = generic fit on Fx32, `run_f32` = generic fit on the FPU, `run_q` = the
firmware's integer fit (`pathfit::q`; its table is built by `init_q` first, not counted)."""
import struct, subprocess
from unicorn import Uc, UC_ARCH_ARM, UC_MODE_THUMB, UC_MODE_MCLASS, UC_HOOK_CODE
from unicorn.arm_const import UC_ARM_REG_SP, UC_ARM_REG_LR, UC_ARM_REG_R0

RAM, RAMSZ = 0x20000000, 8 << 20
STACK_TOP, SENTINEL = RAM + RAMSZ - 16, 0x20700000
TICK_S = 1e-4
ENTRIES = (('run_f32', 'f32 (FPU)'), ('run', 'Fx32 generic'), ('run_q', 'integer (firmware)'))


class Elf:
    def __init__(self, path):
        data = open(path, 'rb').read()
        e_phoff, = struct.unpack_from('<I', data, 28)
        e_phentsize, e_phnum = struct.unpack_from('<HH', data, 42)
        self.syms, self.funcs = {}, []
        for line in subprocess.check_output(['nm', '-S', '--demangle', path]).decode().splitlines():
            parts = line.split(None, 3)
            if len(parts) == 4:
                self.syms[parts[3]] = int(parts[0], 16)
                if parts[2] in 'tT':
                    self.funcs.append((int(parts[0], 16) & ~1, int(parts[1], 16), parts[3]))
            elif len(parts) == 3:
                self.syms[parts[2]] = int(parts[0], 16)
        self.funcs.sort()
        self.segments = []
        for i in range(e_phnum):
            p_type, p_offset, p_vaddr, _, p_filesz, p_memsz = struct.unpack_from(
                '<IIIIII', data, e_phoff + i * e_phentsize)
            if p_type == 1 and p_memsz:
                self.segments.append((p_vaddr, data[p_offset:p_offset + p_filesz] + b'\0' * (p_memsz - p_filesz)))


def read_case(path):
    lines = [l for l in open(path).read().split('\n') if l.strip()]
    head = [float(x) for x in lines[0].split()]
    rows = [[float(x) for x in l.split()] for l in lines[1:]][:256]
    return head, rows


def run(elf, case, entry, hook=None):
    """Status (r0), instructions, peak stack (bytes) and OUT (k2 bits, σ bits, error, evals)."""
    uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
    uc.mem_map(RAM, RAMSZ)
    for addr, blob in elf.segments:
        uc.mem_write(addr, blob)
    head, rows = read_case(case)
    flat = head + [x for r in rows for x in r]
    uc.mem_write(elf.syms['INPUT'], struct.pack('<%dq' % len(flat), *[int(round(v * 2**32)) for v in flat]))
    uc.mem_write(elf.syms['INPUT_F32'], struct.pack('<%df' % len(flat), *flat))
    raw = [v for r in rows for v in (int(round(r[0] / TICK_S)), int(round(r[1] * 1e6)), int(round(r[2] * 1e6)))]
    uc.mem_write(elf.syms['INPUT_RAW'], struct.pack('<%di' % len(raw), *raw))
    uc.mem_write(elf.syms['N'], struct.pack('<I', len(rows)))
    uc.mem_write(SENTINEL, b'\x00\xbf\x00\xbf')  # nop; nop

    def call(name):
        uc.reg_write(UC_ARM_REG_SP, STACK_TOP)
        uc.reg_write(UC_ARM_REG_LR, SENTINEL | 1)
        uc.emu_start(elf.syms[name] | 1, SENTINEL, count=200_000_000)
    if entry == 'run_q':
        call('init_q')
    n = [0, STACK_TOP]

    def count(uc, addr, size, user):
        n[0] += 1
        sp = uc.reg_read(UC_ARM_REG_SP)
        if sp < n[1]:
            n[1] = sp
    uc.hook_add(UC_HOOK_CODE, hook or count)
    call(entry)
    out = struct.unpack('<4q', uc.mem_read(elf.syms['OUT'], 32))
    return uc.reg_read(UC_ARM_REG_R0), n[0], STACK_TOP - n[1], out, len(rows)
