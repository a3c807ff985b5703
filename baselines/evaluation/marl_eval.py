"""Per-episode evaluation rows as marl-eval JSON (InstaDeep's ``id-marl-eval`` tools).

marl-eval's statistics and plots (interquartile means, performance profiles, probability
of improvement) read one nested dictionary:

    {env_name: {task_name: {algo_name: {"seed_K": {
        "step_0": {"step_count": int, "elapsed_time": float, metric: [per episode]}, ...,
        "absolute_metrics": {metric: [per episode]}}}}}}

One evaluation of ``baselines.evaluate`` is one logging step of one run: the step holds
the per-episode values of each metric, and ``absolute_metrics`` repeats the latest step
(marl-eval takes the final evaluation of a run from there). Writing into an existing file
merges, so several policies, seeds or training evaluations land in one file, as the
tools expect.

The names are BenchMARL's for its uvms tasks (baselines.benchmarl_tasks), so that the evaluator's
file and BenchMARL's merge (``merge``; marl-eval reads every algorithm of a task with the
first one's runs, steps and metrics): the environment ``uvms``, the task (``paper``,
``short``, ``random_n2``: the random family always with its team size), the algorithm by
what was trained and the run by its training seed (``run_identity``: BenchMARL's algorithm
and seed for ``benchmarl:PATH``; ``<library>_<algo>`` and the seed of the run's config.json
for the project's trainers). A policy with no known training seed (the expert, the
untrained baselines, a saved policy without a run record) is filed, with its label as the
algorithm, under each training seed of the evaluation's trained policies on its task, else
of the task's runs already in the file, else the evaluation seed: one run per training seed,
the same episodes in each, as marl-eval's per-run tables need.

May import: the standard library, numpy, ``baselines.registry``, ``baselines.loaders.saved``
and ``baselines.loaders.sources`` (names), and the loaders they name (on demand; no ray, no torch
otherwise); ``baselines.evaluation.summary`` (the rows' metric reader) when adding rows.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import pickle
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

ENV_NAME = "uvms"  # BenchMARL's name of the uvms tasks' environment (benchmarl_tasks)
RANDOM_FAMILY, DEFAULT_TEAM = "random", 2  # the family whose team size varies; its default
GROUP_RETURN = "uvms_return"  # BenchMARL's return of the agent group, the team's here
# marl-eval averages every list it finds, so only numeric per-episode values; booleans as
# 0/1 so success rates aggregate like returns. Also every per-kind column (violations and
# the graded safety, ``PER_KIND``).
METRICS: tuple[str, ...] = (
    "return",
    GROUP_RETURN,
    "success",
    "clean_success",
    "clean_success_tol",
    "episode_steps",
    "final_pos_error_m",
    "final_att_error_rad",
    "min_obstacle_clearance_m",
    "violation_periods",
    "excess",
    "max_excess",
    "violated_fraction",
    "internal_wrench_rms",
)
PER_KIND = ("violations_", "excess_", "max_excess_", "violated_fraction_")
ABSOLUTE = "absolute_metrics"
STEP_KEYS = ("step_count", "elapsed_time")  # a step's entries that are no metric


def task_name(scenario: str, overrides: dict[str, Any] | None = None) -> str:
    """``paper``, ``random_n2``: marl-eval compares algorithms per task, and a team size
    is a different task (the random family's default team is 2, as BenchMARL's
    ``uvms/random_n2``)."""
    n = (overrides or {}).get("n_agents")
    if n is None and scenario == RANDOM_FAMILY:
        n = DEFAULT_TEAM
    return f"{scenario}_n{n}" if n is not None else scenario


def algo_name(policy: str) -> str:
    # marl-eval's probability-of-improvement plots split algorithm lists on commas
    return policy.replace(",", ";")


@dataclass(frozen=True)
class RunIdentity:
    """A policy's run in marl-eval's terms: the algorithm and the training seed (None:
    not known)."""

    algorithm: str
    seed: int | None


@lru_cache(maxsize=64)
def run_identity(policy: str) -> RunIdentity:
    """The algorithm and training seed of an evaluator ``--policy`` label: a saved policy's
    loader finds what it loads (``LoadedPolicy.locate``); a loader with ``training_run``
    (BenchMARL's) says what trained it; otherwise the run's config.json gives
    ``<library>_<algo>`` (``sb3`` when it names no library) and ``seed``. Anything else, or a
    saved policy that cannot be read here, keeps its label and has no seed. A ``+filter``
    suffix stays on the algorithm: the safety filter makes another controller."""
    from baselines.loaders.sources import FILTER_SUFFIX
    from baselines.registry import DEFAULT_LIBRARY, LOADERS, loader

    base = policy.removesuffix(FILTER_SUFFIX)
    suffix = policy[len(base) :]
    name, _, arg = base.partition(":")
    unknown = RunIdentity(algo_name(policy), None)
    if name not in LOADERS:
        return unknown
    try:
        cls = loader(name)
        saved = cls.locate(name, arg or None)
        training_run = getattr(cls, "training_run", None)
        if training_run is not None:
            run = training_run(saved)
            return RunIdentity(algo_name(run.algorithm + suffix), int(run.seed))
    except (ImportError, ValueError, OSError, EOFError, pickle.UnpicklingError):
        return unknown  # not readable here: the evaluation still goes to the file
    from baselines.loaders.saved import nearest_config, read_config

    # a saved folder's own config.json first, then the loaders' rule (``run_record``'s)
    config = read_config(saved) or nearest_config(saved)
    if config.get("seed") is None:
        return unknown
    algo = config.get("algo")
    trained = f"{config.get('library') or DEFAULT_LIBRARY}_{algo}" if algo else name
    return RunIdentity(algo_name(trained + suffix), int(config["seed"]))


def step_entry(
    rows: Iterable[dict[str, Any]], step_count: int, elapsed_time: float
) -> dict[str, Any]:
    """One logging step. A metric no episode has (``min_obstacle_clearance_m`` without
    obstacles) is left out; one that only some lack (an episode whose policy raised) is
    NaN there, which Python's json, and so marl-eval, reads back as NaN."""
    from baselines.evaluation.summary import metric_values  # here: merging stays light

    rows = [{**r, GROUP_RETURN: r.get("return")} for r in rows]
    kinds = sorted({k for r in rows for k in r if k.startswith(PER_KIND)})
    entry: dict[str, Any] = {"step_count": int(step_count), "elapsed_time": float(elapsed_time)}
    for metric in (*METRICS, *kinds):
        values = metric_values(rows, metric).tolist()
        if not all(map(math.isnan, values)):
            entry[metric] = values
    return entry


def is_metric(key: str) -> bool:
    return key not in STEP_KEYS


def add_evaluation(
    data: dict[str, Any],
    rows: list[dict[str, Any]],
    seed: int,
    step_count: int = 0,
    elapsed_time: float = 0.0,
    overrides: dict[str, Any] | None = None,
    step: int | None = None,
    env_name: str = ENV_NAME,
    identity: RunIdentity | None = None,
) -> dict[str, Any]:
    """Add one evaluation (rows of ``baselines.evaluate``, any policies and scenarios) to
    ``data`` as logging step ``step`` (None: the run's next) of each policy's run
    (``identity`` where the caller knows it, as a training run evaluating its own snapshots
    does, else ``run_identity``; ``seed``, the evaluation's, where no training seed is
    known: module docstring), and make it the run's ``absolute_metrics``. Returns
    ``data``."""
    # (task, algorithm, training seed or None) -> its rows
    groups: dict[tuple[str, str, int | None], list[dict[str, Any]]] = {}
    for row in rows:
        who = identity or run_identity(row["policy"])
        key = (task_name(row["scenario"], overrides), who.algorithm, who.seed)
        groups.setdefault(key, []).append(row)
    trained: dict[str, set[int]] = {}
    for task, _, s in groups:
        if s is not None:
            trained.setdefault(task, set()).add(s)
    env = data.setdefault(env_name, {})
    for (task, algo, trained_seed), group in groups.items():
        group = sorted(group, key=lambda r: r["episode"])
        run_seeds = {trained_seed} if trained_seed is not None else trained.get(task, set())
        keys = [f"seed_{s}" for s in sorted(run_seeds)]
        if not keys:  # the runs the file holds for the task, else the evaluation's seed
            held = {k for runs in env.get(task, {}).values() for k in runs}
            keys = sorted(held, key=_seed_order) or [f"seed_{seed}"]
        entry = step_entry(group, step_count, elapsed_time)
        for seed_key in keys:
            run = env.setdefault(task, {}).setdefault(algo, {}).setdefault(seed_key, {})
            index = step if step is not None else sum(k.startswith("step_") for k in run)
            run[f"step_{index}"] = copy.deepcopy(entry)
            run.pop(ABSOLUTE, None)
            # the absolute metrics close the run, as marl-eval's logger writes them
            run[ABSOLUTE] = {m: v for m, v in entry.items() if is_metric(m)}
    return data


def _seed_order(key: str) -> tuple[int, int, str]:
    tail = key.removeprefix("seed_")
    return (0, int(tail), "") if tail.isdigit() else (1, 0, key)


def _runs(data: dict[str, Any]) -> Iterator[tuple[tuple[str, str, str, str], dict[str, Any]]]:
    """Every run of a marl-eval dataset: (environment, task, algorithm, seed key), steps."""
    for env, tasks in data.items():
        for task, algos in tasks.items():
            for algo, runs in algos.items():
                for seed_key, run in runs.items():
                    yield (env, task, algo, seed_key), run


def final_only(data: dict[str, Any]) -> dict[str, Any]:
    """``data`` with each run's last logging step only, as ``step_0``, and
    ``absolute_metrics`` its per-episode values: every run then has the same steps, and the
    absolute metrics mean the same in BenchMARL's runs (there: each metric's maximum over
    the evaluations) and this module's (the latest evaluation)."""
    out: dict[str, Any] = copy.deepcopy(data)
    for (env, task, algo, seed_key), run in _runs(out):
        steps = [k for k in run if k.startswith("step_")]
        last = run[max(steps, key=lambda k: int(k.removeprefix("step_")))]
        absolute = {m: v for m, v in last.items() if is_metric(m)}
        out[env][task][algo][seed_key] = {"step_0": last, ABSOLUTE: absolute}
    return out


def merge(*datas: dict[str, Any], final: bool = False) -> dict[str, Any]:
    """One marl-eval dataset of several files' (this module's and BenchMARL's): their
    environments, tasks, algorithms, runs and steps together, each task's metrics cut to
    those that every step and ``absolute_metrics`` of its runs hold (marl-eval reads each
    run's metrics by the first run's names). marl-eval also reads every run at the first
    run's logging steps: ``final`` keeps each run's last evaluation only (``final_only``),
    which compares a BenchMARL run's training curve's end with the evaluator's one
    evaluation. A logging step that two datasets give differently raises ValueError."""
    out: dict[str, Any] = {}
    for data in map(final_only, datas) if final else datas:
        for (env, task, algo, seed_key), steps in _runs(data):
            run = out.setdefault(env, {}).setdefault(task, {}).setdefault(algo, {})
            run = run.setdefault(seed_key, {})
            for name, entry in steps.items():
                if name != ABSOLUTE and name in run and run[name] != entry:
                    where = f"{env}/{task}/{algo}/{seed_key}/{name}"
                    raise ValueError(f"two different evaluations for {where}")
                run[name] = copy.deepcopy(entry)
            run[ABSOLUTE] = run.pop(ABSOLUTE, {})  # last, as the writers put it
    for tasks in out.values():
        for algos in tasks.values():
            entries = [e for runs in algos.values() for r in runs.values() for e in r.values()]
            if not entries:
                continue
            common = set.intersection(*({m for m in e if is_metric(m)} for e in entries))
            for entry in entries:
                for metric in [m for m in entry if is_metric(m) and m not in common]:
                    del entry[metric]
    return out


def write(path: Path, rows: list[dict[str, Any]], seed: int, **kwargs: Any) -> dict[str, Any]:
    """Merge one evaluation into the JSON file at ``path`` (created if missing); see
    ``add_evaluation`` for the keywords. Returns the whole file's data."""
    path = Path(path)
    data = json.loads(path.read_text()) if path.exists() else {}
    add_evaluation(data, rows, seed, **kwargs)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2) + "\n")
    return data


def main(argv: list[str] | None = None) -> None:
    """``python -m baselines.evaluation.marl_eval merge A.json B.json ... --out C.json
    [--final]``."""
    parser = argparse.ArgumentParser(
        prog="python -m baselines.evaluation.marl_eval",
        description="Merge marl-eval JSON files (``merge``).",
        allow_abbrev=False,
    )
    parser.add_argument("command", choices=["merge"])
    parser.add_argument("files", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--final", action="store_true", help="each run's last evaluation only")
    args = parser.parse_args(argv)
    data = merge(*(json.loads(path.read_text()) for path in args.files), final=args.final)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(data, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
