"""RL baselines on stable-baselines3: the parameter-sharing VecEnv adapter, training, and
trained models as per-agent policies (PPO's decision compiled whole, ``actor``). May import:
uvms_env, stable-baselines3, torch, and ``baselines.imitation``'s compiled-network code."""
