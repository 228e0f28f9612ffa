#!/usr/bin/env bash
# Benchmarks of the calibration on the emulated Cortex-M4F (QEMU mps2-an386).
#
# usage: bench.sh [bench|footprint|flash|all] [--verify]
#
#   bench      instruction counts (src/bin/bench.rs), f32, [i16; 3] samples:
#                BENCH <name> n=<n> instructions=<count>
#   footprint  flash, stack and RAM (src/bin/footprint.rs):
#                FOOTPRINT <name> flash=<bytes> stack=<bytes> ram_per_sample=<bytes>
#              and the flash of a method chosen at run time with the core's
#              method features (none, or one optional method added):
#                FOOTPRINT runtime-method features=<feature> flash=<bytes>
#              and LS9 + ADC2 built for the Cortex-M0+ (thumbv6m-none-eabi,
#              no FPU: f32 in software), the same program and profile:
#                FOOTPRINT ls9+adc2-thumbv6m flash=<bytes> stack=<bytes> ram_per_sample=<bytes>
#              and LS9 + ADC2 with the core built without outlier handling
#              (its `robust` feature off: the plain pipeline), on the M4F:
#                FOOTPRINT ls9+adc2-plain flash=<bytes> stack=<bytes> ram_per_sample=<bytes>
#   flash      the flash of LS9 + ADC2 alone (two of the footprint's builds,
#              no QEMU run): FOOTPRINT ls9+adc2 flash=<bytes>, as `footprint`
#              gives it (`cargo xtask ablation` reads it), then the plain
#              build's: FOOTPRINT ls9+adc2-plain flash=<bytes>
#   all        bench and footprint (the default)
#   --verify   with `bench`/`all`: run the bench a second time single-stepped
#              with QEMU's exec log, count every instruction between the
#              markers around each timed region, and compare with the
#              SysTick figures (VERIFY lines; takes about 7 minutes; fails
#              when a figure is off by more than 0.1 %)
#
# Lines starting with `#` are comments (iterations, absolute sizes, checks).
# Needs qemu-system-arm, defmt-print, flip-link (the linker), and `size` (binutils) or `llvm-size`.
# The instruction counts need `-icount shift=0`: QEMU then advances its
# virtual clock by 1 ns per instruction, and the 25 MHz SysTick ticks once
# per 40 instructions (the bench checks that factor and fails without it).
# The plain cargo runner (runner.sh, qemu-run.sh) does not pass it.
set -euo pipefail
cd "$(dirname "$0")"
# This crate is its own workspace with its own target: do not inherit a
# calling cargo's settings (e.g. from `cargo xtask bench`).
unset CARGO_TARGET_DIR CARGO_BUILD_TARGET MAG_CAL_FOOTPRINT

what=all
verify=0
for arg in "$@"; do
    case $arg in
        bench | footprint | flash | all) what=$arg ;;
        --verify) verify=1 ;;
        *)
            echo "usage: $0 [bench|footprint|flash|all] [--verify]" >&2
            exit 2
            ;;
    esac
done

out=target/thumbv7em-none-eabihf/release
build() { cargo build --release --locked --no-default-features --features qemu --bin "$@" >&2; }
# The core without its `robust` feature (and without the optional methods):
# the plain pipeline alone.
build_plain() { cargo build --release --locked --no-default-features --features qemu-base --bin "$@" >&2; }
# The Cortex-M0+ build (ARMv6-M, no FPU): f32 arithmetic is compiler-builtins'
# software routines (`__aeabi_fadd`, ...), linked in and counted in the flash.
v6m=thumbv6m-none-eabi
out_v6m=target/$v6m/release
build_v6m() { build "$@" --target "$v6m"; }
qemu=(qemu-system-arm -cpu cortex-m4 -machine mps2-an386 -nographic -monitor none
      -serial none -semihosting-config enable=on,target=native)
# run_qemu ELF [QEMU ARGS...]: the firmware's defmt log, one message a line;
# fails with the firmware's exit status (or 124 after QEMU_TIMEOUT seconds).
run_qemu() {
    local elf=$1
    shift
    timeout "${QEMU_TIMEOUT:-900}" "${qemu[@]}" "$@" -kernel "$elf" \
        | defmt-print --log-format "{s}" -e "$elf"
}

sizer=
for tool in size llvm-size rust-size; do
    if command -v "$tool" >/dev/null; then
        sizer=$tool
        break
    fi
done
# flash_of ELF: bytes of .text + .rodata.
flash_of() {
    "$sizer" -A -d "$1" | awk '$1 == ".text" || $1 == ".rodata" { s += $2 } END { print s + 0 }'
}

run_bench() {
    build bench
    local elf=$out/bench
    local log
    log=$(mktemp)
    run_qemu "$elf" -icount shift=0 | tee "$log"
    if [ "$verify" = 1 ]; then
        verify_bench "$elf" "$log"
    fi
    rm -f "$log"
}

# verify_bench ELF LOG: counts the instructions of each timed region in the
# exec log of a single-stepped run (one translation block per instruction,
# no chaining: one `Trace` line per instruction executed) and compares them
# with the SysTick figures of LOG.
verify_bench() {
    local elf=$1 log=$2
    local mark
    mark=$(nm "$elf" | awk '$3 == "bench_mark" { print $1 }')
    if [ -z "$mark" ]; then
        echo "bench.sh: no bench_mark symbol in $elf" >&2
        return 1
    fi
    # Clear the Thumb bit: the exec log shows the instruction address.
    mark=$(printf '%08x' $((0x$mark & ~1)))
    local dir
    dir=$(mktemp -d)
    mkfifo "$dir/exec"
    # Region k lies between the (2k-1)-th and (2k)-th call of bench_mark;
    # the count excludes the marker's own three instructions at the start.
    LC_ALL=C awk -v pc="/$mark/" '
        index($0, pc) {
            if (have) { seg++; if (seg % 2 == 1) print n - 1 }
            have = 1; n = 0; next
        }
        { n++ }' "$dir/exec" >"$dir/regions" &
    local awk_pid=$!
    echo "# verify: single-stepped run with the exec log (about 7 minutes)" >&2
    run_qemu "$elf" -icount shift=0 -singlestep -d exec,nochain -D "$dir/exec" >"$dir/log2"
    wait "$awk_pid"
    # Regions: 1 the empty measurement, 2 the check loop, then one per
    # BENCH line except adc2-other (computed) and the background-* figures
    # (single calls timed without markers), in order; `# <name>: mean of
    # <k> calls` gives the repetitions.
    local status=0
    LC_ALL=C awk -v regions="$dir/regions" '
        BEGIN {
            while ((getline line < regions) > 0) r[++nr] = line
            empty = r[1]; k = 2; bad = 0
        }
        /^# [^ ]+: mean of [0-9]+ calls/ { reps[$2] = $5; next }
        /^BENCH / { names[++nb] = $2; ns[nb] = $3; v[nb] = $4; next }
        END {
            for (i = 1; i <= nb; i++) {
                if (names[i] == "adc2-other" || names[i] ~ /^background-/) continue
                k++
                split(v[i], kv, "=")
                calls = reps[names[i] ":"] ? reps[names[i] ":"] : 1
                exec = (r[k] - empty) / calls
                d = exec - kv[2]
                rel = kv[2] > 0 ? d / kv[2] : 0
                printf "VERIFY %s %s systick=%d exec=%d diff=%+d (%+.4f%%)\n", names[i], ns[i], kv[2], exec, d, 100 * rel
                if (rel > 0.001 || rel < -0.001) bad = 1
            }
            if (k != nr) { print "VERIFY region count mismatch: " nr " regions, " k " used"; bad = 1 }
            exit bad
        }' "$dir/log2" || status=$?
    rm -rf "$dir"
    return $status
}

# attribute BASE ELF: code and read-only data of ELF that BASE lacks, by
# component: the core by folder (pipeline, steps, robust, judge, numerics,
# the rest), the optional methods apart; symbol sizes from nm; `other` is
# mostly anonymous constants.
attribute() {
    LC_ALL=C awk '
        FNR == 1 { file++ }
        NF >= 4 && $3 ~ /^[tTrR]$/ {
            name = $0
            sub(/^[^ ]+ [^ ]+ [^ ]+ /, "", name)
            if (file == 1) { base[name] = 1; next }
            if (name in base) next
            size = 0
            hex = tolower($2)
            for (i = 1; i <= length(hex); i++) size = size * 16 + index("0123456789abcdef", substr(hex, i, 1)) - 1
            n = name
            sub(/^[<&]+/, "", n)
            if (n ~ /^mag_cal_core::steps::methods::(submle|adc2_iter|adc1)/ || n ~ /^mag_cal_core::numerics::quasi_newton::Anderson/) c = "core-other-methods"
            else if (n ~ /^mag_cal_core::(calibrate|pipeline)/) c = "core-pipeline"
            else if (n ~ /^mag_cal_core::steps/) c = "core-steps"
            else if (n ~ /^mag_cal_core::robust/) c = "core-robust"
            else if (n ~ /^mag_cal_core::judge/) c = "core-judge"
            else if (n ~ /^mag_cal_core::numerics/) c = "core-numerics"
            else if (n ~ /^mag_cal_core/) c = "core-rest"
            else if (n ~ /^(nalgebra|simba)/) c = "nalgebra"
            else if (n ~ /^libm/) c = "libm"
            else if (n ~ /^(compiler_builtins|__aeabi)/) c = "compiler-builtins"
            else if (n ~ /^core::/) c = "rust-core"
            else c = "other"
            sum[c] += size; total += size
        }
        END {
            line = "total=" total
            k = split("core-pipeline core-steps core-robust core-judge core-numerics core-rest core-other-methods nalgebra libm compiler-builtins rust-core other", order, " ")
            for (i = 1; i <= k; i++) line = line " " order[i] "=" sum[order[i]] + 0
            print line
        }' <(nm -S -C --defined-only "$1") <(nm -S -C --defined-only "$2")
}

run_footprint() {
    if [ -z "$sizer" ]; then
        echo "bench.sh: need size (binutils) or llvm-size for the flash figures" >&2
        return 1
    fi
    mkdir -p target/footprint
    local v
    declare -A flash
    for v in baseline ls ls9+adc2 all; do
        MAG_CAL_FOOTPRINT=$v build footprint
        cp "$out/footprint" "target/footprint/$v.elf"
        flash[$v]=$(flash_of "target/footprint/$v.elf")
    done
    if ! [ "${flash[ls9+adc2]}" -gt "${flash[baseline]}" ]; then
        echo "bench.sh: the footprint builds did not differ (MAG_CAL_FOOTPRINT not applied?)" >&2
        return 1
    fi
    echo "# flash (.text + .rodata, opt-level s, fat LTO): baseline=${flash[baseline]} ls=${flash[ls]} ls9+adc2=${flash[ls9+adc2]} all=${flash[all]} bytes"
    for v in ls ls9+adc2 all; do
        echo "# flash $v over baseline, by symbol: $(attribute "target/footprint/baseline.elf" "target/footprint/$v.elf")"
    done
    build footprint
    local log
    log=$(mktemp)
    run_qemu "$out/footprint" >"$log"
    sed 's/^/# /' "$log"
    # ram_of LOG: the bytes of one stored sample (the run's RAM line).
    ram_of() { awk '/^RAM / { for (i = 2; i <= NF; i++) if ($i ~ /^sample_bytes=/) { sub(/.*=/, "", $i); print $i } }' "$1"; }
    local ram_per_sample
    ram_per_sample=$(ram_of "$log")
    # A method's figure (stack_of METHOD LOG) is the largest of its clean,
    # contaminated and doubtful runs.
    stack_of() { awk -v m="$1" '$1 == "STACK" && ($2 == m || $2 == m "-contaminated" || $2 == m "-doubtful") { sub(/.*=/, "", $4); if ($4 + 0 > s) s = $4 + 0 } END { print s + 0 }' "$2"; }
    local max_stack
    max_stack=$(awk '$1 == "STACK" { sub(/.*=/, "", $4); if ($4 + 0 > m) m = $4 + 0 } END { print m + 0 }' "$log")
    echo "FOOTPRINT ls flash=$((flash[ls] - flash[baseline])) stack=$(stack_of ls "$log") ram_per_sample=$ram_per_sample"
    echo "FOOTPRINT ls9+adc2 flash=$((flash[ls9+adc2] - flash[baseline])) stack=$(stack_of adc2 "$log") ram_per_sample=$ram_per_sample"
    echo "FOOTPRINT all-methods flash=$((flash[all] - flash[baseline])) stack=$max_stack ram_per_sample=$ram_per_sample"
    rm -f "$log"
    # The core's method features, with the method chosen at run time:
    # LS, LS9 and ADC2 alone, then each optional method or LS variant
    # added (the `all` build, every feature).
    local feature f
    for feature in none adc1 adc2-iter submle svd10 lg10; do
        local features=qemu-base,mag-cal-core/robust
        [ "$feature" = none ] || features="$features,mag-cal-core/$feature"
        MAG_CAL_FOOTPRINT=all cargo build --release --locked --no-default-features \
            --features "$features" --bin footprint >&2
        f=$(flash_of "$out/footprint")
        echo "FOOTPRINT runtime-method features=$feature flash=$((f - flash[baseline]))"
    done
    # LS9 + ADC2 on the Cortex-M0+: the same builds for thumbv6m-none-eabi
    # (baseline and ls9+adc2 for the flash, over the baseline built for it
    # too). The stack run's build executes on the same emulated Cortex-M4:
    # ARMv6-M's Thumb instructions are a subset of ARMv7-M's, so QEMU runs
    # the M0+ build's own instructions and the painted stack is the M0+
    # build's.
    for v in baseline ls9+adc2; do
        MAG_CAL_FOOTPRINT=$v build_v6m footprint
        cp "$out_v6m/footprint" "target/footprint/$v-$v6m.elf"
        flash[$v-$v6m]=$(flash_of "target/footprint/$v-$v6m.elf")
    done
    echo "# flash $v6m (.text + .rodata, opt-level s, fat LTO): baseline=${flash[baseline-$v6m]} ls9+adc2=${flash[ls9+adc2-$v6m]} bytes"
    echo "# flash ls9+adc2-$v6m over baseline, by symbol: $(attribute "target/footprint/baseline-$v6m.elf" "target/footprint/ls9+adc2-$v6m.elf")"
    build_v6m footprint
    log=$(mktemp)
    run_qemu "$out_v6m/footprint" >"$log"
    sed "s/^/# $v6m: /" "$log"
    echo "FOOTPRINT ls9+adc2-thumbv6m flash=$((flash[ls9+adc2-$v6m] - flash[baseline-$v6m])) stack=$(stack_of adc2 "$log") ram_per_sample=$(ram_of "$log")"
    rm -f "$log"
    # LS9 + ADC2 with the core's plain pipeline (no `robust`): the same
    # builds with the core's features off, over the baseline built so too.
    # The stack run's contaminated samples are no refusal there either.
    for v in baseline ls9+adc2; do
        MAG_CAL_FOOTPRINT=$v build_plain footprint
        cp "$out/footprint" "target/footprint/$v-plain.elf"
        flash[$v-plain]=$(flash_of "target/footprint/$v-plain.elf")
    done
    echo "# flash plain (.text + .rodata, opt-level s, fat LTO): baseline=${flash[baseline-plain]} ls9+adc2=${flash[ls9+adc2-plain]} bytes"
    echo "# flash ls9+adc2-plain over baseline, by symbol: $(attribute "target/footprint/baseline-plain.elf" "target/footprint/ls9+adc2-plain.elf")"
    # (Every method, as the stack run calibrates with each.)
    build_plain footprint --features mag-cal-core/all-methods
    log=$(mktemp)
    run_qemu "$out/footprint" >"$log"
    sed "s/^/# plain: /" "$log"
    echo "FOOTPRINT ls9+adc2-plain flash=$((flash[ls9+adc2-plain] - flash[baseline-plain])) stack=$(stack_of adc2 "$log") ram_per_sample=$(ram_of "$log")"
    rm -f "$log"
}

# The FOOTPRINT ls9+adc2 flash figure of run_footprint alone.
run_flash() {
    if [ -z "$sizer" ]; then
        echo "bench.sh: need size (binutils) or llvm-size for the flash figures" >&2
        return 1
    fi
    local v
    declare -A flash
    for v in baseline ls9+adc2; do
        MAG_CAL_FOOTPRINT=$v build footprint
        flash[$v]=$(flash_of "$out/footprint")
    done
    if ! [ "${flash[ls9+adc2]}" -gt "${flash[baseline]}" ]; then
        echo "bench.sh: the footprint builds did not differ (MAG_CAL_FOOTPRINT not applied?)" >&2
        return 1
    fi
    echo "# flash (.text + .rodata, opt-level s, fat LTO): baseline=${flash[baseline]} ls9+adc2=${flash[ls9+adc2]} bytes"
    echo "FOOTPRINT ls9+adc2 flash=$((flash[ls9+adc2] - flash[baseline]))"
    for v in baseline ls9+adc2; do
        MAG_CAL_FOOTPRINT=$v build_plain footprint
        flash[$v-plain]=$(flash_of "$out/footprint")
    done
    echo "# flash plain (.text + .rodata, opt-level s, fat LTO): baseline=${flash[baseline-plain]} ls9+adc2=${flash[ls9+adc2-plain]} bytes"
    echo "FOOTPRINT ls9+adc2-plain flash=$((flash[ls9+adc2-plain] - flash[baseline-plain]))"
}

case $what in
    bench) run_bench ;;
    footprint) run_footprint ;;
    flash) run_flash ;;
    all)
        run_bench
        run_footprint
        ;;
esac
