"""3D replays of an episode: one self-contained HTML file (three.js, the episode's data inline).

``ReplayRecorder`` records an episode from any loop over a ``parallel_env`` and writes the
page; ``replay_from_trajectory`` builds one from the main job's ``trajectory.npz``,
recomputing the constraint values from the recorded states and inputs, since that file
does not hold them:

    python -m uvms_env.replay runs/paper/trajectory.npz [--out replay.html] [--full-rate]

The poses are computed here, once, so the page does no kinematics. Rendering stays
optional: nothing here is imported by the environment's step. Reference: docs/replay.md
(what the page shows, the display frame, decimation, the three.js subset).

May import: numpy, casadi, ``uvms_env.dynamics``, ``uvms_env.navigation``,
``uvms_env.scenarios``, ``uvms_env.task.metrics`` (the metrics' names), ``uvms_env.env.infos``
(the infos' layout) and, to rebuild a recorded episode's geometry and constraints, the
environment (``uvms_env.parallel_env``, lazily).
"""

from __future__ import annotations

import argparse
import base64
import json
import math
import re
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import casadi as cs
import numpy as np

from uvms_env.dynamics.spatial import rot_zyx
from uvms_env.dynamics.uvms import default_model
from uvms_env.env.infos import (
    CONSTRAINT_PREFIX,
    EPISODE_END_NAMES,
    constraint_kinds,
    episode_metrics,
)
from uvms_env.navigation import Cylinder
from uvms_env.scenarios import Scenario
from uvms_env.task.metrics import HEAD, TAIL, json_ready

# A page stays a few MB and plays smoothly up to this many frames; longer episodes are
# decimated unless ``full_rate``.
MAX_FRAMES = 1500
THREE_JS = "three-0.187.0.min.js"
# NED -> display (x right, y up, z towards the viewer): (x, y, z) -> (x, -z, y), det +1.
NED_TO_DISPLAY = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
# The metrics the page lists (when the episode has them), in the metrics' order: how the
# episode ended and the episode's totals but the bookkeeping a viewer does not read (the
# per-kind violations are listed apart).
NOT_SHOWN = frozenset("violation_periods control_effort grasp_drift_max_m".split())
SHOWN_METRICS = ("episode_end", *(m for m in (*HEAD, *TAIL) if m not in NOT_SHOWN))


@dataclass
class Episode:
    """What a replay shows: frame 0 is the start state, frame k the state after period k."""

    scenario: Scenario
    segments: np.ndarray  # (S, 2, 3) the object's segments, object frame (NED axes)
    object_radius: float
    agents: list[str]
    constraints: list[str]
    t: np.ndarray  # (F,)
    q: np.ndarray  # (F, N, 10)
    x_o: np.ndarray  # (F, 6)
    g: np.ndarray  # (F, N, C); NaN where not evaluated (the start state)
    metrics: dict[str, Any] = field(default_factory=dict)
    title: str = ""


class ReplayRecorder:
    """Records an episode of a ``parallel_env`` from any loop; writes its replay page.

    Create it after ``env.reset()`` (it records the start state), call ``record(infos)``
    after every ``env.step``, then ``write(path)`` (example: docs/replay.md)."""

    def __init__(self, env: Any, title: str = "") -> None:
        self.env = env.unwrapped
        sim = self.env.sim
        self.agents = list(self.env.possible_agents)
        self.title = title
        self.t: list[float] = []
        self.q: list[np.ndarray] = []
        self.x_o: list[np.ndarray] = []
        self.g: list[np.ndarray] = []
        self.constraints: list[str] | None = None
        self.metrics: dict[str, Any] = {}
        self.scenario = self.env.scenario
        self.segments = np.array([[a, b] for a, b in sim.object.segments], dtype=float)
        self.object_radius = float(sim.object.radius)
        self._append(None)

    def _append(self, g: np.ndarray | None) -> None:
        st = self.env.sim.state
        self.t.append(float(st.t))
        self.q.append(np.array(st.q, dtype=float))
        self.x_o.append(np.array(st.x_O, dtype=float))
        self.g.append(g if g is not None else np.full((len(self.agents), 0), np.nan))

    def record(self, infos: dict[str, dict[str, Any]]) -> None:
        """The state after a step and the step's constraint values (``infos``)."""
        first = infos[self.agents[0]]
        if self.constraints is None:
            self.constraints = constraint_kinds(first)
        keys = [CONSTRAINT_PREFIX + c for c in self.constraints]
        g = np.array([[infos[a][k] for k in keys] for a in self.agents])
        self._append(g)
        ended = episode_metrics(first)
        if ended is not None:
            self.metrics = {**ended, "episode_end": EPISODE_END_NAMES[int(first["episode_end"])]}

    def episode(self) -> Episode:
        names = self.constraints or []
        g = np.full((len(self.t), len(self.agents), len(names)), np.nan)
        for k, gk in enumerate(self.g):
            if gk.size:
                g[k] = gk
        return Episode(
            scenario=self.scenario,
            segments=self.segments,
            object_radius=self.object_radius,
            agents=self.agents,
            constraints=names,
            t=np.array(self.t),
            q=np.stack(self.q),
            x_o=np.stack(self.x_o),
            g=g,
            metrics=self.metrics,
            title=self.title or self.scenario.name,
        )

    def write(self, path: str | Path, full_rate: bool = False) -> Path:
        """Write the replay page; returns its path."""
        return write_replay(self.episode(), path, full_rate)


# -- from the main job's trajectory.npz ----------------------------------------------------
def replay_from_trajectory(
    path: str | Path, scenario: str | Scenario | None = None, seed: int | None = None
) -> Episode:
    """The episode of a ``trajectory.npz`` (``nmpc_expert``: t, q, zeta, x_o, v_o, action
    after each period). ``scenario``: the episode's ``Scenario`` (its geometry as run), or a
    family name that with ``seed`` rebuilds it; both default to the ``metrics.json`` beside
    the file. The constraint values are recomputed from each recorded state (``input``
    from the recorded action), as the environment evaluates them after a step."""
    import uvms_env

    path = Path(path)
    arr = np.load(path)
    metrics: dict[str, Any] = {}
    side = path.with_name("metrics.json")
    if side.exists():
        metrics = json.loads(side.read_text())
    seed = int(seed if seed is not None else metrics.get("seed", 0))
    if isinstance(scenario, Scenario):
        env, name = uvms_env.parallel_env(scenario=scenario), scenario.name
    else:
        name = scenario or metrics.get("scenario", "paper")
        env = uvms_env.parallel_env(scenario=name, seed=seed)
        if len(env.possible_agents) != arr["q"].shape[1]:
            env = uvms_env.parallel_env(scenario=name, seed=seed, n_agents=arr["q"].shape[1])
    env.reset(seed=seed)
    recorder = ReplayRecorder(env, title=f"{name} (seed {seed})")
    sim = env.sim
    for k in range(len(arr["t"])):
        sim.set_state(arr["q"][k], arr["zeta"][k], arr["x_o"][k], arr["v_o"][k])
        values = env.constraint_values()  # with zero actions: "input" is redone below
        for i, a in enumerate(recorder.agents):
            values[a]["input"] = float(np.max(np.abs(arr["action"][k, i])) - 1.0)
        recorder.record(values_as_infos(values))
        recorder.t[-1] = float(arr["t"][k])
    recorder.metrics = metrics
    return recorder.episode()


def replay_path(folder: str | Path, *parts: Any) -> Path:
    """``folder/replay_PART_PART.html``, each part made safe for a file name (a policy such
    as ``ppo:runs/x+filter`` becomes ``ppo_runs_x_filter``)."""
    name = "_".join(re.sub(r"[^\w.-]+", "_", str(p)).strip("_") for p in ("replay", *parts))
    return Path(folder) / f"{name}.html"


def values_as_infos(values: dict[str, dict[str, float]]) -> dict[str, dict[str, Any]]:
    """Per-agent constraint values in the shape of a step's infos (``uvms_env.env.infos``)."""
    return {a: {CONSTRAINT_PREFIX + k: g for k, g in v.items()} for a, v in values.items()}


# -- the page ----------------------------------------------------------------------------
def frame_indices(
    n_frames: int, full_rate: bool = False, max_frames: int = MAX_FRAMES
) -> np.ndarray:
    """The frames a page keeps: all, or every k-th (the first and the last always)."""
    if full_rate or n_frames <= max_frames:
        return np.arange(n_frames)
    stride = math.ceil((n_frames - 1) / (max_frames - 1))
    keep = np.arange(0, n_frames, stride)
    return keep if keep[-1] == n_frames - 1 else np.append(keep, n_frames - 1)


def window_max(g: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """g of each kept frame: the largest value over the frames since the previous kept one
    (NaN where none of them was evaluated)."""
    out = np.empty((len(keep), *g.shape[1:]))
    start = 0
    for j, k in enumerate(keep):
        window = g[start : k + 1]
        out[j] = np.nan if np.isnan(window).all() else np.nanmax(window, axis=0)
        start = k + 1
    return out


def _quaternions(euler: np.ndarray) -> np.ndarray:
    """(M, 3) ZYX Euler angles (NED) -> (M, 4) display-frame quaternions (x, y, z, w)."""
    theta = cs.SX.sym("theta", 3)
    rot = cs.Function("rot", [theta], [cs.vec(rot_zyx(theta))]).map(len(euler))
    r = np.array(rot(euler.T)).T.reshape(len(euler), 3, 3).transpose(0, 2, 1)  # column-major
    r = NED_TO_DISPLAY @ r @ NED_TO_DISPLAY.T
    return _matrix_to_quaternion(r)


def _matrix_to_quaternion(r: np.ndarray) -> np.ndarray:
    """(M, 3, 3) rotation matrices -> (M, 4) unit quaternions (x, y, z, w), w >= 0; each
    from its largest component, the well-conditioned choice."""
    tr = np.trace(r, axis1=1, axis2=2)
    cand = np.stack([r[:, 0, 0], r[:, 1, 1], r[:, 2, 2], tr], axis=1)
    out = np.empty((len(r), 4))
    for m, i in enumerate(np.argmax(cand, axis=1)):
        rm = r[m]
        if i == 3:
            s = 2.0 * math.sqrt(max(1.0 + tr[m], 1e-12))
            v = [rm[2, 1] - rm[1, 2], rm[0, 2] - rm[2, 0], rm[1, 0] - rm[0, 1], s * s / 4]
        else:
            j, k = (i + 1) % 3, (i + 2) % 3
            s = 2.0 * math.sqrt(max(1.0 + rm[i, i] - rm[j, j] - rm[k, k], 1e-12))
            v = [0.0, 0.0, 0.0, rm[k, j] - rm[j, k]]
            v[i] = s * s / 4
            v[j] = rm[j, i] + rm[i, j]
            v[k] = rm[k, i] + rm[i, k]
        out[m] = np.array(v) / s
    out *= np.where(out[:, 3:] < 0, -1.0, 1.0)
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def display(points: np.ndarray) -> np.ndarray:
    """NED points (..., 3) in the display frame."""
    return np.asarray(points, dtype=float) @ NED_TO_DISPLAY.T


def _b64(a: np.ndarray) -> dict[str, Any]:
    a32 = np.ascontiguousarray(a, dtype=np.float32)
    return {"shape": list(a32.shape), "b64": base64.b64encode(a32.tobytes()).decode("ascii")}


def page_data(ep: Episode, full_rate: bool = False) -> dict[str, Any]:
    """The page's JSON: the scene (display frame) and the frames' arrays."""
    model = default_model()
    keep = frame_indices(len(ep.t), full_rate)
    f, n = len(keep), ep.q.shape[1]
    q = ep.q[keep]
    pts = np.array(model.body_points.map(f * n)(q.reshape(-1, q.shape[-1]).T))  # (3, 6 F N)
    pts = pts.reshape(3, f * n, -1).transpose(1, 2, 0).reshape(f, n, -1, 3)
    sc = ep.scenario
    ws = sc.workspace
    cylinders = [o for o in sc.obstacles if isinstance(o, Cylinder)]
    spheres = [o for o in sc.obstacles if not isinstance(o, Cylinder)]
    wp = np.asarray(sc.waypoints, dtype=float)
    return {
        "title": ep.title,
        "agents": ep.agents,
        "constraints": ep.constraints,
        "metrics": {k: json_ready(ep.metrics[k]) for k in SHOWN_METRICS if k in ep.metrics},
        "violations": {
            c: json_ready(ep.metrics[f"violations_{c}"])
            for c in ep.constraints
            if f"violations_{c}" in ep.metrics
        },
        "period": float(sc.period),
        "episode_frames": len(ep.t),
        "radii": {
            "vehicle": float(model.params.vehicle.bounding_radius),
            "tube": float(model.params.arm.tube_radius),
            "object": ep.object_radius,
        },
        "scene": {
            "workspace": {
                "center": display(ws.center).tolist(),
                "radius": float(ws.radius),
            },
            "cylinders": [[o.x, o.y, o.radius] for o in cylinders],  # NED x, y: vertical axis
            "spheres": [[*display(o.center).tolist(), o.radius] for o in spheres],
            "waypoints": display(wp[:, :3]).tolist(),
            "segments": display(ep.segments).tolist(),
        },
        "frames": {
            "index": _b64(keep),
            "t": _b64(ep.t[keep]),
            "points": _b64(display(pts)),
            "vehicle_quat": _b64(_quaternions(q[..., 3:6].reshape(-1, 3)).reshape(f, n, 4)),
            "object_pos": _b64(display(ep.x_o[keep, :3])),
            "object_quat": _b64(_quaternions(ep.x_o[keep, 3:6])),
            "g": _b64(window_max(ep.g, keep)),
        },
    }


def _asset(name: str) -> str:
    return resources.files("uvms_env").joinpath("replay_assets", name).read_text("utf-8")


def replay_html(ep: Episode, full_rate: bool = False) -> str:
    """The replay page of an episode, as one string."""
    data = json.dumps(page_data(ep, full_rate), separators=(",", ":"), allow_nan=False)
    three = _asset(THREE_JS)
    if "</script" in three.lower():  # would end the inline script early
        raise ValueError(f"{THREE_JS} contains '</script'")
    page = _asset("viewer.html")
    data = data.replace("</", "<\\/")  # JSON inside <script>: "</" must not close it
    return page.replace("/*@THREE@*/", three).replace("/*@DATA@*/", data)


def write_replay(ep: Episode, path: str | Path, full_rate: bool = False) -> Path:
    """Write the replay page of an episode; returns its path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(replay_html(ep, full_rate), encoding="utf-8")
    return path


def main(argv: list[str] | None = None) -> Path:
    ap = argparse.ArgumentParser(
        prog="python -m uvms_env.replay",
        allow_abbrev=False,
        description="Write a 3D replay page (one HTML file) from a trajectory.npz.",
    )
    ap.add_argument("trajectory", type=Path, help="trajectory.npz of python -m nmpc_expert")
    ap.add_argument("--out", type=Path, default=None, help="default: replay.html beside it")
    ap.add_argument("--full-rate", action="store_true", help="every period, no decimation")
    ap.add_argument("--scenario", default=None, help="default: from metrics.json beside it")
    ap.add_argument("--seed", type=int, default=None, help="default: from metrics.json")
    args = ap.parse_args(argv)
    ep = replay_from_trajectory(args.trajectory, args.scenario, args.seed)
    out = write_replay(ep, args.out or args.trajectory.with_name("replay.html"), args.full_rate)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB, {len(ep.t)} frames)")
    return out


if __name__ == "__main__":
    main()
