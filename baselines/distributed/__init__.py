"""Scale-out of the baselines: Ray RLlib training, Ray evaluation and marl-eval output (the
BenchMARL task is an example: examples/benchmarl). Ray and RLlib are optional
(``pip install -e ".[distributed]"``):
each module imports them only inside the functions that need them, except the RLlib
modules, which are only imported on demand."""

ENV_NAME = "uvms_coop"  # the environment's name in RLlib's registry
