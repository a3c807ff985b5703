"""CasADi's generated C cut so that it compiles in seconds, not minutes.

An SX function becomes one straight-line C function: the controller's model Jacobian is
65,000 statements with ~2,000 values live at once. GCC's register allocation grows faster
than linearly with such a block (measured: 30 s at -O3 for that one function), so:

1. ``cut_long_functions``: each long straight-line function becomes parts of at most
   ``max_statements`` statements, called in order; a value one part computes and a later
   part reads lives in one array, every other value stays in the part's locals. The same
   operations in the same order (only a fused multiply-add across a cut can no longer
   form), 3.6x faster to compile at -O3 and within 4 % of its speed
   (``benchmarks/compile_time.py``).
2. ``translation_units``: the parts spread over several translation units, compiled in
   parallel, one per core (``compile_units``).

Only the shapes CasADi emits for SX functions are cut (``aN=...;`` and ``if (res[i]!=0)
res[i][j]=aN;`` lines); any other function is left whole.

May import: the standard library only.
"""

from __future__ import annotations

import os
import re
import subprocess
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

# Statements per part: measured on the controller's Jacobian (-O3, one core), 250: 7.7 s
# and +5 % run time, 500: 8.3 s and +2 %, 1000: 9.7 s and +4 % (noise), uncut: 30 s.
MAX_STATEMENTS = 500
# Functions longer than this are cut: the simulator's robot stage (13,000 statements) and
# the environment kernel's compile 15-20 % faster cut, at no measured cost to the step.
CUT_ABOVE = 10_000
# a library this long or shorter is compiled whole; a longer one in a unit per core (the
# main job's kernel, 22,600 lines: 6.5-7.2 s whole, 3.6-4.2 s in 2 units; the wrench,
# 10,000 lines: 3.3 s whole, 3.8 s in 2 units)
LINES_PER_UNIT = 10_000

_SIGNATURE = "const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem"
_FUNCTION = re.compile(
    r"^static int (casadi_f\d+)\(" + re.escape(_SIGNATURE) + r"\) \{\n(.*?)^\}\n", re.S | re.M
)
_VARIABLE = re.compile(r"\ba(\d+)\b")
_DECLARATION = "  casadi_real a"
# what a part looks like: unit_of() finds the parts again to move them
_PART = "CASADI_PREFIX({name}_part{k})"
_PART_HEAD = (
    "static __attribute__((noinline)) void {part}(const casadi_real** arg, casadi_real** res, "
    "casadi_real* __restrict__ s)"
)
_PART_DEFINITION = re.compile(r"^static __attribute__\(\(noinline\)\) void .*?^\}\n", re.S | re.M)
_HIDDEN = '__attribute__((visibility("hidden"))) '

# top-level helper definitions of the preamble (casadi_sq, casadi_copy, ...): global in
# the first unit, private copies in the others
_HELPER = re.compile(r"^(casadi_real|casadi_int|void|int) (casadi_\w+)\(", re.M)
_PREAMBLE_END = re.compile(r"^(CASADI_SYMBOL_EXPORT|static const|static int casadi_f)", re.M)
_EXTERN_C_END = '\n#ifdef __cplusplus\n} /* extern "C" */\n#endif\n'


def _straight_line(statements: list[str]) -> bool:
    return all(s.startswith(("  a", "  if (res[")) for s in statements)


def _liveness(chunks: list[list[str]]) -> tuple[list[set[str]], list[set[str]]]:
    """Per chunk: the variables it assigns, and those live at its start (read in it or
    after it before being assigned again)."""
    assigned, read_first = [], []
    for chunk in chunks:
        defined: set[str] = set()
        used: set[str] = set()
        for line in chunk:
            target, _, value = line.partition("=") if line.startswith("  a") else ("", "", line)
            used |= {v for v in _VARIABLE.findall(value) if v not in defined}
            if target:
                defined.add(_VARIABLE.search(target).group(1))
        assigned.append(defined)
        read_first.append(used)
    live_in: list[set[str]] = [set() for _ in chunks]
    after: set[str] = set()
    for k in range(len(chunks) - 1, -1, -1):
        live_in[k] = read_first[k] | (after - assigned[k])
        after = live_in[k]
    return assigned, live_in


def _cut(name: str, statements: list[str], max_statements: int) -> str:
    chunks = [statements[i : i + max_statements] for i in range(0, len(statements), max_statements)]
    assigned, live_in = _liveness(chunks)
    shared = sorted(set().union(*live_in[1:]), key=int)
    slot = {v: i for i, v in enumerate(shared)}

    def through_array(line: str) -> str:
        return _VARIABLE.sub(
            lambda m: f"s[{slot[m.group(1)]}]" if m.group(1) in slot else m.group(0), line
        )

    parts = []
    for k, chunk in enumerate(chunks):
        local = sorted(assigned[k] - slot.keys(), key=int)
        body = [_PART_HEAD.format(part=_PART.format(name=name, k=k)) + " {"]
        if local:
            body.append("  casadi_real " + ", ".join(f"a{v}" for v in local) + ";")
        body += [through_array(line) for line in chunk]
        parts.append("\n".join([*body, "}"]) + "\n")
    wrapper = [
        f"static int {name}({_SIGNATURE}) {{",
        f"  casadi_real s[{max(1, len(shared))}];",
        *(f"  {_PART.format(name=name, k=k)}(arg, res, s);" for k in range(len(chunks))),
        "  return 0;",
        "}",
    ]
    return "\n".join(parts) + "\n" + "\n".join(wrapper) + "\n"


def cut_long_functions(
    source: str, above: int = CUT_ABOVE, max_statements: int = MAX_STATEMENTS
) -> str:
    """``source`` with every straight-line function of more than ``above`` statements cut
    into parts of ``max_statements`` (module docstring)."""
    out, pos = [], 0
    for m in _FUNCTION.finditer(source):
        lines = m.group(2).splitlines()
        statements = [
            s for s in lines if not s.startswith(_DECLARATION) and s.strip() != "return 0;"
        ]
        if len(statements) <= above or not _straight_line(statements):
            continue
        out += [source[pos : m.start()], _cut(m.group(1), statements, max_statements)]
        pos = m.end()
    out.append(source[pos:])
    return "".join(out)


def translation_units(source: str, units: int) -> list[str]:
    """``source`` (after ``cut_long_functions``) as up to ``units`` translation units of
    similar size: the first holds the API and everything that cannot move, each other one
    the preamble (its helpers private) and straight-line functions or parts. One unit when
    nothing can move."""
    movable = _movable(source)
    if units <= 1 or len(movable) < 2:
        return [source]
    preamble = source[: _PREAMBLE_END.search(source).start()]
    private = _HELPER.sub(r"static \1 \2(", preamble)
    sizes = [text.count("\n") for text, _ in movable]
    # longest first onto the lightest unit; unit 0 starts with what cannot move
    load = [source.count("\n") - sum(sizes)] + [0] * (units - 1)
    members: list[list[int]] = [[] for _ in range(units)]
    for i in sorted(range(len(movable)), key=lambda i: -sizes[i]):
        u = min(range(units), key=load.__getitem__)
        load[u] += sizes[i]
        members[u].append(i)
    moved = {movable[i][0] for u in members[1:] for i in u}
    # every movable definition linked across units: hidden, not static
    shared = [(text, _HIDDEN + text.removeprefix("static ")) for text, _ in movable]
    prototypes = "".join(head + ";\n" for _, head in movable)
    first = source
    for (text, _), (_, global_text) in zip(movable, shared, strict=True):
        first = first.replace(text, "" if text in moved else global_text, 1)
    first = first.replace(preamble, preamble + prototypes, 1)
    others = [
        private + prototypes + "".join(shared[i][1] for i in sorted(u)) + _EXTERN_C_END
        for u in members[1:]
        if u
    ]
    return [first, *others]


def _movable(source: str) -> list[tuple[str, str]]:
    """(definition, hidden prototype) of every definition another unit can hold: the
    parts of cut functions and the straight-line functions left whole."""
    texts = [m.group(0) for m in _PART_DEFINITION.finditer(source)]
    for m in _FUNCTION.finditer(source):
        statements = [s for s in m.group(2).splitlines() if not s.startswith(_DECLARATION)]
        if _straight_line([s for s in statements if s.strip() != "return 0;"]):
            texts.append(m.group(0))
    return [(t, _HIDDEN + t.split(" {\n", 1)[0].removeprefix("static ")) for t in texts]


def compile_units(
    compiler: str,
    sources: Sequence[str],
    folder: Path,
    suffix: str,
    flags: Sequence[str],
    output: Path,
    libraries: Sequence[str] = ("-lm",),
) -> None:
    """Compile ``sources`` (one per translation unit, written to ``folder`` with
    ``suffix``) in parallel with ``flags`` and link them into the shared library
    ``output``. CalledProcessError on a compiler error."""
    compile_flags = [f for f in flags if f != "-shared"]
    paths = []
    for i, text in enumerate(sources):
        path = folder / f"unit{i}{suffix}"
        path.write_text(text)
        paths.append(path)
    if len(paths) == 1:
        subprocess.run([compiler, *flags, str(paths[0]), "-o", str(output), *libraries], check=True)
        return

    def one(path: Path) -> Path:
        obj = path.with_suffix(".o")
        subprocess.run([compiler, *compile_flags, "-c", str(path), "-o", str(obj)], check=True)
        return obj

    with ThreadPoolExecutor(max_workers=len(paths)) as pool:
        objects = list(pool.map(one, paths))
    link = [compiler, *flags, *map(str, objects), "-o", str(output), *libraries]
    subprocess.run(link, check=True)


def default_units(source: str) -> int:
    """Translation units for ``source``: one per ``LINES_PER_UNIT`` lines, at most one per
    core this process may use (a small library compiles faster whole)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, 1 + source.count("\n") // LINES_PER_UNIT))
