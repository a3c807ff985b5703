"""Every dotted name of the project that README.md and the reference pages of docs/ cite
(``uvms_env.…``, ``nmpc_expert.…``, ``baselines.…``) exists: a module, or an attribute
chain inside one. A rename that leaves a page behind fails here. Dated notes
(docs/notes/) speak of their day and are left out. And no two modules of the packages
share a file name: a module is found by a name that says what it holds."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [
    ROOT / "README.md",
    *sorted(p for p in (ROOT / "docs").rglob("*.md") if "notes" not in p.parts),
]
NAME = re.compile(r"(?<![\w./-])((?:uvms_env|nmpc_expert|baselines)(?:\.[A-Za-z_]\w*)+)")


def resolves(name: str) -> bool:
    """The longest importable module prefix of ``name``, then attributes for the rest."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def cited(page: Path) -> set[str]:
    return {m.group(1) for m in NAME.finditer(page.read_text())}


def test_the_pattern_finds_names_and_the_resolver_tells_them_apart():
    assert cited(ROOT / "docs" / "options.md") >= {"uvms_env.env.options.ENV_OPTIONS"}
    assert resolves("uvms_env.robot.memory.RobotMemory") and resolves("baselines.rl")
    assert not resolves("uvms_env.env.parallel.ENV_OPTIONS")  # an old home, gone


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_cited_name_exists(page):
    missing = sorted(n for n in cited(page) if not resolves(n))
    assert not missing, f"{page.name} cites names that do not exist: {missing}"


def test_no_two_modules_share_a_file_name():
    """A file name names one job: across uvms_env, nmpc_expert and baselines no two
    modules (``__init__`` and ``__main__`` aside) are called the same."""
    seen: dict[str, list[str]] = {}
    for package in ("uvms_env", "nmpc_expert", "baselines"):
        for path in sorted((ROOT / package).rglob("*.py")):
            if path.name not in ("__init__.py", "__main__.py"):
                seen.setdefault(path.name, []).append(str(path.relative_to(ROOT)))
    shared = {name: paths for name, paths in seen.items() if len(paths) > 1}
    assert not shared, f"modules sharing a file name: {shared}"
