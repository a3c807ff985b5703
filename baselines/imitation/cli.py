"""``python -m baselines.imitate``: collect expert demonstrations, clone, DAgger.

    python -m baselines.imitate collect --scenario paper --episodes 4 --out data/paper_expert
    python -m baselines.imitate bc --data data/paper_expert --out runs/bc
    python -m baselines.imitate dagger --data data/paper_expert --iterations 4 --out runs/dagger

DAgger (Ross et al. 2011): iteration k rolls out ``--episodes-per-iteration`` episodes in
which each robot executes the expert's action with probability beta_k = 0.5^k (k >= 1;
the demonstrations are iteration 0 with beta = 1) and the learner's otherwise; the expert
labels every visited observation; the aggregated data retrains the network (warm start).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from baselines.imitation import bc, dataset
from baselines.imitation.network import ClonedPolicy
from baselines.imitation.rollout import rollouts
from baselines.policies import PolicySource


def _env_factory(scenario: str, overrides: dict):
    import uvms_env

    return lambda seed: uvms_env.parallel_env(scenario=scenario, seed=seed, **overrides)


def _spaces(scenario: str, overrides: dict):
    env = _env_factory(scenario, overrides)(0)
    agent = env.possible_agents[0]
    return env.observation_space(agent), env.action_space(agent)


def collect(args: argparse.Namespace) -> None:
    overrides = _overrides(args)
    expert = PolicySource.parse(args.expert).factory(args.seed)
    streams, metrics = rollouts(
        _env_factory(args.scenario, overrides), expert, args.episodes, args.seed
    )
    root, name = dataset.split_path(args.out)
    obs_space, act_space = _spaces(args.scenario, overrides)
    dataset_id = dataset.write_dataset(streams, root, name, obs_space, act_space)
    wins = sum(bool(m.get("success")) for m in metrics)
    print(
        f"wrote Minari dataset {dataset_id} under {root}: {len(streams)} robot streams, "
        f"{sum(len(s.actions) for s in streams)} steps, expert success {wins}/{len(metrics)}"
    )


def train_bc(args: argparse.Namespace) -> None:
    root, name = dataset.split_path(args.data)
    obs, act, _ = dataset.read_dataset(root, name)
    net, losses = bc.fit(
        obs, act, epochs=args.epochs, seed=args.seed, log_path=args.out / "bc_loss.csv"
    )
    net.save(args.out / "policy.pt", {"method": "bc", "data": str(args.data), "steps": len(obs)})
    print(f"bc: {len(obs)} samples, final loss {losses[-1]:.4g}; saved {args.out / 'policy.pt'}")


def train_dagger(args: argparse.Namespace) -> None:
    overrides = _overrides(args)
    root, name = dataset.split_path(args.data)
    obs, act, _ = dataset.read_dataset(root, name)
    net, _ = bc.fit(
        obs, act, epochs=args.epochs, seed=args.seed, log_path=args.out / "dagger_loss.csv"
    )
    expert = PolicySource.parse(args.expert).factory(args.seed)
    log = []
    for k in range(1, args.iterations + 1):
        path = args.out / f"iter_{k - 1}" / "policy.pt"
        net.save(path, {"method": "dagger", "iteration": k - 1})
        beta = 0.5**k
        streams, metrics = rollouts(
            _env_factory(args.scenario, overrides),
            expert,
            args.episodes_per_iteration,
            args.seed + 1000 * k,
            learner=lambda spec, p=path: ClonedPolicy(spec, p),
            beta=beta,
        )
        new_obs = np.concatenate([np.stack(s.observations[:-1]) for s in streams])
        new_act = np.concatenate([np.stack(s.actions) for s in streams])
        obs, act = np.concatenate([obs, new_obs]), np.concatenate([act, new_act])
        net, losses = bc.fit(
            obs,
            act,
            epochs=args.epochs,
            seed=args.seed + k,
            net=net,
            log_path=args.out / "dagger_loss.csv",
        )
        wins = sum(bool(m.get("success")) for m in metrics)
        log.append(
            {
                "iteration": k,
                "beta": beta,
                "samples": len(obs),
                "loss": losses[-1],
                "rollout_success": wins / max(1, len(metrics)),
            }
        )
        print(json.dumps(log[-1]))
    net.save(args.out / "policy.pt", {"method": "dagger", "iterations": args.iterations})
    (args.out / "dagger_log.json").write_text(json.dumps(log, indent=2))
    print(f"saved {args.out / 'policy.pt'}")


def _overrides(args: argparse.Namespace) -> dict:
    return {"n_agents": args.n_agents} if getattr(args, "n_agents", None) else {}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        prog="python -m baselines.imitate",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = ap.add_subparsers(dest="command", required=True)
    c = sub.add_parser("collect", help="expert demonstrations to a Minari dataset")
    c.add_argument("--scenario", default="paper")
    c.add_argument("--episodes", type=int, default=4)
    c.add_argument("--n-agents", type=int, default=None)
    c.add_argument("--expert", default="nmpc")
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--out", type=Path, required=True, help="data/NAME")
    b = sub.add_parser("bc", help="behaviour cloning")
    b.add_argument("--data", type=Path, required=True)
    b.add_argument("--epochs", type=int, default=50)
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--out", type=Path, default=Path("runs/bc"))
    d = sub.add_parser("dagger", help="DAgger with the expert relabelling")
    d.add_argument("--data", type=Path, required=True, help="initial demonstrations")
    d.add_argument("--scenario", default="paper")
    d.add_argument("--n-agents", type=int, default=None)
    d.add_argument("--iterations", type=int, default=4)
    d.add_argument("--episodes-per-iteration", type=int, default=2)
    d.add_argument("--epochs", type=int, default=30)
    d.add_argument("--expert", default="nmpc")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--out", type=Path, default=Path("runs/dagger"))
    args = ap.parse_args(argv)
    {"collect": collect, "bc": train_bc, "dagger": train_dagger}[args.command](args)


if __name__ == "__main__":
    main()
