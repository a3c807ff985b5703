"""A strict stand-in for CuPy over numpy: device arrays that refuse to become host arrays
implicitly, for testing the CUDA backend's array code without a GPU.

CuPy refuses what would silently copy a device array to the host: ``np.asarray(a)``
(``__array__`` raises TypeError), numpy arrays mixed into its ufuncs and functions
(TypeError), ``float``/``int`` (TypeError) and ``bool`` (ValueError, as numpy) of arrays
with more than one element, numpy ufunc methods other than calls (``np.add.reduce(a)``)
and numpy functions it has no counterpart of (``__array_function__`` gives up:
TypeError). ``StrictArray`` does the same
over a numpy array it holds, and ``xp`` is the namespace (the subset of CuPy's API the
package uses, plus ``asnumpy``: the explicit copy to the host). What CuPy allows, this
allows: host index arrays and lists (copied to the device), host values assigned through
advanced indexing, ``float``/``bool`` of one element (CuPy synchronizes), ``item``,
``tolist`` and ``get`` (explicit copies), DLPack in both directions.

Stricter than CuPy, on purpose: iterating over an array raises (CuPy yields one device
array per element, a synchronization each where they are read: never wanted in a step),
and the namespace's functions take no host arrays at all (some CuPy functions copy them to
the device silently, others refuse).

How the package's emulated CUDA device takes it: ``EmulatedCudaFunction.xp`` (the array
namespace of ``uvms_env.vector.kernels_emulated``) set to ``xp`` (the ``emulated_xp``
fixture); its kernels read and write the arrays' memory through DLPack, as a GPU kernel
reads device memory. ``host_reads`` counts the device-to-host reads (a synchronization
each on a GPU, those CuPy makes inside included) and ``uploads`` the host-to-device
copies, for tests that bound them.

May import: numpy only (a test helper).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

_HOST_MESSAGE = (
    "Implicit conversion to a NumPy array is not allowed. "
    "Please use `.get()` to construct a NumPy array explicitly."
)
_SCALARS = bool | int | float | complex | np.generic


class HostReads:
    """Device-to-host reads (each a synchronization on a GPU), by kind: ``bool``,
    ``scalar`` (float/int/complex/item), ``copy`` (get/asnumpy/tolist), and the ones
    CuPy makes inside: ``mask`` (boolean-mask indexing, reading the count of True) and
    ``nonzero`` (argwhere, flatnonzero, nonzero, unique: reading the output size)."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}

    def note(self, kind: str) -> None:
        self.counts[kind] = self.counts.get(kind, 0) + 1

    def total(self) -> int:
        return sum(self.counts.values())

    def clear(self) -> None:
        self.counts.clear()


host_reads = HostReads()
# host-to-device copies (no synchronization, a transfer each): ``asarray`` of host data,
# host ``index`` arrays and lists, host ``value`` arrays assigned
uploads = HostReads()

# the numpy ufuncs CuPy has (cupy.<name>), by name
UFUNCS = frozenset(
    """add subtract multiply divide true_divide floor_divide remainder mod fmod power
    float_power negative positive absolute abs fabs sign sqrt cbrt square reciprocal exp exp2
    expm1 log log2 log10 log1p sin cos tan arcsin arccos arctan arctan2 hypot sinh cosh
    tanh arcsinh arccosh arctanh deg2rad rad2deg degrees radians floor ceil trunc rint
    copysign nextafter ldexp frexp modf minimum maximum fmin fmax isfinite isinf isnan
    signbit logical_and logical_or logical_xor logical_not bitwise_and bitwise_or
    bitwise_xor bitwise_not invert left_shift right_shift equal not_equal less less_equal
    greater greater_equal matmul conj conjugate""".split()
)
# the numpy functions CuPy has a counterpart of that the namespace offers (cupy.<name>)
FUNCTIONS = frozenset(
    """where concatenate stack hstack vstack column_stack clip argwhere flatnonzero nonzero
    repeat tile broadcast_to broadcast_arrays einsum round around cumsum cumprod unique
    sort argsort any all sum prod mean std var max min amax amin argmax argmin ptp reshape
    transpose ravel squeeze expand_dims moveaxis swapaxes take take_along_axis
    count_nonzero isin dot outer inner cross diff ndim shape size atleast_1d atleast_2d
    copy allclose isclose array_equal zeros_like ones_like empty_like full_like
    result_type can_cast nan_to_num interp searchsorted flip roll""".split()
)
_CMP = ("equal", "not_equal", "less", "less_equal", "greater", "greater_equal")


def _is_host_array(x: Any) -> bool:
    """A host array (numpy, or anything else that converts to one) where CuPy needs a
    device array."""
    if isinstance(x, StrictArray | _SCALARS | type | np.dtype | str) or x is None:
        return False
    return isinstance(x, np.ndarray) or hasattr(x, "__array__") or hasattr(x, "__dlpack__")


def _check(args: Any, what: str) -> None:
    """TypeError if ``args`` (nested lists and tuples) hold a host array."""
    if isinstance(args, list | tuple):
        for a in args:
            _check(a, what)
    elif isinstance(args, dict):
        for a in args.values():
            _check(a, what)
    elif _is_host_array(args):
        raise TypeError(
            f"{what}: got a host array ({type(args).__name__}) where a device array is "
            "needed (no implicit host-to-device conversion)"
        )


def _raw(x: Any) -> Any:
    """The numpy arrays inside ``x`` (nested lists, tuples and dicts)."""
    if isinstance(x, StrictArray):
        return x._a
    if isinstance(x, list):
        return [_raw(a) for a in x]
    if isinstance(x, tuple):
        return tuple(_raw(a) for a in x)
    if isinstance(x, dict):
        return {k: _raw(a) for k, a in x.items()}
    return x


def _wrap(x: Any) -> Any:
    """numpy results as device arrays; numpy scalars as 0-d arrays (as CuPy returns)."""
    if isinstance(x, np.ndarray):
        return StrictArray(x)
    if isinstance(x, np.generic):
        return StrictArray(np.asarray(x))
    if isinstance(x, tuple):
        return tuple(_wrap(a) for a in x)
    if isinstance(x, list):
        return [_wrap(a) for a in x]
    return x


# functions whose output size CuPy reads from the device
_SIZE_READS = frozenset({"argwhere", "flatnonzero", "nonzero", "unique"})


def _device_function(fn: Callable, name: str) -> Callable:
    """``fn`` (numpy) as a function of the device namespace: device arrays in and out."""

    def call(*args: Any, **kwargs: Any) -> Any:
        _check((args, kwargs), f"xp.{name}")
        if name in _SIZE_READS:
            host_reads.note("nonzero")
        out = kwargs.get("out")
        result = fn(*_raw(args), **_raw(kwargs))
        return out if isinstance(out, StrictArray) else _wrap(result)

    call.__name__ = call.__qualname__ = name
    return call


class StrictArray:
    """A device array: a numpy array behind CuPy's rules (module docstring)."""

    __slots__ = ("_a",)
    __array_priority__ = 100
    __hash__ = None  # type: ignore[assignment]

    def __init__(self, a: np.ndarray) -> None:
        if not isinstance(a, np.ndarray) or type(a) is not np.ndarray:
            raise TypeError(f"StrictArray holds a plain numpy array, got {type(a).__name__}")
        self._a = a

    # -- what CuPy refuses -----------------------------------------------------------------
    def __array__(self, *args: Any, **kwargs: Any) -> np.ndarray:
        raise TypeError(_HOST_MESSAGE)

    def __iter__(self) -> Any:
        raise TypeError(
            "iteration over a device array (one device read per element): index it, or "
            "copy it to the host explicitly"
        )

    def __bool__(self) -> bool:
        if self._a.size == 0:  # CuPy's (deprecated) answer
            warnings.warn("truth value of an empty array", DeprecationWarning, stacklevel=2)
            return False
        if self._a.size > 1:
            raise ValueError(
                "The truth value of an array with more than one element is ambiguous. "
                "Use a.any() or a.all()"
            )
        host_reads.note("bool")
        return bool(self._a.reshape(()))

    def __float__(self) -> float:
        return float(self._scalar("float"))

    def __int__(self) -> int:
        return int(self._scalar("int"))

    def __complex__(self) -> complex:
        return complex(self._scalar("complex"))

    def _scalar(self, what: str) -> Any:
        if self._a.size != 1:
            raise TypeError(f"only size-1 arrays can be converted to Python {what}s")
        host_reads.note("scalar")
        return self._a.reshape(()).item()

    # CuPy defines no __index__: a device array is no Python index (range, list[...])

    def __array_ufunc__(self, ufunc: np.ufunc, method: str, *inputs: Any, **kwargs: Any) -> Any:
        if method != "__call__" or ufunc.__name__ not in UFUNCS:
            return NotImplemented  # numpy raises TypeError, as with CuPy
        out = kwargs.get("out")
        outs = out if isinstance(out, tuple) else (() if out is None else (out,))
        if ufunc.__name__ in _CMP:  # CuPy's workaround: 0-d host arrays compare as scalars
            inputs = tuple(
                x.item() if isinstance(x, np.ndarray) and x.ndim == 0 else x for x in inputs
            )
        for x in (*inputs, *outs):
            if isinstance(x, np.ndarray) or _is_host_array(x):
                raise TypeError(f"Unsupported type {type(x)} in np.{ufunc.__name__}")
            if not isinstance(x, StrictArray | _SCALARS):
                return NotImplemented
        result = ufunc(*_raw(inputs), **_raw(kwargs))
        if outs:
            return outs[0] if len(outs) == 1 else outs
        return _wrap(result)

    def __array_function__(self, func: Callable, types: Any, args: Any, kwargs: Any) -> Any:
        name = func.__name__
        path = func.__module__.split(".")[1:]  # numpy.linalg -> ["linalg"]
        namespace: Any = xp
        for part in path:
            namespace = getattr(namespace, part, None)
        target = getattr(namespace, name, None) if namespace is not None else None
        if target is None:
            return NotImplemented  # numpy raises TypeError: CuPy has no counterpart
        return target(*args, **kwargs)

    # -- attributes ---------------------------------------------------------------------------
    shape = property(lambda self: self._a.shape)
    dtype = property(lambda self: self._a.dtype)
    ndim = property(lambda self: self._a.ndim)
    size = property(lambda self: self._a.size)
    strides = property(lambda self: self._a.strides)
    itemsize = property(lambda self: self._a.itemsize)
    nbytes = property(lambda self: self._a.nbytes)
    flags = property(lambda self: self._a.flags)
    T = property(lambda self: StrictArray(self._a.T))
    real = property(lambda self: StrictArray(self._a.real))
    imag = property(lambda self: StrictArray(self._a.imag))

    def __len__(self) -> int:
        if self._a.ndim == 0:
            raise TypeError("len() of unsized object")
        return len(self._a)

    def __repr__(self) -> str:
        return f"StrictArray({self._a!r})"

    def __str__(self) -> str:
        return str(self._a)

    def __format__(self, spec: str) -> str:
        return format(self._a, spec)

    # -- explicit copies to the host ------------------------------------------------------
    def get(self) -> np.ndarray:
        host_reads.note("copy")
        return self._a.copy()

    def item(self) -> Any:
        if self._a.size != 1:
            raise ValueError("can only convert an array of size 1 to a Python scalar")
        host_reads.note("scalar")
        return self._a.item()

    def tolist(self) -> Any:
        host_reads.note("copy")
        return self._a.tolist()

    # -- DLPack -------------------------------------------------------------------------------
    def __dlpack__(self, **kwargs: Any) -> Any:
        return self._a.__dlpack__(**kwargs)

    def __dlpack_device__(self) -> tuple[int, int]:
        return self._a.__dlpack_device__()

    # -- indexing -----------------------------------------------------------------------------
    def __getitem__(self, key: Any) -> Any:
        _check_index(key)
        return _wrap(self._a[_raw(key)])

    def __setitem__(self, key: Any, value: Any) -> None:
        _check_index(key)
        if _is_host_array(value) and np.ndim(value) > 0 and not _advanced(key):
            # CuPy fills basic-indexed targets: host arrays are refused there
            raise TypeError(f"a host array assigned to a device array's slice ({type(value)})")
        if not isinstance(value, StrictArray | _SCALARS | np.ndarray | list):
            _check(value, "assignment")
        if isinstance(value, np.ndarray | list) and np.ndim(value) > 0:
            uploads.note("value")
        self._a[_raw(key)] = _raw(value)

    def fill(self, value: Any) -> None:
        if isinstance(value, np.ndarray) and value.ndim > 0:
            raise ValueError("non-scalar numpy.ndarray cannot be used for fill")
        self._a.fill(_raw(value))

    def __neg__(self) -> StrictArray:
        return np.negative(self)

    def __pos__(self) -> StrictArray:
        return self

    def __abs__(self) -> StrictArray:
        return np.absolute(self)

    def __invert__(self) -> StrictArray:
        return np.invert(self)


def _method(name: str) -> Callable:
    def call(self: StrictArray, *args: Any, **kwargs: Any) -> Any:
        _check((args, kwargs), f"ndarray.{name}")
        if name in _SIZE_READS:
            host_reads.note("nonzero")
        out = kwargs.get("out")
        result = getattr(self._a, name)(*_raw(args), **_raw(kwargs))
        return out if isinstance(out, StrictArray) else _wrap(result)

    call.__name__ = name
    return call


# CuPy's ndarray methods that the package may use
for _name in (
    "astype copy reshape transpose ravel flatten squeeze swapaxes repeat take sum prod mean "
    "std var max min argmax argmin all any cumsum cumprod round clip nonzero dot conj view"
).split():
    setattr(StrictArray, _name, _method(_name))


def _operators(ufunc: np.ufunc) -> tuple[Callable, Callable, Callable]:
    """a op b, b op a, a op= b: through numpy's ufunc, so through ``__array_ufunc__``."""

    def op(self: StrictArray, other: Any) -> Any:
        return ufunc(self, other)

    def rop(self: StrictArray, other: Any) -> Any:
        return ufunc(other, self)

    def iop(self: StrictArray, other: Any) -> Any:
        return ufunc(self, other, out=(self,))

    return op, rop, iop


for _op, _uf in (
    ("add", np.add),
    ("sub", np.subtract),
    ("mul", np.multiply),
    ("truediv", np.true_divide),
    ("floordiv", np.floor_divide),
    ("mod", np.remainder),
    ("pow", np.power),
    ("and", np.bitwise_and),
    ("or", np.bitwise_or),
    ("xor", np.bitwise_xor),
    ("lshift", np.left_shift),
    ("rshift", np.right_shift),
    ("matmul", np.matmul),
):
    for _fmt, _fn in zip(("__{}__", "__r{}__", "__i{}__"), _operators(_uf), strict=True):
        setattr(StrictArray, _fmt.format(_op), _fn)
for _op, _uf in (
    ("eq", np.equal),
    ("ne", np.not_equal),
    ("lt", np.less),
    ("le", np.less_equal),
    ("gt", np.greater),
    ("ge", np.greater_equal),
):
    setattr(StrictArray, f"__{_op}__", _operators(_uf)[0])


def _advanced(key: Any) -> bool:
    keys = key if isinstance(key, tuple) else (key,)
    return any(isinstance(k, StrictArray | np.ndarray | list) for k in keys)


def _check_index(key: Any) -> None:
    """Indices: ints, slices, None, Ellipsis, device arrays, and host arrays or lists
    (CuPy copies them to the device); nothing else that converts to an array. A boolean
    array among them is a host read (CuPy reads how many are True)."""
    for k in key if isinstance(key, tuple) else (key,):
        if isinstance(k, StrictArray | np.ndarray) and k.dtype == bool and k.ndim > 0:
            host_reads.note("mask")
        if isinstance(k, np.ndarray | list):
            uploads.note("index")
        if isinstance(k, StrictArray | np.ndarray | list | slice | _SCALARS) or k is None:
            continue
        if k is Ellipsis:
            continue
        raise TypeError(f"unsupported index type {type(k).__name__}")


class _Namespace:
    """Attributes: the device functions (``FUNCTIONS``, ``UFUNCS``), creation, dtypes."""

    def __init__(self, names: dict[str, Any]) -> None:
        self.__dict__.update(names)

    def __repr__(self) -> str:
        return "<strict CuPy stand-in>"


def asarray(obj: Any, dtype: Any = None, order: Any = None) -> StrictArray:
    """To the device: a device array as it is (or cast), anything else copied."""
    if isinstance(obj, StrictArray):
        if dtype is None or np.dtype(dtype) == obj.dtype:
            return obj
        return StrictArray(obj._a.astype(dtype))
    _check_nested_device(obj)
    uploads.note("asarray")
    return StrictArray(np.array(obj, dtype=dtype, order=order or "K", copy=True))


def array(obj: Any, dtype: Any = None, copy: bool = True, order: Any = None) -> StrictArray:
    if isinstance(obj, StrictArray):
        return StrictArray(np.array(obj._a, dtype=dtype, copy=True, order=order or "K"))
    return asarray(obj, dtype, order)


def _check_nested_device(obj: Any) -> None:
    if isinstance(obj, list | tuple):
        for o in obj:
            if isinstance(o, StrictArray):
                raise TypeError("xp.asarray of a list holding device arrays: use xp.stack")


def ascontiguousarray(a: Any, dtype: Any = None) -> StrictArray:
    _check(a, "xp.ascontiguousarray")
    if not isinstance(a, StrictArray):
        raise TypeError(f"xp.ascontiguousarray takes a device array, got {type(a).__name__}")
    return StrictArray(np.ascontiguousarray(a._a, dtype=dtype))


def asnumpy(a: Any) -> np.ndarray:
    """The explicit copy to the host (``cupy.asnumpy``)."""
    return a.get() if isinstance(a, StrictArray) else np.asarray(a)


def from_dlpack(x: Any) -> StrictArray:
    """A device array sharing ``x``'s memory (``cupy.from_dlpack``)."""
    a = np.from_dlpack(x)
    return StrictArray(a if type(a) is np.ndarray else a.view(np.ndarray))


def _creation(fn: Callable, name: str) -> Callable:
    def call(*args: Any, **kwargs: Any) -> StrictArray:
        _check((args, kwargs), f"xp.{name}")
        return StrictArray(np.asarray(fn(*_raw(args), **_raw(kwargs))))

    call.__name__ = name
    return call


def _build() -> _Namespace:
    names: dict[str, Any] = {}
    for name in FUNCTIONS | UFUNCS:
        names[name] = _device_function(getattr(np, name), name)
    for name in ("zeros", "ones", "empty", "full", "arange", "linspace", "eye", "identity"):
        names[name] = _creation(getattr(np, name), name)
    for name in (
        "float16 float32 float64 int8 int16 int32 int64 uint8 uint32 uint64 bool_ "
        "complex64 complex128 dtype pi e inf nan newaxis"
    ).split():
        names[name] = getattr(np, name)
    names.update(
        ndarray=StrictArray,
        asarray=asarray,
        array=array,
        ascontiguousarray=ascontiguousarray,
        asnumpy=asnumpy,
        from_dlpack=from_dlpack,
        linalg=_Namespace({"norm": _device_function(np.linalg.norm, "linalg.norm")}),
    )
    return _Namespace(names)


xp = _build()

__all__ = ["FUNCTIONS", "UFUNCS", "StrictArray", "asnumpy", "host_reads", "uploads", "xp"]
