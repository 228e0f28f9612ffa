#!/usr/bin/env bash
# Link proof that mag-cal-core's public API has no reachable panic
# (see src/main.rs and docs/robustness.md). Exit 0 only when:
#   1. the baseline (the harness without any mag-cal-core call) links;
#   2. the canary build (the baseline plus one deliberate, opaque out-of-bounds
#      index) FAILS to link with "undefined symbol:
#      mag_cal_core_has_a_reachable_panic": the check sees a panic that
#      survives optimisation; and
#   3. the real build (every public entry point, on opaque input) LINKS, i.e.
#      no panic call survives the firmware's opt-level "s" with fat LTO.
# When 3 fails, the same code is linked again with the symbol defined
# (--defsym, code unchanged) and find_panics.py lists every surviving panic
# call site with its source line and inlined call chain.
#
#   bash no-panic-check/check.sh
#   CARGO_PROFILE_RELEASE_OPT_LEVEL=z bash no-panic-check/check.sh
#   CARGO_PROFILE_RELEASE_OPT_LEVEL=3 NO_PANIC_CHECK_FLASH_KB=4096 bash no-panic-check/check.sh
#     (opt-level 3 does not fit the nRF52833's 512 KiB flash)
#
# Options:
#   --no-list    skip the listing of panic sites on failure;
#   --per-group  also build each entry point group alone (Cargo features
#                calibrate, calibration, align, heading, store, collector,
#                persist) and say which link.
set -euo pipefail
cd "$(dirname "$0")"

SYMBOL=mag_cal_core_has_a_reachable_panic
# Every monomorphisation of the public API at once (4 sample types x 2
# precisions x every method, the FFI) took 532 012 bytes of .text at
# opt-level "s" on 2026-12-03, over the nRF52833's 512 KiB: the proof is
# about which panics the optimiser leaves, not about the size (a firmware
# links one or two of them: LS9 + ADC2 is 44 KiB), so the harness gets 1 MiB
# unless told otherwise.
export NO_PANIC_CHECK_FLASH_KB=${NO_PANIC_CHECK_FLASH_KB:-1024}
ELF=target/thumbv7em-none-eabihf/release/no-panic-check
LIST=1
PER_GROUP=0
GROUPS_ALL=(calibrate calibration align heading store collector persist ffi)
for arg in "$@"; do
    case "$arg" in
    --no-list) LIST=0 ;;
    --per-group) PER_GROUP=1 ;;
    *)
        echo "usage: $0 [--no-list] [--per-group]" >&2
        exit 2
        ;;
    esac
done

log=$(mktemp)
trap 'rm -f "$log"' EXIT

echo "no-panic-check: opt-level ${CARGO_PROFILE_RELEASE_OPT_LEVEL:-s (Cargo.toml)}, fat LTO, panic=abort"

echo "[1/3] baseline: the harness alone (no mag-cal-core call) must link"
if ! cargo build --release --no-default-features >"$log" 2>&1; then
    cat "$log" >&2
    echo "FAIL: the baseline does not link; the harness itself is broken" >&2
    exit 1
fi
echo "      ok"

echo "[2/3] canary: one deliberate panic path must make the link fail"
if cargo build --release --no-default-features --features canary >"$log" 2>&1; then
    echo "FAIL: the canary build linked; the check cannot detect a panic" >&2
    exit 1
fi
if ! grep -q "undefined symbol: $SYMBOL" "$log"; then
    cat "$log" >&2
    echo "FAIL: the canary build failed for another reason than the panic symbol" >&2
    exit 1
fi
echo "      ok: the canary's panic is detected"

if [[ $PER_GROUP == 1 ]]; then
    echo "      per entry point group:"
    for group in "${GROUPS_ALL[@]}"; do
        if cargo build --release --no-default-features --features "$group" >"$log" 2>&1; then
            echo "        $group: links (no reachable panic)"
        elif grep -q "undefined symbol: $SYMBOL" "$log"; then
            echo "        $group: PANIC PATH"
        else
            cat "$log" >&2
            echo "        $group: build error" >&2
            exit 1
        fi
    done
fi

echo "[3/3] mag-cal-core's public API must link without the panic symbol"
if cargo build --release >"$log" 2>&1; then
    echo "PASS: no panic path is reachable from the public API (see src/main.rs)"
    exit 0
fi
if ! grep -q "undefined symbol: $SYMBOL" "$log"; then
    cat "$log" >&2
    echo "FAIL: the build failed (not the panic symbol)" >&2
    exit 1
fi
echo "FAIL: at least one panic path survives optimisation" >&2
if [[ $LIST == 1 ]]; then
    if command -v python3 >/dev/null && command -v llvm-objdump >/dev/null &&
        command -v llvm-addr2line >/dev/null; then
        echo "Linking the same code with the symbol defined, to list the panic sites:" >&2
        cargo rustc --release --bin no-panic-check -- \
            -C "link-arg=--defsym=$SYMBOL=DefaultHandler_" >"$log" 2>&1 ||
            { cat "$log" >&2; exit 1; }
        python3 find_panics.py "$ELF" >&2 || true
    else
        echo "(install python3, llvm-objdump and llvm-addr2line to list the panic sites)" >&2
    fi
fi
exit 1
