"""Hydra plugin package of uvms-coop (the plugin: ``searchpath.py``): BenchMARL's Hydra
commands find the tasks of ``baselines.benchmarl_tasks``."""
