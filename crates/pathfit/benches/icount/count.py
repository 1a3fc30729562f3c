"""Instruction count and peak stack of one harness entry on one case (see emu.py).
Usage: count.py ELF CASE [ENTRY]."""
import sys
from emu import Elf, run

status, n, stack, out, rows = run(Elf(sys.argv[1]), sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else 'run')
print(f"samples {rows}: status {status}, k2 {out[0] / 2**32:.6f} m, sigma {out[1] / 2**32:.6f} m, path evals {out[3]}")
print(f"instructions {n}, peak stack {stack} bytes")
