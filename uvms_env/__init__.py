"""uvms_env: cooperative transport by several underwater vehicle-manipulator systems.

Layers, lowest first (a layer imports only those below it):
``models`` (parameters, URDF) -> ``dynamics`` (CasADi functions of one UVMS and of the
object) -> ``sim`` (closed-chain truth simulator) ; ``navigation`` (navigation function)
-> ``scenarios`` (validated task configs; used by ``sim``) -> ``env`` (the PettingZoo
environment, its Gymnasium view, rendering; imports all of the above). Beside them:
``policy`` (the per-robot policy interface) and ``episode`` (the one closed-loop episode
driver every evaluation and rollout plays through).

    import uvms_env
    env = uvms_env.parallel_env(scenario="paper")  # PettingZoo ParallelEnv

    from uvms_env.scenarios import make
    from uvms_env.sim import Simulator
    sim = Simulator(make("paper"))

Importing the package registers ``uvms_env/CoopTransport-v1`` with PettingZoo
(``pettingzoo.make("parallel", ...)``) and Gymnasium (``gymnasium.make(...)``).
"""

__version__ = "0.1.0"

from uvms_env.env import parallel_env
from uvms_env.env.registration import register_all

register_all()

__all__ = ["__version__", "parallel_env"]
