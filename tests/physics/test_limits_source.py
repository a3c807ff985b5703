"""One source per limit: change one limit in the one place it is defined (the model's
``parameters.toml`` for the physical limits, ``uvms_env.task.constraints`` for the
manipulability bound and the pitch margin) and the environment's constraint value, the
expert's OCP bound and the safety filter's bound all move, by the same amount, and
nothing else does.

The environment's side is its per-step kernel (``team_function``, uncompiled: built from
the model of the parameter file as the environment builds it, evaluated in CasADi's
virtual machine); the controllers' side is the bound vector their QP builder receives
(the ``scale`` rows of ``LocalController.weights``: the limit each row is normalized by;
the back-offs are fractions of it)."""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterator
from pathlib import Path

import casadi as cs
import numpy as np
import pytest

from nmpc_expert import NMPCPolicy, NMPCSettings, SafetyFilter
from nmpc_expert.ocp import CONSTRAINT_NAMES, NC, WEIGHT_OFFSETS
from uvms_env.dynamics.uvms import default_model
from uvms_env.models import Limits, load_parameters, parameters
from uvms_env.navigation.parametric import NAV_PARAMETERS
from uvms_env.policy import AgentSpec
from uvms_env.robot.observation import FAR_OBSTACLE, OBSERVATION_LAYOUT
from uvms_env.scenarios import make
from uvms_env.task import constraints
from uvms_env.task.constraints import CONSTRAINTS
from uvms_env.task.team_kernel import WAYPOINT_SLOTS, team_function

# (the limit, where it is defined, its tightened value from the current one, the env's
# constraint kind, the OCP rows bounded by it, the state entry put at the current limit
# (``q``/``zeta`` index; None: none needed), the sign of the env value's move per unit
# of the limit's move: g = value - limit moves by -d, g = eps - det by +d and
# g = |theta| - (pi/2 - margin) by +d; vehicle_speed, value / limit - 1, by old / new - 1)
CASES = [
    ("joint_position", "toml", 0.8, "joint_limit", "joint_position_", ("q", 6), -1.0),
    ("joint_speed", "toml", 0.8, "joint_speed", "joint_speed_", ("zeta", 7), -1.0),
    ("vehicle_linear_speed", "toml", 0.8, "vehicle_speed", "vehicle_speed_uvw", ("zeta", 1), -1.0),
    ("vehicle_angular_speed", "toml", 0.8, "vehicle_speed", "vehicle_speed_pqr", ("zeta", 5), -1.0),
    ("MANIPULABILITY_EPS", "module", 1.5, "manipulability", "manipulability", None, 1.0),
    ("REPRESENTATION_MARGIN", "module", 1.5, "representation", "_pitch", ("q", 4), 1.0),
]


def _rows(pattern: str) -> list[int]:
    """The OCP rows a limit bounds (``CONSTRAINT_NAMES`` by prefix, or vehicle axes)."""
    if pattern.startswith("vehicle_speed_"):
        axes = pattern.removeprefix("vehicle_speed_")
        return [CONSTRAINT_NAMES.index(f"vehicle_speed_{a}") for a in axes]
    return [k for k, name in enumerate(CONSTRAINT_NAMES) if pattern in name]


def _current(name: str) -> float:
    if hasattr(constraints, name):
        return float(getattr(constraints, name))
    return float(getattr(load_parameters().limits, name))


def _clear_caches() -> None:
    load_parameters.cache_clear()
    default_model.cache_clear()


@pytest.fixture
def source(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[object]:
    """``set(name, value)``: redefine one limit where it is defined; undone afterwards
    (the parameter caches cleared before and after, so no other test sees the change)."""

    def set_limit(name: str, value: float) -> None:
        if name in {f.name for f in dataclasses.fields(Limits)}:
            text = parameters.PARAMETER_FILE.read_text()
            edited, count = re.subn(
                rf"^({name}\s*=\s*)[^\s#]+", rf"\g<1>{value!r}", text, flags=re.M
            )
            assert count == 1, f"{name} is defined {count} times in the parameter file"
            path = tmp_path / "parameters.toml"
            path.write_text(edited)
            monkeypatch.setattr(parameters, "PARAMETER_FILE", path)
        else:
            monkeypatch.setattr(constraints, name, value)
        _clear_caches()

    _clear_caches()
    try:
        yield set_limit
    finally:
        monkeypatch.undo()
        _clear_caches()


@pytest.fixture(scope="module")
def spec() -> AgentSpec:
    return AgentSpec.from_scenario(make("paper"), 0)


class _Zero:
    """A proposal for the filter (never asked for one here)."""

    def __init__(self) -> None:
        self.stats: dict = {}

    def reset(self) -> None:
        pass

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros(8)


def _env_constraints(q: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """The environment's constraint values (``CONSTRAINTS`` order) of one robot at (q,
    zeta), through its kernel built now (``__wrapped__``: not the process cache's)."""
    fn = team_function.__wrapped__(1, 1, 0, 0, OBSERVATION_LAYOUT, tuple(FAR_OBSTACLE), False)
    grasp = np.r_[0.0, 0.0, 0.0, np.eye(3).ravel()]
    static = np.r_[1.0, 0.0, 0.0, 0.0, np.eye(3).ravel()]
    args = [
        np.zeros(8),
        q,
        zeta,
        q,
        zeta,
        np.zeros(6),  # object pose
        grasp,
        static,
        np.zeros(2),  # the robot's sequencer: its first waypoint
        np.zeros(5),  # the team's sequencer and its tests' constants
        cs.DM(NAV_PARAMETERS, WAYPOINT_SLOTS),  # the waypoints' navigation (all zero)
        np.ones(1),  # one waypoint
        np.zeros(6),  # goal
        np.zeros(1),  # time fraction
        np.array([-0.9, 0.0, 0.0, 0.9, 0.0, 0.0]),  # one object segment
        cs.DM(4, 0),  # no cylinders
        cs.DM(5, 0),  # no spheres
        np.array([0.0, 0.0, 0.0, 100.0]),  # workspace
    ]
    return np.asarray(fn(*[cs.DM(a) for a in args])[2]).ravel()


def _controller_limits(spec: AgentSpec) -> dict[str, np.ndarray]:
    """The limit of every OCP row, as the QP builders of the expert (its default
    settings) and of the safety filter (its own default settings) receive it."""
    o = WEIGHT_OFFSETS["scale"]
    expert = NMPCPolicy(spec)
    filt = SafetyFilter(spec, _Zero(), workspace=False)
    return {
        "expert": expert.solver.weights[o : o + NC].copy(),
        "filter": filt.solver.weights[o : o + NC].copy(),
    }


@pytest.mark.parametrize(("name", "where", "factor", "kind", "rows", "entry", "sign"), CASES)
def test_one_limit_changed_in_one_place_moves_env_expert_and_filter(
    source, spec: AgentSpec, name, where, factor, kind, rows, entry, sign
) -> None:
    old = _current(name)
    new = factor * old
    # a state with the limited quantity exactly at its current limit (for the pitch: the
    # vehicle pitched to the bound) and every other speed zero: the changed term is then
    # the largest of its kind before and after, so the kind moves by the whole change
    q = make("paper").initial_q[0].copy()
    zeta = np.zeros(10)
    if entry is not None:
        vector = q if entry[0] == "q" else zeta
        vector[entry[1]] = old if name != "REPRESENTATION_MARGIN" else np.pi / 2 - old
    g_before, c_before = _env_constraints(q, zeta), _controller_limits(spec)

    source(name, new)
    assert _current(name) == new and (where == "module") == hasattr(constraints, name)
    g_after, c_after = _env_constraints(q, zeta), _controller_limits(spec)

    moved = g_after - g_before
    k = CONSTRAINTS.index(kind)
    # vehicle_speed is the speed beyond the limit as a fraction of it: speed / limit - 1
    expected = old / new - 1.0 if kind == "vehicle_speed" else sign * (new - old)
    np.testing.assert_allclose(moved[k], expected, rtol=0, atol=1e-12)
    assert np.all(moved[np.arange(len(CONSTRAINTS)) != k] == 0.0), "another kind moved"
    # the OCP rows are normalized by the bound itself: the limit, eps, or pi/2 - margin
    expected_rows = np.zeros(NC, dtype=bool)
    expected_rows[_rows(rows)] = True
    assert expected_rows.sum() >= 1
    row_move = old - new if name == "REPRESENTATION_MARGIN" else new - old
    for who in ("expert", "filter"):
        shift = c_after[who] - c_before[who]
        np.testing.assert_allclose(shift[expected_rows], row_move, rtol=0, atol=1e-12)
        assert np.all(shift[~expected_rows] == 0.0), f"{who}: another row moved"


def test_expert_limits_are_the_environments_by_default_and_tighten_relative_to_them() -> None:
    """With the default settings the expert's limits are exactly the model's and the
    task's; a tightening is a fraction of (or a margin beyond) them, never a new number,
    and loosening is refused."""
    lim = load_parameters().limits
    for s in (NMPCSettings(), NMPCSettings.paper()):
        assert s.vehicle_speed == (lim.vehicle_linear_speed, lim.vehicle_angular_speed)
        assert s.joint_speed == lim.joint_speed and s.joint_position == lim.joint_position
        assert s.pitch_margin == constraints.REPRESENTATION_MARGIN
        assert s.manipulability_eps == constraints.MANIPULABILITY_EPS
    tight = NMPCSettings(
        vehicle_speed_fraction=(0.5, 0.25),
        joint_speed_fraction=0.8,
        joint_position_fraction=0.9,
        pitch_margin_extra=0.1,
        manipulability_factor=2.0,
    )
    assert tight.vehicle_speed == (0.5 * lim.vehicle_linear_speed, 0.25 * lim.vehicle_angular_speed)
    assert tight.joint_speed == 0.8 * lim.joint_speed
    assert tight.joint_position == 0.9 * lim.joint_position
    assert tight.pitch_margin == constraints.REPRESENTATION_MARGIN + 0.1
    assert tight.manipulability_eps == 2.0 * constraints.MANIPULABILITY_EPS
    for loose in (
        {"vehicle_speed_fraction": (1.0, 1.1)},
        {"joint_speed_fraction": 1.2},
        {"joint_position_fraction": 0.0},
        {"pitch_margin_extra": -0.05},
        {"manipulability_factor": 0.9},
    ):
        with pytest.raises(ValueError):
            NMPCSettings(**loose)  # type: ignore[arg-type]
    # the control period is the scenario's, not a second 0.12
    assert NMPCSettings().period == make("paper").period
    # the limits themselves are not settings: no number to retype
    for name in ("vehicle_speed", "joint_speed", "joint_position", "pitch_margin"):
        assert name not in NMPCSettings.field_names()
