"""Train one policy shared by all robots: ``python -m baselines.train --library L ...``.

    python -m baselines.train --library sb3 --algo ppo --scenario short --robot-steps 200000 \\
        --num-envs 4 --seed 0 --out runs/ppo --eval-every 50000

Libraries (``baselines.registry``): ``sb3`` (default), ``benchmarl``, ``rllib``; each trainer
only builds, learns and saves, and ``baselines.runs`` keeps the run folder. ``--engine`` is
the flag's earlier name, still accepted. Every option is checked before the run folder,
the env and the model (the environment's own checks, the library's: ``check_library``);
a refusal is a usage error. Reference: docs/rl.md, docs/scale-out.md.

May import: ``baselines.runs``, ``baselines.command_line``, ``baselines.lagrangian``,
``baselines.loaders.saved`` (the run folder's config file), ``baselines.registry`` and
the trainer modules it names (imported on demand: a library
loads only when it is chosen), and ``uvms_env`` (its checks of the environment options).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from dataclasses import fields
from pathlib import Path
from typing import Any

from baselines.command_line import (
    SCENARIOS,
    add_condition_arguments,
    add_evaluation_arguments,
    command_parser,
    condition_overrides,
    existing_path,
    key_value,
    key_value_pairs,
    non_negative_float,
    non_negative_int,
    objects,
    positive_int,
    team_sizes,
    team_variants,
    usage_errors,
)
from baselines.lagrangian import COSTS, LIMIT_UNITS, CostSettings
from baselines.loaders.saved import CONFIG_FILE, read_config
from baselines.registry import DEFAULT_LIBRARY, LIBRARIES, library, trainer_module
from baselines.runs import RunSettings

SHARED_GROUP = "shared options (every library)"


LIBRARY_FLAGS = ("--library", "--engine")


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
    g.add_argument(
        "--scenario",
        choices=SCENARIOS,
        default="short",
        help="short (learning-sized), paper, random",
    )
    g.add_argument(
        "--env-option",
        action="append",
        type=key_value,
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
        help="acoustic channel preset (uvms_env.robot.channel.PRESETS; default off): the "
        "shared policy's action gains the send flag and the message",
    )
    g.add_argument(
        "--hp",
        action="append",
        type=key_value,
        default=[],
        metavar="KEY=JSON",
        help="the library's hyperparameter (see the library's options)",
    )
    g.add_argument(
        "--robot-steps",
        type=positive_int,
        default=200_000,
        help="training budget (rounded up to whole rollouts, announced)",
    )
    g.add_argument(
        "--num-envs",
        type=positive_int,
        default=None,
        help="env copies of N robots each (default: the library's)",
    )
    g.add_argument("--seed", type=non_negative_int, default=0)
    g.add_argument("--out", type=Path, default=None, help="run folder (default runs/LIBRARY_ALGO)")
    _add_evaluation_arguments(g)
    g.add_argument(
        "--checkpoint-every", type=non_negative_int, default=50_000, help="robot-steps (0: none)"
    )
    g.add_argument(
        "--resume",
        type=existing_path,
        default=None,
        help="run folder (or checkpoint) to continue; --robot-steps counts the steps already done",
    )
    g.add_argument(
        "--geometry-pool",
        type=non_negative_int,
        default=None,
        help="seeded families: episodes use this many bank geometries "
        "(0: each copy keeps its first; default: the library's)",
    )
    _add_cost_arguments(g)
    g.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_evaluation_arguments(g: Any) -> None:
    """The periodic evaluations' options."""
    g.add_argument(
        "--eval-every",
        type=non_negative_int,
        default=0,
        help="robot-steps between evaluations through baselines.evaluate (0: none)",
    )
    # None: not given (a run without --eval-every refuses it); RunSettings has the default
    add_evaluation_arguments(
        g, episodes=None, episodes_help=f"(default {RunSettings.eval_episodes})"
    )
    g.add_argument(
        "--eval-ladder",
        action="store_true",
        help="evaluate on every rung of the task ladder, not the scenario alone",
    )


# the cost flags beside --cost: (flag, CostSettings field, meaning)
COST_FLAGS = (
    ("--cost-weight", "multiplier", "with --cost: the starting multiplier"),
    ("--cost-limit", "cost_limit", "with --cost: the target cost per robot and --cost-limit-per"),
    ("--multiplier-lr", "lr", "with --cost: the dual step size (0: fixed penalty)"),
)


def _add_cost_arguments(g: Any) -> None:
    """The constraint cost's options (``baselines.lagrangian``)."""
    g.add_argument(
        "--cost",
        choices=("none", *COSTS),
        default="none",
        help="per-robot constraint cost subtracted from its reward",
    )
    # None: not given; with --cost, CostSettings' defaults (without it, refused)
    for flag, field, what in COST_FLAGS:
        default = getattr(CostSettings, field)
        g.add_argument(
            flag, type=non_negative_float, default=None, help=f"{what} (default {default})"
        )
    g.add_argument(
        "--cost-limit-per",
        choices=LIMIT_UNITS,
        default=None,
        help="with --cost: the limit is per episode (its summed cost) or per period (its "
        f"cost over the periods it covers, whatever its length) (default {CostSettings.limit_per})",
    )


def build_parser(name: str) -> argparse.ArgumentParser:
    module = trainer_module(name)
    ap = command_parser("baselines.train", __doc__)
    add_shared_arguments(ap, name, library(name).algos)
    note = getattr(module, "OPTIONS_NOTE", None)
    module.add_arguments(ap.add_argument_group(f"{name} library", description=note))
    return ap


def settings_from(args: argparse.Namespace, defaults: dict[str, Any]) -> RunSettings:
    """The run's settings from the parsed command line, checked against the environment
    (``check_environment``): ValueError or TypeError naming the option otherwise."""
    cost = _cost_settings(args)
    evaluation = {"--eval-ladder": args.eval_ladder or None, "--eval-seed": args.eval_seed}
    evaluation["--eval-episodes"] = args.eval_episodes
    dropped = [flag for flag, value in evaluation.items() if value is not None]
    if not args.eval_every and dropped:
        raise ValueError(f"{', '.join(dropped)} without --eval-every: no periodic evaluation")
    overrides = key_value_pairs(args.env_option)
    sizes, kinds = team_sizes(args), objects(args)
    for flag, key, values in (("--n-agents", "n_agents", sizes), ("--object", "object", kinds)):
        if values and key in overrides:
            raise ValueError(f"give the {key} once: {flag} or --env-option {key}")
    # one team size or object is the env's own option; several: a group of env copies each
    one = {key: v[0] for key, v in (("n_agents", sizes), ("object", kinds)) if len(v) == 1}
    sizes, kinds = (v if len(v) > 1 else () for v in (sizes, kinds))
    comm = {} if args.comm is None else {"comm": args.comm}
    for key, value in (condition_overrides(args) | one | comm).items():
        if key in overrides and overrides[key] != value:
            raise ValueError(f"--{key} {value} contradicts --env-option {key}={overrides[key]!r}")
        overrides[key] = value
    check_environment(args.scenario, overrides, sizes, kinds)
    # the shared options named as RunSettings' fields, as given; the library's defaults
    # (``defaults``: num_envs, geometry_pool) or the dataclass's where not given
    given = {f.name: getattr(args, f.name, None) for f in fields(RunSettings)}
    return RunSettings(
        **defaults
        | {key: value for key, value in given.items() if value is not None}
        | {
            "overrides": overrides,
            "out": args.out
            or _resumed_folder(args.resume)
            or Path(f"runs/{args.library}_{args.algo}"),
            "cost": cost,
            "hyperparameters": key_value_pairs(args.hp),
            "progress": not args.no_progress,
            "team_sizes": sizes,
            "objects": kinds,
        }
    )


def _cost_settings(args: argparse.Namespace) -> CostSettings | None:
    """``--cost`` and its flags; ValueError where a flag is given without ``--cost``."""
    flags = (*COST_FLAGS, ("--cost-limit-per", "limit_per", ""))
    given = {
        field: getattr(args, flag[2:].replace("-", "_"))
        for flag, field, _ in flags
        if getattr(args, flag[2:].replace("-", "_")) is not None
    }
    if args.cost == "none":
        if given:
            named = [flag for flag, field, _ in flags if field in given]
            raise ValueError(f"{', '.join(named)} without --cost: no cost to weigh")
        return None
    return CostSettings(args.cost, **given)


def check_environment(
    scenario: str, overrides: dict[str, Any], sizes: tuple[int, ...], kinds: tuple[str, ...] = ()
) -> None:
    """ValueError (or TypeError) in the environment's own words where it would refuse
    ``scenario`` with ``overrides`` (and each of ``sizes`` as its team, each of ``kinds``
    as its object): its checks (``uvms_env.env.options.resolve``) on the geometry of seed
    0, built once, before any run folder, env copy or model."""
    from uvms_env.env.options import resolve, split_keywords

    try:
        split_keywords(overrides)  # every key and value as given (the seed's too)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"--env-option: {exc}") from exc
    probe = {**overrides, "seed": 0, "reseed_geometry": False}
    for variant in team_variants(sizes, kinds):
        try:
            resolve(scenario, probe | variant)
        except (TypeError, ValueError) as exc:
            team = "".join(f" --{key.replace('_', '-')} {v}" for key, v in variant.items())
            raise ValueError(f"--scenario {scenario}{team}: {exc}") from exc


def check_library(name: str, algo: str, settings: Any, args: argparse.Namespace) -> None:
    """ValueError naming the option where library ``name`` cannot honour the shared
    options in ``settings`` or its own in ``args``: an option is honoured or refused,
    never dropped. A trainer module says whether it trains over several groups of env
    copies, several team sizes or objects (``SEVERAL_TEAM_SIZES``; without it, it does
    not) and checks the rest itself (``check_options(settings, algo, args)``, where it has
    one)."""

    def several(module: Any) -> bool:
        return bool(getattr(module, "SEVERAL_TEAM_SIZES", False))

    module = trainer_module(name)
    if algo not in library(name).algos:
        raise ValueError(f"{name} trains {library(name).algos}, not {algo!r}")
    groups = {"--n-agents": settings.team_sizes, "--object": settings.objects}
    for flag, values in groups.items():
        if len(values) > 1 and not several(module):
            takers = [n for n in LIBRARIES if several(trainer_module(n))]
            raise ValueError(
                f"{flag} with several values {list(values)}: the {name} trainer takes one; "
                f"the libraries that take several: {', '.join(takers)}"
            )
    check = getattr(module, "check_options", None)
    if check is not None:
        check(settings, algo, args)
    from baselines.runs import previous_record

    previous_record(settings, name)


def resumed_argv(ap: argparse.ArgumentParser, argv: list[str]) -> list[str]:
    """The command line of a run resumed by ``argv``: the run's recorded one (its
    config.json ``command``, itself merged so at every resume) with every option that
    ``argv`` gives again replaced by ``argv``'s, so that a resume continues the run as it
    was configured (its cost, reward, seed, env options) and changes only what it names
    (a next scenario, a larger budget); ``argv`` itself where nothing is recorded."""
    args, _ = ap.parse_known_args(argv)
    folder = _resumed_folder(args.resume)
    recorded = (read_config(folder) if folder is not None else {}).get("command")
    if not recorded:
        return argv
    words = shlex.split(recorded)
    if "baselines.train" in words:
        words = words[words.index("baselines.train") + 1 :]
    actions = ap._option_string_actions  # argparse's own table of option -> action
    given = {actions[w.split("=")[0]].dest for w in argv if w.split("=")[0] in actions}
    kept: list[str] = []
    skipping = False
    for word in words:
        name = word.split("=")[0]
        if name in actions:
            skipping = actions[name].dest in given
            if not skipping:
                kept.append(word)
        elif not skipping:
            kept.append(word)
    return [*kept, *argv]


def known_resume(argv: list[str]) -> bool:
    """Whether ``argv`` resumes a run."""
    return any(w.split("=")[0] == "--resume" for w in argv)


def _resumed_folder(resume: Path | None) -> Path | None:
    """The run folder ``--resume`` names (a checkpoint's run), where a resumed run goes on
    unless ``--out`` says otherwise."""
    if resume is None:
        return None
    folder = resume if resume.is_dir() else resume.parent
    if not (folder / CONFIG_FILE).exists() and (folder.parent / CONFIG_FILE).exists():
        return folder.parent
    return folder


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
    if args is None:
        args = build_parser(name).parse_args(["--library", name])
        unknown = sorted(set(library_options) - set(vars(args)))
        if unknown:
            raise ValueError(f"{name} has no option {unknown[0]!r}")
        vars(args).update(library_options)
    for key, default in module.DEFAULTS.items():
        if getattr(settings, key) is None:
            setattr(settings, key, default)
    check_library(name, algo, settings, args)
    run = Run.start(settings, name, algo, command)
    trainer = module.Trainer(run, algo, args)
    if settings.progress:  # the bar opens once stepping starts (``Run.begin``)
        print(
            f"building the {name} {algo} run: env copies, geometries, kernels, model ...",
            flush=True,
        )
    try:
        run.write_config(**trainer.build())
        steps = trainer.learn()
        run.end()
        trainer.save(run.folder)
        trainer.close()
        run.finish(steps, **trainer.results())
    except BaseException:
        run.close_bar()
        trainer.close()
        raise
    return run.folder


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else list(argv)
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    add_library_argument(pre, DEFAULT_LIBRARY)
    pre.add_argument("--resume", type=Path)
    known, _ = pre.parse_known_args(argv)
    name = known.library
    if known.resume is not None and not any(w.split("=")[0] in LIBRARY_FLAGS for w in argv):
        # a resume without --library continues the run's own library: its options parse
        folder = _resumed_folder(known.resume)
        recorded = read_config(folder) if folder is not None else {}
        name = recorded.get("library", recorded.get("engine", name))  # "engine": earlier
    ap = build_parser(name if name in LIBRARIES else known.library)
    argv = resumed_argv(ap, argv) if known_resume(argv) else argv
    args = ap.parse_args(argv)
    with usage_errors(ap):  # every check before the run folder, the env and the model
        settings = settings_from(args, trainer_module(args.library).DEFAULTS)
        check_library(args.library, args.algo, settings, args)
    command = ["python", "-m", "baselines.train", *argv]
    out = train(args.library, args.algo, settings, args, command)
    print(f"saved the {args.library} {args.algo} run in {out}")


if __name__ == "__main__":
    main()
