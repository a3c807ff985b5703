"""Episodes of ``baselines.evaluate`` as Ray tasks: ``--backend ray [--address ADDR]``.

Each episode job runs ``baselines.evaluation.episode_row.run_episode`` in a Ray worker, one
CPU each, on a local Ray (``num_cpus`` = the evaluator's ``--workers``) or on the cluster at
``address``. A row depends only on its job, so the rows equal the process pool's; the
caller sorts them. Every node needs the project installed (same Python, same checkout):
the tasks import it by name.

May import: ray (inside functions), ``baselines.ray_runtime`` (the install check and the Ray
it joins or starts) and ``baselines.evaluation``'s job and episode function (passed in, so
this module does not import the evaluator).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any

from baselines.ray_runtime import init_ray


def run_jobs(
    run_episode: Callable[[Any], dict[str, Any]],
    jobs: Sequence[Any],
    address: str | None = None,
    num_cpus: int | None = None,
) -> Iterator[dict[str, Any]]:
    """Yield one row per job as the tasks finish (any order)."""
    init_ray(address, num_cpus)
    import ray

    task = ray.remote(num_cpus=1, max_retries=0)(run_episode)
    pending = [task.remote(job) for job in jobs]
    while pending:
        done, pending = ray.wait(pending, num_returns=1)
        yield from ray.get(done)
