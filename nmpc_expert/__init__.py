"""nmpc_expert: a reproduction of the distributed NMPC of Heshmati-alamdari, Karras and
Kyriakopoulos (with the repairs docs/expert.md lists), one controller per robot, behind the
shared policy interface (``uvms_env.policy``).

    from nmpc_expert import NMPCPolicy, SafetyFilter, make_policy
    policy = NMPCPolicy(AgentSpec.from_scenario(scenario, i), solver="rti")   # or "ipopt"
    paper = NMPCPolicy(spec, settings=NMPCSettings.paper())  # the paper's controller
    safe = SafetyFilter(spec, other_policy)   # the expert's constraints around any policy

One job per module, each said in its docstring: the OCP and its solvers (``ocp``, ``rti``,
``ipopt_solver``), the safety filter (``safety_filter``, ``filter_batch``,
``filter_workspace_rows``), the full-information reference (``central``, ``central_rti``,
``team_model``, ``central_model``), the talking expert (``comm``). The prediction model
(docs/model.md) and the steady input are ``uvms_env.dynamics.local_model``.
Reference: docs/expert.md.

May import: numpy, scipy, casadi, matplotlib, tqdm and ``uvms_env``. Never ``baselines``.
"""

from nmpc_expert.central import CentralNMPC, make_central_policy
from nmpc_expert.comm import TalkingNMPCPolicy, make_talking_policy
from nmpc_expert.local_controller import NMPCPolicy, make_policy
from nmpc_expert.safety_filter import SafetyFilter, make_filter
from nmpc_expert.settings import CONTROLLERS, NMPCSettings, controller_settings

# Re-exported for compatibility: the environment's definition (the expert's bound is
# ``NMPCSettings.manipulability_eps``, derived from it).
from uvms_env.task.constraints import MANIPULABILITY_EPS

__all__ = [
    "CONTROLLERS",
    "MANIPULABILITY_EPS",
    "CentralNMPC",
    "NMPCPolicy",
    "NMPCSettings",
    "SafetyFilter",
    "TalkingNMPCPolicy",
    "controller_settings",
    "make_central_policy",
    "make_filter",
    "make_policy",
    "make_talking_policy",
]
