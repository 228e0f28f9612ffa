#!/usr/bin/env bash
# Cargo runner for both builds of the firmware (see .cargo/config.toml).
# An ELF built with `--features qemu` carries the marker string below (see
# src/sim_sensor.rs) and runs on QEMU; any other ELF is flashed to a
# micro:bit v2 with probe-rs.
set -euo pipefail
elf=$1
here=$(dirname "$0")
if grep -qa 'mag-cal-firmware-example:qemu' "$elf"; then
    exec "$here/qemu-run.sh" "$elf"
else
    if ! command -v probe-rs >/dev/null; then
        echo "runner.sh: probe-rs not found (cargo install probe-rs-tools --locked)," \
             "and a micro:bit v2 must be attached; for QEMU build with" \
             "--no-default-features --features qemu" >&2
        exit 127
    fi
    exec probe-rs run --chip nRF52833_xxAA "$elf"
fi
