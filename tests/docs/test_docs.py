"""The documentation is tested like code: the README's and every page's Python blocks run,
every command they show exists and takes the options it is shown with, and the site
builds with warnings as errors (a broken link or anchor fails it)."""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import sys
from functools import cache
from pathlib import Path

import pytest
from help_in_process import help_in_process

ROOT = Path(__file__).resolve().parents[2]
# the reference pages and the results appendix (docs/results/), not the dated notes
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PAGES += sorted((ROOT / "docs" / "results").glob("*.md"))
SKIP = "<!-- docs-test: skip"
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)


def blocks(page: Path, language: str) -> list[tuple[int, str]]:
    """(line, code) of the page's fenced blocks in ``language`` not marked to be skipped."""
    text = page.read_text()
    out = []
    for m in FENCE.finditer(text):
        if m.group(1) != language:
            continue
        before = text[: m.start()].rstrip().splitlines()
        if before and before[-1].startswith(SKIP):
            continue
        out.append((text[: m.start()].count("\n") + 1, m.group(2)))
    return out


PYTHON_PAGES = [p for p in PAGES if blocks(p, "python")]


@pytest.mark.parametrize("page", PYTHON_PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_python_blocks_run(page: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A page's blocks run in order in one namespace, as a reader would paste them."""
    monkeypatch.chdir(tmp_path)  # whatever a block writes lands here
    namespace: dict = {"__name__": "__docs__"}
    for line, code in blocks(page, "python"):
        try:
            exec(compile(code, f"{page.name}:{line}", "exec"), namespace)
        except Exception as exc:
            raise AssertionError(f"{page.name}, the block at line {line} failed: {exc!r}") from exc


def commands(page: Path) -> list[tuple[int, list[str]]]:
    """The ``python -m MODULE`` and ``python benchmarks/X.py`` commands of a page's bash
    blocks, as argument lists (continuation lines joined; comments dropped)."""
    out = []
    for line, code in blocks(page, "bash"):
        for logical in code.replace("\\\n", " ").splitlines():
            for part in re.split(r"&&|;|\|", logical.split("  #")[0].split(" # ")[0]):
                try:
                    words = shlex.split(part, comments=True)
                except ValueError:  # an unbalanced quote inside a longer shell line
                    continue
                if words[:1] == ["python"] and len(words) > 1:
                    out.append((line, words[1:]))
    return out


def command_target(args: list[str]) -> tuple[list[str], list[str]]:
    """(the command up to its subcommand, the options it is given)."""
    if args[0] == "-m":
        head, rest = args[:2], args[2:]
    else:
        head, rest = args[:1], args[1:]
    # leading bare words: a subcommand (e.g. ``imitate collect``) or positionals; a path
    # positional (a run folder, a CSV) is left out, so the commands that differ only in
    # their files share one ``--help``; a Hydra override (``key=value``) stays
    lead = []
    for word in rest:
        if word.startswith("-"):
            break
        if "/" not in word or "=" in word:
            lead.append(word)
    options = sorted({w.split("=")[0] for w in rest if re.fullmatch(r"--[a-z][\w-]*(=.*)?", w)})
    # an option that picks the parser (the trainer's RL library) is part of the command
    selector = [w for i, w in enumerate(rest[:-1]) if w == "--library" for w in (w, rest[i + 1])]
    return head + lead + selector, options


@cache
def help_text(command: tuple[str, ...]) -> str:
    status, out = help_in_process(command)  # the imports once, not once per command
    assert status == 0, f"python {' '.join(command)} --help exited {status}:\n{out[-2000:]}"
    return out


SHOWN = sorted(
    {
        (page.name, tuple(head), tuple(options))
        for page in PAGES
        for _, args in commands(page)
        for head, options in [command_target(args)]
        if not any("$" in w or "..." in w for w in head)
    }
)


@pytest.mark.parametrize(("page", "command", "options"), SHOWN, ids=lambda v: str(v)[:60])
def test_shown_commands_exist_with_their_options(
    page: str, command: tuple[str, ...], options: tuple[str, ...]
) -> None:
    if command[0] != "-m":
        assert (ROOT / command[0]).is_file(), f"{page}: no script {command[0]}"
    text = help_text(command)
    missing = [o for o in options if not re.search(rf"{re.escape(o)}\b", text)]
    assert not missing, f"{page}: python {' '.join(command)} has no option {missing}"


def test_site_builds_strict(tmp_path: Path) -> None:
    mkdocs = shutil.which("mkdocs", path=str(Path(sys.executable).parent))
    assert mkdocs, "mkdocs is missing: the test extra installs it (with mkdocs-material)"
    run = subprocess.run(
        [mkdocs, "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={"NO_MKDOCS_2_WARNING": "1", "PATH": str(Path(sys.executable).parent) + ":/usr/bin"},
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert (tmp_path / "site" / "environment" / "index.html").is_file()
