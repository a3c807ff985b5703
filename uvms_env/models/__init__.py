"""Model data: the physical parameters of one UVMS and of the object, and the UVMS URDF.

Everything physical lives in ``parameters.toml`` (one number, one source); this module
loads it into typed, read-only records and renders the URDF the rigid-body library
reads. It is the lowest layer of ``uvms_env``: it may import only the standard library
and numpy.
"""

from uvms_env.models.parameters import (
    ArmParameters,
    CurrentPreset,
    Limits,
    ObjectParameters,
    Parameters,
    VehicleParameters,
    load_parameters,
)
from uvms_env.models.urdf import URDF_PATH, render_urdf

__all__ = [
    "URDF_PATH",
    "ArmParameters",
    "CurrentPreset",
    "Limits",
    "ObjectParameters",
    "Parameters",
    "VehicleParameters",
    "load_parameters",
    "render_urdf",
]
