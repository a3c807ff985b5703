"""Hydra plugin package of benchmarl-uvms (the plugin: ``benchmarl_uvms_searchpath.py``)."""
