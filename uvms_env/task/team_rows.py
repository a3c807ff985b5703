"""The rows of the team kernel's team output, (T,) + B, as the task's parts read them.

One place for the layout ``uvms_env.task.team_kernel`` writes (``TeamKinematics.team_rows``)
and ``rules``, ``sequencing`` and ``tally`` read, and for the kernel's ``team`` input.
May import: ``uvms_env.task.constraints``.
"""

from __future__ import annotations

from uvms_env.task.constraints import CONSTRAINTS

NK = len(CONSTRAINTS)
CLEARANCE, MANIPULABILITY, GRASP_ERROR, VIOLATED, ACTION_SQ = range(5)
KINDS = slice(5, 5 + NK)  # per constraint kind: is it violated by any robot
# then the object's clearance and workspace excess (rows 5 + NK, 6 + NK)
# The team's sequencer on the true object (``team_kernel.team_sequenced``): its new index
# and done flag, the reward's potential towards its waypoint before and after it moved,
# whether it passed an intermediate waypoint, whether the object is at the goal.
TEAM_SEQUENCER = slice(7 + NK, 9 + NK)
POTENTIAL, POTENTIAL_AFTER, PASSED, AT_GOAL = range(9 + NK, 13 + NK)
TEAM_ROWS = 13 + NK
#: The kernel's ``team`` input: the team sequencer's [index, done], then the task's
#: constants of its tests: [attitude weight, position tolerance, attitude tolerance].
TEAM_INPUT = 5
ALL = ...  # every environment, as an index (also of a single environment's 0-d arrays)
