"""Imitation learning from the NMPC expert: demonstrations (Minari), behaviour cloning,
DAgger. Written on torch because the ``imitation`` package pins gymnasium 0.29 and SB3
2.2, incompatible with ours. The cloned network and its features are
``baselines.networks``'; a saved clone as a per-agent policy is
``baselines.loaders.clone_policy``.
May import: uvms_env, nmpc_expert, torch, minari, ``baselines.networks``,
``baselines.loaders``, ``baselines.evaluation`` (the periodic evaluations and the
preflight), ``baselines.runs`` and ``baselines.command_line``."""
