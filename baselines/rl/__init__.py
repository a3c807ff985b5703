"""RL on one machine: the SB3 trainer (``sb3_trainer``) and the BenchMARL trainer
(``benchmarl_trainer``: MAPPO, IPPO, MASAC on the TorchRL view) of ``baselines.train``, the
parameter-sharing VecEnv adapter, the SB3 side of the constraint cost (``cost``), learning
curves (``plot``), PPO started from a clone and anchored to it (``init_actor``, ``anchor``).
Trained models as per-agent policies are ``baselines.loaders``' (PPO's decision compiled
whole: ``baselines.networks.ppo_decision``). May import: uvms_env, stable-baselines3,
torch, torchrl, benchmarl, ray, ``baselines.runs``, ``baselines.lagrangian``,
``baselines.loaders``, ``baselines.registry``, ``baselines.command_line``,
``baselines.benchmarl_tasks``, ``baselines.evaluation`` (the figures, the shield's
records), ``baselines.ray_runtime`` and ``baselines.networks`` (the clones' network)."""
