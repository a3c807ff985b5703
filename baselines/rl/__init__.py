"""RL on one machine: the SB3 trainer (``sb3_trainer``) and the BenchMARL trainer
(``benchmarl_trainer``: MAPPO, IPPO, MASAC on the TorchRL view) of ``baselines.train``, the
parameter-sharing VecEnv adapter, the SB3 side of the constraint cost (``cost``), learning
curves (``plot``), and trained models as per-agent policies (``policy``; PPO's decision
compiled whole, ``actor``). May import: uvms_env, stable-baselines3, torch, torchrl,
benchmarl, ``baselines.runs``, ``baselines.lagrangian``, ``baselines.loaders``,
``baselines.registry``, ``baselines.command_line``, ``baselines.benchmarl_tasks``,
``baselines.evaluation.report`` (the figures) and ``baselines.imitation``'s compiled-network
code."""
