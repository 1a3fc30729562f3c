#!/usr/bin/env bash
# Instructions per plant step on the firmware ISA (needs python3 + unicorn: pip install unicorn).
set -euo pipefail
cd "$(dirname "$0")"
RUSTFLAGS="-C link-arg=-T$(pwd)/link.ld -C link-arg=--nmagic" \
  cargo build -q --release --target thumbv7em-none-eabihf
python3 count.py target/thumbv7em-none-eabihf/release/plant-target-cost
