"""Learning curves of RL runs from their ``evaluations.csv`` and ``progress.csv``.

    python -m baselines.rl.plot runs/ppo runs/sac --out docs/figures/learning_curves.png

Top: success rate and mean return of the periodic evaluations (``baselines.evaluate``,
fixed seeds, deterministic policy); bottom: the final position error of those
evaluations and the training episodes' mean return (``rollout/ep_rew_mean``) when logged.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np


def read_csv(path: Path) -> dict[str, np.ndarray]:
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    keys = list(rows[0]) if rows else []
    return {k: np.array([_num(r.get(k)) for r in rows], dtype=float) for k in keys}


def _num(x: str | None) -> float:
    try:
        return float(x)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return float("nan")


def progress(run: Path) -> dict[str, np.ndarray]:
    """progress.csv and the earlier parts kept by resumed runs, in timestep order."""
    parts = [*sorted(run.glob("progress.part*.csv")), run / "progress.csv"]
    tables = [read_csv(p) for p in parts if p.exists() and p.stat().st_size > 0]
    out: dict[str, np.ndarray] = {}
    for key in {k for t in tables for k in t}:
        n = [len(next(iter(t.values()), [])) for t in tables]
        out[key] = np.concatenate(
            [t.get(key, np.full(m, np.nan)) for t, m in zip(tables, n, strict=True)]
        )
    return out


def label(run: Path) -> str:
    cfg = run / "config.json"
    if cfg.exists():
        c = json.loads(cfg.read_text())
        minutes = c.get("wall_time_s", float("nan")) / 60
        return f"{c['algo'].upper()} ({c.get('timesteps_done', 0):,} steps, {minutes:.0f} min)"
    return run.name


def plot(runs: list[Path], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(9, 5.5), sharex=False)
    for k, run in enumerate(runs):
        color, name = f"C{k}", label(run)
        ev = run / "evaluations.csv"
        if ev.exists():
            e = read_csv(ev)
            t = e["timesteps"]
            axes[0, 0].plot(t, e["success_rate"], "o-", color=color, ms=3, label=name)
            axes[0, 1].plot(t, e["mean_return"], "o-", color=color, ms=3, label=name)
            if "final_pos_error_m" in e:
                axes[1, 0].plot(t, e["final_pos_error_m"], "o-", color=color, ms=3, label=name)
        p = progress(run)
        if "rollout/ep_rew_mean" in p:
            ok = np.isfinite(p["rollout/ep_rew_mean"])
            axes[1, 1].plot(
                p["time/total_timesteps"][ok], p["rollout/ep_rew_mean"][ok], color=color, label=name
            )
    titles = [
        ("eval success rate", "success rate"),
        ("eval mean return (default reward weights)", "return"),
        ("eval final position error", "m"),
        ("training episodes: mean return (training reward)", "return"),
    ]
    for ax, (title, ylabel) in zip(axes.flat, titles, strict=True):
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("robot-steps")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylim(-0.05, 1.05)
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=80)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m baselines.rl.plot", description=__doc__)
    ap.add_argument("runs", type=Path, nargs="+", help="run folders")
    ap.add_argument("--out", type=Path, default=Path("docs/figures/learning_curves.png"))
    args = ap.parse_args(argv)
    plot(args.runs, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
