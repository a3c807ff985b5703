"""Batched simulation: K environments stepped together, on CPU lanes and threads or a GPU.

Built from the same CasADi graphs as the single environment (ARCHITECTURE: one graph,
three targets): ``kernels`` compiles a generated function for K environments per call,
``simulator`` steps K truth simulators of one team size and object through it.

May import: numpy, casadi, and ``uvms_env`` below ``vector`` (dynamics, sim, scenarios);
torch and CuPy only inside the CUDA backend, when asked for.
"""
