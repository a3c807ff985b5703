"""Scale-out of the baselines: Ray RLlib training, Ray evaluation, marl-eval output and a
BenchMARL task. Ray, RLlib and BenchMARL are optional (``pip install -e ".[distributed]"``):
each module imports them only inside the functions that need them, except the RLlib
modules, which are only imported on demand."""
