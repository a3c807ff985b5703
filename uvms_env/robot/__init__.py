"""The robot's own side: what one robot measures, remembers, computes and says.

``observation`` (its local observation: layout, sensor noise, navigator), ``priors``
(the features and the steady input a_ss it computes from its observation and what it
knows before the task), ``memory`` (its last command and disturbance estimate, for
``observation_mode="memory"``) and ``channel`` (the acoustic messages between robots).

May import ``uvms_env.models``, ``dynamics``, ``navigation`` and ``scenarios``; never
``uvms_env.task``, ``uvms_env.env`` or ``uvms_env.vector``.
"""
