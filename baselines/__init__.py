"""Baselines: learning policies (RL, imitation) and the one evaluation tool that compares
every policy, the NMPC expert included, on the same seeded episodes.

May import: uvms_env, nmpc_expert (nothing imports baselines).
"""
