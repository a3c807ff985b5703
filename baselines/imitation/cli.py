"""``python -m baselines.imitate``: collect expert demonstrations, clone, DAgger.

    python -m baselines.imitate collect --scenario short --episodes 16 --out data/short
    python -m baselines.imitate bc --data data/short --data data/paper --out runs/bc
    python -m baselines.imitate dagger --data data/short --data data/paper \\
        --scenario short --scenario paper --iterations 4 --out runs/dagger

Every option, the schedule and the outputs: docs/imitation.md; ``--help`` lists the
options. Every option is checked before any rollout or fit: the environment of each
scenario and team size and the teacher (``--expert``) are built once, ``--init`` and
``--resume`` read, and a refusal is a usage error naming the option.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from tqdm import tqdm

from baselines.command_line import (
    SCENARIOS,
    add_condition_arguments,
    add_evaluation_arguments,
    command_parser,
    condition_overrides,
    existing_path,
    fraction,
    non_negative_float,
    non_negative_int,
    objects,
    positive_float,
    positive_int,
    team_sizes,
    team_variants,
    usage_errors,
)
from baselines.evaluation.during_training import evaluate_rungs
from baselines.imitation import bc, dataset
from baselines.imitation.dataset import AgentStream
from baselines.imitation.labelled_rollouts import RolloutJob, parallel_rollouts
from baselines.loaders.sources import PolicySource
from baselines.networks.features import FEATURES
from baselines.networks.mlp import MLPPolicyNet
from baselines.runs import EVAL_KEEP, hardware, training_env_options, write_json

# ``--expert`` value of safe distillation: the safety filter around the current network
SELF_FILTER = "self+filter"
# the options every fit of the command line passes to ``bc.fit`` (and train.json records)
FIT_OPTIONS = ("epochs", "hidden", "lr", "batch_size", "loss_scale", "lr_schedule", "margin_weight")
# what a DAgger run's train.json records of its options, in this order (``_dagger_settings``)
DAGGER_SETTINGS = (
    "scenarios iterations warm_start_epochs save_data episodes_per_iteration beta_schedule "
    "rollout_noise gate max_cycles constraint_mode n_agents object course current mismatch "
    "workers expert init"
).split()
Samples = tuple[np.ndarray, np.ndarray, np.ndarray]  # observations, labels, object keys


def env_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """Environment options from the command line: the conditions (``--current``,
    ``--mismatch``: one value an override, several a per-episode draw) and
    ``--constraint-mode``; the team sizes and objects are the job's (``rollout_job``);
    ``--max-cycles`` is applied as a cap."""
    out: dict[str, Any] = condition_overrides(args)
    if getattr(args, "constraint_mode", None):
        out["constraint_mode"] = args.constraint_mode
    return training_env_options(out)


def rollout_job(scenario: str, args: argparse.Namespace, **labelling: Any) -> RolloutJob:
    """The rollouts of ``scenario`` the command line asks for (``--n-agents`` for the
    random family only: the fixed scenarios have their own teams)."""
    drawn = scenario == "random"
    return RolloutJob(
        scenario,
        env_overrides(args),
        team_sizes(args) if drawn else (),
        args.max_cycles,
        labelling.pop("expert", args.expert),
        objects=tuple(objects(args)) if drawn else (),
        **labelling,
    )


def _write_dataset(
    streams: list[AgentStream],
    job: RolloutJob,
    root: Path,
    name: str,
    algorithm: str,
    spec: bool = True,
) -> str:
    """``streams`` as Minari dataset ``root/NAME`` in one robot's spaces of ``job``'s
    environment. With ``spec``, the Gymnasium ``EnvSpec`` the data came from (for Minari's
    ``recover_environment``): the scenario, its overrides and the episode length actually
    used; none where the episodes had several team sizes (no one environment made them)."""
    env = job.env(0, 0)
    agent = env.possible_agents[0]
    env_spec = None
    if spec and len(job.n_agents) <= 1 and len(job.objects) <= 1:
        kwargs = dict(job.overrides)
        if job.objects:
            kwargs["object"] = job.objects[0]
        if job.n_agents:
            kwargs["n_agents"] = job.n_agents[0]
        if job.cap:
            kwargs["max_cycles"] = env.max_cycles
        env_spec = dataset.env_spec(job.scenario, **kwargs)
    spaces = env.observation_space(agent), env.action_space(agent)
    return dataset.write_dataset(streams, root, name, *spaces, algorithm, spec=env_spec)


def _summary(metrics: list[dict]) -> dict[str, Any]:
    steps = [m.get("episode_steps") for m in metrics if m.get("episode_steps") is not None]
    return {
        "episodes": len(metrics),
        "success": sum(bool(m.get("success")) for m in metrics),
        "mean_steps": float(np.mean(steps)) if steps else None,
    }


def collect(args: argparse.Namespace) -> None:
    start = time.time()
    job = rollout_job(args.scenario, args, noise=args.noise)
    streams, metrics = parallel_rollouts(
        job, args.episodes, args.seed, workers=args.workers, desc="collect"
    )
    root, name = dataset.split_path(args.out)
    algorithm = f"expert {args.expert}" + (f", DART noise {args.noise}" if args.noise else "")
    dataset_id = _write_dataset(streams, job, root, name, algorithm)
    summary = _summary(metrics)
    steps = sum(len(s.actions) for s in streams)
    # the teacher's time per control period, its robots together: a team teacher's whole
    # decision is timed on its first robot, a per-robot expert's on each
    periods: dict[int, np.ndarray] = {}
    for s in streams:
        periods[s.seed] = periods.get(s.seed, 0.0) + np.asarray(s.solve_ms)
    period_ms = np.concatenate(list(periods.values())) if periods else np.zeros(0)
    print(
        f"wrote Minari dataset {dataset_id} under {args.out}: {len(streams)} robot streams, "
        f"{steps} steps, expert success {summary['success']}/{summary['episodes']}, "
        f"expert time per period (all robots) median {np.median(period_ms):.3f} ms, "
        f"{time.time() - start:.0f} s"
    )


def _common(args: argparse.Namespace) -> dict[str, Any]:
    """What train.json records of every fit."""
    return {
        "data": [str(p) for p in args.data or []],
        **{k: getattr(args, k) for k in FIT_OPTIONS},
        "hidden": list(args.hidden),
        "features": args.features,
        "seed": args.seed,
        "python": platform.python_version(),
        "hardware": hardware(),
    }


def _scenario_episodes(entry: str, default: int) -> tuple[str, int]:
    """``NAME`` or ``NAME:EPISODES`` (DAgger rollouts per iteration of that scenario)."""
    name, _, count = entry.partition(":")
    return name, int(count) if count else default


def scenario_entry(text: str) -> str:
    """An argparse ``type`` for ``NAME`` or ``NAME:EPISODES``: NAME a scenario family,
    EPISODES a positive count."""
    name, sep, episodes = text.partition(":")
    if name not in SCENARIOS:
        raise argparse.ArgumentTypeError(f"unknown scenario {name!r}; expected one of {SCENARIOS}")
    if sep:
        positive_int(episodes)  # its own message: expected int >= 1
    return text


def _fit(
    args: argparse.Namespace,
    samples: Samples,
    stage: str,
    seed: int,
    net: MLPPolicyNet | None = None,
    epochs: int | None = None,
) -> tuple[MLPPolicyNet, list[float]]:
    """``bc.fit`` with the command line's options, logged as ``stage`` in the run's
    ``{bc,dagger}_loss.csv``: from ``net`` when given (``epochs``, where given, instead of
    ``--epochs``), else a new network on ``--features``."""
    obs, act, ring = samples
    fit = {k: getattr(args, k) for k in FIT_OPTIONS} | {"hidden": tuple(args.hidden)}
    if epochs is not None:
        fit["epochs"] = epochs
    return bc.fit(
        obs,
        act,
        object_key=ring,
        net=net,
        features=args.features if net is None else net.features,
        seed=seed,
        log_path=args.out / f"{args.command}_loss.csv",
        stage=stage,
        val_fraction=0.05,
        **fit,
    )


def train_bc(args: argparse.Namespace) -> None:
    start = time.time()
    obs, act, ring, n_streams = dataset.read_many(args.data, memory=args.features == "memory")
    (args.out / "bc_loss.csv").unlink(missing_ok=True)
    net, losses = _fit(args, (obs, act, ring), "bc", args.seed)
    info = {
        "method": "bc",
        **_common(args),
        "samples": len(obs),
        "robot_streams": n_streams,
        "final_train_loss": losses[-1],
        "train_wall_s": round(time.time() - start, 1),
    }
    net.save(args.out / "policy.pt", info)
    write_json(args.out / "train.json", info)  # net.save made the folder
    print(f"bc: {len(obs)} samples, final loss {losses[-1]:.4g}; saved {args.out / 'policy.pt'}")


def _init_network(source: str) -> MLPPolicyNet:
    """``--init``: the network of a ``bc:`` / ``dagger:`` source (ValueError naming the
    option where it is none)."""
    parsed = PolicySource.parse(source)
    if parsed.name not in ("bc", "dagger") or parsed.filtered:
        raise ValueError(f"--init takes bc:PATH or dagger:PATH (or :pretrained), got {source!r}")
    from baselines.loaders.clone_policy import ClonedPolicy

    try:
        return MLPPolicyNet.load(ClonedPolicy.locate(parsed.name, parsed.arg))
    except (OSError, RuntimeError, ValueError) as exc:
        raise ValueError(f"--init {source}: {exc}") from exc


def _joined(*parts: Samples | None) -> Samples | None:
    """Sample sets one after the other (None: no samples)."""
    given = [p for p in parts if p is not None]
    if not given:
        return None
    obs, act, ring = (np.concatenate(column) for column in zip(*given, strict=True))
    return obs, act, ring


def train_dagger(args: argparse.Namespace) -> None:
    start = time.time()
    if args.resume is not None:
        args.out = args.resume
    init = _init_network(args.init) if args.init is not None else None
    memory = (args.features if init is None else init.features) == "memory"
    demos = dataset.read_many(args.data, memory=memory) if args.data else None
    n_streams, samples = (demos[3], demos[:3]) if demos else (0, None)
    if args.resume is not None:
        info, net = _resume_record(args, memory)
        history = info["history"]
        first = history[-1]["iteration"] + 1
        print(f"resuming {args.resume} after iteration {first - 1}")
        if first > 1:  # the rollouts of the iterations done so far (--save-data)
            paths = [args.out / "data" / f"iter_{k}" for k in range(1, first)]
            samples = _joined(samples, dataset.read_many(paths, memory=memory)[:3])
        start -= float(info.get("train_wall_s", 0.0))
    else:
        (args.out / "dagger_loss.csv").unlink(missing_ok=True)
        first = 1
        if init is None:
            assert samples is not None  # check_dagger: --data or --init
            net, losses = _fit(args, samples, "dagger_0", args.seed)
            row = {"iteration": 0, "beta": 1.0, "samples": len(samples[0]), "loss": losses[-1]}
            _evaluate_iteration(args, net, 0, len(samples[0]), start)
        else:
            net = init
            row = {"iteration": 0, "init": args.init, "samples": _count(samples)}
        history = [row]
        # a run stopped during the first iteration's rollouts resumes after the first fit
        _save_dagger(args, net, n_streams, _count(samples), history, start)
    bar = tqdm(
        total=args.iterations, initial=first - 1, desc="dagger", unit="iteration", leave=True
    )
    for k in range(first, args.iterations + 1):
        net, samples, row = _dagger_iteration(args, net, k, samples, start)
        evaluated = _evaluate_iteration(args, net, k, _count(samples), start)
        history.append(row)
        bar.write(json.dumps(row))
        # after every iteration: what --resume continues from
        _save_dagger(args, net, n_streams, _count(samples), history, start)
        postfix = {"loss": f"{row['loss']:.3g}"}  # and the evaluation's means over the rungs
        if evaluated:
            postfix["success"] = f"{np.mean([r['success_rate'] for r in evaluated]):.2f}"
            postfix["clean"] = f"{np.mean([r['clean_success_rate'] for r in evaluated]):.2f}"
        bar.set_postfix(postfix, refresh=False)
        bar.update()
    bar.close()
    info = _save_dagger(args, net, n_streams, _count(samples), history, start)
    print(f"saved {args.out / 'policy.pt'} ({_count(samples)} samples, {info['train_wall_s']} s)")


def _count(samples: Samples | None) -> int:
    return 0 if samples is None else len(samples[0])


def _dagger_iteration(
    args: argparse.Namespace, net: MLPPolicyNet, k: int, samples: Samples | None, start: float
) -> tuple[MLPPolicyNet, Samples, dict[str, Any]]:
    """Iteration ``k``: the network so far saved as ``iter_{k-1}``, its rollouts labelled,
    joined to the aggregate and fitted; (the new network, the aggregate, its history row)."""
    path = (args.out / f"iter_{k - 1}" / "policy.pt").resolve()
    net.save(path, {"method": "dagger", "iteration": k - 1})
    # safe distillation: the teacher is the safety filter around the network itself
    expert = f"dagger:{path}+filter" if args.expert == SELF_FILTER else args.expert
    row: dict[str, Any] = {"iteration": k, "beta": args.beta**k}
    streams = _dagger_rollouts(args, k, expert, path, row)
    new_obs, new_act, new_ring, acted = _stacked(streams, net.features == "memory")
    # the quantity DAgger drives down: the current network's error on the states it
    # visits itself (before they join the training data), per component, against the
    # (clipped) expert labels
    if acted.any():
        err = net.predict(new_obs[acted], new_ring[acted]) - np.clip(new_act[acted], -1, 1)
        row["learner_state_rmse"] = [round(float(v), 4) for v in np.sqrt(np.mean(err**2, axis=0))]
    samples = _joined(samples, (new_obs, new_act, new_ring))
    assert samples is not None
    # from the previous network with --init or --warm-start (its epochs), else a new one
    warm = args.init is not None or args.warm_start is not None
    net, losses = _fit(
        args, samples, f"dagger_{k}", args.seed + k, net if warm else None, args.warm_start
    )
    row.update(
        samples=len(samples[0]),
        new_samples=len(new_obs),
        learner_share=float(np.mean(acted)),
        loss=losses[-1],
        wall_s=round(time.time() - start, 1),
    )
    return net, samples, row


def _dagger_settings(args: argparse.Namespace) -> dict[str, Any]:
    """The options a DAgger run's train.json records (``DAGGER_SETTINGS``)."""
    options = vars(args) | {
        "scenarios": args.scenario or ["short"],
        "warm_start_epochs": args.warm_start,
        "beta_schedule": f"beta_k = {args.beta}**k",
        "rollout_noise": args.noise,
    }
    return {key: options[key] for key in DAGGER_SETTINGS}


def _save_dagger(
    args: argparse.Namespace,
    net: MLPPolicyNet,
    n_streams: int,
    samples: int,
    history: list[dict[str, Any]],
    start: float,
) -> dict[str, Any]:
    """The run's ``policy.pt`` and ``train.json`` as they stand."""
    info = {
        "method": "dagger",
        **_common(args),
        **_dagger_settings(args),
        "demo_robot_streams": n_streams,
        "samples": samples,
        "history": history,
        "train_wall_s": round(time.time() - start, 1),
    }
    net.save(args.out / "policy.pt", info)
    write_json(args.out / "train.json", info)  # net.save made the folder
    return info


def _resume_record(args: argparse.Namespace, memory: bool) -> tuple[dict[str, Any], MLPPolicyNet]:
    """``--resume RUN``'s train.json and network, written after each iteration; ValueError
    naming the option where the run cannot be continued: the iterations' rollouts must have
    been saved (``--save-data``), its features have the memory block where this command's
    do (``memory``)."""
    info_path = args.resume / "train.json"
    if not info_path.exists() or not (args.resume / "policy.pt").exists():
        raise ValueError(
            f"--resume: nothing to resume at {args.resume} (no train.json and policy.pt)"
        )
    info = json.loads(info_path.read_text())
    if info["history"][-1]["iteration"] >= 1 and not info.get("save_data"):
        raise ValueError(
            f"--resume {args.resume} did not save its rollouts (--save-data): its aggregate is lost"
        )
    if not args.save_data:
        raise ValueError("--resume needs --save-data: the next resume reads this run's rollouts")
    net = MLPPolicyNet.load(args.resume / "policy.pt")
    if (net.features == "memory") != memory:
        raise ValueError(f"--resume {args.resume} was trained on {net.features!r} features")
    return info, net


def dagger_rungs(args: argparse.Namespace, scenarios: list[str]) -> dict[str, tuple[str, dict]]:
    """The periodic evaluations' rungs of a DAgger run: each scenario it rolls out on,
    under its conditions, the random family once per team size and object."""
    rungs: dict[str, tuple[str, dict]] = {}
    for entry in scenarios:
        scenario, _ = _scenario_episodes(entry, 1)
        job = rollout_job(scenario, args)
        keep = {k: v for k, v in job.overrides.items() if k in EVAL_KEEP}
        for variant in team_variants(job.n_agents, job.objects):
            tag = f"_{variant['object']}" if len(job.objects) > 1 else ""
            size = f"_n{variant['n_agents']}" if "n_agents" in variant else ""
            rungs[f"{scenario}{tag}{size}"] = (scenario, {**keep, **variant})
    return rungs


def _evaluate_iteration(
    args: argparse.Namespace, net: MLPPolicyNet, k: int, samples: int, start: float
) -> list[dict[str, Any]]:
    """With ``--eval-episodes``: iteration ``k``'s network on every rung (``dagger_rungs``),
    rows in the run's evaluations.csv at its labelled robot-steps so far (``samples``);
    the rows (none without)."""
    if not args.eval_episodes:
        return []
    path = (args.out / f"iter_{k}" / "policy.pt").resolve()
    net.save(path, {"method": "dagger", "iteration": k})
    rows = evaluate_rungs(
        args.out,
        dagger_rungs(args, args.scenario or ["short"]),
        f"dagger:{path}",
        args.eval_episodes,
        args.eval_seed if args.eval_seed is not None else args.seed,
        samples,
        algorithm="dagger",
        training_seed=args.seed,
        elapsed=time.time() - start,
        max_cycles=args.eval_max_cycles,
    )
    for r in rows:
        tqdm.write(
            f"iteration {k} on {r['rung']}: success {r['success_rate']:.2f}, clean "
            f"{r['clean_success_rate']:.2f}, violation periods median "
            f"{r['violation_periods_median']:.0f}"
        )
    return rows


def _dagger_rollouts(
    args: argparse.Namespace, k: int, expert: str, path: Path, row: dict[str, Any]
) -> list[AgentStream]:
    """Iteration ``k``'s rollouts of the clone saved at ``path`` on every scenario, labelled
    by ``expert`` (a policy source) with the iteration's ``row["beta"]`` (the summaries go
    into ``row``), on ``--workers`` processes; written as a dataset with --save-data."""
    streams: list[AgentStream] = []
    jobs = []
    for j, entry in enumerate(args.scenario or ["short"]):
        scenario, episodes = _scenario_episodes(entry, args.episodes_per_iteration)
        job = rollout_job(scenario, args, expert=expert, learner=path, beta=row["beta"],
                          noise=args.noise, gate=args.gate)  # fmt: skip
        new, metrics = parallel_rollouts(
            job,
            episodes,
            args.seed + 1000 * k + 100 * j,
            workers=args.workers,
            desc=f"dagger {k} {scenario}",
        )
        streams += new
        jobs.append(job)
        row[f"rollouts_{scenario}"] = _summary(metrics)
    if args.save_data:
        # one environment to recover only when the rollouts had one scenario
        algorithm = f"DAgger iteration {k}, labels {args.expert}"
        _write_dataset(streams, jobs[0], args.out / "data", f"iter_{k}", algorithm, len(jobs) == 1)
    return streams


def _stacked(
    streams: list[AgentStream], memory: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Observations (``memory``: each followed by its memory block), expert labels, ring
    radii and learner-acted flags, stream after stream (each stream's last observation has
    no label)."""
    obs = np.concatenate([np.stack(s.observations[:-1]) for s in streams])
    if memory:
        blocks = np.concatenate([np.stack(s.memory[:-1]) for s in streams])
        obs = np.concatenate([obs, blocks], axis=1)
    act = np.concatenate([np.stack(s.actions) for s in streams])
    ring = np.concatenate([np.full(len(s.actions), s.object_key) for s in streams])
    acted = np.concatenate([s.learner_acted for s in streams])
    return obs, act, ring, acted


def _add_env_args(p: argparse.ArgumentParser) -> None:
    from uvms_env.env.options import CONSTRAINT_MODES

    add_condition_arguments(p)
    p.add_argument(
        "--workers",
        type=positive_int,
        default=1,
        help="processes that play the episodes (one core each)",
    )
    p.add_argument(
        "--max-cycles", type=positive_int, default=None, help="cap on the episode length"
    )
    p.add_argument("--constraint-mode", default=None, choices=CONSTRAINT_MODES)
    p.add_argument(
        "--noise",
        type=non_negative_float,
        default=0.0,
        help="std of Gaussian noise on executed actions (DART)",
    )
    p.add_argument(
        "--expert",
        default="nmpc",
        help=f"any baselines.evaluate --policy source; dagger: also {SELF_FILTER}",
    )


def _add_train_args(p: argparse.ArgumentParser, epochs: int, data_required: bool = True) -> None:
    p.add_argument(
        "--data", type=existing_path, action="append", required=data_required, help="data/NAME"
    )
    p.add_argument("--epochs", type=positive_int, default=epochs)
    p.add_argument("--lr", type=positive_float, default=1e-3)
    p.add_argument("--lr-schedule", default="constant", choices=bc.LR_SCHEDULES)
    p.add_argument("--batch-size", type=positive_int, default=256)
    p.add_argument(
        "--loss-scale", default="none", choices=bc.LOSS_SCALES, help="std: per-component 1/var"
    )
    p.add_argument(
        "--hidden", type=positive_int, nargs="*", default=[128, 128], help="widths; none: linear"
    )
    p.add_argument(
        "--margin-weight",
        type=non_negative_float,
        default=0.0,
        help="samples near a speed or joint limit weigh up to 1 + W (bc.margin_weights)",
    )
    p.add_argument("--features", default="features", choices=FEATURES, help="input set")
    p.add_argument("--seed", type=non_negative_int, default=0)


def _add_dagger_args(d: argparse.ArgumentParser) -> None:
    d.add_argument(
        "--init", default=None, help="start from this clone (dagger:pretrained, bc:PATH, ...)"
    )
    d.add_argument(
        "--scenario",
        action="append",
        type=scenario_entry,
        default=None,
        help="NAME or NAME:EPISODES (per iteration); repeatable; default short",
    )
    d.add_argument("--iterations", type=non_negative_int, default=4)
    d.add_argument(
        "--warm-start",
        type=positive_int,
        default=None,
        metavar="EPOCHS",
        help="iterations 1.. fine-tune the previous network for EPOCHS epochs on the "
        "aggregate (default: a new network each iteration, --epochs)",
    )
    d.add_argument("--episodes-per-iteration", type=positive_int, default=2, help="per scenario")
    d.add_argument("--beta", type=fraction, default=0.5, help="beta_k = beta**k")
    d.add_argument("--save-data", action="store_true", help="write each iteration's data")
    d.add_argument(
        "--resume",
        type=existing_path,
        default=None,
        metavar="RUN",
        help="continue a run saved with --save-data up to --iterations (its folder is --out)",
    )
    d.add_argument(
        "--gate",
        type=positive_float,
        default=None,
        help="learner acts only within this of the label",
    )
    add_evaluation_arguments(
        d, 0, "after each fit, evaluate the network on every rung this many episodes (0: none)"
    )


def check_collect(args: argparse.Namespace) -> None:
    """``collect``'s options: ValueError naming the one the environment or the teacher
    refuses."""
    env_overrides(args)
    _check_rollouts(args, [args.scenario], args.seed)


def check_dagger(args: argparse.Namespace) -> None:
    """``dagger``'s options: ValueError naming the one that cannot be honoured."""
    if not args.data and args.init is None:
        raise ValueError("dagger needs --data (demonstrations) or --init (a clone to start from)")
    env_overrides(args)
    features = args.features if args.init is None else _init_network(args.init).features
    if args.resume is not None:
        _resume_record(args, features == "memory")
    _check_rollouts(args, args.scenario or ["short"], args.seed)


def _preflight(option: str, policies: list[str], cases: list, seed: int, cap: int | None) -> None:
    """The evaluator's ``preflight``, its refusal a ValueError naming ``option``."""
    from baselines.evaluation.runner import UsageError, preflight

    try:
        preflight(policies, cases, seed, {}, cap, progress=False)
    except UsageError as exc:
        raise ValueError(f"{option}: {exc}") from exc


def _check_rollouts(args: argparse.Namespace, entries: list[str], seed: int) -> None:
    """The environment of every scenario (each of its team sizes) and the teacher
    (``--expert``; not ``self+filter``, the network itself) built once, through the
    evaluator's ``preflight``; ``--n-agents`` that no scenario would use is refused."""
    from baselines.evaluation.runner import Case

    scenarios = [_scenario_episodes(e, 1)[0] for e in entries]
    if objects(args) and "random" not in scenarios:
        raise ValueError(f"--object: only the random family draws an object, not {scenarios[0]}")
    if "random" not in scenarios:
        # the fixed scenarios keep their own team: a size they do not have is refused
        for scenario in scenarios:
            for n in team_sizes(args):
                overrides = {**env_overrides(args), "n_agents": n}
                case = Case(scenario, scenario, tuple(overrides.items()))
                _preflight(f"--n-agents {n}", [], [case], seed, None)
    cases = []
    for scenario in dict.fromkeys(scenarios):
        job = rollout_job(scenario, args)
        for variant in team_variants(job.n_agents, job.objects):
            flags = "".join(f" --{k.replace('_', '-')} {v}" for k, v in variant.items())
            overrides = dict(job.overrides) | variant
            cases.append(Case(scenario + flags, scenario, tuple(overrides.items())))
    _preflight("--scenario", [], cases, seed, args.max_cycles)
    if args.expert != SELF_FILTER:
        _preflight("--expert", [args.expert], cases[:1], seed, args.max_cycles)


# each subcommand: its help, its check of the options (before any rollout, fit or file)
# and what it runs
COMMANDS = {
    "collect": ("expert demonstrations to a Minari dataset", check_collect, collect),
    "bc": ("behaviour cloning", None, train_bc),
    "dagger": ("DAgger with the expert relabelling", check_dagger, train_dagger),
}


def main(argv: list[str] | None = None) -> None:
    ap = command_parser("baselines.imitate", __doc__)
    sub = ap.add_subparsers(dest="command", required=True)
    c, b, d = (sub.add_parser(n, help=h, allow_abbrev=False) for n, (h, *_) in COMMANDS.items())
    c.add_argument("--scenario", choices=SCENARIOS, default="paper")
    c.add_argument("--episodes", type=positive_int, default=4)
    c.add_argument("--seed", type=non_negative_int, default=0)
    c.add_argument("--out", type=Path, required=True, help="data/NAME")
    _add_env_args(c)
    _add_train_args(b, epochs=50)
    b.add_argument("--out", type=Path, default=Path("runs/bc"))
    _add_train_args(d, epochs=30, data_required=False)
    _add_dagger_args(d)
    d.add_argument("--out", type=Path, default=Path("runs/dagger"))
    _add_env_args(d)
    args = ap.parse_args(argv)
    _, check, run = COMMANDS[args.command]
    if check is not None:
        with usage_errors(sub.choices[args.command], (ValueError,)):
            check(args)
    run(args)


if __name__ == "__main__":
    main()
