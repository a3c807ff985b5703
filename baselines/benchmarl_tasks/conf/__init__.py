"""The uvms tasks' Hydra configs (``task/uvms/*.yaml``): a package so that Hydra can read
them as ``pkg://baselines.benchmarl_tasks.conf``."""
