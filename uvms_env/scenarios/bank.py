"""Pre-built geometries of the seeded scenario families, kept on disk, so that resetting a
batched environment copies a start instead of solving for one (docs/batched.md,
"Geometry bank"; build costs: docs/simulator.md, "Measured"):

    bank = GeometryBank("random", n_agents=4)
    g = bank.get(17)              # Geometry(scenario, navigation), built on first use
    bank.fill(range(1024))        # or ahead of time:
    python -m uvms_env.vector.build_bank random --n-agents 4 --seeds 0:1024 --workers 2
    python -m uvms_env.vector.build_bank random --n-agents 4 --object bar --course mixed

A geometry depends on the family, its geometry options (the team size; the random
family's object and course) and the seed only; every other scenario override is laid
over it with ``scenarios.replace`` (``Geometry.scenario_with``), so one bank serves every
such setting. Entries are keyed by a hash of the code that builds them
(the scenario and navigation modules and the model parameters): a change there starts a
new bank instead of serving stale geometries. ``geometry_of_seed`` gives the single and
the batched environment the same scenario of a seed.

May import: numpy, tqdm (the build's progress), ``uvms_env.scenarios``,
``uvms_env.navigation`` and ``uvms_env.dynamics.compiled`` (the cache folder).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import pickle
from collections.abc import Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from uvms_env.dynamics.compiled import cache_dir, exclusive
from uvms_env.navigation.task_navigator import waypoint_table
from uvms_env.scenarios.config import Scenario
from uvms_env.scenarios.families import (
    RANDOM_DEFAULT_COURSE,
    RANDOM_DEFAULT_OBJECT,
    SEEDED_FAMILIES,
    make,
    replace,
)
from uvms_env.scenarios.overrides import (
    FAMILY_OPTIONS,
    RANDOM_COURSES,
    RANDOM_OBJECTS,
    SCENARIO_OVERRIDES,
    Option,
    option_type,
)

# The geometry options a bank is kept per (besides the team size), with their defaults:
# a bank of the defaults keeps its folder name.
GEOMETRY_OPTIONS = {"object": RANDOM_DEFAULT_OBJECT, "course": RANDOM_DEFAULT_COURSE}


@dataclass(frozen=True)
class Geometry:
    """One pre-built task geometry: the scenario (family defaults, its seed and team size)
    and its navigation parameters, one (NAV_PARAMETERS,) row per waypoint."""

    scenario: Scenario
    navigation: np.ndarray

    def scenario_with(self, overrides: dict[str, Any]) -> Scenario:
        """The scenario with the non-geometry ``overrides`` laid over it."""
        rest = {k: v for k, v in overrides.items() if k != "seed" and k not in FAMILY_OPTIONS}
        return replace(self.scenario, **rest) if rest else self.scenario


def navigation_table(scenario: Scenario) -> np.ndarray:
    """(waypoints, NAV_PARAMETERS): each waypoint's parameters of the shared navigation
    function, from the navigator every robot of ``scenario`` uses."""
    s = scenario
    return waypoint_table(s.waypoints, s.workspace, s.obstacles, s.team_radius)


def build_geometry(
    family: str, n_agents: int, seed: int | None, options: dict[str, str] | None = None
) -> Geometry:
    """The geometry of ``seed``; ``options``: the family's geometry options (``object``,
    ``course``) other than their defaults."""
    scenario = make(family, seed=seed, n_agents=n_agents, **(options or {}))
    return Geometry(scenario, navigation_table(scenario))


def geometry_options(overrides: dict[str, Any] | None) -> dict[str, str]:
    """The geometry options among scenario ``overrides`` that differ from the defaults."""
    given = overrides or {}
    return {
        k: given[k] for k, default in GEOMETRY_OPTIONS.items() if given.get(k, default) != default
    }


# scenarios modules no geometry is built from: a change there keeps every bank
NOT_BUILT_FROM = ("reach.py",)


@cache
def _code_key() -> str:
    """Hash of the sources a geometry is built from."""
    root = Path(__file__).resolve().parent.parent
    scenarios = sorted(f for f in (root / "scenarios").glob("*.py") if f.name not in NOT_BUILT_FROM)
    files = scenarios + sorted((root / "navigation").glob("*.py"))
    files += [root / "models" / "parameters.toml"]
    digest = hashlib.sha256()
    for f in files:
        digest.update(f.read_bytes())
    return digest.hexdigest()[:12]


class GeometryBank:
    """Geometries of one seeded family, team size and geometry options: in memory, on
    disk, or built. ``overrides``: the environment's scenario overrides (only the
    geometry options among them count: ``GEOMETRY_OPTIONS``)."""

    def __init__(
        self,
        family: str,
        n_agents: int,
        folder: Path | None = None,
        overrides: dict[str, Any] | None = None,
    ) -> None:
        if family not in SEEDED_FAMILIES:
            raise ValueError(f"only seeded families have a bank {SEEDED_FAMILIES}, got {family!r}")
        self.family, self.n_agents = family, int(n_agents)
        self.options = geometry_options(overrides)
        base = Path(folder) if folder is not None else cache_dir() / "geometry_bank"
        tags = "".join(f"_{k}-{v}" for k, v in self.options.items())
        self.folder = base / f"{family}_n{self.n_agents}{tags}_{_code_key()}"
        self._memory: dict[int, Geometry] = {}

    def path(self, seed: int) -> Path:
        return self.folder / f"{seed}.pkl"

    def get(self, seed: int) -> Geometry:
        """The geometry of ``seed``, built and stored on first use."""
        seed = int(seed)
        if seed in self._memory:
            return self._memory[seed]
        path = self.path(seed)
        geometry = None
        if path.exists():
            try:
                geometry = pickle.loads(path.read_bytes())
            except (OSError, EOFError, pickle.UnpicklingError, AttributeError):
                geometry = None  # a damaged entry is rebuilt
        if geometry is None:
            geometry = build_geometry(self.family, self.n_agents, seed, self.options)
            self._store(path, geometry)
        self._memory[seed] = geometry
        return geometry

    def missing(self, seeds: Iterable[int]) -> list[int]:
        return [int(s) for s in seeds if int(s) not in self._memory and not self.path(s).exists()]

    def fill(self, seeds: Iterable[int], workers: int = 1, progress: bool = False) -> int:
        """Build every missing geometry of ``seeds`` (in ``workers`` processes); returns
        how many were built."""
        seeds = list(seeds)
        if not self.missing(seeds):
            return 0
        self.folder.mkdir(parents=True, exist_ok=True)
        # one builder per bank at a time: a process that needs it waits, then reads
        with exclusive(self.folder / "build.lock"):
            return self._fill(self.missing(seeds), workers, progress)

    def _fill(self, todo: list[int], workers: int, progress: bool) -> int:
        if not todo:
            return 0
        what = f"{self.family} N={self.n_agents}" + "".join(f" {v}" for v in self.options.values())
        bar = _progress(len(todo), what) if progress else None
        if workers <= 1:
            for seed in todo:
                geometry = build_geometry(self.family, self.n_agents, seed, self.options)
                self._store(self.path(seed), geometry)
                if bar is not None:
                    bar.update()
        else:
            with ProcessPoolExecutor(workers) as pool:
                jobs = [(self.family, self.n_agents, s, self.options) for s in todo]
                for seed, geometry in zip(todo, pool.map(_build, jobs), strict=True):
                    self._store(self.path(seed), geometry)
                    if bar is not None:
                        bar.update()
        if bar is not None:
            bar.close()
        return len(todo)

    def _store(self, path: Path, geometry: Geometry) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        part = path.with_suffix(f".{os.getpid()}.part")
        part.write_bytes(pickle.dumps(geometry))
        part.replace(path)  # atomic: a parallel reader never sees half an entry


def _build(job: tuple[str, int, int, dict[str, str]]) -> Geometry:
    return build_geometry(*job)


def _progress(total: int, what: str) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, desc=f"geometries {what}", unit="geometry")


def _seed_range(text: str) -> range:
    """``START:STOP`` (STOP excluded) or one seed ``START``; seeds are >= 0."""
    start, sep, stop = text.partition(":")
    try:
        first = int(start)
        last = int(stop) if sep else first + 1
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START:STOP or SEED, got {text!r}") from None
    if first < 0 or last <= first:
        raise argparse.ArgumentTypeError(f"expected 0 <= START < STOP, got {text!r}")
    return range(first, last)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m uvms_env.vector.build_bank",
        description="Build the geometries of a seeded scenario family ahead of training.",
        allow_abbrev=False,
    )
    parser.add_argument("family", choices=SEEDED_FAMILIES)
    parser.add_argument("--n-agents", type=option_type(SCENARIO_OVERRIDES["n_agents"]), default=2)
    parser.add_argument("--seeds", type=_seed_range, default=range(0, 256), help="START:STOP")
    parser.add_argument(
        "--workers",
        type=option_type(Option("int", "", low=1)),
        default=len(os.sched_getaffinity(0)),
    )
    parser.add_argument("--object", choices=RANDOM_OBJECTS, default=RANDOM_DEFAULT_OBJECT)
    parser.add_argument("--course", choices=RANDOM_COURSES, default=RANDOM_DEFAULT_COURSE)
    args = parser.parse_args(argv)
    options = {"object": args.object, "course": args.course}
    bank = GeometryBank(args.family, args.n_agents, overrides=options)
    built = bank.fill(args.seeds, workers=args.workers, progress=True)
    print(f"{built} built, {len(args.seeds) - built} already there: {bank.folder}")


if __name__ == "__main__":
    main()
