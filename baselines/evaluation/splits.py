"""The evaluation's two splits of episodes: ``dev`` for tuning, selection and design, ``test``
played once per release of the tables.

A split is a base seed (episode k of a case with scenario S is ``case_episode_seed(seed,
S, k)``, ``baselines.evaluation.runner``) and how many episodes each kind of rung plays per
case. ``dev`` is seed 202's episodes, on which the expert's settings, the clones and the
from-scratch recipes were tuned and chosen. ``test`` is seed 61061, named nowhere in the
repository before it was frozen here (a test checks its episodes against every seed the
repository names and against the training runs' geometry pools): at least 50 episodes per
case for the rungs that decide in well under 5 ms (learned policies, the trivial rungs),
20 for the model-based ones (the expert's controllers and every ``+filter`` rung: a QP per
robot and period) and 10 for the full-information reference, whose episodes cost minutes.
The first episodes of a case are the same whatever the count, so every pair of rungs is
compared on the episodes both played.

Beyond the training conditions (``Split.beyond``; the ladder's ``--beyond``): random rings
and bars of 7 and 8 robots, team sizes no learned rung trained on, with their own counts
per kind of rung (``beyond``: fast, model, central), smaller than the split's own because
an episode of 8 robots costs several of 2. ``test`` version 2 is version 1's cases,
episode for episode, and these; the other condition beyond training, mismatch 0.25, is
the split's own cases under ``--mismatch 0.25``.

Changing a setting after looking at ``test`` numbers spends the split: freeze a new one
(a new seed and ``version``) and say so in the results. Reference: docs/evaluation.md,
"Splits".

May import: the standard library only.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

CENTRAL = "nmpc:central"
FILTER_SUFFIX = "+filter"


@dataclass(frozen=True)
class Split:
    """A split: its name, version and base seed, and the episodes per case of each kind of
    rung (``kind_of``)."""

    name: str
    version: int
    seed: int
    fast: int  # learned and trivial rungs
    model: int  # the expert's controllers and the +filter rungs
    central: int  # the full-information reference
    beyond: tuple[int, int, int]  # fast, model, central on the cases beyond training

    def episodes(self, policy: str, beyond: bool = False) -> int:
        """How many episodes per case ``policy`` plays on this split (``beyond``: on the
        cases beyond the training conditions)."""
        kind = kind_of(policy)
        return self.beyond[KINDS.index(kind)] if beyond else getattr(self, kind)


KINDS = ("fast", "model", "central")


def kind_of(policy: str) -> str:
    """``central`` (the full-information reference), ``model`` (a controller that solves a
    QP per robot and period: the ``nmpc`` family and any ``+filter`` rung) or ``fast``."""
    if policy == CENTRAL:
        return "central"
    if policy.startswith("nmpc") or policy.endswith(FILTER_SUFFIX):
        return "model"
    return "fast"


DEV = Split("dev", 1, 202, fast=10, model=10, central=10, beyond=(10, 10, 10))
TEST = Split("test", 2, 61061, fast=50, model=20, central=10, beyond=(20, 10, 5))
SPLITS = {s.name: s for s in (DEV, TEST)}


def add_split_arguments(
    ap: argparse.ArgumentParser, seed_type: object, count_type: object, default_seed: int
) -> None:
    """``--split dev|test`` or ``--seed S`` (not both), and ``--episodes N`` (a split's own
    counts per kind of rung without it)."""
    which = ap.add_mutually_exclusive_group()
    which.add_argument(
        "--split",
        choices=tuple(SPLITS),
        default=None,
        help=f"the split's episodes: dev (seed {DEV.seed}, for tuning and selection) or test "
        f"(seed {TEST.seed}, {TEST.fast}/{TEST.model}/{TEST.central} episodes per case for "
        "fast/model-based/full-information rungs; played once per release of the tables)",
    )
    which.add_argument(
        "--seed",
        type=seed_type,  # type: ignore[arg-type]
        default=None,
        help=f"the evaluation's seed outside the splits (default {default_seed})",
    )
    ap.add_argument(
        "--episodes",
        type=count_type,  # type: ignore[arg-type]
        default=None,
        help="episodes per case for every rung (default: the split's counts, else 10 for "
        "the ladder and 20 for the evaluator)",
    )
