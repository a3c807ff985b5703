"""Train one policy shared by all robots: ``python -m baselines.train --engine E ...``.

    python -m baselines.train --engine sb3 --algo ppo --scenario short --robot-steps 200000 \\
        --num-envs 4 --seed 0 --out runs/ppo --eval-every 50000

Engines (each only builds, learns, saves and names its policy loader; the run folder,
records, evaluations and resuming are ``baselines.runs``'s):

* ``sb3`` (default): stable-baselines3 PPO or SAC on one machine (``baselines.rl.train``);
* ``torchrl``: TorchRL's PPO with env, rollouts and updates on one device, a GPU with
  ``--backend cuda`` (``baselines.rl.torchrl_ppo``);
* ``rllib``: Ray RLlib's PPO, local or on a cluster (``baselines.distributed.rllib_train``).

The shared options (``--help`` lists them for every engine) count the budget and every
cadence in robot-steps; the conditions are ``--n-agents`` (several: one group of env
copies per team size), ``--current`` (several: each episode draws one) and ``--mismatch``
(LOW HIGH: each episode draws one), the evaluator's flags; other environment options go
through ``--env-option KEY=JSON`` (``max_cycles=200``, ``action_mode=residual``, ...).
``--cost`` adds the constraint cost (``baselines.lagrangian``; PPO-Lagrangian with
``--multiplier-lr`` > 0).

May import: ``baselines.runs``, ``baselines.options``, ``baselines.lagrangian`` and the
engine modules (imported on demand: an engine's library loads only when it is chosen).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path
from typing import Any

from baselines.lagrangian import COSTS, CostSettings
from baselines.options import (
    add_condition_arguments,
    condition_overrides,
    key_value_pairs,
    team_sizes,
)

ENGINE_MODULES = {
    "sb3": "baselines.rl.train",
    "torchrl": "baselines.rl.torchrl_ppo",
    "rllib": "baselines.distributed.rllib_train",
}
ENGINES = tuple(ENGINE_MODULES)
SHARED_GROUP = "shared options (every engine)"


def engine_module(name: str) -> Any:
    """The engine's module: ``ALGOS``, ``DEFAULTS`` (num_envs, geometry_pool),
    ``add_arguments(group)`` and ``Engine(run, algo, args)`` (``baselines.runs.Engine``)."""
    if name not in ENGINE_MODULES:
        raise ValueError(f"unknown engine {name!r}; expected one of {ENGINES}")
    return importlib.import_module(ENGINE_MODULES[name])


def add_shared_arguments(ap: argparse.ArgumentParser, engine: str, algos: tuple[str, ...]) -> None:
    """What every engine takes (one group, the same for every engine)."""
    g = ap.add_argument_group(SHARED_GROUP)
    g.add_argument("--engine", choices=ENGINES, default=engine, help="the RL library")
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
        help="the engine's hyperparameter (see the engine's options)",
    )
    g.add_argument("--robot-steps", type=int, default=200_000, help="training budget")
    g.add_argument(
        "--num-envs",
        type=int,
        default=None,
        help="env copies of N robots each (default: the engine's)",
    )
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--out", type=Path, default=None, help="run folder (default runs/ENGINE_ALGO)")
    g.add_argument(
        "--eval-every",
        type=int,
        default=0,
        help="robot-steps between evaluations through baselines.evaluate (0: none)",
    )
    g.add_argument("--eval-episodes", type=int, default=5)
    g.add_argument(
        "--eval-seed",
        type=int,
        default=None,
        help="seed of the periodic evaluations' episodes (default: --seed)",
    )
    g.add_argument(
        "--eval-max-cycles",
        type=int,
        default=None,
        help="cap on the evaluation episodes and the final record (default: the scenarios' "
        "own length)",
    )
    g.add_argument(
        "--eval-ladder",
        action="store_true",
        help="evaluate on every rung of the task ladder, not the scenario alone",
    )
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
        "(0: each copy keeps its first; default: the engine's)",
    )
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
    g.add_argument("--no-progress", action="store_true", help="no progress lines")


def build_parser(engine: str) -> argparse.ArgumentParser:
    module = engine_module(engine)
    ap = argparse.ArgumentParser(
        prog="python -m baselines.train",
        description=__doc__.split("May import")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_shared_arguments(ap, engine, module.ALGOS)
    note = getattr(module, "OPTIONS_NOTE", None)
    module.add_arguments(ap.add_argument_group(f"{engine} engine", description=note))
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
        out=args.out if args.out is not None else Path(f"runs/{args.engine}_{args.algo}"),
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
    engine: str,
    algo: str,
    settings: Any,
    args: argparse.Namespace | None = None,
    command: list[str] | None = None,
    **engine_options: Any,
) -> Path:
    """Build the engine's trainer over a ``baselines.runs.Run`` with ``settings``
    (``RunSettings``), learn, save; return the run folder. The engine's own options:
    ``args`` (its parsed command line) or its defaults changed by ``engine_options``
    (e.g. ``backend="cuda"``)."""
    from baselines.runs import Run

    module = engine_module(engine)
    if algo not in module.ALGOS:
        raise ValueError(f"the {engine} engine trains {module.ALGOS}, not {algo!r}")
    if args is None:
        args = build_parser(engine).parse_args(["--engine", engine])
        for key, value in engine_options.items():
            if not hasattr(args, key):
                raise ValueError(f"the {engine} engine has no option {key!r}")
            setattr(args, key, value)
    for key, default in module.DEFAULTS.items():
        if getattr(settings, key) is None:
            setattr(settings, key, default)
    run = Run.start(settings, engine, algo, command)
    trainer = module.Engine(run, algo, args)
    try:
        run.write_config(**trainer.build())
        steps = trainer.learn()
        trainer.save(run.folder)
        trainer.close()
        run.finish(steps, trainer, **trainer.results())
    except BaseException:
        trainer.close()
        raise
    return run.folder


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else list(argv)
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--engine", choices=ENGINES, default="sb3")
    known, _ = pre.parse_known_args(argv)
    ap = build_parser(known.engine)
    args = ap.parse_args(argv)
    module = engine_module(args.engine)
    settings = settings_from(args, module.DEFAULTS)
    command = ["python", "-m", "baselines.train", *argv]
    out = train(args.engine, args.algo, settings, args, command)
    print(f"saved the {args.engine} {args.algo} run in {out}")


if __name__ == "__main__":
    main()
