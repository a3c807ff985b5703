"""The rows of the team kernel's team output, (T,) + B, as the task's parts read them.

One place for the layout ``uvms_env.task.team_kernel`` writes (``TeamKinematics.team_rows``)
and ``rules``, ``sequencing`` and ``tally`` read. May import: ``uvms_env.task.constraints``.
"""

from __future__ import annotations

from uvms_env.task.constraints import CONSTRAINTS

NK = len(CONSTRAINTS)
CLEARANCE, MANIPULABILITY, GRASP_ERROR, VIOLATED, ACTION_SQ = range(5)
KINDS = slice(5, 5 + NK)  # per constraint kind: is it violated by any robot
ALL = ...  # every environment, as an index (also of a single environment's 0-d arrays)
