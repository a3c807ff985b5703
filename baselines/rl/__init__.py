"""RL on one machine: the SB3 engine (``train``) and the TorchRL engine (``torchrl_ppo``) of
``baselines.train``, the parameter-sharing VecEnv adapter, the SB3 side of the constraint
cost (``cost``), learning curves (``plot``), and trained models as per-agent policies
(PPO's decision compiled whole, ``actor``). May import: uvms_env, stable-baselines3, torch,
torchrl, ``baselines.runs``, ``baselines.lagrangian`` and ``baselines.imitation``'s
compiled-network code."""
