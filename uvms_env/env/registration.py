"""Put the environment in PettingZoo's and Gymnasium's registries (on ``import uvms_env``).

* PettingZoo 1.27: ``pettingzoo.make("parallel", "uvms_env/CoopTransport-v1", **kwargs)``
  (``max_cycles`` is passed through when given).
* Gymnasium (>= 1.0): ``gymnasium.make("uvms_env/CoopTransport-v1", **kwargs)``, or
  without a prior import ``gymnasium.make("uvms_env:uvms_env/CoopTransport-v1")``.
* Gymnasium's vector API: ``gymnasium.make_vec("uvms_env/CoopTransport-v1", num_envs=K,
  **kwargs)`` builds the batched ``uvms_env.vector.gym_vector.CoopTransportVectorEnv``
  (the ``vector_entry_point``, Gymnasium's default mode when one is registered; kwargs as
  ``uvms_env.vector.VectorEnv``: ``scenario``, ``dtype``, ``threads``, overrides);
  ``vectorization_mode="sync"`` or ``"async"`` steps K single environments instead.

Entry points are strings, so registering imports nothing heavy. Registering twice is a
no-op (no "overriding" warnings). May import: gymnasium, pettingzoo.
"""

from __future__ import annotations

import gymnasium
import pettingzoo

ENV_ID = "uvms_env/CoopTransport-v1"
PARALLEL_ENTRY_POINT = "uvms_env.env.parallel:parallel_env"
GYMNASIUM_ENTRY_POINT = "uvms_env.env.gym_wrapper:CoopTransportGymEnv"
VECTOR_ENTRY_POINT = "uvms_env.vector.gym_vector:CoopTransportVectorEnv"


def register_pettingzoo() -> None:
    if ENV_ID not in pettingzoo.parallel_registry:
        pettingzoo.register("parallel", ENV_ID, entry_point=PARALLEL_ENTRY_POINT)


def register_gymnasium() -> None:
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(
            id=ENV_ID, entry_point=GYMNASIUM_ENTRY_POINT, vector_entry_point=VECTOR_ENTRY_POINT
        )


def register_all() -> None:
    register_pettingzoo()
    register_gymnasium()
