"""The reference tables of docs/options.md against the code they describe: every
environment option and every trainer flag has exactly one row, with the code's type and
default, so an option added to the code without its row (or a row left behind) fails.
The committed models' cards name the docs tables that use them, and those tables do."""

from __future__ import annotations

import argparse
import ast
import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
OPTIONS_PAGE = ROOT / "docs" / "options.md"
PIPE = re.compile(r"(?<!\\)\|")  # a cell may hold an escaped pipe, \|


def table_after(page: Path, heading: str) -> list[dict[str, str]]:
    """The rows of the first Markdown table under ``## heading``, as header -> cell."""
    lines = page.read_text().splitlines()
    start = lines.index(f"## {heading}")
    # from the table's first row to the first line that is not a row
    first = next(i for i, line in enumerate(lines[start:], start) if line.startswith("|"))
    end = next((i for i in range(first, len(lines)) if not lines[i].startswith("|")), len(lines))
    rows = lines[first:end]
    header = [c.strip() for c in PIPE.split(rows[0].strip("|"))]
    out = []
    for row in rows[2:]:  # after the header and its |---| line
        cells = [c.strip() for c in PIPE.split(row.strip().strip("|"))]
        assert len(cells) == len(header), f"{page.name}: malformed row {row!r}"
        out.append(dict(zip(header, cells, strict=True)))
    return out


def code_name(cell: str) -> str:
    match = re.fullmatch(r"`([^`]+)`", cell)
    assert match, f"expected one `name`, got {cell!r}"
    return match.group(1)


def default_literal(cell: str):
    """The cell's first backticked Python literal (what follows it is commentary)."""
    match = re.match(r"`([^`]+)`", cell)
    assert match, f"the default cell {cell!r} starts with no `literal`"
    return ast.literal_eval(match.group(1))


# ---------------------------------------------------------------- environment options


@pytest.fixture(scope="module")
def env_rows() -> dict[str, dict[str, str]]:
    rows = table_after(OPTIONS_PAGE, "Environment options")
    names = [code_name(r["keyword"]) for r in rows]
    assert len(names) == len(set(names)), "a keyword has two rows"
    return dict(zip(names, rows, strict=True))


def test_every_environment_option_has_one_row_and_no_row_is_stale(env_rows):
    from uvms_env.env.options import ENV_OPTIONS
    from uvms_env.scenarios.overrides import SCENARIO_OVERRIDES

    code = set(SCENARIO_OVERRIDES) | set(ENV_OPTIONS)
    assert set(env_rows) - code == set(), "rows for options the code does not have"
    assert code - set(env_rows) == set(), "options the docs table does not list"


def test_environment_option_types_are_the_codes(env_rows):
    from uvms_env.env.options import ENV_OPTIONS
    from uvms_env.scenarios.overrides import SCENARIO_OVERRIDES

    for name, option in {**SCENARIO_OVERRIDES, **ENV_OPTIONS}.items():
        assert env_rows[name]["type"] == option.describe(), name
        assert env_rows[name]["meaning"], name


def test_environment_option_defaults_are_what_an_env_built_without_them_uses(env_rows):
    """Defaults read back from built objects, not from a second table: the scenario's
    fields, the environment's settings and its priors."""
    import dataclasses

    import uvms_env
    from uvms_env.env.options import ENV_OPTIONS
    from uvms_env.scenarios import make
    from uvms_env.scenarios.config import Scenario
    from uvms_env.scenarios.families import RANDOM_DEFAULT_COURSE, RANDOM_DEFAULT_OBJECT
    from uvms_env.scenarios.overrides import SCENARIO_FIELDS

    fields = {f.name: f.default for f in dataclasses.fields(Scenario)}
    for name in SCENARIO_FIELDS:
        assert default_literal(env_rows[name]["default"]) == fields[name], name
    assert default_literal(env_rows["n_agents"]["default"]) == make("random", seed=0).n_agents
    assert default_literal(env_rows["object"]["default"]) == RANDOM_DEFAULT_OBJECT
    assert make("random", seed=0).object_shape == RANDOM_DEFAULT_OBJECT
    assert default_literal(env_rows["course"]["default"]) == RANDOM_DEFAULT_COURSE

    env = uvms_env.parallel_env("paper")
    built = {
        "constraint_mode": env.constraint_mode,
        "reseed_geometry": env.reseed_geometry,
        "internal_wrench_every": env.internal_wrench_every,
        **dataclasses.asdict(env.priors),
    }
    for name, value in built.items():
        assert default_literal(env_rows[name]["default"]) == value, name
    # the rest default to None: "not given" (max_cycles then is the scenario's max_steps)
    for name in set(ENV_OPTIONS) - set(built):
        assert default_literal(env_rows[name]["default"]) is None, name
        assert ENV_OPTIONS[name].optional, name
    assert env.max_cycles == env.scenario.max_steps


# ---------------------------------------------------------------- trainer flags


def parser_flags(library: str) -> dict[str, argparse.Action]:
    """The flags ``python -m baselines.train --library LIBRARY --help`` shows."""
    from baselines.train import build_parser

    actions = build_parser(library)._actions
    return {
        a.option_strings[0]: a
        for a in actions
        if a.option_strings and a.help != argparse.SUPPRESS and "-h" not in a.option_strings
    }


@pytest.fixture(scope="module")
def flag_rows() -> dict[str, dict[str, str]]:
    rows = table_after(OPTIONS_PAGE, "Trainer flags")
    names = [code_name(r["flag"]) for r in rows]
    assert len(names) == len(set(names)), "a flag has two rows"
    return dict(zip(names, rows, strict=True))


def libraries_of(row: dict[str, str]) -> list[str]:
    from baselines.registry import LIBRARIES

    cell = row["libraries"]
    return list(LIBRARIES) if cell == "all" else [e.strip() for e in cell.split(",")]


def test_every_trainer_flag_has_one_row_per_library_and_no_row_is_stale(flag_rows):
    from baselines.registry import LIBRARIES

    for library in LIBRARIES:
        documented = {f for f, row in flag_rows.items() if library in libraries_of(row)}
        shown = set(parser_flags(library))
        assert documented - shown == set(), f"{library}: rows for flags it does not take"
        assert shown - documented == set(), f"{library}: flags the docs table does not list"


def test_trainer_flag_defaults_are_the_parsers(flag_rows):
    for flag, row in flag_rows.items():
        for library in libraries_of(row):
            action = parser_flags(library)[flag]
            if flag == "--algo":  # each library's first algorithm: the cell names every one
                assert f"`{action.default!r}`" in row["default"], (flag, library)
                continue
            expected = "sb3" if flag == "--library" else action.default  # main's default library
            assert default_literal(row["default"]) == expected, (flag, library)
        assert row["meaning"], flag


# ---------------------------------------------------------------- model cards


def test_each_committed_model_names_the_docs_tables_that_use_it():
    """A model no table uses should not be committed; a card's table must name it."""
    pretrained = ROOT / "baselines" / "pretrained"
    folders = sorted(p for p in pretrained.iterdir() if p.is_dir())
    assert folders
    for folder in folders:
        card = json.loads((folder / "info.json").read_text())
        assert card["docs_tables"], folder.name
        for entry in card["docs_tables"]:
            page, _, heading = entry.partition(", ")
            text = (ROOT / page).read_text()
            assert f"## {heading}" in text, (folder.name, entry)
            section = text.split(f"## {heading}", 1)[1].split("\n## ", 1)[0]
            table = "\n".join(line for line in section.splitlines() if line.startswith("|"))
            short = card["name"].removeprefix("ppo:baselines/pretrained/")
            assert short in table, (folder.name, entry)


# ---------------------------------------------------------------- observations, metrics


def test_the_observation_table_is_the_layout_the_env_builds():
    """Every part of the raw observation, by name and index range, in layout order."""
    from uvms_env.env import OBSERVATION_STRUCTURE

    rows = table_after(OPTIONS_PAGE, "Observations")
    documented = []
    for row in rows:
        name = re.match(r"`(\w+)`", row["meaning"])
        assert name, row
        first, _, last = row["index"].partition("-")
        documented.append((name.group(1), int(first), int(last or first) + 1))
    code = [(name, s.start, s.stop) for name, s in OBSERVATION_STRUCTURE.items()]
    assert documented == code


def test_the_metrics_table_lists_every_metric_once():
    """Every metric by name, the per-kind ones once each as ``<measure>_<kind>``."""
    from uvms_env.task.metrics import HEAD, METRICS, PER_KIND, TAIL

    rows = table_after(OPTIONS_PAGE, "Episode metrics")
    names = [re.match(r"`([\w<>]+)`", r["metric"]).group(1) for r in rows]
    per_kind = [f"{p}_<kind>" for p in PER_KIND]
    assert sorted(names) == sorted((*HEAD, *TAIL, *per_kind)) and len(names) == len(set(names))
    kinds = [m for m in METRICS if m not in HEAD and m not in TAIL]
    assert len(kinds) == len(PER_KIND) * 8  # the table's patterns cover every per-kind key
