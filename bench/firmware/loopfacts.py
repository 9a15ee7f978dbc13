"""Loop-bound facts the generators state in the C they write: `/* wcet-loop: N */` on each counted `for` line.

The generators write every loop of the model's and the observer's C (codegen.py, the model kinds' and loss models'
fragments, observergen.py, udgen.py), and each of those loops counts an index from a constant to a constant (a
literal, or a #define of the generated header: 4 nodes, the filter's states, the measurements). `annotate_loops`
writes that count on the loop's line, where `target_sim.firmware.wcet.loop_facts` reads it and the WCET analysis
finds it by the image's line table: a loop clang leaves in a form the machine-code count does not recognize
(`target_sim.firmware.counted_loops`) is still bounded, by what the generator knows. A start that is not a literal
(`j = i + 1`) counts as 0, which can only overstate; a limit that is neither a literal nor an upper-case name (a
function parameter: `dot`'s n, inlined with a constant and counted in the machine code) gets no fact.
"""

from __future__ import annotations

import re

_FOR = re.compile(r"for \((\w+) = ([^;]+); \1 < ([A-Za-z_0-9]+)(?: && [^;]+)?; \1\+\+\)")


def loop_bound(start: str, limit: str) -> str | None:
    """The annotation's bound of `for (i = start; i < limit; i++)`, or None when the generator cannot state one."""
    if limit.isdigit():
        first = int(start) if start.strip().isdigit() else 0
        return str(max(int(limit) - first, 0))
    if re.fullmatch(r"[A-Z][A-Z0-9_]*", limit):
        return limit                    # a #define of the sources; a literal start above 0 only overstates it
    return None


def annotate_loops(c_text: str) -> str:
    """`c_text` with `/* wcet-loop: N */` at the end of each line that opens a `for` loop with a stated count (a
    line that already has one is left as it is)."""
    lines = []
    for line in c_text.split("\n"):
        found = _FOR.search(line)
        bound = loop_bound(found.group(2), found.group(3)) if found and "wcet-loop:" not in line else None
        lines.append(f"{line} /* wcet-loop: {bound} */" if bound is not None else line)
    return "\n".join(lines)
