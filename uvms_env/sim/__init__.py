"""The truth simulator: N UVMSs rigidly grasping one object, as a closed kinematic chain.

May import: numpy, casadi, ``uvms_env.models`` and ``uvms_env.dynamics``. It reads the
fields of a ``uvms_env.scenarios.Scenario`` without importing that higher layer.
"""

from uvms_env.sim.simulator import SimState, Simulator, StepInfo

__all__ = ["SimState", "Simulator", "StepInfo"]
