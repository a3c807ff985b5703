"""nmpc_expert: the distributed NMPC of Heshmati-alamdari, Karras and Kyriakopoulos, one
controller per robot, behind the shared policy interface (``uvms_env.policy``).

    from nmpc_expert import NMPCPolicy, make_policy
    policy = NMPCPolicy(AgentSpec.from_scenario(scenario, i), solver="rti")   # or "ipopt"

Modules (one job each): ``local_model`` (MODEL section 5 prediction model), ``ocp`` (the
OCP's compiled pieces and the RTI's QP), ``rti`` (fast default solver), ``ipopt_solver``
(reference solver), ``reference`` (navigation-function reference over the horizon),
``observation`` (reading the own observation), ``settings``, ``policy``, ``rollout``
(closed loop + metrics), ``figures``, ``__main__`` (the main job).

May import: numpy, scipy, casadi, matplotlib, tqdm and ``uvms_env``. Never ``baselines``.
"""

from nmpc_expert.policy import NMPCPolicy, make_policy
from nmpc_expert.settings import MANIPULABILITY_EPS, NMPCSettings

__all__ = ["MANIPULABILITY_EPS", "NMPCPolicy", "NMPCSettings", "make_policy"]
