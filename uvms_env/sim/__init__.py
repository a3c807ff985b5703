"""The truth simulator: N UVMSs rigidly grasping one object, as a closed kinematic chain.

May import: numpy, casadi, ``uvms_env.models``, ``uvms_env.dynamics`` and
``uvms_env.scenarios`` (for the scenario description it simulates).
"""

from uvms_env.sim.simulator import SimState, Simulator, StepInfo

__all__ = ["SimState", "Simulator", "StepInfo"]
