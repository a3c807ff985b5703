"""RL baselines on stable-baselines3: the parameter-sharing VecEnv adapter, training, and
trained models as per-agent policies. May import: uvms_env, stable-baselines3, torch."""
