"""One NMPCPolicy per robot played by the episode driver (``uvms_env.episode``), with the
trajectory the figures and the .npz file need.

Each policy gets only its own agent's observation. The trajectory (true states, inputs,
constraint values, decision times) is recorded per step; the metrics are the driver's
(the environment's plus ``policy_time_ms``) and the expert's own counters (fallbacks,
waypoint order).

May import: numpy, tqdm, ``uvms_env`` and this package.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

import uvms_env
from nmpc_expert.local_controller import NMPCPolicy
from nmpc_expert.settings import NMPCSettings
from uvms_env.episode import Step, play
from uvms_env.policy import AgentSpec
from uvms_env.task.constraints import CONSTRAINTS, MANIPULABILITY_EPS


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
    replay: Path | None = None,
    **overrides: Any,
) -> tuple[dict[str, Any], dict[str, np.ndarray], Any]:
    """Run one episode; returns (metrics, trajectory arrays, the env's scenario);
    ``replay``: also write the episode's 3D replay page there."""
    if max_steps is not None:
        overrides["max_cycles"] = max_steps
    env = uvms_env.parallel_env(scenario=scenario, seed=seed, **overrides)
    traj = Trajectory()
    order_ok, last_wp = True, None
    desc = f"{scenario} NMPC ({solver})"
    bar: tqdm | None = None

    def record(step: Step) -> None:
        nonlocal order_ok, last_wp, bar
        if bar is None:
            # opened after the first period: the compiles of the first decision and step
            # (announced on their own lines) stay out of its rate and ETA
            bar = tqdm(total=env.max_cycles, desc=desc, unit="step", disable=not progress)
        agents = list(step.policies)
        wp = np.array([step.policies[a].stats["waypoint_index"] for a in agents])
        last = np.zeros_like(wp) if last_wp is None else last_wp
        order_ok &= bool(np.all((wp == last) | (wp == last + 1)))
        last_wp = wp
        st = step.env.unwrapped.sim.state
        traj.t.append(st.t)
        traj.q.append(st.q.copy())
        traj.zeta.append(st.zeta.copy())
        traj.x_o.append(st.x_O.copy())
        traj.v_o.append(st.v_O.copy())
        traj.action.append(np.stack([step.actions[a] for a in agents]))
        g = [step.infos[a]["constraint_manipulability"] for a in agents]
        traj.manipulability.append(MANIPULABILITY_EPS - np.array(g))
        traj.waypoint.append(wp)
        traj.policy_ms.append(step.decision_ms)
        bar.update(1)

    def nmpc(spec: AgentSpec) -> NMPCPolicy:
        return NMPCPolicy(spec, solver=solver, settings=settings)

    episode = play(env, nmpc, seed, on_step=record, replay=replay)
    if bar is not None:
        bar.total = bar.n  # the episode's end is the bar's end, not the step cap
        bar.refresh()
        bar.close()
    metrics = episode.metrics
    metrics["episode_end"] = episode.end
    metrics["fallbacks"] = int(sum(p.fallbacks for p in episode.policies.values()))
    metrics["waypoints_in_order"] = bool(order_ok)
    metrics["solver"] = solver
    metrics["scenario"] = scenario
    metrics["seed"] = seed
    metrics["n_agents"] = len(episode.policies)
    metrics["constraint_kinds"] = list(CONSTRAINTS)
    return metrics, traj.arrays(), env.scenario
