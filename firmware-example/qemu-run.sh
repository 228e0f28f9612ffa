#!/usr/bin/env bash
# Runs a firmware ELF built with `--features qemu` on QEMU's mps2-an386
# (Cortex-M4F) and decodes its defmt log, which the firmware writes to the
# host's stdout through semihosting. The firmware ends through a semihosting
# exit, whose status QEMU returns; a hung firmware is killed after 120 s
# (QEMU_TIMEOUT seconds, if set) and the script fails with status 124.
#
# usage: qemu-run.sh ELF
set -euo pipefail

if [ $# -ne 1 ]; then
    echo "usage: $0 ELF" >&2
    exit 2
fi
elf=$1

timeout "${QEMU_TIMEOUT:-120}" qemu-system-arm \
    -cpu cortex-m4 \
    -machine mps2-an386 \
    -nographic \
    -monitor none \
    -serial none \
    -semihosting-config enable=on,target=native \
    -kernel "$elf" \
  | defmt-print --log-format "{s}" -e "$elf"
# With pipefail the pipeline's status is QEMU's (or timeout's 124) when it is
# non-zero, so a failed or hung firmware fails the run.
