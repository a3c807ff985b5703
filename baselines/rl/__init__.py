"""RL on one machine: the SB3 trainer (``sb3_trainer``) and the TorchRL trainer
(``torchrl_ppo``) of ``baselines.train``, the parameter-sharing VecEnv adapter, the SB3 side
of the constraint cost (``cost``), learning curves (``plot``), and trained models as
per-agent policies (``policy``, ``torchrl_policy``; PPO's decision compiled whole,
``actor``). May import: uvms_env, stable-baselines3, torch, torchrl, ``baselines.runs``,
``baselines.lagrangian``, ``baselines.loaders.saved``, ``baselines.registry``,
``baselines.command_line``, ``baselines.evaluation.report`` (the figures) and
``baselines.imitation``'s compiled-network code."""
