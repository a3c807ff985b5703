"""One fair comparison of policies on the same seeded episodes.

    python -m baselines.evaluate --policy nmpc --policy random --scenario paper \\
        --scenario random --episodes 20 --seed 0 --workers 2 --out runs/eval

Every policy plays exactly the same episodes: episode k of scenario S has the seed
``episode_seed(seed, S, k)``, which fixes the random family's geometry, the truth-model
draws, the current and the sensor noise. Episodes run in worker processes; a result
depends only on (policy, scenario, seed), never on the number of workers. A policy that
raises ends its episode as a failure with the error recorded, not the evaluation.

Writes ``episodes.csv`` (one row per episode), ``results.json``, ``results.md`` and plots;
episodes whose current is beyond the team's reach (``current_within_reach`` false) are
counted apart and left out of the success rates. A team policy (``nmpc:central``,
``uvms_env.episode.play_team``) plays the same episodes; its rows carry ``information:
full`` (a full-information bound) against the per-robot policies' ``local``. Outputs and
policies: docs/evaluation.md.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import hashlib
import json
import os
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from baselines.options import add_condition_arguments
from baselines.policies import PolicySource, check_policy
from baselines.stats import bootstrap_mean_interval, wilson_interval
from uvms_env.env.constraints import CONSTRAINTS
from uvms_env.env.metrics import METRICS
from uvms_env.episode import decision_time_summary
from uvms_env.policy import AgentSpec, Policy, PolicyFactory

VIOLATION_KINDS = CONSTRAINTS
BACKENDS = ("process", "ray")
# numeric per-episode metrics averaged with bootstrap intervals (same names as the env's);
# success and clean success are rates, the violations are counted per kind
NOT_AVERAGED = ("success", "clean_success", "violations", "violation_periods", "policy_time_ms")
MEAN_METRICS = (*(m for m in METRICS if m not in NOT_AVERAGED), "return")


def episode_seed(seed: int, scenario: str, index: int) -> int:
    """A stable 32-bit seed per (evaluation seed, scenario, episode index)."""
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


@dataclass(frozen=True)
class EpisodeJob:
    policy: str
    scenario: str
    index: int
    seed: int
    overrides: tuple[tuple[str, Any], ...]
    max_cycles: int | None
    record_path: bool
    replay: str | None = None  # where to write the episode's 3D replay page
    label: str | None = None  # the rows' scenario (a ``Case``'s label); None: the scenario


def run_episode(job: EpisodeJob) -> dict[str, Any]:
    """Play one episode; never raises (errors become failed episodes)."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import uvms_env
    from uvms_env.episode import Step, play, play_team

    row: dict[str, Any] = {
        "policy": job.policy,
        # "full": a team policy's full-information bound, never a decentralized entry
        "information": PolicySource.parse(job.policy).information,
        "scenario": job.label or job.scenario,
        "episode": job.index,
        "seed": job.seed,
        "error": "",
    }
    times: list[np.ndarray] = []  # kept here too: a failed episode reports its decisions
    path: list[list[float]] = []
    filtered, interventions, deviation = 0, 0, 0.0  # safety-filter decisions (``+filter``)
    total_reward = 0.0

    def reached(env: Any, _obs: Any) -> None:
        row["current_within_reach"] = within_reach(env.scenario)

    def record(step: Step) -> None:
        nonlocal filtered, interventions, deviation, total_reward
        times.append(step.decision_ms)
        for policy in step.policies.values():
            if "intervened" in policy.stats:
                filtered += 1
                interventions += bool(policy.stats["intervened"])
                deviation += float(policy.stats["intervention"])
        total_reward += float(next(iter(step.rewards.values()))) if step.rewards else 0.0
        if job.record_path:
            path.append(step.env.unwrapped.sim.state.x_O[:3].tolist())

    try:
        kwargs = dict(job.overrides)
        if job.max_cycles is not None:
            kwargs["max_cycles"] = job.max_cycles
        env = uvms_env.parallel_env(scenario=job.scenario, seed=job.seed, **kwargs)
        source = PolicySource.parse(job.policy)
        hooks: dict[str, Any] = {"on_step": record, "on_reset": reached, "replay": job.replay}
        if source.team:  # one decision for the whole team, from the global state
            episode = play_team(env, source.team_factory(job.seed), job.seed, **hooks)
        else:
            episode = play(env, checked(source, job.seed), job.seed, **hooks)
        env.close()
        row.update(flatten_metrics(episode.metrics))
    except Exception as exc:  # a failing policy must not stop the evaluation
        row["error"] = f"{type(exc).__name__}: {exc}"
        row["traceback"] = traceback.format_exc(limit=5)
        row["success"] = False
    row["return"] = total_reward
    if row["error"]:  # no env metrics: the episode did not end
        row["violation_periods"] = 0
        row["clean_success"] = False
    row["interventions"] = interventions
    row["filtered_decisions"] = filtered
    row["intervention_rate"] = interventions / filtered if filtered else None
    row["intervention_mean"] = deviation / filtered if filtered else None
    timing = decision_time_summary(np.concatenate(times) if times else np.zeros(0))
    for key in ("median", "p95", "max"):
        row[f"policy_time_ms_{key}"] = timing[key] if timing else float("nan")
    row["_decision_ms"] = np.concatenate(times).tolist() if times else []
    row["_path"] = path
    return row


def checked(source: PolicySource, seed: int) -> PolicyFactory:
    """The source's policies, each checked against the interface as it is built. The
    source's factory is made with the first policy, after the env's reset: a source that
    fails (a missing model) fails an episode whose reach is known."""
    made: list[PolicyFactory] = []

    def build(spec: AgentSpec) -> Policy:
        if not made:
            made.append(source.factory(seed))
        policy = made[0](spec)
        check_policy(policy)
        return policy

    return build


def within_reach(scenario: Any) -> bool:
    """Whether the team can hold against the scenario's current at all
    (``uvms_env.scenarios.reach``); no current is always within reach."""
    if scenario.current == "none":
        return True
    from uvms_env.scenarios.reach import current_within_reach

    return current_within_reach(scenario)[0]


def flatten_metrics(metrics: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in metrics.items():
        if key == "violations" and isinstance(value, dict):
            extra = [k for k in value if k not in VIOLATION_KINDS]  # extra_constraints
            for kind in (*VIOLATION_KINDS, *extra):
                out[f"violations_{kind}"] = int(value.get(kind, 0))
        elif key == "policy_time_ms":
            continue  # a dict: the row has its parts
        elif isinstance(value, bool | int | float | np.floating | np.integer) or value is None:
            out[key] = value
    return out


def aggregate(rows: list[dict[str, Any]], seed: int) -> list[dict[str, Any]]:
    """One summary per (policy, scenario): rates with Wilson, means with bootstrap."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["policy"], row["scenario"]), []).append(row)
    out = []
    for (policy, scenario), group in sorted(groups.items()):
        # episodes whose current is beyond the team's reach are no policy's failure:
        # counted apart, left out of the rates
        reachable = [r for r in group if r.get("current_within_reach", True)]
        n = len(reachable)
        wins = sum(bool(r.get("success")) for r in reachable)
        lo, hi = wilson_interval(wins, n)
        clean = sum(bool(r.get("clean_success")) for r in reachable)
        summary: dict[str, Any] = {
            "policy": policy,
            "information": group[0].get("information", "local"),
            "scenario": scenario,
            "episodes": len(group),
            "out_of_reach": len(group) - n,
            "errors": sum(bool(r["error"]) for r in group),
            "success_rate": wins / n if n else float("nan"),
            "success_ci95": [lo, hi],
            "clean_success_rate": clean / n if n else float("nan"),
            "clean_success_ci95": list(wilson_interval(clean, n)),
        }
        for key in MEAN_METRICS:
            vals = np.array([r.get(key, np.nan) for r in group], dtype=float)
            if np.isfinite(vals).any():
                summary[key] = float(np.nanmean(vals))
                summary[f"{key}_ci95"] = list(bootstrap_mean_interval(vals, seed=seed))
        summary["violations"] = {
            kind: int(sum(r.get(f"violations_{kind}", 0) or 0 for r in group))
            for kind in VIOLATION_KINDS
        }
        decided = sum(r.get("filtered_decisions", 0) for r in group)
        # the safety filter's share of decisions changed by more than its tolerance,
        # pooled over the episodes' decisions (None: no filter)
        summary["intervention_rate"] = (
            sum(r.get("interventions", 0) for r in group) / decided if decided else None
        )
        summary["intervention_mean"] = (
            sum((r.get("intervention_mean") or 0.0) * r.get("filtered_decisions", 0) for r in group)
            / decided
            if decided
            else None
        )
        ms = np.concatenate([np.asarray(r["_decision_ms"], float) for r in group] or [[]])
        summary["policy_time_ms"] = decision_time_summary(ms) or dict.fromkeys(
            ("median", "p95", "max")
        )
        out.append(summary)
    return out


def markdown_table(summaries: list[dict[str, Any]]) -> str:
    def fmt(x: Any, digits: int = 2) -> str:
        return (
            "n/a"
            if x is None or (isinstance(x, float) and not np.isfinite(x))
            else f"{x:.{digits}f}"
        )

    lines = [
        "| policy | information | scenario | episodes | current out of reach | "
        "success [95% CI] | clean success | final pos. error m | min clearance m | "
        "internal wrench rms | control effort | violations (total) | violations / episode | "
        "intervention rate | decision ms median / p95 | errors |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in summaries:
        lo, hi = s["success_ci95"]
        t = s["policy_time_ms"]
        lines.append(
            f"| {s['policy']} | {s.get('information', 'local')} | {s['scenario']} | "
            f"{s['episodes']} | "
            f"{s.get('out_of_reach', 0)} | {fmt(s['success_rate'])} [{fmt(lo)}, {fmt(hi)}] | "
            f"{fmt(s.get('clean_success_rate'))} | "
            f"{fmt(s.get('final_pos_error_m'))} | {fmt(s.get('min_obstacle_clearance_m'))} | "
            f"{fmt(s.get('internal_wrench_rms'))} | {fmt(s.get('control_effort'))} | "
            f"{sum(s['violations'].values())} | "
            f"{fmt(sum(s['violations'].values()) / s['episodes'], 1)} | "
            f"{fmt(s.get('intervention_rate'), 3)} | "
            f"{fmt(t['median'], 3)} / {fmt(t['p95'], 3)} | {s['errors']} |"
        )
    kinds = " | ".join(VIOLATION_KINDS)
    lines += ["", f"| policy | scenario | {kinds} |", "|---|---|" + "---|" * len(VIOLATION_KINDS)]
    for s in summaries:
        counts = " | ".join(str(s["violations"][k]) for k in VIOLATION_KINDS)
        lines.append(f"| {s['policy']} | {s['scenario']} | {counts} |")
    if any(s.get("information") == "full" for s in summaries):
        lines += [
            "",
            "information `full`: a team policy that sees the global state and decides for "
            "every robot (a full-information bound, not a decentralized entry); `local`: "
            "one policy per robot on its own observation. Decision time: per team decision "
            "for `full`, per agent decision for `local`.",
        ]
    return "\n".join(lines) + "\n"


def write_plots(rows: list[dict[str, Any]], summaries: list[dict[str, Any]], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenarios = sorted({s["scenario"] for s in summaries})
    policies = list(dict.fromkeys(s["policy"] for s in summaries))
    fig, ax = plt.subplots(figsize=(6, 3.5))
    width = 0.8 / max(1, len(policies))
    for k, policy in enumerate(policies):
        for j, scen in enumerate(scenarios):
            s = next(
                (x for x in summaries if x["policy"] == policy and x["scenario"] == scen), None
            )
            if s is None:
                continue
            lo, hi = s["success_ci95"]
            rate = s["success_rate"]
            ax.bar(j + k * width, rate, width, color=f"C{k}", label=policy if j == 0 else None)
            yerr = [[max(0.0, rate - lo)], [max(0.0, hi - rate)]]  # rounding: never < 0
            ax.errorbar(j + k * width, rate, yerr=yerr, color="k", capsize=3)
    ax.set_xticks(np.arange(len(scenarios)) + width * (len(policies) - 1) / 2, scenarios)
    ax.set_ylabel("success rate (Wilson 95%)")
    ax.set_ylim(0, 1.05)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "success_by_scenario.png", dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 3.5))
    data = [
        np.concatenate([r["_decision_ms"] for r in rows if r["policy"] == p] or [[np.nan]])
        for p in policies
    ]
    ax.boxplot(
        [d[np.isfinite(d)] if np.isfinite(d).any() else [np.nan] for d in data], showfliers=False
    )
    ax.set_xticks(np.arange(1, len(policies) + 1), policies)
    ax.set_yscale("log")
    ax.set_ylabel("decision time per agent [ms]")
    fig.tight_layout()
    fig.savefig(out / "decision_time.png", dpi=120)
    plt.close(fig)

    paths = [r for r in rows if r["scenario"] == "paper" and r["episode"] == 0 and r["_path"]]
    if paths:
        from uvms_env.scenarios import make

        scen = make("paper")
        fig, ax = plt.subplots(figsize=(6, 5))
        for obs in scen.obstacles:
            ax.add_patch(plt.Circle((obs.y, obs.x), obs.radius, color="0.5"))
            ax.add_patch(
                plt.Circle((obs.y, obs.x), obs.radius + scen.team_radius, fill=False, ls=":")
            )
        for r in paths:
            p = np.array(r["_path"])
            ax.plot(p[:, 1], p[:, 0], color=f"C{policies.index(r['policy'])}", label=r["policy"])
        ax.plot(scen.waypoints[:, 1], scen.waypoints[:, 0], "k*", ms=12, label="waypoints")
        ax.set_xlabel("y (east) [m]")
        ax.set_ylabel("x (north) [m]")
        ax.set_aspect("equal")
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / "paths_paper.png", dpi=120)
        plt.close(fig)


def evaluate(
    policies: list[str],
    scenarios: list[str] | list[Case],
    episodes: int,
    seed: int,
    workers: int,
    overrides: dict[str, Any] | None = None,
    max_cycles: int | None = None,
    progress: bool = True,
    backend: str = "process",
    address: str | None = None,
    replay_dir: Path | None = None,
) -> list[dict[str, Any]]:
    """Run every (policy, scenario, episode) and return the per-episode rows, sorted.
    ``scenarios``: names, or ``Case``s whose keywords go over ``overrides``.
    ``replay_dir``: write each policy's first episode per scenario there as a 3D replay
    page (``uvms_env.replay.replay_path``).
    ``backend``: ``process`` (a process pool of ``workers``; 1: in this process) or
    ``ray`` (Ray tasks on a local Ray of ``workers`` CPUs, or on the cluster at
    ``address``); the rows do not depend on it."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; expected one of {BACKENDS}")
    if backend == "ray":
        from baselines.distributed.ray_backend import require_ray

        require_ray()  # before the warm-up episodes
    for p in policies:
        PolicySource.parse(p)  # fail fast on a typo, before any worker starts
    cases = [Case.of(c) for c in scenarios]
    labels = [c.label for c in cases]
    if len(set(labels)) != len(labels):
        raise ValueError(f"two scenarios share a label: {labels}")
    from uvms_env.replay import replay_path

    def make_job(p: str, c: Case, k: int) -> EpisodeJob:
        path = replay_path(replay_dir, p, c.label) if replay_dir is not None and k == 0 else None
        trail = k == 0 and c.label == "paper"  # the object's path, for the paper's plot
        items = tuple(sorted({**(overrides or {}), **dict(c.overrides)}.items()))
        seed_k = episode_seed(seed, c.scenario, k)
        path_s = path and str(path)
        return EpisodeJob(p, c.scenario, k, seed_k, items, max_cycles, trail, path_s, c.label)

    jobs = [make_job(p, c, k) for p in policies for c in cases for k in range(episodes)]
    rows: list[dict[str, Any]] = []
    bar = tqdm(total=len(jobs), desc="episodes", disable=not progress, unit="ep")
    if backend == "process" and workers <= 1:
        for job in jobs:
            rows.append(run_episode(job))
            bar.update()
    else:
        # Build each (policy, scenario) once here first: compiled controllers and
        # simulators land in the disk cache before the workers would race to build them.
        seen = set()
        for job in jobs:
            if (job.policy, job.scenario, job.overrides) not in seen:
                seen.add((job.policy, job.scenario, job.overrides))
                run_episode(dataclasses.replace(job, max_cycles=1, record_path=False, replay=None))
        if backend == "ray":
            from baselines.distributed.ray_backend import run_jobs

            for row in run_jobs(run_episode, jobs, address, workers):
                rows.append(row)
                bar.update()
        else:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                for fut in as_completed([pool.submit(run_episode, j) for j in jobs]):
                    rows.append(fut.result())
                    bar.update()
    bar.close()
    rows.sort(
        key=lambda r: (policies.index(r["policy"]), labels.index(r["scenario"]), r["episode"])
    )
    return rows


def read_episodes(path: Path) -> list[dict[str, Any]]:
    """``write_outputs``' episodes.csv back as rows: booleans and numbers typed, empty
    cells None, ``error`` "" when absent (the per-decision times are not in the file, only
    each episode's summary ``policy_time_ms_*``)."""

    def typed(value: str) -> Any:
        if value in ("True", "False"):
            return value == "True"
        if value == "":
            return None
        try:
            return float(value)
        except ValueError:
            return value

    with open(path, newline="") as fh:
        rows = [{k: typed(v) for k, v in r.items()} for r in csv.DictReader(fh)]
    for r in rows:
        r["episode"] = int(r["episode"])
        r["error"] = r.get("error") or ""
    return rows


def write_outputs(rows: list[dict[str, Any]], seed: int, out: Path) -> list[dict[str, Any]]:
    out.mkdir(parents=True, exist_ok=True)
    summaries = aggregate(rows, seed)
    keys = list(
        dict.fromkeys(k for r in rows for k in r if not k.startswith("_") and k != "traceback")
    )
    with open(out / "episodes.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=keys)
        writer.writeheader()
        for r in rows:
            writer.writerow({k: r.get(k, "") for k in keys})
    (out / "results.json").write_text(json.dumps(summaries, indent=2))
    (out / "results.md").write_text(markdown_table(summaries))
    write_plots(rows, summaries, out)
    return summaries


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m baselines.evaluate",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument(
        "--policy",
        action="append",
        required=True,
        help="nmpc, random, zero, ppo:PATH, sac:PATH, rllib:PATH, bc:PATH, dagger:PATH, "
        "pkg.mod:factory; "
        "suffix +filter: inside the expert's safety filter; nmpc:central: the centralized "
        "NMPC, a team policy with full information (its rows say information full: a bound, "
        "not a decentralized entry)",
    )
    ap.add_argument("--scenario", action="append", default=None, help="paper, random (repeatable)")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--max-cycles", type=int, default=None)
    add_condition_arguments(ap, draws=False)  # the trainers' flags, one value each
    ap.add_argument(
        "--comm",
        default=None,
        metavar="PRESET",
        help="acoustic channel preset (uvms_env.env.channel.PRESETS; default off): policies "
        "that do not read messages play silent",
    )
    for flag, what in (("reward-term", "reward term"), ("constraint", "constraint")):
        ap.add_argument(
            f"--extra-{flag}",
            action="append",
            default=[],
            metavar="NAME=MODULE:FUNCTION",
            help=f"an extra {what} fn(s, xp) of the environment (uvms_env.env.task)",
        )
    ap.add_argument("--out", type=Path, default=Path("runs/eval"))
    ap.add_argument(
        "--replay",
        action="store_true",
        help="also write a 3D replay page of each policy's first episode per scenario to --out",
    )
    ap.add_argument(
        "--backend",
        choices=BACKENDS,
        default="process",
        help="process: a process pool of --workers; ray: Ray tasks (pip install -e "
        '".[distributed]"), on a local Ray of --workers CPUs or the cluster at --address',
    )
    ap.add_argument("--address", default=None, help="Ray cluster to join (--backend ray)")
    ap.add_argument(
        "--marl-eval-json",
        type=Path,
        default=None,
        metavar="PATH",
        help="also write (merge into) marl-eval's JSON: env uvms_coop, task = scenario, "
        "algorithm = policy, run seed_SEED (baselines.distributed.marl_eval)",
    )
    ap.add_argument(
        "--marl-eval-step-count",
        type=int,
        default=0,
        help="the step_count recorded in the marl-eval JSON (e.g. the policy's training steps)",
    )
    return ap


def env_overrides(ap: argparse.ArgumentParser, args: argparse.Namespace) -> dict[str, Any]:
    """The environment keywords of the command line (``ap.error`` on a malformed one)."""
    overrides = {
        k: v
        for k, v in {
            "n_agents": args.n_agents,
            "current": args.current,
            "mismatch": args.mismatch,
            "comm": args.comm,
        }.items()
        if v is not None
    }
    for key, given in (
        ("extra_reward_terms", args.extra_reward_term),
        ("extra_constraints", args.extra_constraint),
    ):
        if given:
            if not all("=" in g for g in given):
                ap.error(f"--{key.replace('_', '-')[:-1]}: expected NAME=MODULE:FUNCTION")
            overrides[key] = dict(g.split("=", 1) for g in given)
    return overrides


def main(argv: list[str] | None = None) -> None:
    ap = build_parser()
    args = ap.parse_args(argv)
    overrides = env_overrides(ap, args)
    rows = evaluate(
        args.policy,
        args.scenario or ["paper"],
        args.episodes,
        args.seed,
        args.workers,
        overrides,
        args.max_cycles,
        backend=args.backend,
        address=args.address,
        replay_dir=args.out if args.replay else None,
    )
    summaries = write_outputs(rows, args.seed, args.out)
    if args.marl_eval_json is not None:
        from baselines.distributed import marl_eval

        marl_eval.write(
            args.marl_eval_json,
            rows,
            args.seed,
            step_count=args.marl_eval_step_count,
            overrides=overrides,
        )
        print(f"wrote {args.marl_eval_json} (marl-eval)")
    print(markdown_table(summaries))
    print(f"wrote {args.out}/episodes.csv, results.json, results.md and plots")


if __name__ == "__main__":
    main()
