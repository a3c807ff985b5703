"""Imitation learning from the NMPC expert: demonstrations (Minari), behaviour cloning,
DAgger, and cloned networks as per-agent policies. Written on torch because the
``imitation`` package pins gymnasium 0.29 and SB3 2.2, incompatible with ours.
May import: uvms_env, nmpc_expert, torch, minari."""
