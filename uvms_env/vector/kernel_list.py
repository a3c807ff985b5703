"""The CasADi functions the batched engine compiles: one list for ``BatchedEngine`` and for
the CUDA compile check (``kernels_check``), so that the check compiles exactly what a GPU
would run.

May import: casadi, ``uvms_env`` below ``vector`` (the ``env`` kernels, the period
routine's error-control constants) and ``uvms_env.vector.kernels``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from uvms_env.robot.observation import FAR_OBSTACLE, OBSERVATION_LAYOUT
from uvms_env.robot.priors import prior_functions
from uvms_env.sim import period
from uvms_env.task.team_kernel import (
    CYLINDER_SLOTS,
    SPHERE_SLOTS,
    WAYPOINT_SLOTS,
    team_function,
)
from uvms_env.vector.kernels import Refinement


def kernel_functions(
    n: int,
    n_seg: int,
    noisy: bool,
    chain: Any,
    wrench: bool,
    prior_object_key: float | None,
    waypoints: int = WAYPOINT_SLOTS,
) -> dict[str, Any]:
    """The CasADi functions ``BatchedEngine`` batches besides the period step, by role:
    the kinematics of ``n`` robots around an object of ``n_seg`` segments (with or without
    sensor noise; ``waypoints`` slots for the robots' sequencing and navigation; with
    ``wrench`` the ``chain``'s internal wrench inside, in the same call) and with
    ``prior_object_key`` (the object's ``object_key``) the priors' a_ss and features. One
    list for the engine and for ``kernels_check``, which compiles them for a GPU."""
    layout = (OBSERVATION_LAYOUT, tuple(FAR_OBSTACLE), noisy)
    sampled = chain.internal_wrench if wrench else None
    fns = {
        "kinematics": team_function(
            n, n_seg, CYLINDER_SLOTS, SPHERE_SLOTS, *layout, waypoints, sampled
        )
    }
    if prior_object_key is not None:
        fns["prior_steady"], fns["prior_features"] = prior_functions(prior_object_key)
    return fns


def period_refinement(n: int, dtype: str = "float64") -> Refinement:
    """The period routine's error control (``uvms_env.sim.period``) for the CUDA kernel of
    the period step of ``n`` robots in ``dtype``: its constants, from there (the
    tolerances in that precision)."""
    pose, twist, grasp = period.tolerances(np.dtype(dtype))
    return Refinement(n, pose, twist, grasp, period.MAX_REFINEMENTS)
