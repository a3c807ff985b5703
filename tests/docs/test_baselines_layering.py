"""The folders of ``baselines`` are layered (docs/development.md, "Layers"): between its
units (each subpackage, ``baselines/loaders`` say, is one unit; each root module
``baselines/X.py`` is its own) no import chain leads back to where it started.

Every import statement counts, read from the source with ``ast``: module level, inside
functions (the lazy ones that keep a library off the import path) and under
``TYPE_CHECKING``, because a cycle hidden in a function is still a cycle of what the
folders need from each other. Names imported by string (``importlib`` through
``baselines.registry``) are a lookup by name, not an import statement, and do not count.
``../shared/tools/import-graph`` checks the modules themselves; this checks the folders,
where two modules that never import each other can still tie their folders together.
"""

from __future__ import annotations

import ast
import itertools
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "baselines"


@dataclass(frozen=True)
class Line:
    """One import statement, where it is."""

    path: str
    lineno: int
    source: str

    def __str__(self) -> str:
        return f"{self.path}:{self.lineno}: {self.source}"


Graph = dict[str, dict[str, list[Line]]]  # unit -> imported unit -> the import lines


def modules(root: Path, package: str) -> dict[str, Path]:
    """Every module of ``package`` under ``root`` by dotted name (a package by its own)."""
    out = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def unit(module: str, package: str, folders: set[str]) -> str:
    """The folder a module belongs to: ``pkg.sub`` for anything inside the subpackage
    ``sub``, the module itself for a root module, ``pkg`` for the package's own
    ``__init__``."""
    parts = module.split(".")
    if len(parts) >= 2 and f"{package}.{parts[1]}" in folders:
        return f"{package}.{parts[1]}"
    return ".".join(parts[:2])


def imported(node: ast.Import | ast.ImportFrom, module: str, is_package: bool) -> Iterator[str]:
    """The dotted names an import statement brings in (``from a import b`` gives ``a.b``,
    which ``unit`` cuts to its folder whether ``b`` is a module or a name)."""
    if isinstance(node, ast.Import):
        yield from (alias.name for alias in node.names)
        return
    base = node.module or ""
    if node.level:  # relative: from the module's package, one folder up per extra dot
        anchor = module.split(".") if is_package else module.split(".")[:-1]
        anchor = anchor[: len(anchor) - (node.level - 1)]
        base = ".".join([*anchor, *([base] if base else [])])
    for alias in node.names:
        yield f"{base}.{alias.name}" if alias.name != "*" else base


def folder_graph(root: Path, package: str) -> Graph:
    """The import graph between ``package``'s units, each edge with its import lines."""
    found = modules(root, package)
    folders = {m for m, p in found.items() if p.name == "__init__.py" and m != package}
    graph: Graph = {unit(m, package, folders): {} for m in found}
    for module, path in found.items():
        source = path.read_text()
        here = unit(module, package, folders)
        # ast.walk reaches imports in function bodies and in ``if TYPE_CHECKING:`` alike
        for node in ast.walk(ast.parse(source, str(path))):
            if not isinstance(node, ast.Import | ast.ImportFrom):
                continue
            text = " ".join((ast.get_source_segment(source, node) or "").split())
            line = Line(str(path.relative_to(root)), node.lineno, text)
            for name in imported(node, module, path.name == "__init__.py"):
                if name != package and not name.startswith(f"{package}."):
                    continue
                there = unit(name, package, folders)
                if there not in graph:  # a name from the package's own __init__
                    there = package
                lines = graph[here].setdefault(there, []) if there != here else []
                if line not in lines:  # one line per statement, however many names
                    lines.append(line)
    return graph


def components(graph: Graph) -> list[list[str]]:
    """Tarjan's strongly connected components with more than one unit: each holds a cycle."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def cycles(graph: Graph, limit: int = 50) -> list[list[str]]:
    """The elementary cycles (up to ``limit``), each from its smallest unit, found by a
    depth-first search inside each strongly connected component."""
    out: list[list[str]] = []

    def extend(path: list[str], members: set[str]) -> None:
        start = path[0]
        for w in sorted(graph[path[-1]]):
            if len(out) >= limit:
                return
            if w == start:
                out.append([*path, start])
            elif w in members and w > start and w not in path:  # each cycle once
                extend([*path, w], members)

    for component in components(graph):
        for start in component:
            extend([start], set(component))
    return out


def describe(graph: Graph, found: list[list[str]]) -> str:
    """The cycles as chains of units, shortest first, then once each step of them with
    the import lines that make it."""
    found = sorted(found, key=lambda c: (len(c), c))
    steps = sorted({(a, b) for c in found for a, b in itertools.pairwise(c)})
    lines = [f"{len(found)} folder cycles in {', '.join(sorted({u for c in found for u in c}))}:"]
    lines += [f"  {' -> '.join(c)}" for c in found]
    lines.append("made by these imports:")
    for a, b in steps:
        lines.append(f"  {a} -> {b}:")
        lines += [f"    {line}" for line in graph[a][b]]
    return "\n".join(lines)


def test_baselines_folders_import_no_cycle():
    graph = folder_graph(ROOT, PACKAGE)
    assert {"baselines.loaders", "baselines.evaluation", "baselines.train"} <= set(graph)
    found = cycles(graph)
    assert not found, describe(graph, found)


def write(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_the_search_sees_lazy_type_checking_and_relative_imports_and_long_cycles(tmp_path):
    """A three-folder cycle closed only by a function-level import, a TYPE_CHECKING one and
    a relative one is found, with its lines; a root module is a unit of its own."""
    write(
        tmp_path,
        {
            "pkg/__init__.py": "",
            "pkg/top.py": "from pkg.low.x import f\n",
            "pkg/low/__init__.py": "",
            "pkg/low/x.py": "def f():\n    from pkg.mid import y\n",
            "pkg/mid/__init__.py": "",
            "pkg/mid/y.py": (
                "from typing import TYPE_CHECKING\n"
                "from . import z\n"
                "if TYPE_CHECKING:\n"
                "    from pkg.high.w import W\n"
            ),
            "pkg/mid/z.py": "",
            "pkg/high/__init__.py": "",
            "pkg/high/w.py": "from ..low import x\n",
        },
    )
    graph = folder_graph(tmp_path, "pkg")
    assert set(graph) == {"pkg", "pkg.top", "pkg.low", "pkg.mid", "pkg.high"}
    assert graph["pkg.top"] == {"pkg.low": [Line("pkg/top.py", 1, "from pkg.low.x import f")]}
    assert "pkg.mid" not in graph["pkg.mid"]  # a folder importing itself is no edge
    found = cycles(graph)
    assert found == [["pkg.high", "pkg.low", "pkg.mid", "pkg.high"]]
    text = describe(graph, found)
    assert "pkg/low/x.py:2: from pkg.mid import y" in text
    assert "pkg/mid/y.py:4: from pkg.high.w import W" in text
    assert "pkg/high/w.py:1: from ..low import x" in text
    # broken by moving the lazy import's target below: no cycle left
    write(tmp_path, {"pkg/low/x.py": "def f():\n    pass\n"})
    assert cycles(folder_graph(tmp_path, "pkg")) == []
