"""The run layer every RL library's trainer writes through: one run folder, one
``config.json``, one ``progress.csv`` and one ``evaluations.csv`` schema, periodic
evaluation through ``baselines.evaluate``, the best snapshot and resuming.

    run = Run.start(settings, library="sb3", algo="ppo", command=argv)
    trainer = Trainer(run, algo, args)         # the library's trainer (``Trainer``)
    run.write_config(**trainer.build())        # env and model; config.json
    steps = trainer.learn()                    # see ``Trainer.learn``
    run.end()                                  # the training time ends here
    trainer.save(run.folder); trainer.close()
    run.finish(steps)                          # robot-steps, times, recorded evaluation

``baselines.train.train`` is that sequence. The run never calls the trainer: the
trainer's loop (SB3's: its callbacks, ``baselines.rl.sb3_callbacks``) writes a row
(``iteration``), saves what is due (``due``) and hands the run a saved snapshot to
evaluate (``evaluate_snapshot``), each save and evaluation inside ``apart``. Every budget and
cadence counts robot-steps. The progress bar, its rate and its ETA, and the robot-steps/s
of the records count the stepping and the updates only: the build before ``begin`` (env,
geometries, compiled kernels, model) and what runs ``apart`` are timed apart (``build_s``,
``eval_s`` beside ``train_s`` in config.json). The run folder's files: docs/rl.md.

May import: the standard library, numpy, tqdm, ``baselines.evaluation`` (the periodic
evaluations: ``during_training``), ``baselines.ladder``, ``baselines.lagrangian``,
``baselines.loaders.saved``
(the config file it reads back), ``baselines.registry`` and ``uvms_env``.
"""

from __future__ import annotations

import csv
import json
import math
import platform
import shlex
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from tqdm import tqdm

from baselines.command_line import team_variants
from baselines.evaluation.during_training import append_row, evaluate_rungs, evaluation_score
from baselines.lagrangian import CostSettings
from baselines.loaders.saved import CONFIG_FILE, read_config
from baselines.registry import policy_spec
from uvms_env.task.rules import EPISODE_ENDS

PROGRESS_FILE = "progress.csv"
SNAPSHOT = "eval_snapshot"
BEST = "best"
# One row per training iteration (a rollout and its update): the training episodes that
# ended in it (unscaled team return), the constraint cost and multiplier of
# PPO-Lagrangian (empty without it) and the throughput.
# ``episode_objective_mean``: what PPO maximizes, the return less the multiplier times the
# cost at this iteration's multiplier (the return itself without a cost); ``ends_<name>``:
# how the iteration's training episodes ended (``EPISODE_END_NAMES``), so that a run that
# learns to end episodes early shows it.
ENDS = tuple(f"ends_{name}" for name in EPISODE_ENDS)
PROGRESS_COLUMNS = (
    "iteration",
    "robot_steps",
    "episodes",
    "episode_return_mean",
    "episode_len_mean",
    "episode_cost_mean",
    "multiplier",
    "episode_objective_mean",
    *ENDS,
    "iteration_s",
    "wall_time_s",
    "robot_steps_per_s",
)
RECORD_EPISODES = 2  # the final policy's recorded per-episode evaluation ("eval")
# Training drops the internal-wrench metric (docs/simulator.md, "Measured"): it changes
# no observation, reward or dynamics.
TRAIN_ENV_DEFAULTS: dict[str, Any] = {"internal_wrench_every": 0}
# The batched step of every trainer: its precisions (float32 is the fast mode; its
# deviation is far below a stochastic policy's own noise, and evaluation stays on float64
# single envs) and its kernel threads (one: with two, a kernel call waits for both cores,
# so anything else running on a small machine, torch included, stalls the step).
DTYPES = ("float32", "float64")
DEFAULT_DTYPE = "float32"
DEFAULT_ENV_THREADS = 1
# The options a periodic evaluation keeps from training's: the team, the channel and the
# conditions (the evaluation plays the plain environment otherwise: a policy applies its
# own priors).
EVAL_KEEP = ("n_agents", "object", "course", "comm", "current", "mismatch", "randomize")


def add_step_arguments(g: Any) -> None:
    """``--dtype`` and ``--env-threads``: the batched step's precision and threads."""
    g.add_argument(
        "--dtype", choices=DTYPES, default=DEFAULT_DTYPE, help="the batched step's precision"
    )
    g.add_argument(
        "--env-threads", type=int, default=DEFAULT_ENV_THREADS, help="threads of the batched step"
    )


class Trainer(Protocol):
    """What an RL library implements to train under a ``Run`` (``Trainer(run, algo,
    args)``, ``args`` its own command-line options). A training-loop addition that is no
    library's business (a safety filter around the env, a policy initialized from the
    expert) goes in ``build``: it makes the env and the model."""

    def build(self) -> dict[str, Any]:
        """Make the env and the model (from ``run.settings.resume`` when set); return the
        library's settings for config.json."""
        ...

    def learn(self) -> int:
        """Train until ``run.settings.robot_steps``: ``run.begin`` once the envs are reset
        and stepping starts; after each iteration ``run.iteration`` (its row), then, each
        inside ``run.apart()``, a numbered checkpoint under the run folder where
        ``run.due("checkpoint_every", ...)`` and a snapshot saved to ``run.snapshot`` and
        handed to ``run.evaluate_snapshot`` where ``run.due("eval_every", ...)``; return the
        robot-steps done in all."""
        ...

    def save(self, folder: Path) -> None:
        """Write what the policy's loader (``baselines.registry``) and a resume need into
        ``folder``."""
        ...

    def results(self) -> dict[str, Any]:
        """What the trainer adds to ``library_settings`` at the end."""
        ...

    def close(self) -> None: ...


@dataclass
class RunSettings:
    """What every library shares (``baselines.train``'s shared options)."""

    scenario: str = "short"
    overrides: dict[str, Any] = field(default_factory=dict)
    robot_steps: int = 200_000
    num_envs: int | None = None  # None: the library's default
    seed: int = 0
    out: Path = Path("runs/train")
    eval_every: int = 0
    eval_episodes: int = 5
    eval_ladder: bool = False
    checkpoint_every: int = 50_000
    resume: Path | None = None
    cost: CostSettings | None = None
    geometry_pool: int | None = None  # None: the library's default
    hyperparameters: dict[str, Any] = field(default_factory=dict)
    progress: bool = True
    record_eval: bool = True  # the final policy's per-episode result, in config.json
    team_sizes: tuple[int, ...] = ()  # several: one group of env copies each (empty: one)
    objects: tuple[str, ...] = ()  # several: one group of env copies each, per team size
    eval_seed: int | None = None  # the periodic evaluations' seed (None: ``seed``)
    eval_max_cycles: int | None = None  # cap on evaluation episodes (None: the scenario's)

    def env_options(self) -> dict[str, Any]:
        """The environment options training uses (``training_env_options``)."""
        return training_env_options(self.overrides)

    def groups(self) -> list[dict[str, Any]]:
        """The groups of env copies the run trains on, each its environment options: one
        per team size and object where several are given (``team_sizes`` x ``objects``),
        else one. Every library's trainer builds its env copies from these."""
        return [self.env_options() | v for v in team_variants(self.team_sizes, self.objects)]

    def rungs(self) -> dict[str, tuple[str, dict[str, Any]]]:
        """The evaluation's rungs: the benchmark's ladder (``baselines.ladder``'s cases
        under its conditions), or the training scenario once per group of env copies
        (``groups``) with the run's channel and conditions (``EVAL_KEEP``)."""
        from baselines.ladder import CONDITIONS, cases

        comm = {"comm": self.overrides["comm"]} if "comm" in self.overrides else {}
        if self.eval_ladder:
            return {
                case.rung: (case.scenario, {**dict(case.overrides), **CONDITIONS, **comm})
                for case in cases()
            }
        groups = [{k: v for k, v in group.items() if k in EVAL_KEEP} for group in self.groups()]
        if len(groups) == 1:
            return {self.scenario: (self.scenario, groups[0])}
        return {_group_name(self.scenario, g, self.objects): (self.scenario, g) for g in groups}

    @property
    def evaluation_seed(self) -> int:
        return self.seed if self.eval_seed is None else self.eval_seed


def training_env_options(overrides: dict[str, Any]) -> dict[str, Any]:
    """The environment options of every training loop (the RL trainers', DAgger's): the
    training defaults (``TRAIN_ENV_DEFAULTS``), then ``overrides``."""
    return {**TRAIN_ENV_DEFAULTS, **overrides}


def _group_name(scenario: str, group: dict[str, Any], objects: tuple[str, ...]) -> str:
    """A group's rung name: ``random_n3``, ``random_n3_bar`` where the run has several
    objects."""
    name = f"{scenario}_n{group['n_agents']}" if "n_agents" in group else scenario
    return f"{name}_{group['object']}" if objects else name


def seeded_pool(scenario: str, overrides: dict[str, Any], pool: int | None) -> int | None:
    """The geometry pool a run uses: seeded families only (a fixed scenario has one
    geometry), 0 or None: no pool."""
    from uvms_env.scenarios import SEEDED_FAMILIES

    seeded = scenario in SEEDED_FAMILIES and overrides.get("reseed_geometry", True)
    return pool if seeded and pool else None


def hardware(extra: dict[str, Any] | None = None) -> dict[str, Any]:
    from uvms_env.vector.kernels import available_cores

    return {"machine": platform.machine(), "cores": available_cores(), **(extra or {})}


def write_json(path: Path, data: dict[str, Any]) -> None:
    path.write_text(json.dumps(data, indent=2, default=_plain) + "\n")


def _plain(x: Any) -> Any:
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return str(x)


class Run:
    """One training run's folder and records; see the module docstring."""

    def __init__(
        self,
        settings: RunSettings,
        library: str,
        algo: str,
        command: list[str] | None = None,
        previous: dict[str, Any] | None = None,
    ) -> None:
        self.settings = settings
        self.folder = Path(settings.out)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.previous = previous or {}
        self.resumed = settings.resume is not None
        self.config: dict[str, Any] = {
            "library": library,
            "algo": algo,
            "command": shlex.join(command) if command else None,
            "scenario": settings.scenario,
            "overrides": settings.overrides,
            "env_defaults": TRAIN_ENV_DEFAULTS,
            "env_options": settings.env_options(),
            "num_envs": settings.num_envs,
            "seed": settings.seed,
            "robot_steps_budget": settings.robot_steps,
            "eval_every": settings.eval_every,
            "eval_episodes": settings.eval_episodes,
            "eval_ladder": settings.eval_ladder,
            "eval_seed": settings.evaluation_seed,
            "eval_max_cycles": settings.eval_max_cycles,
            "team_sizes": list(settings.team_sizes),
            "objects": list(settings.objects),
            "checkpoint_every": settings.checkpoint_every,
            "cost": settings.cost.as_dict() if settings.cost is not None else None,
            "resumes": self.previous.get("resumes", -1) + 1 if self.resumed else 0,
            "hardware": hardware(),
            "library_settings": {},
            "robot_steps": self.previous.get("robot_steps", 0) if self.resumed else 0,
            "wall_time_s": None,
            "build_s": None,
            "train_s": None,
            "eval_s": None,
            "robot_steps_per_s": None,
            "eval": None,
            "best": self.previous.get("best") if self.resumed else None,
        }
        self.multiplier: float | None = None
        self._start = time.perf_counter()
        self._tick = self._start
        self._stepping: float | None = None  # when ``begin`` was called
        self._ended: float | None = None  # when ``end`` was called
        self._eval_s = 0.0  # this session's periodic evaluations and checkpoints
        self._bar: Any = None
        self._postfix: dict[str, Any] = {}
        self._steps_at_start = self.config["robot_steps"]
        self._last_steps = self._steps_at_start
        # the next robot-steps at which each cadence of the settings is due (``due``)
        self._next = {
            every: self._after(getattr(settings, every), self._steps_at_start)
            for every in ("eval_every", "checkpoint_every")
        }
        progress = self.folder / PROGRESS_FILE
        rows: list[dict[str, str]] = []
        if self.resumed and progress.exists():  # the iterations go on from its last
            with open(progress, newline="") as fh:
                reader = csv.DictReader(fh)
                rows = list(reader)
            if tuple(reader.fieldnames or ()) != PROGRESS_COLUMNS:
                # an earlier layout's file: kept aside, the run goes on in the schema
                parts = len(list(self.folder.glob("progress.part*.csv")))
                progress.rename(self.folder / f"progress.part{parts}.csv")
        self._iteration = int(rows[-1]["iteration"]) if rows else 0
        if not self.resumed or not progress.exists():  # a new run starts a new file
            with open(progress, "w", newline="") as fh:
                csv.writer(fh).writerow(PROGRESS_COLUMNS)

    @classmethod
    def start(
        cls, settings: RunSettings, library: str, algo: str, command: list[str] | None = None
    ) -> Run:
        """A new run, or with ``settings.resume`` the continuation of the run there (its
        config.json: resumes, robot-steps and wall time so far, the last multiplier)."""
        previous = previous_record(settings, library)
        if settings.cost is not None and (previous.get("cost") or {}).get("final_multiplier"):
            settings.cost.multiplier = previous["cost"]["final_multiplier"]
        return cls(settings, library, algo, command, previous)

    @property
    def snapshot(self) -> Path:
        """Where the trainer saves the policy that a periodic evaluation loads."""
        return self.folder / SNAPSHOT

    @property
    def env_seed(self) -> int:
        """The seed this session hands its env copies (they derive every episode's seed
        from it): the run's seed, moved on by each resume so that a resumed run does not
        replay its first episodes."""
        return self.settings.seed + 1_000_003 * self.config["resumes"]

    def policy_spec(self, folder: Path) -> str:
        """The evaluator's ``--policy`` spec of this run's policy saved in ``folder``."""
        return policy_spec(self.config["library"], self.config["algo"], folder)

    def write_config(self, **library_settings: Any) -> None:
        """Record the library's own settings (``library_settings``) and write config.json;
        without a ``begin``, the first iteration's time and the training count from here."""
        self.config["library_settings"].update(library_settings)
        write_json(self.folder / CONFIG_FILE, self.config)
        self._tick = time.perf_counter()
        if self._stepping is None:  # a trainer without ``begin``: training starts here
            self._stepping = self._tick

    def begin(
        self, rollout: int | None = None, unit: tuple[str, str] = ("rollout", "rollouts")
    ) -> int:
        """Stepping starts now (the env, its geometries and compiled kernels and the model
        are built, the envs reset): the build is timed apart from training from here, and
        the progress bar opens. ``rollout``: the robot-steps of one iteration (None: not
        known in advance; ``unit``: what it is called, one and several); a budget that is
        no whole number of them is announced, rounded up. Returns the robot-steps the run
        will end at."""
        s, done = self.settings, self._steps_at_start
        remaining = max(0, s.robot_steps - done)
        total = s.robot_steps
        if rollout and remaining % rollout:
            k = math.ceil(remaining / rollout)
            total = done + k * rollout
            after = f" after the {done} done" if done else ""
            print(
                f"--robot-steps {s.robot_steps} rounds up to {total}: {k} "
                f"{unit[k != 1]} of {rollout} robot-steps{after}",
                flush=True,
            )
        self._stepping = self._tick = time.perf_counter()
        if s.progress:
            self._bar = tqdm(
                total=total,
                initial=done,
                desc=f"{self.config['library']} {self.config['algo']}",
                unit="robot-step",
                unit_scale=True,
                dynamic_ncols=True,
            )
        return total

    def end(self) -> float:
        """Training is over (the last update included): the time from ``begin`` to here,
        less the periodic evaluations and checkpoints, is the session's ``train_s``
        (without a call, up to ``finish``). Returns the time it ended."""
        self._ended = time.perf_counter()
        self.close_bar()
        return self._ended

    def advance(self, robot_steps: int) -> None:
        """The bar at ``robot_steps`` done in all, between two iterations' rows (a library
        that reports each step)."""
        if self._bar is not None and robot_steps > self._bar.n:
            self._bar.update(robot_steps - self._bar.n)

    # -- the training loop's hooks --------------------------------------------------------
    def iteration(
        self,
        robot_steps: int,
        returns: list[float] | None = None,
        lengths: list[float] | None = None,
        episode_cost: float | None = None,
        multiplier: float | None = None,
        ends: list[str] | None = None,
    ) -> dict[str, Any]:
        """One progress row at ``robot_steps`` done in all: the training episodes that
        ended in the iteration (their team returns, the environment's shared reward with
        no normalization and no cost penalty, lengths and how they ended), the cost and
        multiplier, and the objective (the return less the multiplier times the cost)."""
        summary = (len(returns or []), _mean(returns), _mean(lengths))
        objective = summary[1]
        if objective is not None and episode_cost is not None and multiplier is not None:
            objective -= multiplier * episode_cost
        if multiplier is not None:
            self.multiplier = multiplier
        now = time.perf_counter()
        self._iteration += 1
        steps = robot_steps - self._last_steps
        seconds = now - self._tick
        row = {
            "iteration": self._iteration,
            "robot_steps": int(robot_steps),
            "episodes": summary[0],
            "episode_return_mean": _round(summary[1]),
            "episode_len_mean": _round(summary[2]),
            "episode_cost_mean": _round(episode_cost),
            "multiplier": _round(multiplier),
            "episode_objective_mean": _round(objective),
            **{c: (ends.count(c[len("ends_") :]) if ends is not None else None) for c in ENDS},
            "iteration_s": round(seconds, 3),
            "wall_time_s": round(self._wall_before + now - self._start, 2),
            "robot_steps_per_s": round(steps / seconds, 1) if seconds > 0 else None,
        }
        append_row(self.folder / PROGRESS_FILE, PROGRESS_COLUMNS, row)
        self._tick, self._last_steps = now, robot_steps
        if row["episode_return_mean"] is not None:
            self._postfix["return"] = f"{row['episode_return_mean']:.3g}"
        if self._bar is not None:
            self._bar.set_postfix(self._postfix, refresh=False)
            self.advance(robot_steps)
        return row

    @contextmanager
    def apart(self) -> Iterator[None]:
        """What runs inside (a checkpoint, a periodic evaluation) is no training: neither
        the bar's rate nor the current iteration's time counts it (``eval_s``)."""
        start = time.perf_counter()
        try:
            yield
        finally:
            spent = time.perf_counter() - start
            self._eval_s += spent
            self._tick += spent
            if self._bar is not None:
                self._bar.unpause()

    def due(self, every: str, robot_steps: int) -> bool:
        """Whether the cadence ``every`` of the settings (``eval_every``,
        ``checkpoint_every``; 0: never) is due at ``robot_steps``; if so, its next time
        moves on."""
        cadence = getattr(self.settings, every)
        if cadence <= 0 or robot_steps < self._next[every]:
            return False
        self._next[every] = self._after(cadence, robot_steps)
        return True

    def evaluate_snapshot(self, robot_steps: int) -> list[dict[str, Any]]:
        """The snapshot the trainer just saved (``snapshot``, with config.json: its policy
        rebuilds the run's priors from it) on every rung (``evaluate_rungs``), kept as the
        best where it is (``keep_best``); its success and clean success (means over the
        rungs) go to the bar's postfix and a line. Returns the rows."""
        write_json(self.snapshot / CONFIG_FILE, self.config)
        s = self.settings
        rows = evaluate_rungs(
            self.folder,
            s.rungs(),
            self.policy_spec(self.snapshot),
            s.eval_episodes,
            s.evaluation_seed,
            robot_steps,
            algorithm=f"{self.config['library']}_{self.config['algo']}",
            training_seed=s.seed,
            elapsed=time.perf_counter() - self._start,
            max_cycles=s.eval_max_cycles,
        )
        self.keep_best(robot_steps, rows)
        success = float(np.mean([r["success_rate"] for r in rows]))
        clean = float(np.mean([r["clean_success_rate"] for r in rows]))
        self._postfix.update(success=f"{success:.2f}", clean=f"{clean:.2f}")
        if self._bar is not None:
            self._bar.set_postfix(self._postfix)
            self._bar.write(
                f"evaluation at {robot_steps} robot-steps: success {success:.2f}, clean "
                f"success {clean:.2f} ({', '.join(r['rung'] for r in rows)})"
            )
        return rows

    def keep_best(self, robot_steps: int, rows: list[dict[str, Any]]) -> bool:
        """Copy the snapshot just evaluated to ``best/`` when its ``evaluation_score``
        beats every earlier one of the run (resumed runs included); record it in
        config.json. Whether it did."""
        score = evaluation_score(rows)
        best = self.config.get("best")
        if best is not None and tuple(best["score"]) >= score:
            return False
        target = self.folder / BEST
        shutil.rmtree(target, ignore_errors=True)
        shutil.copytree(self.snapshot, target)
        self.config["best"] = {"robot_steps": int(robot_steps), "score": list(score)}
        write_json(self.folder / CONFIG_FILE, self.config)
        write_json(target / CONFIG_FILE, self.config)
        return True

    def record(self, policy: str) -> dict[str, Any]:
        """The saved policy's per-episode result on fixed seeds (the training scenario,
        seed 0): a regression value produced by running, which tests check for the
        committed models."""
        from baselines.evaluation.runner import evaluate

        scenario, overrides = next(iter(self.settings.rungs().values()))
        max_cycles = self.settings.eval_max_cycles
        rows = evaluate(
            [policy],
            [scenario],
            RECORD_EPISODES,
            0,
            1,
            overrides,
            max_cycles,
            progress=False,
            check=False,  # the run just saved it; a failure is the record's to show
        )
        keys = ("return", "episode_steps", "final_pos_error_m")
        return {
            "scenario": scenario,
            "overrides": overrides,
            "max_cycles": max_cycles,
            "seed": 0,
            "episodes": [
                {
                    "episode": r["episode"],
                    "seed": r["seed"],
                    "success": bool(r.get("success")),
                    **{k: r.get(k) for k in keys},
                }
                for r in rows
            ],
        }

    def finish(self, robot_steps: int, **results: Any) -> dict:
        """Robot-steps done, wall time (all sessions of a resumed run), robot-steps/s of
        this session, the last multiplier, the trainer's ``results`` and
        (``settings.record_eval``) the recorded evaluation of the policy saved in the run
        folder; written to config.json."""
        ended = self._ended if self._ended is not None else self.end()
        wall = time.perf_counter() - self._start
        done = robot_steps - self._steps_at_start
        stepping = self._stepping if self._stepping is not None else ended
        train_s = max(0.0, ended - stepping - self._eval_s)
        before = self.previous if self.resumed else {}
        self.config.update(
            robot_steps=int(robot_steps),
            wall_time_s=round(self._wall_before + wall, 1),
            # every session's together, as the wall time
            build_s=round(float(before.get("build_s") or 0.0) + stepping - self._start, 1),
            train_s=round(float(before.get("train_s") or 0.0) + train_s, 1),
            eval_s=round(float(before.get("eval_s") or 0.0) + self._eval_s, 1),
            # this session's, on its stepping and updates alone
            robot_steps_per_s=round(done / train_s, 1) if train_s > 0 else None,
        )
        self.config["library_settings"].update(results)
        if self.config["cost"] is not None and self.multiplier is not None:
            self.config["cost"]["final_multiplier"] = self.multiplier
        write_json(self.folder / CONFIG_FILE, self.config)
        if self.settings.record_eval:
            self.config["eval"] = self.record(self.policy_spec(self.folder))
            best = self.folder / BEST
            if best.is_dir():  # the early-stopped policy gets its own record
                best_config = {
                    **self.config,
                    "robot_steps": self.config["best"]["robot_steps"],
                    "run_robot_steps": self.config["robot_steps"],
                }
                best_config["eval"] = self.record(self.policy_spec(best))
                write_json(best / CONFIG_FILE, best_config)
        if self.snapshot.is_dir():
            shutil.rmtree(self.snapshot, ignore_errors=True)
        write_json(self.folder / CONFIG_FILE, self.config)
        return self.config

    def close_bar(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    # -- helpers ----------------------------------------------------------------------------
    @property
    def _wall_before(self) -> float:
        return float(self.previous.get("wall_time_s") or 0.0) if self.resumed else 0.0

    @staticmethod
    def _after(every: int, steps: int) -> int:
        """The first multiple of ``every`` above ``steps``."""
        return (steps // every + 1) * every if every > 0 else 0


def previous_record(settings: RunSettings, library: str) -> dict[str, Any]:
    """The config.json of the run ``settings.resume`` continues ({} for a new run);
    ValueError where ``library`` did not train it."""
    if settings.resume is None:
        return {}
    resume = Path(settings.resume)
    folder = resume if resume.is_dir() else resume.parent
    # a run folder, a file in it, or a checkpoint under its checkpoints/ (RLlib's: folders)
    previous = (
        read_config(folder) or read_config(folder.parent) or read_config(folder.parent.parent)
    )
    trained_by = previous.get("library", previous.get("engine", library))
    if trained_by != library:  # "engine": the key's earlier name
        raise ValueError(f"--resume {resume} was trained with {trained_by}, not {library}")
    return previous


def _mean(values: list[float] | None) -> float | None:
    return round(float(np.mean(values)), 4) if values else None


def _round(x: float | None) -> float | None:
    return None if x is None else round(float(x), 6)
