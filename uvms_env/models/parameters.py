"""Typed, read-only view of ``parameters.toml``.

May import: the standard library and numpy.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

PARAMETER_FILE = Path(__file__).with_name("parameters.toml")


@dataclass(frozen=True)
class VehicleParameters:
    mass: float
    displaced_volume: float
    center_of_gravity: tuple[float, float, float]
    center_of_buoyancy: tuple[float, float, float]
    inertia: tuple[float, float, float]
    added_mass: tuple[float, ...]
    damping_linear: tuple[float, ...]
    damping_quadratic: tuple[float, ...]
    box: tuple[float, float, float]

    @property
    def bounding_radius(self) -> float:
        """Radius of the sphere around the vehicle origin that holds the hull box."""
        return 0.5 * float(np.linalg.norm(self.box))


@dataclass(frozen=True)
class ArmParameters:
    mount_xyz: tuple[float, float, float]
    mount_rpy: tuple[float, float, float]
    dh: tuple[tuple[float, float, float, float], ...]
    base_housing_mass: float
    base_housing_volume: float
    link_mass: tuple[float, ...]
    link_volume: tuple[float, ...]
    tube_radius: float
    trim_neutral: bool
    armature: tuple[float, ...]
    joint_damping: tuple[float, ...]
    drag_coefficient: float
    axial_added_mass_fraction: float
    axial_drag_coefficient: float
    linear_drag_per_length: float


@dataclass(frozen=True)
class ObjectParameters:
    tube_radius: float
    net_weight: float
    drag_coefficient: float
    axial_added_mass_fraction: float
    axial_drag_coefficient: float
    linear_drag_per_length: float
    bar_length: float
    ring_segments: int
    random_bar_lengths: tuple[float, ...]  # the random family's bar for N = 2, 3, ... robots

    def random_bar_length(self, n_agents: int) -> float:
        """The random family's bar for a team of ``n_agents`` (from 2)."""
        k = n_agents - 2
        if not 0 <= k < len(self.random_bar_lengths):
            top = len(self.random_bar_lengths) + 1
            raise ValueError(f"the random family's bars hold 2..{top} robots, got {n_agents}")
        return self.random_bar_lengths[k]


@dataclass(frozen=True)
class Limits:
    """The physical limits (``[limits]``): the one source of the input saturations, the
    environment's joint, joint-rate and vehicle-speed constraints and the expert's bounds
    on them (``uvms_env.task.constraints``, ``nmpc_expert.settings``)."""

    vehicle_force: float
    vehicle_moment: float
    joint_torque: float
    joint_position: float
    joint_speed: float
    vehicle_linear_speed: float
    vehicle_angular_speed: float

    @property
    def tau_max(self) -> np.ndarray:
        """Saturation of the 8 inputs: surge, sway, heave forces, yaw moment, 4 joint torques."""
        f, m, t = self.vehicle_force, self.vehicle_moment, self.joint_torque
        return np.array([f, f, f, m, t, t, t, t])


@dataclass(frozen=True)
class CurrentPreset:
    mean: float
    mu: float
    sigma: float
    min: float
    max: float
    heading_sigma: float


@dataclass(frozen=True)
class Parameters:
    water_density: float
    gravity: float
    vehicle: VehicleParameters
    arm: ArmParameters
    object: ObjectParameters
    limits: Limits
    currents: dict[str, CurrentPreset]


def _tuple(x: list) -> tuple:
    return tuple(_tuple(v) if isinstance(v, list) else float(v) for v in x)


def _fields(table: dict, cls: type) -> dict:
    names = cls.__dataclass_fields__
    return {k: (_tuple(v) if isinstance(v, list) else v) for k, v in table.items() if k in names}


@cache
def load_parameters(path: Path | None = None) -> Parameters:
    """Load the parameter file, ``PARAMETER_FILE`` by default (cached: the file is read
    once per process).

    Every limit of the testbed is read from here, by the environment and the expert alike;
    ``PARAMETER_FILE`` is looked up at call time so that a test can point it at an edited
    copy (then ``load_parameters.cache_clear()``) and see every user move together."""
    raw = tomllib.loads(Path(PARAMETER_FILE if path is None else path).read_text())
    obj = raw["object"]
    return Parameters(
        water_density=float(raw["environment"]["water_density"]),
        gravity=float(raw["environment"]["gravity"]),
        vehicle=VehicleParameters(**_fields(raw["vehicle"], VehicleParameters)),
        arm=ArmParameters(**_fields(raw["arm"], ArmParameters)),
        object=ObjectParameters(
            **_fields(obj, ObjectParameters),
            bar_length=float(obj["bar"]["length"]),
            ring_segments=int(obj["ring"]["segments"]),
            random_bar_lengths=tuple(float(v) for v in obj["bar"]["random_lengths"]),
        ),
        limits=Limits(**_fields(raw["limits"], Limits)),
        currents={
            name: CurrentPreset(**{k: float(v) for k, v in preset.items()})
            for name, preset in raw["current"].items()
            if isinstance(preset, dict)
        },
    )
