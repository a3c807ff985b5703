"""Learning curves of training runs (any library) from their ``evaluations.csv`` and
``progress.csv`` (the schemas of ``baselines.runs``).

    python -m baselines.rl.plot runs/ppo runs/benchmarl_mappo runs/rllib_ppo \
        --out docs/figures/learning_curves.png
    python -m baselines.rl.plot --group "PPO-Lag=runs/a0,runs/a1,runs/a2" --group ... \
        --out docs/figures/learning_curves_seeds.png

``--group``: runs of one variant over training seeds, drawn as the mean and its 95% band
(Student t over the seeds, ``baselines.stats``); ``--per-seed``: every seed's
evaluations on every rung. Reference: docs/rl.md.

May import: the standard library, numpy, ``baselines.evaluation.report`` (the figures'
backend), ``baselines.command_line`` and ``baselines.stats``.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

from baselines.command_line import command_parser
from baselines.evaluation.report import pyplot, save
from baselines.stats import t_band


def read_rows(path: Path) -> list[dict[str, str]]:
    """A CSV's rows (none where there is no file)."""
    if not path.exists():
        return []
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def columns(rows: list[dict[str, str]]) -> dict[str, np.ndarray]:
    """CSV rows as float columns (missing or non-numeric cells: NaN)."""
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
    tables = [columns(read_rows(p)) for p in parts if p.exists() and p.stat().st_size > 0]
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
        minutes = (c.get("wall_time_s") or float("nan")) / 60
        steps = c.get("robot_steps", 0)
        library = c.get("library", c.get("engine", "sb3"))  # "engine": the earlier key
        return f"{library} {c['algo'].upper()} ({steps:,} steps, {minutes:.1f} min)"
    return run.name


def _label(axes: Any, titles: list[tuple[str, str]]) -> None:
    for ax, (title, ylabel) in zip(axes.flat, titles, strict=True):
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("robot-steps")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)


def plot(runs: list[Path], out: Path) -> None:
    fig, axes = pyplot().subplots(2, 2, figsize=(9, 5.5), sharex=False)
    for k, run in enumerate(runs):
        color, name = f"C{k}", label(run)
        # the first rung's rows (all rows where evaluations.csv has no rung)
        e = next(iter(rung_table(run).values()), None)
        if e is not None:
            t = e["robot_steps"]
            axes[0, 0].plot(t, e["success_rate"], "o-", color=color, ms=3, label=name)
            axes[0, 1].plot(t, e["mean_return"], "o-", color=color, ms=3, label=name)
            if "final_pos_error_m" in e:
                axes[1, 0].plot(t, e["final_pos_error_m"], "o-", color=color, ms=3, label=name)
        p = progress(run)
        if "episode_return_mean" in p:
            ok = np.isfinite(p["episode_return_mean"])
            axes[1, 1].plot(
                p["robot_steps"][ok], p["episode_return_mean"][ok], color=color, label=name
            )
    titles = [
        ("eval success rate", "success rate"),
        ("eval mean return (default reward weights)", "return"),
        ("eval final position error", "m"),
        ("training episodes: mean return (training reward)", "return"),
    ]
    _label(axes, titles)
    axes[0, 0].set_ylim(-0.05, 1.05)
    axes[0, 0].legend(fontsize=8)
    save(fig, out, dpi=80)


def mean_band(xs: list[np.ndarray], ys: list[np.ndarray], grid: np.ndarray):
    """Mean and 95% t-interval half-width over runs of y(x), interpolated onto ``grid``."""
    table = np.array(
        [np.interp(grid, x, y, left=np.nan, right=np.nan) for x, y in zip(xs, ys, strict=True)]
    )
    return t_band(table)


# the progress columns of ``plot_groups``' training panels (an ended-early share is
# derived from the ``ends_*`` counts)
EARLY_ENDS = ("ends_diverged", "ends_collision", "ends_constraint")


def early_share(p: dict[str, np.ndarray]) -> np.ndarray | None:
    """Per iteration, the share of its training episodes that ended early (diverged,
    collided or ended by a constraint), NaN without an episode; None without the counts."""
    if not all(k in p for k in EARLY_ENDS) or "episodes" not in p:
        return None
    early = sum(p[k] for k in EARLY_ENDS)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(p["episodes"] > 0, early / p["episodes"], np.nan)


def plot_groups(groups: dict[str, list[Path]], out: Path) -> None:
    """Per group of runs (its seeds): the mean and 95 % band of the training episodes'
    return, PPO's objective (return less the multiplier times the cost), the cost, the
    share of episodes that ended early, and the evaluations' success and clean success."""
    panels = [
        ("training episodes: mean return", "return"),
        ("training episodes: objective (return - multiplier x cost)", "objective"),
        ("training episodes: constraint cost per robot", "cost"),
        ("training episodes ended early (diverged, collision, constraint)", "share"),
        ("evaluation: success (training rungs)", "rate"),
        ("evaluation: clean success (training rungs)", "rate"),
    ]
    fig, axes = pyplot().subplots(3, 2, figsize=(9, 8.0))
    for k, (name, runs) in enumerate(groups.items()):
        color = f"C{k}"
        series: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in panels]
        for run in runs:
            p = progress(run)
            t = p.get("robot_steps")
            keys = ("episode_return_mean", "episode_objective_mean", "episode_cost_mean")
            values = [p.get(key) for key in keys] + [early_share(p)]
            for j, v in enumerate(values):
                if t is not None and v is not None:
                    ok = np.isfinite(v)
                    if ok.any():  # a run without a cost (or an older run) records none
                        series[j].append((t[ok], v[ok]))
            e = _rung_evaluations(run)
            if e is not None:
                series[4].append((e["robot_steps"], e["success_rate"]))
                series[5].append((e["robot_steps"], e["clean_success_rate"]))
        for ax, curves in zip(axes.flat, series, strict=True):
            if not curves:
                continue
            top = max(float(c[0].max()) for c in curves)
            grid = np.linspace(min(float(c[0].min()) for c in curves), top, 60)
            mean, half = mean_band([c[0] for c in curves], [c[1] for c in curves], grid)
            ax.plot(grid, mean, color=color, label=f"{name} ({len(curves)} seeds)")
            ax.fill_between(grid, mean - half, mean + half, color=color, alpha=0.2)
    _label(axes, panels)
    for ax in axes.flat[3:]:
        ax.set_ylim(-0.05, 1.05)
    axes[0, 0].legend(fontsize=8, loc="lower right")
    save(fig, out, dpi=80)


SEED_PANELS = (
    ("success_rate", "success rate"),
    ("clean_success_rate", "clean success rate"),
    ("violation_periods_median", "violation periods per episode (median)"),
)


def rung_table(run: Path) -> dict[str, dict[str, np.ndarray]]:
    """evaluations.csv by rung: rung -> column -> values, in robot-step order."""
    rows = read_rows(run / "evaluations.csv")
    rungs = dict.fromkeys(r.get("rung") or "" for r in rows)
    return {rung: columns([r for r in rows if (r.get("rung") or "") == rung]) for rung in rungs}


def plot_seed_curves(groups: dict[str, list[Path]], out: Path) -> None:
    """Every seed's evaluations, one column per rung, one row per ``SEED_PANELS`` metric:
    a line per run (its group's color), robot-steps on x (violation periods on a
    symmetric log scale: they span 0 to thousands)."""
    tables = {(name, run): rung_table(run) for name, runs in groups.items() for run in runs}
    rungs = list(dict.fromkeys(r for t in tables.values() for r in t))
    if not rungs:
        raise SystemExit("no evaluations.csv with rows in the runs")
    fig, axes = pyplot().subplots(
        len(SEED_PANELS), len(rungs), figsize=(2.6 * len(rungs) + 1, 6.5), squeeze=False
    )
    names = list(groups)
    for (name, run), table in tables.items():
        color = f"C{names.index(name)}"
        seed = groups[name].index(run)
        for j, rung in enumerate(rungs):
            if rung not in table:
                continue
            t = table[rung]
            for i, (key, _) in enumerate(SEED_PANELS):
                if key not in t:
                    continue
                label = f"{name}" if (i, j, seed) == (0, 0, 0) else None
                axes[i, j].plot(t["robot_steps"], t[key], "o-", color=color, ms=2, lw=1,
                                alpha=0.8, label=label)  # fmt: skip
    for j, rung in enumerate(rungs):
        axes[0, j].set_title(rung, fontsize=9)
        for i, (_, title) in enumerate(SEED_PANELS):
            ax = axes[i, j]
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=7)
            if i < 2:
                ax.set_ylim(-0.05, 1.05)
            else:
                ax.set_yscale("symlog", linthresh=10)
            if j == 0:
                ax.set_ylabel(title, fontsize=8)
            if i == len(SEED_PANELS) - 1:
                ax.set_xlabel("robot-steps", fontsize=8)
    axes[0, 0].legend(fontsize=7)
    save(fig, out, dpi=80)


def _rung_evaluations(run: Path) -> dict[str, np.ndarray] | None:
    """The evaluations on the run's training rung (the first rung of a ladder), or for a
    run over a distribution evaluated on the ladder the mean over every rung."""
    rows = read_rows(run / "evaluations.csv")
    if not rows or "clean_success_rate" not in rows[0]:
        return None
    config = json.loads((run / "config.json").read_text()) if (run / "config.json").exists() else {}
    keys = ("robot_steps", "success_rate", "clean_success_rate")
    if config.get("eval_ladder") and (config.get("team_sizes") or config.get("objects")):
        steps = sorted({_num(r["robot_steps"]) for r in rows})
        at = [columns([r for r in rows if _num(r["robot_steps"]) == step]) for step in steps]
        means = {k: np.array([np.mean(table[k]) for table in at]) for k in keys[1:]}
        return {"robot_steps": np.array(steps), **means}
    rung = _training_rung(config, rows[0].get("rung"))
    # a run evaluated without --eval-ladder labels its rows with the scenario's name
    rows = [r for r in rows if r.get("rung") == rung] or [
        r for r in rows if r.get("rung") == config.get("scenario")
    ]
    return {k: v for k, v in columns(rows).items() if k in keys} or None


def _training_rung(config: dict, first: str | None) -> str | None:
    """The rung of evaluations.csv that is the run's own training scenario: on the ladder
    (``--eval-ladder``) the random rung of its team size or paper, else the first rung."""
    scenario = config.get("scenario")
    if config.get("eval_ladder") and scenario in ("random", "paper"):
        n = config.get("overrides", {}).get("n_agents", 2)
        return f"random_n{n}" if scenario == "random" else "paper"
    return first or scenario


def main(argv: list[str] | None = None) -> None:
    ap = command_parser("baselines.rl.plot", __doc__)
    ap.add_argument("runs", type=Path, nargs="*", help="run folders")
    ap.add_argument(
        "--group", action="append", default=[], metavar="NAME=RUN,RUN", help="seeds of a variant"
    )
    ap.add_argument(
        "--per-seed",
        action="store_true",
        help="with --group: every seed's evaluations per rung (success, clean success, "
        "violation periods) instead of the mean and band of the training rung",
    )
    ap.add_argument("--out", type=Path, default=Path("docs/figures/learning_curves.png"))
    args = ap.parse_args(argv)
    if args.group:
        groups = {}
        for item in args.group:
            name, sep, runs = item.rpartition("=")  # a name may hold "=", run paths do not
            if not sep:
                raise SystemExit(f"expected NAME=RUN,RUN, got {item!r}")
            groups[name] = [Path(r) for r in runs.split(",")]
        (plot_seed_curves if args.per_seed else plot_groups)(groups, args.out)
    elif args.runs:
        plot(args.runs, args.out)
    else:
        raise SystemExit("give run folders or --group NAME=RUN,RUN")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
