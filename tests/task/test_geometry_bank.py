"""The geometry bank serves the seeded families' geometries from disk: equal to building
them, built once, keyed by what they depend on."""

from __future__ import annotations

import numpy as np
import pytest

from uvms_env.navigation.parametric import twist_parameters
from uvms_env.robot.observation import make_navigator
from uvms_env.scenarios import bank as bank_module
from uvms_env.scenarios import make
from uvms_env.scenarios.bank import GeometryBank, main


def test_a_stored_geometry_is_the_built_one_and_is_not_built_again(tmp_path, monkeypatch):
    first = GeometryBank("short", 2, folder=tmp_path)
    geometry = first.get(4)
    assert first.path(4).exists()

    def refuse(*args):
        raise AssertionError("the bank built a geometry it had on disk")

    monkeypatch.setattr(bank_module, "build_geometry", refuse)
    again = GeometryBank("short", 2, folder=tmp_path).get(4)
    built = make("short", seed=4, current="mild", mismatch=0.1)
    mine = again.scenario_with({"current": "mild", "mismatch": 0.1, "seed": 4})
    for field in ("initial_q", "grasp_offsets", "grasp_rotations", "waypoints", "object_start"):
        assert np.array_equal(getattr(mine, field), getattr(built, field)), field
    assert (mine.current, mine.mismatch, mine.seed) == ("mild", 0.1, 4)
    nav = make_navigator(built)
    row = np.concatenate([np.ravel(p, order="F") for p in twist_parameters(nav, 0)])
    assert np.array_equal(again.navigation[0], row)
    assert np.array_equal(again.navigation, geometry.navigation)


def test_fill_builds_only_what_is_missing_and_the_command_line_runs(tmp_path, monkeypatch, capsys):
    bank = GeometryBank("short", 2, folder=tmp_path / "geometry_bank")  # the default place
    assert bank.fill(range(3)) == 3
    assert bank.fill(range(5)) == 2
    assert bank.missing(range(6)) == [5]
    monkeypatch.setattr(bank_module, "cache_dir", lambda: tmp_path)
    main(["short", "--seeds", "0:6", "--workers", "1"])
    assert "1 built, 5 already there" in capsys.readouterr().out


def test_only_seeded_families_have_a_bank():
    with pytest.raises(ValueError, match="seeded families"):
        GeometryBank("paper", 2)
