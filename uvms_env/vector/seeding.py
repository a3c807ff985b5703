"""The one seeding rule of every parameter-sharing adapter (SB3's ``VectorVecEnv``,
RLlib's ``baselines.rl.rllib_env``).

A training run of base seed ``s`` steps K env copies; episode e of copy k (e = 0 the
first) is reset with seed (``copy_reset_seed``)

    s + k + K e                 (no geometry pool)
    (s + k + K e) mod P         (a geometry pool of P seeds: a seeded family's episodes
                                 take the bank's first P geometries)

so every (copy, episode) pair has its own seed, copies never share an episode, and a
pool's geometries are dealt round-robin over the copies. ``VectorEnv`` applies it inside
its automatic reset (``geometry_pool``); without a pool, its episodes after the first
continue each copy's own generator on the same geometry (the single env's ``reset()``),
which is the one exception: a batched copy does not rebuild a geometry inside a step.

May import: nothing but the standard library.
"""

from __future__ import annotations


def copy_reset_seed(
    seed: int, copy: int, episode: int, num_envs: int, pool: int | None = None
) -> int:
    """The seed that env ``copy`` (of ``num_envs``) is reset with for its ``episode``
    (0: the first) under base ``seed`` and geometry ``pool``: a reset seed, not an
    evaluation episode's seed (``baselines``)."""
    if not 0 <= copy < num_envs:
        raise ValueError(f"copy must be in [0, {num_envs}), got {copy}")
    if episode < 0:
        raise ValueError(f"episode must be >= 0, got {episode}")
    raw = seed + copy + num_envs * episode
    return raw % pool if pool else raw
