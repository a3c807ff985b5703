"""Train one policy shared by all robots: ``python -m baselines.train --library L ...``.

    python -m baselines.train --library sb3 --algo ppo --scenario short --robot-steps 200000 \\
        --num-envs 4 --seed 0 --out runs/ppo --eval-every 50000

Libraries (``baselines.registry``): ``sb3`` (default), ``torchrl``, ``rllib``; each trainer
only builds, learns and saves, and ``baselines.runs`` keeps the run folder. ``--engine`` is
the flag's earlier name, still accepted. Reference: docs/rl.md, docs/scale-out.md.

May import: ``baselines.runs``, ``baselines.options``, ``baselines.lagrangian``,
``baselines.registry`` and the trainer modules it names (imported on demand: a library
loads only when it is chosen).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from baselines.lagrangian import COSTS, CostSettings
from baselines.options import (
    add_condition_arguments,
    add_evaluation_arguments,
    command_parser,
    condition_overrides,
    key_value_pairs,
    team_sizes,
)
from baselines.registry import DEFAULT_LIBRARY, LIBRARIES, library, trainer_module

SHARED_GROUP = "shared options (every library)"


def add_library_argument(g: Any, default: str) -> None:
    """``--library`` (and its earlier name ``--engine``, not listed)."""
    g.add_argument("--library", choices=tuple(LIBRARIES), default=default, help="the RL library")
    g.add_argument(
        "--engine",
        dest="library",
        choices=tuple(LIBRARIES),
        default=argparse.SUPPRESS,
        help=argparse.SUPPRESS,
    )


def add_shared_arguments(ap: argparse.ArgumentParser, name: str, algos: tuple[str, ...]) -> None:
    """What every library takes (one group, the same for every library)."""
    g = ap.add_argument_group(SHARED_GROUP)
    add_library_argument(g, name)
    g.add_argument("--algo", choices=algos, default=algos[0], help="the algorithm")
    g.add_argument("--scenario", default="short", help="short (learning-sized), paper, random")
    g.add_argument(
        "--env-option",
        action="append",
        default=[],
        metavar="KEY=JSON",
        help="environment option, e.g. max_cycles=200, n_agents=3 or "
        "reward_weights='{\"effort\": 0.01}'",
    )
    add_condition_arguments(g)
    g.add_argument(
        "--comm",
        default=None,
        metavar="PRESET",
        help="acoustic channel preset (uvms_env.env.channel.PRESETS; default off): the "
        "shared policy's action gains the send flag and the message",
    )
    g.add_argument(
        "--hp",
        action="append",
        default=[],
        metavar="KEY=JSON",
        help="the library's hyperparameter (see the library's options)",
    )
    g.add_argument("--robot-steps", type=int, default=200_000, help="training budget")
    g.add_argument(
        "--num-envs",
        type=int,
        default=None,
        help="env copies of N robots each (default: the library's)",
    )
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--out", type=Path, default=None, help="run folder (default runs/LIBRARY_ALGO)")
    _add_evaluation_arguments(g)
    g.add_argument("--checkpoint-every", type=int, default=50_000, help="robot-steps (0: none)")
    g.add_argument(
        "--resume",
        type=Path,
        default=None,
        help="run folder (or checkpoint) to continue; --robot-steps counts the steps already done",
    )
    g.add_argument(
        "--geometry-pool",
        type=int,
        default=None,
        help="seeded families: episodes use this many bank geometries "
        "(0: each copy keeps its first; default: the library's)",
    )
    _add_cost_arguments(g)
    g.add_argument("--no-progress", action="store_true", help="no progress lines")


def _add_evaluation_arguments(g: Any) -> None:
    """The periodic evaluations' options."""
    g.add_argument(
        "--eval-every",
        type=int,
        default=0,
        help="robot-steps between evaluations through baselines.evaluate (0: none)",
    )
    add_evaluation_arguments(g, episodes=5)
    g.add_argument(
        "--eval-ladder",
        action="store_true",
        help="evaluate on every rung of the task ladder, not the scenario alone",
    )


def _add_cost_arguments(g: Any) -> None:
    """The constraint cost's options (``baselines.lagrangian``)."""
    g.add_argument(
        "--cost",
        choices=("none", *COSTS),
        default="none",
        help="per-robot constraint cost subtracted from its reward",
    )
    g.add_argument("--cost-weight", type=float, default=0.1, help="starting multiplier")
    g.add_argument("--cost-limit", type=float, default=0.0, help="cost per episode and robot")
    g.add_argument(
        "--multiplier-lr", type=float, default=0.0, help="dual step size (0: fixed penalty)"
    )


def build_parser(name: str) -> argparse.ArgumentParser:
    module = trainer_module(name)
    ap = command_parser("baselines.train", __doc__)
    add_shared_arguments(ap, name, library(name).algos)
    note = getattr(module, "OPTIONS_NOTE", None)
    module.add_arguments(ap.add_argument_group(f"{name} library", description=note))
    return ap


def settings_from(args: argparse.Namespace, defaults: dict[str, Any]) -> Any:
    from baselines.runs import RunSettings

    cost = None
    if args.cost != "none":
        cost = CostSettings(args.cost, args.cost_weight, args.cost_limit, args.multiplier_lr)
    pool = args.geometry_pool if args.geometry_pool is not None else defaults["geometry_pool"]
    overrides = key_value_pairs(args.env_option)
    for key, value in condition_overrides(args).items():
        if key in overrides and overrides[key] != value:
            raise ValueError(f"--{key} contradicts --env-option {key}={overrides[key]!r}")
        overrides[key] = value
    sizes = team_sizes(args)
    if sizes and "n_agents" in overrides:
        raise ValueError("give the team size once: --n-agents or --env-option n_agents")
    if len(sizes) == 1:
        overrides["n_agents"], sizes = sizes[0], ()
    if sizes and args.scenario != "random":
        raise ValueError(
            f"--n-agents with several sizes needs --scenario random, not {args.scenario}"
        )
    if args.comm is not None:
        if "comm" in overrides and overrides["comm"] != args.comm:
            raise ValueError(
                f"--comm {args.comm} contradicts --env-option comm={overrides['comm']!r}"
            )
        overrides["comm"] = args.comm
    return RunSettings(
        scenario=args.scenario,
        overrides=overrides,
        robot_steps=args.robot_steps,
        num_envs=args.num_envs if args.num_envs is not None else defaults["num_envs"],
        seed=args.seed,
        out=args.out if args.out is not None else Path(f"runs/{args.library}_{args.algo}"),
        eval_every=args.eval_every,
        eval_episodes=args.eval_episodes,
        eval_ladder=args.eval_ladder,
        checkpoint_every=args.checkpoint_every,
        resume=args.resume,
        cost=cost,
        geometry_pool=pool,
        hyperparameters=key_value_pairs(args.hp),
        progress=not args.no_progress,
        team_sizes=sizes,
        eval_seed=args.eval_seed,
        eval_max_cycles=args.eval_max_cycles,
    )


def train(
    name: str,
    algo: str,
    settings: Any,
    args: argparse.Namespace | None = None,
    command: list[str] | None = None,
    **library_options: Any,
) -> Path:
    """Build library ``name``'s trainer over a ``baselines.runs.Run`` with ``settings``
    (``RunSettings``), learn, save; return the run folder. The library's own options:
    ``args`` (its parsed command line) or its defaults changed by ``library_options``
    (e.g. ``backend="cuda"``)."""
    from baselines.runs import Run

    module = trainer_module(name)
    if algo not in library(name).algos:
        raise ValueError(f"{name} trains {library(name).algos}, not {algo!r}")
    if args is None:
        args = build_parser(name).parse_args(["--library", name])
        for key, value in library_options.items():
            if not hasattr(args, key):
                raise ValueError(f"{name} has no option {key!r}")
            setattr(args, key, value)
    for key, default in module.DEFAULTS.items():
        if getattr(settings, key) is None:
            setattr(settings, key, default)
    run = Run.start(settings, name, algo, command)
    trainer = module.Trainer(run, algo, args)
    try:
        run.write_config(**trainer.build())
        steps = trainer.learn()
        trainer.save(run.folder)
        trainer.close()
        run.finish(steps, **trainer.results())
    except BaseException:
        trainer.close()
        raise
    return run.folder


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else list(argv)
    pre = argparse.ArgumentParser(add_help=False)
    add_library_argument(pre, DEFAULT_LIBRARY)
    known, _ = pre.parse_known_args(argv)
    ap = build_parser(known.library)
    args = ap.parse_args(argv)
    settings = settings_from(args, trainer_module(args.library).DEFAULTS)
    command = ["python", "-m", "baselines.train", *argv]
    out = train(args.library, args.algo, settings, args, command)
    print(f"saved the {args.library} {args.algo} run in {out}")


if __name__ == "__main__":
    main()
