"""Shared fixtures: the models and the paper scenario are built once per test session."""

from __future__ import annotations

import numpy as np
import pytest

from uvms_env.dynamics import ObjectModel
from uvms_env.scenarios import make
from uvms_env.scenarios.geometry import uvms_model


@pytest.fixture(scope="session")
def uvms():
    return uvms_model()


@pytest.fixture(scope="session")
def bar():
    return ObjectModel("bar")


@pytest.fixture(scope="session")
def paper():
    return make("paper")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
