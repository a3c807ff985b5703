"""Reading one robot's own observation: the layout, validation and the parts the NMPC uses.

The layout is the environment's (``uvms_env.robot.observation.OBSERVATION_STRUCTURE``,
names -> slices); it is re-exported here so the expert and its tests use names, never
magic indices. The controller uses ``q``, ``zeta`` and ``waypoint``; it computes its own
object estimate from its model (the same formula as the environment's ``object_pose``).

May import: math, numpy and ``uvms_env.robot.observation`` (layout constants only).
"""

from __future__ import annotations

import math

import numpy as np

from uvms_env.robot.observation import OBSERVATION_SIZE, OBSERVATION_STRUCTURE

__all__ = ["OBSERVATION_SIZE", "OBSERVATION_STRUCTURE", "check_observation"]


def check_observation(obs: np.ndarray) -> np.ndarray:
    """The observation as float64 (79,), or ValueError naming what is wrong with it."""
    arr = np.asarray(obs)
    if arr.shape != (OBSERVATION_SIZE,):
        raise ValueError(f"observation must have shape ({OBSERVATION_SIZE},), got {arr.shape}")
    if arr.dtype.kind not in "iufc":  # numbers (np.issubdtype(dtype, np.number))
        raise ValueError(f"observation must be numeric, got dtype {arr.dtype}")
    arr = arr.astype(np.float64)
    if math.isfinite(arr.sum()):  # NaN and inf survive a sum: one reduction, the hot path
        return arr
    bad = ~np.isfinite(arr)
    if bad.any():
        index = int(np.flatnonzero(bad)[0])
        field = next(
            name for name, sl in OBSERVATION_STRUCTURE.items() if sl.start <= index < sl.stop
        )
        raise ValueError(
            f"observation contains NaN or inf at index {index} (field {field!r}, "
            f"{int(bad.sum())} bad entries)"
        )
    return arr
