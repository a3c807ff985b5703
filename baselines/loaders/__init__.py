"""Saved and named policies as per-robot policies: the evaluator's ``--policy NAME[:ARG]``
(``sources``), the one base and lookup rule of saved networks (``saved``) and one adapter
per library that saves them (SB3, RLlib, BenchMARL, the clones). The registry of
names (``baselines.registry``) imports the adapters on demand: a library loads only when
its policy is asked for.

May import: nothing at package level (each module says what it imports).
"""
