"""The physics of one environment for ``EnvCore``: the scalar compiled functions.

``ScalarEngine`` is the engine ``parallel_env`` runs (``uvms_env.env.core``, batch shape
B = ()): the truth simulator (``uvms_env.sim.Simulator``, one compiled call per period)
and the kinematics kernel (``TeamKinematics``: observations with each robot's waypoint
sequencing and navigation twist, constraints, team rows, and the internal wrench where
it is switched on: one compiled call after the period). The same CasADi graphs as the
batched engine's, compiled for one environment (no C compiler needed). One set of
compiled objects per geometry, the last ``GEOMETRY_CACHE_SIZE`` kept (a seeded family
changes geometry with the seed).

May import: numpy, ``uvms_env`` below ``env`` (the simulator, the team kernel, the
observation's layout) and ``uvms_env.env.core`` (the protocol it implements).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np

from uvms_env.dynamics import NQ
from uvms_env.env.core import Engine
from uvms_env.env.options import GEOMETRY_CACHE_SIZE
from uvms_env.robot.observation import FAR_OBSTACLE, OBSERVATION_LAYOUT
from uvms_env.scenarios import Scenario
from uvms_env.sim import Simulator
from uvms_env.sim.simulator import SimulationDiverged
from uvms_env.task.conditions import Conditions
from uvms_env.task.team_kernel import TeamKinematics


@dataclass
class World:
    """Everything compiled for one scenario's geometry."""

    scenario: Scenario
    sim: Simulator
    kinematics: TeamKinematics


class ScalarEngine(Engine):
    """One environment's physics (module docstring); ``sim`` is the current geometry's
    truth simulator."""

    xp = np

    def __init__(self, scenario: Scenario, wrench: bool) -> None:
        """``wrench``: the kinematics kernel samples the internal wrench (the variant with
        the simulator's chain inside) at every evaluation."""
        self.noisy = scenario.sensor_noise > 0
        self.wrench = wrench
        self._worlds: OrderedDict[int, World] = OrderedDict()
        self._reason = ""
        self.set_geometry([0], [scenario])
        self.tau_max = self.sim.tau_max

    @property
    def scenario(self) -> Scenario:
        return self.world.scenario

    def set_geometry(self, rows: list[int], scenarios: list[Scenario]) -> None:
        (s,) = scenarios
        key = id(s)
        if key in self._worlds and self._worlds[key].scenario is s:
            self._worlds.move_to_end(key)
        else:
            sim = Simulator(s)
            chain = sim.chain_key if self.wrench else None
            kin = TeamKinematics(
                s, sim.object.segments, OBSERVATION_LAYOUT, FAR_OBSTACLE, chain=chain
            )
            self._worlds[key] = World(s, sim, kin)
            while len(self._worlds) > GEOMETRY_CACHE_SIZE:
                self._worlds.popitem(last=False)
        self.bind(self._worlds[key])

    def bind(self, world: World) -> None:
        """Views into the world's simulator state (kept: it is updated in place)."""
        self.world = world
        self.sim, self.kin = world.sim, world.kinematics
        x, n = world.sim.flat_state, world.scenario.n_agents
        self._q = x[: NQ * n].reshape(n, NQ)
        self._zeta = x[NQ * n : 2 * NQ * n].reshape(n, NQ)
        self._x_o = x[2 * NQ * n : 2 * NQ * n + 6]
        # the kernel's action and sequencers inputs: buffers bound once (a new array each
        # call would be re-bound, which costs more than the copy)
        self._a, self._robots, self._team = np.zeros((n, 8)), np.zeros((n, 2)), np.zeros(5)
        self._q_meas, self._zeta_meas = self._q, self._zeta

    def reset(
        self, rows: list[int], sim_seeds: list[int], conditions: list[Conditions] | None = None
    ) -> None:
        if conditions is None:
            self.sim.reset(seed=sim_seeds[0])
        else:
            self.sim.reset(sim_seeds[0], conditions[0].current, conditions[0].mismatch)

    def step(self, tau: np.ndarray) -> np.bool_:
        try:
            self.sim.advance(tau)  # checked at the adapter; it saturates
        except SimulationDiverged as exc:
            self._reason = str(exc)  # the simulator kept the last valid state
            return np.bool_(True)
        return np.bool_(False)

    def diverged_reasons(self, rows: list[int]) -> list[str]:
        return [self._reason]

    def measure(self, ids: Any, q_noise: np.ndarray, zeta_noise: np.ndarray) -> None:
        self._q_meas = q_noise + self._q
        self._zeta_meas = zeta_noise + self._zeta

    def run_kinematics(
        self, ids: Any, action: Any, elapsed: Any, robots: Any, team: Any, measured: bool = True
    ) -> tuple:
        kin = self.kin
        kin.time_fraction[0] = elapsed
        self._robots[:] = robots
        self._team[:] = team
        self._a[:] = 0.0 if action is None else action
        q, zeta = (self._q_meas, self._zeta_meas) if measured else (self._q, self._zeta)
        extra = self.sim.wrench_inputs() if self.wrench else ()
        kin(self._a, self._q, self._zeta, q, zeta, self._x_o, self._robots, self._team, *extra)
        return (
            kin.observation,
            kin.team_rows(),
            kin.constraints,
            kin.violated_count,
            kin.sequencers,
        )

    def wrench_sq(self, sampled: Any) -> float:
        return float(self.kin.wrench_sq[0])  # the step's evaluation computed it

    def object_pose(self, ids: Any) -> np.ndarray:
        return self._x_o

    def robots(self) -> tuple[np.ndarray, np.ndarray]:
        return self._q, self._zeta

    def flat_state(self) -> np.ndarray:
        return self.sim.flat_state

    def __getstate__(self) -> dict:
        """Pickles hold the current world only (each other would rebuild its compiled
        functions) and no views into it."""
        state = dict(self.__dict__)
        key = id(self.world.scenario)
        state["_worlds"] = OrderedDict([(key, self.world)])
        for view in (
            "_q",
            "_zeta",
            "_x_o",
            "_q_meas",
            "_zeta_meas",
            "sim",
            "kin",
            "_a",
            "_robots",
            "_team",
        ):
            state.pop(view, None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._worlds = OrderedDict([(id(self.world.scenario), self.world)])
        self.bind(self.world)
