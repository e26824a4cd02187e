#!/usr/bin/env python3
"""Where a firmware image's code goes: its .text bytes by the crate they come from, and for the image's own crate by
module, following inlining to the innermost frame outside core (the ELF's DWARF, read by binutils' addr2line).
Code core itself keeps (memcpy, 64-bit division, formatting for panics) is counted as core.

Usage: g431-hw/bloat.py ELF CRATE [LINES]    e.g. g431-hw/bloat.py target/images/thruster-fw thruster-fw 16
"""
import collections
import re
import subprocess
import sys


def sizes(elf):
    """(address, bytes) of every instruction of the ELF's code."""
    listing = subprocess.run(["arm-none-eabi-objdump", "-d", "--no-show-raw-insn", elf],
                             capture_output=True, text=True, check=True).stdout
    starts = [int(m.group(1), 16) for m in re.finditer(r"^\s+([0-9a-f]+):\s", listing, re.M)]
    # Thumb-2 instructions are 2 or 4 bytes; a larger gap is padding or data, counted as 2.
    return [(a, b - a if b - a in (2, 4) else 2) for a, b in zip(starts, starts[1:])]


def inline_chains(elf, addresses):
    """For each address, the source files of its inlined frames, innermost first."""
    out = subprocess.run(["arm-none-eabi-addr2line", "-i", "-a", "-e", elf],
                         input="".join(f"{a:x}\n" for a in addresses),
                         capture_output=True, text=True, check=True).stdout
    chains = []
    for line in out.splitlines():
        if line.startswith("0x"):
            chains.append([])
        elif chains:
            chains[-1].append(line.rsplit(":", 1)[0])
    return chains


def owner(path, crate):
    """The crate (or `crate::module`) a source file belongs to; None for core and what has no line."""
    registry = re.search(r"registry/src/[^/]+/([^/]+)/", path)
    if registry:
        return re.sub(r"-\d+\.\d+\.\d+.*", "", registry.group(1))
    if "/build/embassy-stm32-" in path:
        return "embassy-stm32"  # its generated code, in the target directory
    workspace = re.search(r"/([a-z0-9-]+)/src/(.*)$", path)
    if "/rustc/" in path or not workspace:
        return None
    if workspace.group(1) == crate:
        return f"{crate}::{workspace.group(2).split('/')[0].removesuffix('.rs')}"
    return workspace.group(1)


def main():
    if len(sys.argv) not in (3, 4) or (len(sys.argv) == 4 and not sys.argv[3].isdigit()):
        sys.exit(__doc__.strip().splitlines()[-1])
    elf, crate = sys.argv[1], sys.argv[2]
    lines = int(sys.argv[3]) if len(sys.argv) == 4 else 1_000_000
    instructions = sizes(elf)
    total = collections.Counter()
    for (_, size), chain in zip(instructions, inline_chains(elf, [a for a, _ in instructions])):
        total[next((o for o in (owner(p, crate) for p in chain) if o), "core, compiler-builtins")] += size
    ranked = total.most_common()
    for name, size in ranked[:lines]:
        print(f"{size:8,} B  {name}")
    rest = ranked[lines:]
    if rest:
        print(f"{sum(s for _, s in rest):8,} B  {len(rest)} more")
    print(f"{sum(total.values()):8,} B  of code in all")


if __name__ == "__main__":
    main()
