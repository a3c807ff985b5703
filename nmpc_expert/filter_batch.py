"""One period of many safety filters, their QP builders evaluated in one batched call.

    step = BatchedFilterStep()
    actions = step(filters, observations)   # filters: SafetyFilters (any robots, any
                                            # objects); the same actions as
                                            # [f.act(o) for f, o in zip(filters, observations)]

Each robot's filter still runs alone on its own observation (no communication). The
builders of all robots whose objects share a strip capacity (one ``OCPFunctions``) are
evaluated in one call of ``uvms_env.vector.kernels.BatchedFunction`` (the library's C
compiled with SIMD lanes), one robot per lane; the
QPs are then solved one after another (DAQP has no batched interface; each QP has a
different active set). Reference: docs/safety-filter.md, "Many filters at once".

Rounding: the lane build uses the vector maths library where the scalar build calls
libm, so the builders agree to ~1e-15 relative, not bit for bit; the tests compare the
actions with ``act``'s to 1e-9.

May import: numpy, ``uvms_env`` and this package.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from nmpc_expert.safety_filter import SafetyFilter


class BatchedFilterStep:
    """Callable: ``(filters, observations) -> actions`` (M, 8). ``threads``: OpenMP threads
    of the batched call. Builds (and disk-caches) one lane-parallel builder per object
    the first time it meets it (tens of seconds of compilation, once per machine)."""

    def __init__(self, threads: int = 1) -> None:
        self.threads = int(threads)
        # id(OCPFunctions) -> (those functions, kept alive so the id stays theirs; their
        # builder batched)
        self._batched: dict[int, tuple[Any, Any]] = {}

    def _function(self, funcs: Any) -> Any:
        if id(funcs) not in self._batched:
            from uvms_env.vector.kernels import BatchedFunction

            built = (
                BatchedFunction(funcs.qp_builder, "float64", source=funcs.source)
                if funcs.source is not None  # the library's own C, one robot per lane
                else BatchedFunction(funcs.qp_builder_graph, "float64")
            )
            self._batched[id(funcs)] = (funcs, built)
        return self._batched[id(funcs)][1]

    def __call__(self, filters: Sequence[SafetyFilter], observations: Sequence[np.ndarray]):
        if len(filters) != len(observations):
            raise ValueError(f"{len(filters)} filters but {len(observations)} observations")
        groups: dict[int, list[int]] = {}
        for j, f in enumerate(filters):
            groups.setdefault(id(f.solver.funcs), []).append(j)
        # built before any filter moves (raises RuntimeError without a C++ compiler)
        functions = {g: self._function(filters[m[0]].solver.funcs) for g, m in groups.items()}
        decisions = [f.begin(o) for f, o in zip(filters, observations, strict=True)]
        for g, members in groups.items():
            fn = functions[g]
            k = fn.padded(len(members))
            inputs = [np.zeros((nnz, k)) for nnz in fn.signature.nnz_in]
            for lane, j in enumerate(members):
                for buf, arr in zip(inputs, filters[j].solver.build_inputs(), strict=True):
                    buf[:, lane] = arr.reshape(-1)
            for lane in range(len(members), k):  # padding lanes: a copy of the first robot
                for buf in inputs:
                    buf[:, lane] = buf[:, 0]
            try:
                out = fn(inputs, self.threads)
            except RuntimeError:  # each filter then evaluates its own builder in finish
                continue
            for lane, j in enumerate(members):
                filters[j].solver.load_build([o[:, lane] for o in out])
        return np.stack([f.finish(d) for f, d in zip(filters, decisions, strict=True)])
