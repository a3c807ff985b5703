"""The evaluator by job, under ``python -m baselines.evaluate`` (its command line), the
ladder (``baselines.ladder``) and the channel sweep (``baselines.comm_sweep``):
``episode_row`` (one episode, one row), ``runner`` (cases, the preflight that builds each
case and policy once before any episode, seeded episodes, worker pool, ``Settings``),
``summary`` (the statistics every table reads, the failed episodes per policy), ``report``
(Markdown tables, the failures' lines and plots) and ``outputs`` (the files and the
run-and-write sequence every command shares).

Inside the package, ``outputs`` imports the others, ``runner`` and ``summary`` (the name of
an episode that raised) import ``episode_row``, and ``report`` and ``marl_eval`` (the rows'
metrics, on use) import ``summary``; nothing here imports a command.

May import: the standard library, numpy, tqdm, matplotlib, ``baselines.loaders.sources``,
``baselines.stats``, ``baselines.registry`` and ``uvms_env``; Ray only in ``ray_backend``
(on request, through ``baselines.ray_runtime`` and ``runner``'s install check) and
``marl_eval`` (merging marl-eval's JSON).
"""
