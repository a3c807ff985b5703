"""The paper's figures from a recorded closed loop, each with its bounds drawn, and a GIF.

trajectory.png (top view among the obstacles, 4 snapshots of the team), object.png
(object coordinates over time with the waypoints), manipulability.png
(det(Jbar Jbar^T) per robot with eps), joint_states.png (q_m with +-2 rad),
inputs.png (normalized inputs with +-1), velocities.png (vehicle body twist with
+-0.5 m/s / +-0.1 rad/s and joint rates with +-0.1 rad/s), animation.gif.

May import: numpy, matplotlib (Agg) and ``uvms_env`` (models, dynamics, navigation).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from uvms_env.dynamics.uvms import default_model
from uvms_env.models import load_parameters
from uvms_env.navigation import Cylinder
from uvms_env.task.constraints import MANIPULABILITY_EPS


def _bounds(ax, value: float, label: str | None = None) -> None:
    ax.axhline(value, color="r", ls="--", lw=0.8, label=label)
    ax.axhline(-value, color="r", ls="--", lw=0.8)


def _team_points(q: np.ndarray) -> list[np.ndarray]:
    model = default_model()
    return [np.array(model.body_points(qi)) for qi in q]  # 3 x K each


def _draw_scene(ax, scenario) -> None:
    for obs in scenario.obstacles:
        if isinstance(obs, Cylinder):
            ax.add_patch(plt.Circle((obs.x, obs.y), obs.radius, color="0.5"))
            inflated = obs.radius + scenario.team_radius
            ax.add_patch(plt.Circle((obs.x, obs.y), inflated, fill=False, ls=":", color="0.5"))
        else:
            c = obs.center
            ax.add_patch(plt.Circle((c[0], c[1]), obs.radius, color="0.6"))
    wp = scenario.waypoints
    ax.plot(wp[:, 0], wp[:, 1], "k*", ms=10, label="waypoints")


def _save(fig, out: Path, name: str) -> str:
    fig.savefig(out / name, dpi=110)
    plt.close(fig)
    return name


def _draw_team(ax, q: np.ndarray, x_o: np.ndarray, color: str) -> None:
    for pts in _team_points(q):
        ax.plot(pts[0], pts[1], "-", color=color, lw=1.5)
        ax.plot(pts[0, 0], pts[1, 0], "s", color=color, ms=5)
    ax.plot(x_o[0], x_o[1], "o", color=color, ms=3)


def make_figures(
    arr: dict[str, np.ndarray], scenario, out: Path, animate: bool = True
) -> list[str]:
    """Write the figures into ``out``; returns the file names written."""
    out.mkdir(parents=True, exist_ok=True)
    lim = load_parameters().limits
    t, q = arr["t"], arr["q"]
    written = [
        _trajectory_figure(arr, scenario, out),
        _object_figure(arr, scenario, out),
        _manipulability_figure(arr, out),
        _per_robot(
            out / "joint_states.png",
            t,
            q[:, :, 6:],
            [f"q{j + 1}" for j in range(4)],
            lim.joint_position,
            "limit",
            "[rad]",
            "Joint-level states",
            lw=1.5,
            legend=7,
        ),
        _per_robot(
            out / "inputs.png",
            t,
            arr["action"],
            ["X", "Y", "Z", "N", "tau1", "tau2", "tau3", "tau4"],
            1.0,
            "saturation",
            "(a = tau / tau_max)",
            "Control inputs (normalized: 10 N / 10 N m vehicle, 2 N m joints)",
            lw=0.8,
            legend=6,
        ),
        _velocities_figure(arr, lim, out),
    ]
    if animate:
        written += _animation(arr, scenario, out)
    return written


def _trajectory_figure(arr: dict[str, np.ndarray], scenario, out: Path) -> str:
    t, q, x_o = arr["t"], arr["q"], arr["x_o"]
    fig, ax = plt.subplots(figsize=(7, 6))
    _draw_scene(ax, scenario)
    ax.plot(x_o[:, 0], x_o[:, 1], "b-", lw=1, label="object")
    for k, c in zip(
        np.linspace(0, len(t) - 1, 4).astype(int), ["C0", "C1", "C2", "C3"], strict=True
    ):
        _draw_team(ax, q[k], x_o[k], c)
        ax.annotate(f"t={t[k]:.0f}s", x_o[k, :2], fontsize=8)
    ax.set_aspect("equal")
    ax.set_xlabel("x (north) [m]")
    ax.set_ylabel("y (east) [m]")
    ax.set_title("Trajectory among the obstacles (dotted: inflated by the team radius)")
    ax.legend(loc="upper left", fontsize=8)
    return _save(fig, out, "trajectory.png")


def _object_figure(arr: dict[str, np.ndarray], scenario, out: Path) -> str:
    t, x_o = arr["t"], arr["x_o"]
    fig, axs = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for j, name in enumerate("xyz"):
        axs[0].plot(t, x_o[:, j], label=name)
    for wp in scenario.waypoints:
        for j in range(3):
            axs[0].axhline(wp[j], color=f"C{j}", ls=":", lw=0.6)
    axs[0].set_ylabel("position [m]")
    axs[0].legend(fontsize=8)
    for j, name in enumerate(("roll", "pitch", "yaw")):
        axs[1].plot(t, x_o[:, 3 + j], label=name)
    _bounds(axs[1], np.pi / 2, "|theta_O| < pi/2")
    axs[1].set_ylim(-0.6, 0.6)
    axs[1].set_ylabel("attitude [rad]")
    axs[1].set_xlabel("t [s]")
    axs[1].legend(fontsize=8)
    fig.suptitle("Object coordinates")
    return _save(fig, out, "object.png")


def _manipulability_figure(arr: dict[str, np.ndarray], out: Path) -> str:
    t, man = arr["t"], arr["manipulability"]
    fig, ax = plt.subplots(figsize=(8, 3.5))
    for i in range(man.shape[1]):
        ax.plot(t, man[:, i], label=f"UVMS {i}")
    ax.axhline(MANIPULABILITY_EPS, color="r", ls="--", label="eps")
    ax.set_ylim(bottom=0)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("det(Jbar Jbar^T)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return _save(fig, out, "manipulability.png")


def _velocities_figure(arr: dict[str, np.ndarray], lim, out: Path) -> str:
    t, zeta = arr["t"], arr["zeta"]
    n = zeta.shape[1]
    fig, axs = plt.subplots(n, 3, figsize=(12, 2.6 * n), sharex=True, squeeze=False)
    for i in range(n):
        for j, lab in enumerate("uvw"):
            axs[i, 0].plot(t, zeta[:, i, j], label=lab)
        _bounds(axs[i, 0], lim.vehicle_linear_speed)
        for j, lab in enumerate("pqr"):
            axs[i, 1].plot(t, zeta[:, i, 3 + j], label=lab)
        _bounds(axs[i, 1], lim.vehicle_angular_speed)
        for j in range(4):
            axs[i, 2].plot(t, zeta[:, i, 6 + j], label=f"qd{j + 1}")
        _bounds(axs[i, 2], lim.joint_speed)
        axs[i, 0].set_ylabel(f"UVMS {i}")
        for ax in axs[i]:
            ax.legend(fontsize=6, ncol=4)
    axs[0, 0].set_title("vehicle linear [m/s]")
    axs[0, 1].set_title("vehicle angular [rad/s]")
    axs[0, 2].set_title("joint rates [rad/s]")
    fig.tight_layout()
    return _save(fig, out, "velocities.png")


def _animation(arr: dict[str, np.ndarray], scenario, out: Path, frames: int = 50) -> list[str]:
    try:
        import PIL  # noqa: F401
        from matplotlib.animation import FuncAnimation, PillowWriter
    except ImportError:
        print("pillow is not installed: animation skipped")
        return []
    t, q, x_o = arr["t"], arr["q"], arr["x_o"]
    idx = np.linspace(0, len(t) - 1, frames).astype(int)
    fig, ax = plt.subplots(figsize=(5, 4.5))

    def draw(k: int) -> None:
        ax.clear()
        _draw_scene(ax, scenario)
        ax.plot(x_o[: k + 1, 0], x_o[: k + 1, 1], "b-", lw=1)
        _draw_team(ax, q[k], x_o[k], "C1")
        ax.set_xlim(x_o[:, 0].min() - 3, x_o[:, 0].max() + 3)
        ax.set_ylim(x_o[:, 1].min() - 3, x_o[:, 1].max() + 3)
        ax.set_aspect("equal")
        ax.set_title(f"t = {t[k]:.1f} s")

    anim = FuncAnimation(fig, draw, frames=idx)
    anim.save(out / "animation.gif", writer=PillowWriter(fps=10), dpi=70)
    plt.close(fig)
    return ["animation.gif"]


def _per_robot(
    path: Path,
    t: np.ndarray,
    series: np.ndarray,
    names: list[str],
    bound: float,
    bound_label: str,
    unit: str,
    title: str,
    lw: float,
    legend: int,
) -> str:
    """One panel per robot with its series (T, N, K) and the +-bound drawn."""
    n = series.shape[1]
    fig, axs = plt.subplots(n, 1, figsize=(8, 2.5 * n), sharex=True, squeeze=False)
    for i in range(n):
        ax = axs[i, 0]
        for j, name in enumerate(names):
            ax.plot(t, series[:, i, j], lw=lw, label=name)
        _bounds(ax, bound, bound_label)
        ax.set_ylabel(f"UVMS {i} {unit}")
        ax.legend(fontsize=legend, ncol=len(names) + 1)
    axs[-1, 0].set_xlabel("t [s]")
    fig.suptitle(title)
    return _save(fig, path.parent, path.name)
