#!/bin/sh
# Instruction count and peak stack of pathfit::fit_path on thumbv7em (Cortex-M4F) under
# unicorn, for every case file: f32 on the FPU (`run_f32`) and Fx32 (`run`).
# Usage: crates/pathfit/benches/icount/count.sh [case files...]        one line per case and entry
#        crates/pathfit/benches/icount/count.sh --summary case files...  min / median / max
# (needs python3 + unicorn: `cargo xtask bench` installs it). Builds into target/bench-pathfit.
# Case files of the whole grid, one per request: mkdir d && PATHFIT_DUMP=d cargo test --release
# --test pathfit_grid -- pathfit_grid_on_the_plant (files d/ideal_* and d/realistic_*).
set -e
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../../.." && pwd)
# Its own link script has no MEMORY.RAM: the firmware's flip-link (.cargo/config.toml) does
# not apply to it.
CARGO_TARGET_DIR="$root/target/bench-pathfit" RUSTFLAGS="" \
    CARGO_TARGET_THUMBV7EM_NONE_EABIHF_LINKER=rust-lld \
    cargo build --quiet --release --target thumbv7em-none-eabihf --manifest-path "$here/Cargo.toml"
elf="$root/target/bench-pathfit/thumbv7em-none-eabihf/release/pathfit-icount"
if [ "$1" = "--summary" ]; then
    shift
    exec python3 "$here/summary.py" "$elf" "$@"
fi
[ $# -gt 0 ] || set -- "$here"/cases/*.txt
for c in "$@"; do
    for entry in run_f32 run run_q; do
        printf '%s %s: ' "$(basename "$c")" "$entry"
        python3 "$here/count.py" "$elf" "$c" "$entry" | tr '\n' ' '
        echo
    done
done
