#!/usr/bin/env python3
"""Lists every surviving panic call site in a no-panic-check ELF.

Usage: find_panics.py ELF [--objdump llvm-objdump] [--addr2line llvm-addr2line]
                          [--verbose]

The ELF is the default build linked with the panic symbol defined
(`check.sh` does that with `--defsym` when the real link fails). For every
call or branch into the panic machinery (`core::panicking::*`,
`*unwrap_failed`, `*expect_failed`, `core::slice::index::*`, ...) from a
function outside it, the call's basic block is found, and the branches
that jump to it (its guards). For each guard this prints:

- the innermost source line outside `core` (the nalgebra assert or the
  mag-cal-core index whose check branches to the panic), from DWARF via
  `addr2line -i`;
- the frames it is inlined into, up to this crate's `main`;
- the ELF function that holds the code, and one chain of non-inlined
  callers up to `main` (from the disassembly's direct calls).

Entries with the same panic function, check and inlining chain are merged
(monomorphisations); `--verbose` lists every call and guard address.
Guards found by falling through from the previous instruction can name an
unrelated neighbouring line (line 0 or an epilogue); the branch guards are
exact.

Exit status 0 when no panic call is found, 1 otherwise.
"""

import argparse
import collections
import re
import subprocess
import sys

PANIC_PATTERNS = [
    r"^core::panicking::",
    r"unwrap_failed$",
    r"expect_failed$",
    r"^core::slice::index::.*fail",
    r"^core::str::slice_error_fail",
    r"^core::cell::panic_",
    r"^core::option::expect_failed",
    r"^rust_begin_unwind$",
    r"^__rustc::rust_begin_unwind$",
    r"^no_panic_check::panic$",
    r"^mag_cal_core_has_a_reachable_panic$",
]

FUNC_RE = re.compile(r"^([0-9a-f]+) <(.*)>:$")
# Thumb direct branches: bl, b, b.w, b<cond>, b<cond>.w, cbz, cbnz.
CALL_RE = re.compile(
    r"^\s*([0-9a-f]+):\s+(bl|blx|b|b\.w|b[a-z]{2}|b[a-z]{2}\.w|cbn?z)\s+"
    r"(?:r\d+,\s*)?0x([0-9a-f]+)\s+<([^>]*)>"
)


LEGACY = [
    ("$LT$", "<"), ("$GT$", ">"), ("$u20$", " "), ("$C$", ","), ("$LP$", "("),
    ("$RP$", ")"), ("$RF$", "&"), ("$BP$", "*"), ("$u5b$", "["), ("$u5d$", "]"),
    ("$u7b$", "{"), ("$u7d$", "}"), ("$u3b$", ";"), ("$u27$", "'"), ("$u2b$", "+"),
]


INSN_RE = re.compile(r"^\s*([0-9a-f]+):\s+(.*)$")
TARGET_RE = re.compile(r"\b0x([0-9a-f]+)\s+<")
# Unconditional control transfers (and calls of the never-returning panic
# functions): the next instruction is not reached by falling through.
TERMINATORS = re.compile(
    r"^(?:b|b\.w|bx|udf|pop(?:\.w)?\s+\{[^}]*pc\}|ldr(?:\.w)?\s+pc,.*)(?:\s|$)"
    r"|^bl\s+\S+\s+<(?:core::panicking::|core::option::|core::result::)"
)


def strip_hash(name):
    """Drops the symbol hash and decodes the legacy-mangling escapes left in
    DWARF names (`_$LT$impl$u20$...` -> `<impl ...`)."""
    name = re.sub(r"::h[0-9a-f]{16}$", "", name)
    if "$" in name:
        if name.startswith("_$"):
            name = name[1:]
        for k, v in LEGACY:
            name = name.replace(k, v)
        name = name.replace("..", "::")
    return name


def base_name(target):
    # "<sym+0x12>" -> sym
    return re.sub(r"\+0x[0-9a-f]+$", "", target)


def is_panic(name):
    name = strip_hash(name)
    return any(re.search(p, name) for p in PANIC_PATTERNS)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("elf")
    ap.add_argument("--objdump", default="llvm-objdump")
    ap.add_argument("--addr2line", default="llvm-addr2line")
    ap.add_argument("--root", default="no_panic_check::__cortex_m_rt_main")
    ap.add_argument("--verbose", action="store_true")
    args = ap.parse_args()

    dis = subprocess.run(
        [args.objdump, "-d", "--no-show-raw-insn", "-C", args.elf],
        check=True,
        capture_output=True,
        text=True,
    ).stdout

    current = None
    callers = collections.defaultdict(set)  # callee -> {caller}
    sites = []  # (addr, containing function, panic target)
    insns = []  # (addr, text) in address order
    branches_to = collections.defaultdict(list)  # target addr -> [branch addr]
    for line in dis.splitlines():
        im = INSN_RE.match(line)
        if im:
            insns.append((int(im.group(1), 16), im.group(2).strip()))
            tm = TARGET_RE.search(im.group(2))
            if tm and im.group(2).split()[0].startswith(("b", "cb")):
                branches_to[int(tm.group(1), 16)].append(int(im.group(1), 16))
        m = FUNC_RE.match(line)
        if m:
            # ARM mapping symbols ($t, $d, $a) are labels, not functions.
            if not m.group(2).startswith("$"):
                current = m.group(2)
            continue
        m = CALL_RE.match(line)
        if not m or current is None:
            continue
        addr, op, _target_addr, target = m.groups()
        # A branch into the middle of a function is not a call (mostly data
        # disassembled as code, after a `loop {}`).
        into_middle = "+0x" in target
        target = base_name(target)
        if target == current:
            continue  # a branch within the function
        callers[target].add(current)
        if is_panic(target) and not is_panic(current) and not into_middle:
            sites.append((int(addr, 16), current, target, op))

    if not sites:
        print("no panic call site found")
        return 0

    # Only calls from functions outside the panic machinery are listed
    # (the panic functions' calls among themselves are the runtime's).
    addrs = [hex(a) for a, _, _, _ in sites]

    # addr2line prints, per address, a (function, file:line) pair for each
    # inlined frame, innermost first.
    def frames_at(a):
        out = subprocess.run(
            [args.addr2line, "-e", args.elf, "-i", "-f", "-C", hex(a)],
            check=True,
            capture_output=True,
            text=True,
        ).stdout.splitlines()
        return [
            (strip_hash(out[i]), shorten(out[i + 1]))
            for i in range(0, len(out) - 1, 2)
        ]

    index = {a: i for i, (a, _) in enumerate(insns)}

    def guards(a):
        """Addresses of the branches that lead into the panic call's block,
        and of the instruction before it when the block is fallen into."""
        i = index[a]
        # The block: back from the call to a branch target or to the
        # instruction after a terminator (at most 8 instructions of
        # argument set-up).
        for _ in range(8):
            start = insns[i][0]
            if start in branches_to or i == 0:
                break
            prev = insns[i - 1][1]
            if TERMINATORS.match(prev) or prev.startswith("bl"):
                break
            i -= 1
        start = insns[i][0]
        found = list(branches_to.get(start, []))
        if i > 0 and not TERMINATORS.match(insns[i - 1][1]):
            found.append(insns[i - 1][0])
        return start, found

    chains = {}
    for a in addrs:
        a = int(a, 16)
        start, gs = guards(a)
        entries = []
        for g in gs or [a]:
            frames = frames_at(g)
            entries.append((g, frames))
        chains[hex(a)] = (start, entries, frames_at(a))

    def caller_paths(func, depth=0, seen=()):
        """Non-inlined caller chains from `func` up to the root."""
        if strip_hash(func).startswith(args.root) or depth > 12:
            return [[func]]
        ups = [c for c in sorted(callers.get(func, ())) if c not in seen]
        if not ups:
            return [[func]]
        paths = []
        for c in ups:
            for p in caller_paths(c, depth + 1, seen + (func,)):
                paths.append([func] + p)
        return paths

    def ours(loc):
        return loc.startswith(("mag-cal-core/", "no-panic-check/"))

    def condensed(frames):
        """The innermost frame outside `core` (the check that branches to
        the panic: an nalgebra assert, a mag-cal-core index, ...), then the
        frames it is inlined into, outermost last, up to this crate."""
        frames = [f for f in frames if not f[1].startswith("core-src:")] or frames
        if not frames:
            return ("?", ())
        inner = f"{frames[0][0]} [{frames[0][1]}]"
        chain = []
        for f, l in frames[1:]:
            chain.append(f"{f} [{l}]")
            if l.startswith("no-panic-check/"):
                break
        return (inner, tuple(chain))

    def shortest_path(func):
        paths = caller_paths(func)
        paths.sort(key=len)
        return " <- ".join(strip_hash(x) for x in paths[0]) if paths else "?"

    groups = collections.OrderedDict()
    for addr, func, target, op in sites:
        start, entries, own = chains[hex(addr)]
        for g, frames in entries or [(addr, own)]:
            key = (strip_hash(target),) + condensed(frames)
            groups.setdefault(key, []).append((addr, g, func))

    print(
        f"{len(sites)} panic call sites (calls into the panic machinery); "
        f"{len(groups)} distinct guarded paths into them.\n"
        "Each entry: the panic function, the innermost source line whose "
        "check branches to it,\nthe mag-cal-core frames it is inlined into "
        "(innermost first), and one chain of\nnon-inlined callers up to main.\n"
    )
    for n, ((target, inner, chain), hits) in enumerate(groups.items(), 1):
        print(f"[{n}] {target}")
        print(f"    check: {inner}")
        for c in chain:
            print(f"      in {c}")
        funcs = sorted({strip_hash(f) for _, _, f in hits})
        for f in funcs[:3]:
            func_sym = next(x for _, _, x in hits if strip_hash(x) == f)
            print(f"    code in {f}; callers: {shortest_path(func_sym)}")
        if len(funcs) > 3:
            print(f"    ... and {len(funcs) - 3} more functions")
        print(
            f"    {len(hits)} guard(s) at "
            + ", ".join(sorted({f"{g:#x}" for _, g, _ in hits})[:6])
            + (" ..." if len(hits) > 6 else "")
        )
        if args.verbose:
            for a, g, f in hits:
                print(f"      call {a:#x} guard {g:#x} in {strip_hash(f)}")
        print()
    return 1


def shorten(loc):
    loc = re.sub(r"^.*/rustc/[0-9a-f]+/library/", "core-src:", loc)
    loc = re.sub(r"^.*/registry/src/[^/]+/", "", loc)
    loc = re.sub(r"^.*/work/main/", "", loc)
    return loc


if __name__ == "__main__":
    try:
        sys.exit(main())
    except BrokenPipeError:  # e.g. piped into `head`
        sys.exit(1)
