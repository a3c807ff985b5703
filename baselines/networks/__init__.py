"""The policies' networks and their compiled decisions: what a loader needs to rebuild and
run a trained network, and what the trainers build their networks from.

``features`` (what a cloned network sees, in numpy and CasADi), ``mlp`` (the cloned
network, ``MLPPolicyNet``, saved as ``policy.pt``), ``mlp_decision`` (its whole decision as
one compiled function, and the generated C layers) and ``ppo_decision`` (a trained SB3 PPO
actor's decision compiled the same way). Below ``baselines.loaders`` (which plays them),
``baselines.imitation`` (which trains the clones) and ``baselines.rl`` (which starts PPO from
a clone and anchors it there), so none of those folders imports another for a network.

Inside the package, ``mlp`` and ``mlp_decision`` import ``features``, and ``ppo_decision``
imports both ``features`` and ``mlp_decision``.

May import: numpy, torch, casadi, stable-baselines3 (inside ``ppo_decision``'s functions)
and ``uvms_env``; nothing else of ``baselines``.
"""
