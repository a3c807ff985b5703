"""Policies on the same seeded episodes: the cases, their episodes' seeds and the workers.

Episode k of a case with scenario S has the seed ``case_episode_seed(seed, S, k)``, which
fixes the random family's geometry, the truth-model draws, the current and the sensor
noise: every policy plays the same episodes, and a result depends only on (policy,
scenario, seed), never on the number of workers or the backend. ``Settings`` holds what a
command's evaluations share.

Before any episode, ``preflight`` builds each case's environment and each policy once:
a case the environment refuses or a policy that cannot be loaded is a ``UsageError``
naming it, not a column of failed episodes. A policy that fails while it plays (a solver error)
still ends its episodes as failures, each with its error.

May import: the standard library, tqdm, ``baselines.evaluation`` (episode_row, batched,
splits), ``baselines.loaders.sources``, ``baselines.evaluation.ray_backend`` and
``baselines.ray_runtime`` (``backend="ray"``) and ``uvms_env``.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from baselines.evaluation.batched import batchable, group_key, play_batched
from baselines.evaluation.episode_row import EpisodeJob, run_episode
from baselines.evaluation.splits import SPLITS
from baselines.loaders.sources import PolicySource
from uvms_env.replay import replay_path

BACKENDS = ("process", "ray")


class UsageError(ValueError):
    """What ``evaluate`` refuses before any episode (an unknown policy, two cases with one
    label, a case the environment refuses, a policy that cannot be built): a command
    that passed it on makes it a usage error."""


def case_episode_seed(seed: int, scenario: str, index: int) -> int:
    """The seed of episode ``index`` of every case with ``scenario`` in the evaluation of
    seed ``seed``: a stable 32-bit hash of the three."""
    digest = hashlib.sha256(f"{seed}/{scenario}/{index}".encode()).digest()
    return int.from_bytes(digest[:4], "little")


@dataclass(frozen=True)
class Case:
    """A scenario with its own environment keywords, under a label: the rows' ``scenario``
    (e.g. ``Case("random N=4", "random", (("n_agents", 4),))``). Episode seeds come from
    the scenario's name, so a case plays the episodes of ``--scenario random --n-agents 4``."""

    label: str
    scenario: str
    overrides: tuple[tuple[str, Any], ...] = ()

    @classmethod
    def of(cls, case: Case | str) -> Case:
        return case if isinstance(case, Case) else cls(case, case)

    @property
    def rung(self) -> str:
        """The label as a name: ``random N=2`` -> ``random_n2``, ``random bar N=3`` ->
        ``random_bar_n3`` (a training run's evaluation rungs)."""
        return self.label.replace(" N=", "_n").replace(" ", "_")


def evaluate(
    policies: Sequence[str],
    scenarios: Sequence[str | Case],
    episodes: int | Callable[[str], int],
    seed: int,
    workers: int,
    overrides: dict[str, Any] | None = None,
    max_cycles: int | None = None,
    progress: bool = True,
    backend: str = "process",
    address: str | None = None,
    replay_dir: Path | None = None,
    check: bool = True,
    batch: int = 0,
) -> list[dict[str, Any]]:
    """Run every (policy, scenario, episode) and return the per-episode rows, sorted.
    ``scenarios``: names, or ``Case``s whose keywords go over ``overrides``. ``episodes``:
    per case, for every policy or by policy (a split's ``Split.episodes``); episode k is
    the same episode whatever the count.
    ``replay_dir``: write each policy's first episode per scenario there as a 3D replay
    page (``uvms_env.replay.replay_path``).
    ``backend``: ``process`` (a process pool of ``workers``; 1: in this process) or
    ``ray`` (Ray tasks on a local Ray of ``workers`` CPUs, or on the cluster at
    ``address``); the rows do not depend on it. ``batch``: with the process backend,
    play each per-robot policy's episodes of a case ``batch`` at a time through the
    batched environment (``baselines.evaluation.batched``; 0 or 1: one by one): the same
    episodes, their numbers as the one-by-one ones to ~1e-6 over hundreds of periods, but
    over thousands a marginal episode can end otherwise (docs/evaluation.md), so a table
    plays every rung alike. ``check``: ``preflight`` first. What is refused before
    any episode raises ``UsageError``."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; expected one of {BACKENDS}")
    if batch > 1 and backend != "process":
        raise UsageError("batched episodes (batch > 1) play on the process backend only")
    if backend == "ray":
        from baselines.ray_runtime import require_ray

        require_ray()  # before the warm-up episodes
    for p in policies:
        try:
            PolicySource.parse(p)  # fail fast on a typo, before any worker starts
        except ValueError as exc:
            raise UsageError(str(exc)) from exc
    cases = [Case.of(c) for c in scenarios]
    labels = [c.label for c in cases]
    if len(set(labels)) != len(labels):
        raise UsageError(f"two scenarios share a label: {labels}")
    overrides = overrides or {}
    count = episodes if callable(episodes) else lambda policy: episodes
    if check:
        preflight(policies, cases, seed, overrides, max_cycles, progress)
    jobs = [
        EpisodeJob(
            p,
            c.scenario,
            k,
            case_episode_seed(seed, c.scenario, k),
            tuple(sorted({**overrides, **dict(c.overrides)}.items())),
            max_cycles,
            record_path=k == 0 and c.label == "paper",  # the object's path, for the paper's plot
            replay=str(replay_path(replay_dir, p, c.label)) if replay_dir and k == 0 else None,
            label=c.label,
        )
        for p in policies
        for c in cases
        for k in range(count(p))
    ]
    rows = _play(jobs, workers, backend, address, progress, batch)
    order = list(policies)
    rows.sort(key=lambda r: (order.index(r["policy"]), labels.index(r["scenario"]), r["episode"]))
    return rows


def preflight(
    policies: Sequence[str],
    cases: Sequence[Case],
    seed: int,
    overrides: dict[str, Any],
    max_cycles: int | None = None,
    progress: bool = True,
) -> None:
    """Each case's environment (its first episode's) and each policy (on the first case)
    built once, before any episode: ``UsageError`` naming the case or the policy, with the
    environment's or the loader's message, where one cannot be built."""
    import uvms_env

    envs: list[Any] = []
    with tqdm(
        total=len(cases) + len(policies), desc="building", disable=not progress, unit="item"
    ) as bar:
        try:
            for case in cases:
                kwargs = {**overrides, **dict(case.overrides)}
                if max_cycles is not None:
                    kwargs["max_cycles"] = max_cycles
                episode_seed = case_episode_seed(seed, case.scenario, 0)
                try:
                    env = uvms_env.parallel_env(scenario=case.scenario, seed=episode_seed, **kwargs)
                except Exception as exc:  # whatever the environment refuses: the case's error
                    raise UsageError(f"scenario {case.label}: {type(exc).__name__}: {exc}") from exc
                envs.append(env)
                bar.update()
            for policy in policies:
                try:
                    PolicySource.parse(policy).build_once(envs[0], seed)
                except Exception as exc:  # whatever the loader raises: the policy is unusable
                    raise UsageError(
                        f"policy {policy} cannot be loaded: {type(exc).__name__}: {exc}"
                    ) from exc
                bar.update()
        finally:
            for env in envs:
                env.close()


def _play(
    jobs: list[EpisodeJob],
    workers: int,
    backend: str,
    address: str | None,
    progress: bool,
    batch: int = 0,
) -> list[dict[str, Any]]:
    """The jobs' rows, in the order they finish; the bar counts the failed episodes."""
    rows: list[dict[str, Any]] = []
    units = _units(jobs, workers, batch)
    if backend != "process" or workers > 1:
        # Build each (policy, scenario) once here first: compiled controllers and
        # simulators land in the disk cache before the workers would race to build them.
        firsts: dict[tuple[Any, ...], EpisodeJob] = {}
        for job in jobs:
            firsts.setdefault((job.policy, job.scenario, job.overrides), job)
        for job in tqdm(list(firsts.values()), desc="warm-up", disable=not progress, unit="case"):
            run_episode(dataclasses.replace(job, max_cycles=1, record_path=False, replay=None))
    # opened after the builds: its rate and ETA count the episodes alone
    bar = tqdm(total=len(jobs), desc="episodes", disable=not progress, unit="ep")

    def done(row: dict[str, Any]) -> None:
        rows.append(row)
        failed = sum(bool(r["error"]) for r in rows)
        if failed:
            bar.set_postfix(failed=failed, refresh=False)
        bar.update()

    if backend == "process" and workers <= 1:
        for unit in units:
            if isinstance(unit, EpisodeJob):
                done(run_episode(unit))
            else:
                play_batched(unit, batch, done)
    elif backend == "ray":
        from baselines.evaluation.ray_backend import run_jobs

        for row in run_jobs(run_episode, jobs, address, workers):
            done(row)
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = [pool.submit(_play_unit, u, batch) for u in units]
            for fut in as_completed(futures):
                for row in fut.result():
                    done(row)
    bar.close()
    return rows


Unit = EpisodeJob | list[EpisodeJob]  # one episode, or a chunk of one batched group


def _units(jobs: list[EpisodeJob], workers: int, batch: int) -> list[Unit]:
    """The jobs as units of work: each batchable (policy, case) group in chunks (one per
    worker at least, of ``batch`` episodes or more), every other job alone."""
    if batch <= 1:
        return list(jobs)
    groups: dict[tuple[Any, ...], list[EpisodeJob]] = {}
    units: list[Unit] = []
    for job in jobs:
        if batchable(job) is None:
            groups.setdefault(group_key(job), []).append(job)
        else:
            units.append(job)
    for group in groups.values():
        # every worker busy before the chunks grow past ``batch``
        chunks = max(min(max(1, workers), len(group)), -(-len(group) // batch))
        size = -(-len(group) // chunks)
        units += [group[i : i + size] for i in range(0, len(group), size)]
    return units


def _play_unit(unit: Unit, batch: int) -> list[dict[str, Any]]:
    """A worker's rows of one unit (``_units``)."""
    if isinstance(unit, EpisodeJob):
        return [run_episode(unit)]
    return play_batched(unit, batch)


@dataclass(frozen=True)
class Settings:
    """What a command's evaluations share: the episodes per case, the seed, the workers,
    the environment keywords of every case (``conditions``, ``evaluate``'s
    ``overrides``), the cap on periods, the progress bar, the backend and the replays.
    ``split``: a split's name (``baselines.evaluation.splits``): its seed, and its
    episodes per kind of rung unless ``episodes`` is given (None); ``beyond``: the split's
    counts for the cases beyond the training conditions."""

    episodes: int | None
    seed: int
    workers: int
    conditions: dict[str, Any] = dataclasses.field(default_factory=dict)
    max_cycles: int | None = None
    progress: bool = True
    backend: str = "process"
    address: str | None = None
    replay_dir: Path | None = None
    check: bool = True  # ``evaluate``'s preflight
    split: str | None = None
    beyond: bool = False
    batch: int = 0  # episodes per batched environment (``evaluate``'s ``batch``)

    def __post_init__(self) -> None:
        if self.split is None and self.episodes is None:
            raise ValueError("Settings need episodes or a split")
        if self.split is not None and SPLITS[self.split].seed != self.seed:
            raise ValueError(
                f"split {self.split} has seed {SPLITS[self.split].seed}, not {self.seed}"
            )

    @classmethod
    def of_args(
        cls, args: Any, default_seed: int, default_episodes: int, **options: Any
    ) -> Settings:
        """The settings of ``splits.add_split_arguments``' flags: ``--split`` (its seed,
        its counts unless ``--episodes``), or ``--seed`` and ``--episodes`` with defaults."""
        if args.split is not None:
            return cls(args.episodes, SPLITS[args.split].seed, split=args.split, **options)
        seed = default_seed if args.seed is None else args.seed
        return cls(args.episodes or default_episodes, seed, **options)

    def episodes_of(self, policy: str) -> int:
        """Episodes per case of ``policy``: ``episodes``, or the split's count for it."""
        if self.episodes is not None:
            return self.episodes
        return SPLITS[self.split].episodes(policy, self.beyond)  # type: ignore[index]

    def evaluate(
        self, policies: Sequence[str], cases: Sequence[str | Case]
    ) -> list[dict[str, Any]]:
        """``evaluate`` of the policies on the cases with these settings."""
        options = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        options["overrides"] = options.pop("conditions")
        del options["split"], options["beyond"]
        options["episodes"] = self.episodes_of
        return evaluate(policies, cases, **options)

    def record(self) -> dict[str, Any]:
        """The settings a result records as its ``command`` (a split with its version)."""
        out = {k: getattr(self, k) for k in ("episodes", "seed", "conditions", "max_cycles")}
        if self.split is not None:
            split = SPLITS[self.split]
            out["split"] = {"name": self.split, "version": split.version, "beyond": self.beyond}
        return out
