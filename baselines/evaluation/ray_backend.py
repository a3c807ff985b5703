"""Episodes of ``baselines.evaluate`` as Ray tasks: ``--backend ray [--address ADDR]``.

Each episode job runs ``baselines.evaluation.episode_row.run_episode`` in a Ray worker, one
CPU each, on a local Ray (``num_cpus`` = the evaluator's ``--workers``) or on the cluster at
``address``. A row depends only on its job, so the rows equal the process pool's; the
caller sorts them. Every node needs the project installed (same Python, same checkout):
the tasks import it by name.

May import: ray (inside functions), and ``baselines.evaluation``'s job and episode function
(passed in, so this module does not import the evaluator).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any


def require_ray() -> None:
    """Fail with the install command when Ray is missing."""
    try:
        import ray  # noqa: F401
    except ImportError as exc:
        raise ImportError(
            f'{exc}: the Ray backends need pip install -e ".[distributed]" '
            "-c constraints.txt (best in its own venv: it pins gymnasium 1.2.2)"
        ) from exc


def init_ray(address: str | None, num_cpus: int | None = None) -> None:
    """Join the cluster at ``address``, or start a local Ray with ``num_cpus`` (None:
    every core). ``address="local"`` rather than None: a set ``RAY_ADDRESS`` must not
    turn a local run into a cluster one."""
    require_ray()
    import ray

    if ray.is_initialized():
        return
    if address:
        ray.init(address=address, log_to_driver=False)
    else:
        ray.init(address="local", num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)


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
