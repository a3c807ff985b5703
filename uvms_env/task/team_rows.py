"""The rows of the team kernel's team output, (T,) + B, as the task's parts read them.

One place for the layout ``uvms_env.task.team_kernel`` writes (``TeamKinematics.team_rows``)
and ``rules``, ``sequencing`` and ``tally`` read, and for the kernel's ``team`` input.
May import: ``uvms_env.task.constraints``.
"""

from __future__ import annotations

from uvms_env.task.constraints import CONSTRAINTS

NK = len(CONSTRAINTS)
# VIOLATED: the safety kinds violated, summed over robots (``SAFETY_CONSTRAINTS``)
CLEARANCE, MANIPULABILITY, GRASP_ERROR, VIOLATED, ACTION_SQ = range(5)
KINDS = slice(5, 5 + NK)  # per constraint kind: is it violated by any robot
# then the object's clearance and workspace excess (rows 5 + NK, 6 + NK)
# The team's sequencer on the true object (``team_kernel.team_sequenced``): its new index
# and done flag, the reward's potential towards its waypoint before and after it moved,
# whether it passed an intermediate waypoint, whether the object is at the goal.
TEAM_SEQUENCER = slice(7 + NK, 9 + NK)
POTENTIAL, POTENTIAL_AFTER, PASSED, AT_GOAL = range(9 + NK, 13 + NK)
# The graded safety of the period, per kind (``constraint_scales``): the robots' excess
# max(0, g) / scale summed and its largest, and how many robots violate it; then how many
# robots violate any safety kind.
EXCESS = slice(13 + NK, 13 + 2 * NK)
MAX_EXCESS = slice(13 + 2 * NK, 13 + 3 * NK)
VIOLATED_ROBOTS = slice(13 + 3 * NK, 13 + 4 * NK)
ANY_VIOLATED = 13 + 4 * NK
TEAM_ROWS = 14 + 4 * NK
#: The kernel's ``team`` input: the team sequencer's [index, done], then the task's
#: constants of its tests: [attitude weight, position tolerance, attitude tolerance].
TEAM_INPUT = 5
ALL = ...  # every environment, as an index (also of a single environment's 0-d arrays)
