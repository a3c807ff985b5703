"""Ray, on request: the install check every Ray path makes first (``require_ray``) and
joining or starting the Ray its tasks run on (``init_ray``).

Its users sit in three folders: the evaluator's Ray backend
(``baselines.evaluation.ray_backend``), the RLlib trainer (``baselines.rl.rllib_trainer``)
and the RLlib loader (``baselines.loaders.rllib_policy``, which checks the install before
it imports RLlib). A root module below them all, so that none of those folders imports
another for it.

May import: the standard library and ray (inside functions); nothing of ``baselines``.
"""

from __future__ import annotations


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
