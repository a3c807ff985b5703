"""The task's rules: what the team must do and how an episode is scored.

``rules`` (``Task``: the episode bookkeeping of K environments, waypoint sequencing,
success and ends), ``reward`` (the shared team reward), ``constraints`` (one value per
robot and kind, g <= 0 holds), ``metrics`` (the episode metrics by name), ``conditions``
(per-episode draws of current and model mismatch) and ``team_kernel`` (every per-step
quantity the rules read after a period, in one compiled call: the observations'
measured parts, the constraints, each robot's and the team's waypoint sequencing, the
reward's potential, the goal test and the navigation twist).

May import ``uvms_env.models``, ``dynamics``, ``sim``, ``navigation`` and ``scenarios``;
never ``uvms_env.robot``, ``uvms_env.env`` or ``uvms_env.vector``.
"""
