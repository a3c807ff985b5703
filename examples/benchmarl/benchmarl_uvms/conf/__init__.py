"""The uvms tasks' Hydra configs (``task/uvms/*.yaml``): a package so that Hydra can read
them as ``pkg://benchmarl_uvms.conf``."""
