"""The strict CuPy stand-in (``strict_xp``) is strict: every implicit device-to-host
conversion, host operand and unsupported numpy call that CuPy refuses raises here too,
while what CuPy allows (explicit copies, one-element reads, host indices) works and
computes what numpy does. The emulated-CUDA tests run the package on it
(``emulated_xp`` in conftest)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from strict_xp import StrictArray, host_reads, uploads, xp

from uvms_env.vector.kernels_emulated import _memory


def _a() -> StrictArray:
    return xp.arange(6.0).reshape(2, 3)


HOST = np.ones(3)

# each an operation CuPy refuses (TypeError; ValueError for the truth value of many
# elements, as CuPy and numpy raise it)
REFUSED = {
    "np.asarray": (lambda a: np.asarray(a), TypeError),
    "np.array": (lambda a: np.array(a), TypeError),
    "iteration": (lambda a: list(a), TypeError),
    "unpacking": (lambda a: [x for x, _ in zip(a, range(2), strict=False)], TypeError),
    "float of many": (lambda a: float(a), TypeError),
    "int of many": (lambda a: int(a), TypeError),
    "bool of many": (lambda a: bool(a > 1), ValueError),
    "if array": (lambda a: 1 if a.any(axis=0) else 0, ValueError),
    "a as a Python index": (lambda a: [0, 1][a[0, 1].astype(np.int64)], TypeError),
    "range(a)": (lambda a: range(a[0, 2].astype(np.int64)), TypeError),
    "device + host": (lambda a: a + HOST, TypeError),
    "host + device": (lambda a: HOST + a, TypeError),
    "host * device": (lambda a: HOST * a, TypeError),
    "device < host": (lambda a: a < HOST, TypeError),
    "in place with host": (lambda a: a.__iadd__(HOST), TypeError),
    "ufunc out= host": (lambda a: np.add(a, 1.0, out=np.empty((2, 3))), TypeError),
    "np.add.reduce": (lambda a: np.add.reduce(a), TypeError),
    "np.maximum.at": (lambda a: np.maximum.at(a, [0], 1.0), TypeError),
    "np.median (no CuPy counterpart here)": (lambda a: np.median(a), TypeError),
    "np.where with a host operand": (lambda a: np.where(a > 1, a[0], HOST), TypeError),
    "np.concatenate with a host part": (
        lambda a: np.concatenate([a, HOST[None]]),
        TypeError,
    ),
    "xp.concatenate with a host part": (
        lambda a: xp.concatenate([a, HOST[None]]),
        TypeError,
    ),
    "xp.stack of host arrays": (lambda a: xp.stack([HOST, HOST]), TypeError),
    "xp.ascontiguousarray of a host array": (lambda a: xp.ascontiguousarray(HOST), TypeError),
    "xp.clip with host bounds": (lambda a: xp.clip(a, -HOST, HOST), TypeError),
    "xp.sqrt of a host array": (lambda a: xp.sqrt(HOST), TypeError),
    "xp.asarray of a list of device arrays": (lambda a: xp.asarray([a[0], a[1]]), TypeError),
    "host array into a slice": (lambda a: a.__setitem__(slice(None), np.ones((2, 3))), TypeError),
    "host array into columns": (lambda a: a.__setitem__((slice(None), 0), HOST[:2]), TypeError),
    "torch tensor as an operand": (lambda a: a + torch.ones(3), TypeError),
}


@pytest.mark.parametrize("name", list(REFUSED))
def test_what_cupy_refuses_raises(name):
    op, error = REFUSED[name]
    with pytest.raises(error):
        op(_a())


def test_what_cupy_allows_works_and_computes_as_numpy():
    a, h = _a(), np.arange(6.0).reshape(2, 3)
    assert float(a[1, 2]) == 5.0 and int(a[0, 1]) == 1 and bool(a[0, 1] > 0)
    assert a[0, 0].item() == 0.0 and a.tolist() == h.tolist()
    assert isinstance(a.sum(), StrictArray) and a.sum().shape == ()  # 0-d, as CuPy's
    copy = xp.asnumpy(a)
    assert type(copy) is np.ndarray and np.array_equal(copy, h)
    copy[0, 0] = 7.0  # a copy, not a view
    assert float(a[0, 0]) == 0.0
    # numpy's functions and ufuncs dispatch on device arrays and stay on the device
    for out, ref in (
        (np.clip(a, 1.0, 4.0), np.clip(h, 1.0, 4.0)),
        (np.stack([a, a], -1), np.stack([h, h], -1)),
        (np.where(a > 2, a, 0.0), np.where(h > 2, h, 0.0)),
        (np.sqrt(a) * 2.0 - a / 3, np.sqrt(h) * 2.0 - h / 3),
        (xp.linalg.norm(a, axis=1), np.linalg.norm(h, axis=1)),
        (xp.einsum("ij,ij->j", a, a), np.einsum("ij,ij->j", h, h)),
        (a.max(axis=0), h.max(axis=0)),
    ):
        assert isinstance(out, StrictArray)
        assert np.array_equal(xp.asnumpy(out), ref)
    # host indices and host values through advanced indexing: CuPy copies them over
    b = xp.zeros((2, 3))
    b[:, np.array([0, 2])] = np.ones((2, 2))
    b[np.array([True, False]), 1] = 5.0
    b += a
    assert np.array_equal(xp.asnumpy(b), h + np.array([[1, 5, 1], [1, 0, 1]]))
    assert np.array_equal(xp.asnumpy(a[[1, 0]]), h[[1, 0]])
    # DLPack both ways, sharing memory
    t = torch.from_dlpack(a)
    back = xp.from_dlpack(t)
    back[0, 0] = -1.0
    assert float(a[0, 0]) == -1.0 and t[0, 0].item() == -1.0
    assert math.isclose(float(xp.asarray(torch.ones(2)).sum()), 2.0)


def test_the_emulated_device_reads_and_writes_device_arrays_in_place():
    a = xp.zeros((2, 3))
    view = _memory(a)  # what the emulated kernel writes to: a's memory, not a copy
    view[1, 2] = 4.0
    assert float(a[1, 2]) == 4.0
    host = np.zeros(2)
    assert _memory(host) is host  # numpy as it was


def test_host_reads_are_counted_where_cupy_synchronizes():
    a = _a()
    host_reads.clear()
    uploads.clear()
    b = a * 2.0 + 1.0  # on the device
    b[a > 2] = 0.0  # a mask: CuPy reads how many are True
    float(b[0, 0])
    bool((b > 0).any())
    xp.flatnonzero(b)  # output size read
    xp.asnumpy(b)
    assert host_reads.counts == {"mask": 1, "scalar": 1, "bool": 1, "nonzero": 1, "copy": 1}
    assert uploads.total() == 0
    b[np.array([0, 1])] = np.ones((2, 3))  # a host index and a host value
    xp.asarray(np.ones(2))
    assert uploads.counts == {"index": 1, "value": 1, "asarray": 1}
