"""Batched simulation: K environments stepped together, on CPU lanes and threads or a GPU.

Built from the same CasADi graphs as the single environment (docs/batched.md: one graph
for every target): ``kernels`` compiles a generated function for K environments per call,
``batched_simulator`` steps K truth simulators of one team size and object through it,
``env`` is the whole environment batched (``VectorEnv``), ``bank`` keeps the seeded
families' geometries on disk, ``gym_vector`` and ``sb3`` adapt ``VectorEnv`` to Gymnasium's
and stable-baselines3's vector APIs.

May import: numpy, casadi, gymnasium, and ``uvms_env`` below ``vector`` (dynamics, sim,
navigation, scenarios, env); stable-baselines3 only in ``sb3``; CuPy only inside the
CUDA backend, when asked for.
"""

from uvms_env.vector.batched_simulator import BatchedSimulator
from uvms_env.vector.env import VectorEnv

__all__ = ["BatchedSimulator", "VectorEnv"]
