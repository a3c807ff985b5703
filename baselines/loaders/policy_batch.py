"""Every robot of K episodes decided by one call: a saved network's batched decision.

The batched evaluator (``baselines.evaluation.batched``) plays K episodes of one case on one
``VectorEnv``; each robot's ``LoadedPolicy`` is built as the single evaluator builds it,
and where the robots' policies share a ``batch_key`` (the same network, priors, object and
period) one ``PolicyBatch`` decides for all of them at once. It holds what each robot's
policy would hold for itself: the memory block of the memory mode (``Memory``, the arrays
of all K x N robots, updated by the same compiled function as ``RobotMemory``) and, per
decision, one call for every robot:

* a loader whose whole decision is one compiled function of ([raw; memory], constants)
  (``LoadedPolicy.whole_decision``: SB3's compiled PPO actor, the compiled clones) runs it
  mapped over the K x N robots (``casadi.Function.map``, the constants not repeated): the
  same generated code per robot, so the same numbers as the robot's own call;
* any other batchable loader: the priors' observation of all robots (numpy on (K, N, 79)),
  the loader's ``decide_many`` (one forward of its network), then the priors' command.

``act(obs, slots)`` decides for the copies ``slots`` only; it changes the batch's state only
when it returns, so a caller may retry the copies one at a time after an error to find the
failing episode. ``reset(slot)`` starts a copy's new episode.

May import: numpy, casadi, ``baselines.loaders.saved`` and ``uvms_env``.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from typing import Any

import numpy as np

from baselines.loaders.saved import LoadedPolicy
from uvms_env.dynamics import NU
from uvms_env.dynamics.compiled import BufferCall
from uvms_env.robot.memory import Memory, sent
from uvms_env.robot.observation import OBSERVATION_SIZE


def batch_key(policies: Sequence[Any]) -> Hashable | None:
    """The key one ``PolicyBatch`` decides ``policies`` (one episode's robots) by, or None
    where they must decide one by one (not all saved networks of one key)."""
    keys = {p.batch_key() if isinstance(p, LoadedPolicy) else None for p in policies}
    return keys.pop() if len(keys) == 1 else None


class PolicyBatch:
    """The decisions of ``shape`` = (copies, robots) robots whose policies have the key of
    ``template`` (a robot's ``LoadedPolicy``; see the module docstring)."""

    def __init__(self, template: LoadedPolicy, shape: tuple[int, int]) -> None:
        key = template.batch_key()
        if key is None:
            raise ValueError(f"{type(template).__name__} decides one robot at a time")
        if template.spec is None:
            raise ValueError("a batch of policies needs the robots' AgentSpec")
        self.key, self.template, self.shape = key, template, shape
        self.ring = template.inputs.ring
        self.priors = template.priors
        self.memory = None
        if template.priors.remembers:
            self.memory = Memory(shape, template.spec.period, self.ring)
        self._previous = np.zeros((*shape, OBSERVATION_SIZE), np.float32)
        self._fresh = np.ones(shape[0], bool)  # no decision yet in the copy's episode
        self._whole = None
        whole = template.whole_decision()
        if whole is not None:
            fn, constants = whole
            count = shape[0] * shape[1]
            mapped = fn.map(count, [False] + [True] * len(constants), [False])
            # the copies' inputs, rows of every robot (a copy not deciding keeps its last)
            full = np.zeros((*shape, fn.size1_in(0)))
            self._whole = (BufferCall(mapped), constants, full, full.reshape(count, -1))

    def reset(self, slot: int) -> None:
        """Copy ``slot`` starts a new episode: nothing remembered."""
        self._fresh[slot] = True
        if self.memory is not None:
            self.memory.reset(slot)

    def act(self, obs: np.ndarray, slots: Sequence[int]) -> np.ndarray:
        """The normalized inputs (len(slots), robots, 8) float32 of copies ``slots`` for their
        raw observations ``obs[slots]`` (``obs``: (copies, robots, 79))."""
        ids = np.asarray(slots, dtype=int)
        raw = np.asarray(obs[ids], np.float32)
        block, seen, estimate = None, ids[:0], None
        if self.memory is not None:
            memory, old = self.memory, ~self._fresh[ids]  # old: sent after an observation
            seen = ids[old]
            block = np.concatenate([memory.command[ids], memory.disturbance[ids]], -1)
            if len(seen):
                previous, sent_then = self._previous[seen], memory.command[seen]
                estimate = memory.estimate(seen, previous, raw[old], sent_then)
                block[old, :, NU:] = estimate
            block = block.astype(np.float32)
        actions = self._decide(obs, raw, ids, block)
        # the decision stands: what each robot's own memory now holds
        if self.memory is not None:
            if estimate is not None:
                self.memory.disturbance[seen] = estimate
            self.memory.command[ids] = sent(actions)
        self._previous[ids] = raw
        self._fresh[ids] = False
        return actions

    def _decide(
        self, obs: np.ndarray, raw: np.ndarray, ids: np.ndarray, block: np.ndarray | None
    ) -> np.ndarray:
        if self._whole is not None:
            call, constants, full, rows = self._whole
            given = np.asarray(obs[ids])  # as the robot's own call takes it
            full[ids, :, : given.shape[-1]] = given
            if block is not None:
                full[ids, :, OBSERVATION_SIZE:] = block
            out = call(rows, *constants)[0]
            return out.reshape(*self.shape, -1)[ids].astype(np.float32)
        x = self.priors.observe(raw, self.ring, memory=block)
        chosen = self.template.decide_many(x.reshape(-1, x.shape[-1]))
        chosen = np.clip(chosen, -1.0, 1.0).reshape(*raw.shape[:-1], -1)
        return self.priors.command(raw, chosen, self.ring).astype(np.float32)
