"""Dynamics of the UVMSs and of the grasped object, as CasADi functions.

One source of truth for the physics: the truth simulator (``uvms_env.sim``) and the
controllers' prediction models build on the same symbolic functions defined here.
May import: numpy, casadi, adam-robotics and ``uvms_env.models``.
"""

from uvms_env.dynamics.payload import ObjectModel
from uvms_env.dynamics.uvms import ACTUATED_DOFS, NP, NQ, NU, PARAMETER_LAYOUT, UVMSModel

__all__ = ["ACTUATED_DOFS", "NP", "NQ", "NU", "PARAMETER_LAYOUT", "ObjectModel", "UVMSModel"]
