"""End-to-end PPO training speed per RL library, robot-steps per second, with its shares.

    python benchmarks/train_throughput.py [--libraries sb3 benchmarl] [--n-agents 4]
                                          [--robot-steps 200000] [--repeats 2]

Each library trains PPO (BenchMARL: MAPPO) for ``--robot-steps`` on ``random`` with the team
size(s) of ``--n-agents`` (BenchMARL: one), a mild current and mismatch 0.1, through
``baselines.train.train`` (the command line's code path: the run folder, records and all),
three times per repeat, alternating (the load of a shared machine drifts): with the
settings before this benchmark existed (``before``: the libraries' old defaults), with the
throughput settings (``throughput``: the fastest, the sb3 defaults until 2026-12-02) and
with today's defaults (``after``: chosen for learning). Reported per run: robot-steps/s
over the whole learning loop (setup excluded: compiling and building geometries happen
once per machine and run), and the shares of the learning time spent in the
environment's step (``VectorEnv.step``), in the policy's forward passes while collecting
(SB3 only), in the rest of collecting (the library's buffers, normalization and
bookkeeping) and in the update. The table holds the medians over repeats. Run it on a
quiet machine (it prints the load before and after), with the pool's geometries built
beforehand (``--geometry-pool``: building one in the loop would count as training time).

May import: the standard library, numpy, ``baselines`` and ``uvms_env``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from baselines import train as trainer
from baselines.command_line import positive_int, script_parser, team_size
from baselines.registry import LIBRARIES, trainer_module
from baselines.runs import RunSettings
from uvms_env.vector import VectorEnv

# The libraries' defaults before the distribution-training work (2026-11-26): copies per
# run and the update's settings; for BenchMARL, its own yaml defaults (10 copies, 45
# passes of minibatches of 400). Today's defaults are the trainers' own.
BEFORE: dict[str, dict[str, Any]] = {
    "sb3": {"num_envs": 4, "hp": {"n_steps": 256, "n_epochs": 10}},
    "benchmarl": {
        "num_envs": 10,
        "hp": {
            "experiment.on_policy_n_minibatch_iters": 45,
            "experiment.on_policy_minibatch_size": 400,
        },
    },
}
# The throughput settings: the sb3 trainer's PPO defaults until 2026-12-02 (32 steps per
# sub-env, 4 epochs), chosen for robot-steps per second; the trainer's defaults are now
# chosen for learning (``baselines.rl.sb3_trainer.ALGO_DEFAULTS``), and the benchmark
# measures both.
THROUGHPUT: dict[str, dict[str, Any]] = {
    "sb3": {"hp": {"n_steps": 32, "n_epochs": 4}},
    "benchmarl": {"hp": {}},
}
CONDITIONS = {"current": "mild", "mismatch": 0.1}


class StepTimer:
    """Seconds spent in ``VectorEnv.step`` (every instance), while installed."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self._original = VectorEnv.step

    def __enter__(self) -> StepTimer:
        original, timer = self._original, self

        def timed(env: VectorEnv, actions: Any) -> Any:
            start = time.perf_counter()
            try:
                return original(env, actions)
            finally:
                timer.seconds += time.perf_counter() - start

        VectorEnv.step = timed  # type: ignore[method-assign]
        return self

    def __exit__(self, *exc: object) -> None:
        VectorEnv.step = self._original  # type: ignore[method-assign]


def one_run(
    library: str, settings: str, sizes: tuple[int, ...], robot_steps: int, pool: int
) -> dict:
    """Train once; returns robot-steps/s and the time shares of the learning loop."""
    module = trainer_module(library)
    chosen = {"before": BEFORE, "throughput": THROUGHPUT}.get(settings, {}).get(library, {"hp": {}})
    folder = Path(tempfile.mkdtemp(prefix=f"throughput_{library}_"))
    run_settings = RunSettings(
        scenario="random",
        overrides=dict(CONDITIONS) | ({"n_agents": sizes[0]} if len(sizes) == 1 else {}),
        robot_steps=robot_steps,
        num_envs=chosen.get("num_envs", module.DEFAULTS["num_envs"]),
        seed=0,
        out=folder,
        checkpoint_every=0,
        geometry_pool=pool,
        hyperparameters=dict(chosen["hp"]),
        progress=False,
        record_eval=False,
        team_sizes=sizes if len(sizes) > 1 else (),
    )
    from baselines.runs import Run

    algo = LIBRARIES[library].algos[0]
    run = Run.start(run_settings, library, algo)
    args = trainer.build_parser(library).parse_args(["--library", library])
    trainer_obj = module.Trainer(run, algo, args)
    try:
        run.write_config(**trainer_obj.build())
        update = _time_updates(library, trainer_obj)
        forward = _time_forward(library, trainer_obj)
        with StepTimer() as env_timer:
            start = time.perf_counter()
            steps = trainer_obj.learn()
            wall = time.perf_counter() - start
    finally:
        trainer_obj.close()
        shutil.rmtree(folder, ignore_errors=True)
    updating, acting = update(), forward()
    return {
        "robot_steps_per_s": steps / wall,
        "env": env_timer.seconds / wall,
        "forward": acting / wall,
        "update": updating / wall,
        "collect_other": max(0.0, 1.0 - (env_timer.seconds + acting + updating) / wall),
        "wall_s": wall,
        "robot_steps": steps,
    }


def _time_forward(library: str, trainer_obj: Any):
    """A function that returns the seconds the policy's forward passes have taken while
    collecting (SB3: the policy's ``forward``; BenchMARL: not measured, 0)."""
    spent = [0.0]
    if library == "benchmarl":
        return lambda: spent[0]
    net = trainer_obj.model.policy
    original = net.forward

    def timed(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            spent[0] += time.perf_counter() - start

    net.forward = timed
    return lambda: spent[0]


def _time_updates(library: str, trainer_obj: Any):
    """A function that returns the seconds the trainer has spent updating so far (BenchMARL:
    from each batch's arrival to its training's end, advantages included)."""
    spent = [0.0]
    if library == "benchmarl":
        collected, done = trainer_obj.collected, trainer_obj.iteration_done
        started = [0.0]

        def arrived(batch: Any) -> None:
            collected(batch)
            started[0] = time.perf_counter()

        def trained() -> None:
            spent[0] += time.perf_counter() - started[0]
            done()

        trainer_obj.collected, trainer_obj.iteration_done = arrived, trained
        return lambda: spent[0]
    model = trainer_obj.model
    original = model.train

    def timed() -> None:
        start = time.perf_counter()
        original()
        spent[0] += time.perf_counter() - start

    model.train = timed
    return lambda: spent[0]


def main(argv: list[str] | None = None) -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument(
        "--libraries", nargs="+", default=["sb3", "benchmarl"], choices=["sb3", "benchmarl"]
    )
    ap.add_argument("--n-agents", type=team_size, nargs="+", default=[4])
    ap.add_argument("--robot-steps", type=positive_int, default=200_000)
    ap.add_argument("--repeats", type=positive_int, default=2)
    ap.add_argument(
        "--settings",
        nargs="+",
        default=["before", "throughput", "after"],
        choices=("before", "throughput", "after"),
    )
    ap.add_argument(
        "--geometry-pool",
        type=int,
        default=256,
        help="bank geometries per team size (build them first: python -m "
        "uvms_env.vector.build_bank random --n-agents N --seeds 0:256)",
    )
    args = ap.parse_args(argv)
    sizes = tuple(args.n_agents)
    print(f"load before: {os.getloadavg()}")
    results: dict[tuple[str, str], list[dict]] = {}
    for _ in range(args.repeats):
        for library in args.libraries:
            for settings in args.settings:
                row = one_run(library, settings, sizes, args.robot_steps, args.geometry_pool)
                results.setdefault((library, settings), []).append(row)
                rate = row["robot_steps_per_s"]
                print(f"{library} {settings}: {rate:,.0f} robot-steps/s", flush=True)
    print(f"load after: {os.getloadavg()}")
    print(
        "\n| library | settings | robot-steps/s | env step | policy forward | rest of "
        "collecting | update |\n|---|---|---|---|---|---|---|"
    )
    for (library, settings), rows in results.items():
        med = {k: float(np.median([r[k] for r in rows])) for k in rows[0]}
        print(
            f"| {library} | {settings} | {med['robot_steps_per_s']:,.0f} | {med['env']:.0%} | "
            f"{med['forward']:.0%} | {med['collect_other']:.0%} | {med['update']:.0%} |"
        )


if __name__ == "__main__":
    main()
