"""Closed loop of one NMPCPolicy per robot on the PettingZoo environment, with metrics.

Each policy gets only its own agent's observation. The trajectory (true states, inputs,
constraint values, decision times) is recorded for the figures and the .npz file; the
metrics are the environment's (``uvms_env.env.metrics``) plus ``policy_time_ms`` and the
expert's own counters (fallbacks, waypoint order).

May import: numpy, tqdm, ``uvms_env`` and this package.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from tqdm import tqdm

import uvms_env
from nmpc_expert.policy import NMPCPolicy
from nmpc_expert.settings import NMPCSettings
from uvms_env.env.constraints import CONSTRAINTS, MANIPULABILITY_EPS
from uvms_env.policy import AgentSpec


@dataclass
class Trajectory:
    """Recorded closed loop (arrays stacked over periods)."""

    t: list[float] = field(default_factory=list)
    q: list[np.ndarray] = field(default_factory=list)
    zeta: list[np.ndarray] = field(default_factory=list)
    x_o: list[np.ndarray] = field(default_factory=list)
    v_o: list[np.ndarray] = field(default_factory=list)
    action: list[np.ndarray] = field(default_factory=list)
    manipulability: list[np.ndarray] = field(default_factory=list)
    waypoint: list[np.ndarray] = field(default_factory=list)
    policy_ms: list[np.ndarray] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.asarray(v) for k, v in self.__dict__.items()}


def run_episode(
    scenario: str = "paper",
    solver: str = "rti",
    seed: int = 0,
    max_steps: int | None = None,
    settings: NMPCSettings | None = None,
    progress: bool = True,
    **overrides: Any,
) -> tuple[dict[str, Any], dict[str, np.ndarray], Any]:
    """Run one episode; returns (metrics, trajectory arrays, the env's scenario)."""
    env = uvms_env.parallel_env(scenario=scenario, seed=seed, **overrides)
    if max_steps is not None:
        env.max_cycles = max_steps
    obs, _ = env.reset(seed=seed)
    sc = env.scenario
    pols = {
        a: NMPCPolicy(AgentSpec.from_scenario(sc, i), solver=solver, settings=settings)
        for i, a in enumerate(env.agents)
    }
    agents = list(pols)
    traj = Trajectory()
    order_ok, last_wp = True, np.zeros(len(agents), dtype=int)
    metrics: dict[str, Any] = {}
    total = env.max_cycles
    bar = tqdm(total=total, desc=f"{scenario} NMPC ({solver})", unit="step", disable=not progress)

    def record(actions: np.ndarray, cvals: dict | None, times: np.ndarray, wp: np.ndarray):
        st = env.sim.state
        traj.t.append(st.t)
        traj.q.append(st.q.copy())
        traj.zeta.append(st.zeta.copy())
        traj.x_o.append(st.x_O.copy())
        traj.v_o.append(st.v_O.copy())
        traj.action.append(actions)
        if cvals is not None:
            traj.manipulability.append(
                np.array([MANIPULABILITY_EPS - cvals[a]["manipulability"] for a in agents])
            )
        traj.waypoint.append(wp)
        traj.policy_ms.append(times)

    while True:
        actions, times = {}, np.zeros(len(agents))
        for i, a in enumerate(agents):
            t0 = time.perf_counter()
            actions[a] = pols[a].act(obs[a])
            times[i] = (time.perf_counter() - t0) * 1e3
        wp = np.array([pols[a].stats["waypoint_index"] for a in agents])
        order_ok &= bool(np.all((wp == last_wp) | (wp == last_wp + 1)))
        last_wp = wp
        obs, _, term, trunc, infos = env.step(actions)
        cvals = {a: infos[a]["constraint_values"] for a in agents}
        record(np.stack([actions[a] for a in agents]), cvals, times, wp)
        bar.update(1)
        if any(term.values()) or any(trunc.values()):
            metrics = dict(infos[agents[0]]["metrics"])
            metrics["episode_end"] = infos[agents[0]].get("episode_end")
            break
    bar.close()
    arr = traj.arrays()
    pt = arr["policy_ms"].ravel()
    metrics["policy_time_ms"] = {
        "median": float(np.median(pt)),
        "p95": float(np.percentile(pt, 95)),
        "max": float(pt.max()),
    }
    metrics["fallbacks"] = int(sum(p.fallbacks for p in pols.values()))
    metrics["waypoints_in_order"] = bool(order_ok)
    metrics["solver"] = solver
    metrics["scenario"] = scenario
    metrics["seed"] = seed
    metrics["n_agents"] = len(agents)
    metrics["constraint_kinds"] = list(CONSTRAINTS)
    return metrics, arr, sc
