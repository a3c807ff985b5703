"""Decision time of a cloned policy against the NMPC expert's (one core, one process).

    python benchmarks/cloned_decision.py [--policy dagger:pretrained] [--scenario paper]
                                         [--steps 400] [--seed 0] [--numpy] [--rounds 1]

Each policy drives its own episode of the scenario (same seed) for ``--steps`` periods
or until the episode ends, and every ``act`` call is timed with the environment stepping
in between, as in ``baselines.evaluate`` (so the caches are as warm or cold as in a
real loop; timing the clone between two expert solves instead measured it 3x slower,
the expert's working set evicting the clone's). ``--numpy``: also the same clone with
its layers in numpy after the compiled inputs (``ClonedPolicy(compiled=False)``, the
decision before it was compiled whole). ``--rounds``: the policies take turns that many
times, each time on a new episode, so that a change in machine load spreads over all of
them. Prints median and p95 per policy and the ratios of the medians.
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

import uvms_env
from baselines.command_line import non_negative_int, positive_int, script_parser
from baselines.loaders.sources import PolicySource
from uvms_env.policy import AgentSpec, PolicyFactory

NUMPY = "{} (numpy layers)"


def measure(factory: PolicyFactory, scenario: str, steps: int, seed: int) -> np.ndarray:
    """Decision times (ms) of the policies from ``factory`` driving every robot."""
    kwargs = {"n_agents": 2} if scenario == "random" else {}
    env = uvms_env.parallel_env(scenario=scenario, seed=seed, **kwargs)
    obs, _ = env.reset(seed=seed)
    policies = [factory(AgentSpec.from_scenario(env.scenario, i)) for i in range(len(env.agents))]
    for p in policies:
        p.reset()
    times: list[float] = []
    for _ in range(steps):
        if not env.agents:
            break
        actions = {}
        for i, agent in enumerate(env.agents):
            start = time.perf_counter()
            actions[agent] = policies[i].act(obs[agent])
            times.append(time.perf_counter() - start)
        obs, *_ = env.step(actions)
    return np.asarray(times) * 1e3


def factories(policy: str, numpy_layers: bool, seed: int) -> dict[str, PolicyFactory]:
    out = {p: PolicySource.parse(p).factory(seed) for p in ("nmpc", policy)}
    if numpy_layers:
        from baselines.loaders.clone_policy import ClonedPolicy

        source = PolicySource.parse(policy)
        if source.name not in ("bc", "dagger") or source.filtered:
            raise SystemExit("--numpy needs a bc:... or dagger:... policy")
        path = ClonedPolicy.locate(source.name, source.arg)
        out[NUMPY.format(policy)] = lambda spec: ClonedPolicy(spec, path, compiled=False)
    return out


def main() -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("--policy", default="dagger:pretrained")
    ap.add_argument("--scenario", default="paper", choices=["paper", "random"])
    ap.add_argument("--steps", type=positive_int, default=400)
    ap.add_argument("--seed", type=non_negative_int, default=0)
    ap.add_argument("--numpy", action="store_true")
    ap.add_argument("--rounds", type=positive_int, default=1)
    args = ap.parse_args()
    built = factories(args.policy, args.numpy, args.seed)
    times: dict[str, list[np.ndarray]] = {name: [] for name in built}
    for r in range(args.rounds):
        for name, factory in built.items():
            times[name].append(measure(factory, args.scenario, args.steps, args.seed + r))
    medians = {}
    for name, chunks in times.items():
        t = np.concatenate(chunks)
        medians[name] = np.median(t)
        print(f"{name:>40}: median {medians[name]:.4f} ms, p95 {np.percentile(t, 95):.4f} ms "
              f"({t.size} decisions)")  # fmt: skip
    for name in list(built)[1:]:
        print(f"expert / {name} median: {medians['nmpc'] / medians[name]:.0f}x")


if __name__ == "__main__":
    main()
