"""A cloned network's whole decision, observation to action, as one compiled function.

One generated-C function of (obs, mean, inv_std, clip, weights): the features with
normalization and clipping (``features.inputs_sx``), the layers, and the output
(clip(a_ss + out, -1, 1) on ``features``, tanh(out) otherwise), called through
preallocated buffers (``features.CompiledInputs`` with ``fn``).

The layers of a network without hidden layers are CasADi expressions. Hidden layers are
a C loop nest generated here for the network's widths (``dense_c``), put in the CasADi
function as a node that exists only as generated code (``casadi.Function.jit`` with
``jit`` off: nothing is compiled when it is built, and ``compile_function`` compiles it
with the rest); CasADi's own SX or MX layers are several times slower
(docs/imitation.md). The loop nest keeps 128 partial sums in registers (a block of 32
outputs, 4 interleaved sums each) while it streams the block's weights, in float32 (the
weights as trained; the inputs come in as float64 and are rounded once), and the hidden
tanh is a rational approximation (``TANH_P`` / ``TANH_Q``). The weights are an input
(``pack_layers``), not constants of the code: one library serves every network of an
architecture (training seeds, DAgger iterations, checkpoints), and a new model compiles
nothing.

The node cannot run uncompiled: where nothing is compiled (``UVMS_ENV_NO_COMPILE``, no C
compiler) ``decision_function`` returns None for networks with hidden layers and the
policy keeps its numpy layers.

May import: numpy, casadi, ``uvms_env.dynamics.compiled`` and this package's features.
"""

from __future__ import annotations

import hashlib

import casadi as cs
import numpy as np

from baselines.networks.features import inputs_sx
from uvms_env.dynamics.compiled import compile_function

# tanh(x) ~ x P(x^2) / Q(x^2) on [-9, 9], and +-tanh(9) beyond (1 - tanh(9) = 3e-8):
# a least-squares fit of the linearized residual, reweighted towards the largest errors.
# Max error 3.5e-8 in float64 arithmetic and 3.5e-7 in float32 (torch's float32 tanh:
# ~1e-7); every coefficient is positive, so Q never nears zero.
TANH_LIMIT = 9.0
TANH_P = (0.9999999, 0.13373171, 0.0034865495, 2.0471294e-05, 1.318347e-08)
TANH_Q = (1.0, 0.46706468, 0.025841856, 0.00032713322, 7.702357e-07)
BLOCK = 32  # outputs per block of the generated layers (see dense_c)
ACCUMULATORS = 128  # partial sums per block: 8 AVX-512 registers


def _horner(coefs: tuple[float, ...], var: str) -> str:
    expr = f"{coefs[-1]!r}f"
    for c in coefs[-2::-1]:
        expr = f"{c!r}f+{var}*({expr})"
    return expr


def _pad(n: int, multiple: int) -> int:
    return -(-n // multiple) * multiple


def layer_widths(layers: list[np.ndarray]) -> tuple[int, ...]:
    """The widths (inputs, then each layer's outputs) of ``layers`` ((n + 1, m) weights
    with the bias as the last row). Raises ValueError where the shapes do not chain."""
    widths = (len(layers[0]) - 1, *(w.shape[1] for w in layers))
    if any(w.shape[0] != n + 1 for w, n in zip(layers, widths, strict=False)):
        raise ValueError(f"layer shapes {[w.shape for w in layers]} do not chain")
    return widths


def _plan(widths: tuple[int, ...]) -> tuple[list[int], list[int], list[int]]:
    """Per layer: outputs per block, interleaved sums per output, padded input count."""
    blocks = [next(b for b in (BLOCK, 16, 8, 4, 2, 1) if m % b == 0) for m in widths[1:]]
    parts = [max(1, ACCUMULATORS // b) for b in blocks]
    padded = [_pad(n, p) for n, p in zip(widths, parts, strict=False)]
    return blocks, parts, padded


def pack_layers(layers: list[np.ndarray]) -> np.ndarray:
    """The weights input of ``dense_c``'s code: per layer, its float32 weights padded and
    stored block by block, input by input, then its biases; the float32 words carried in
    float64 ones (CasADi's inputs are doubles; the code reads the float32 back, bit for
    bit), an odd count padded with a zero."""
    widths = layer_widths(layers)
    blocks, _, padded = _plan(widths)
    chunks = []
    for i, (layer, b) in enumerate(zip(layers, blocks, strict=True)):
        n, m = widths[i], widths[i + 1]
        weights = np.zeros((padded[i], m), dtype=np.float32)
        weights[:n] = layer[:n]
        chunks += [weights.reshape(padded[i], m // b, b).transpose(1, 0, 2).ravel()]
        chunks += [np.asarray(layer[n], dtype=np.float32)]
    words = np.concatenate(chunks)
    if len(words) % 2:
        words = np.append(words, np.float32(0))
    return np.ascontiguousarray(words).view(np.float64).copy()


def packed_size(widths: tuple[int, ...]) -> int:
    """The float64 words of ``pack_layers`` for a network of ``widths``."""
    _, _, padded = _plan(widths)
    words = sum(p * m + m for p, m in zip(padded, widths[1:], strict=False))
    return -(-words // 2)


def dense_c(widths: tuple[int, ...], x: str = "z", weights: str = "weights", y: str = "y") -> str:
    """C statements for an MLP of ``widths`` from the double array ``x`` into the double
    array ``y``, its weights read from ``weights`` (``pack_layers``): tanh after every
    layer but the last, float32 arithmetic.

    Outputs go in blocks of up to ``BLOCK``; each block keeps ``ACCUMULATORS`` partial
    sums in registers (``parts`` interleaved sums over the inputs per output, so that
    enough independent multiply-add chains hide their latency) while it streams its
    weights, stored block by block, input by input. Inputs are padded with zeros to a
    multiple of ``parts``."""
    blocks, parts, padded = _plan(widths)
    padded = [*padded, widths[-1]]  # the layers' inputs, then the output
    code = [
        "{",
        # float32 words in a double array: may_alias tells the compiler they are read so
        "  typedef float __attribute__((may_alias)) uvms_weight;",
        f"  const uvms_weight* packed = (const uvms_weight*) {weights};",
        "  int j0, j, k, p;",
        "  const uvms_weight *w;",
    ]
    code += [f"  float h{i}[{n}];" for i, n in enumerate(padded)]
    offset = 0
    for i in range(len(widths) - 1):
        m = widths[i + 1]
        code.append(f"  const uvms_weight* w{i} = packed + {offset};")
        offset += padded[i] * m
        code.append(f"  const uvms_weight* b{i} = packed + {offset};")
        offset += m
    code.append(f"  for (k = 0; k < {widths[0]}; ++k) h0[k] = (float) {x}[k];")
    code += [
        f"  for (k = {n}; k < {pn}; ++k) h{i}[k] = 0;"
        for i, (n, pn) in enumerate(zip(widths[:-1], padded[:-1], strict=True))
        if pn > n
    ]
    for i, (b, np_) in enumerate(zip(blocks, parts, strict=True)):
        m, last = widths[i + 1], i == len(widths) - 2
        total = "+".join(f"a[{q * b} + j]" for q in range(np_))
        if last:
            store = f"h{i + 1}[j0 + j] = {total};"
        else:
            store = (
                f"const float t0 = {total};\n"
                f"      const float t = t0 > {TANH_LIMIT}f ? {TANH_LIMIT}f"
                f" : (t0 < -{TANH_LIMIT}f ? -{TANH_LIMIT}f : t0);\n"
                "      const float s = t * t;\n"
                f"      h{i + 1}[j0 + j] = t * ({_horner(TANH_P, 's')}) / ({_horner(TANH_Q, 's')});"
            )
        code += [
            f"  for (j0 = 0, w = w{i}; j0 < {m}; j0 += {b}) {{",
            f"    float a[{np_ * b}];",
            f"    for (j = 0; j < {b}; ++j) a[j] = b{i}[j0 + j];",
            f"    for (j = {b}; j < {np_ * b}; ++j) a[j] = 0;",
            f"    for (k = 0; k < {padded[i]}; k += {np_}, w += {np_ * b})",
            f"      for (p = 0; p < {np_}; ++p)",
            f"        for (j = 0; j < {b}; ++j) a[p * {b} + j] += w[p * {b} + j] * h{i}[k + p];",
            f"    for (j = 0; j < {b}; ++j) {{",
            f"      {store}",
            "    }",
            "  }",
        ]
    code.append(f"  for (j = 0; j < {widths[-1]}; ++j) {y}[j] = h{len(widths) - 1}[j];")
    code.append("}")
    return "\n".join(code) + "\n"


def architecture_tag(widths: tuple[int, ...]) -> str:
    """A network's widths in a function name: ``w95_128_128_8``."""
    return "w" + "_".join(map(str, widths))


def layers_digest(layers: list[np.ndarray]) -> str:
    h = hashlib.sha256()
    for w in layers:
        h.update(np.ascontiguousarray(w, dtype=float).tobytes())
    return h.hexdigest()[:12]


def linear_decision_function(
    features: str, object_key: float, weights: np.ndarray, residual: bool, dim: int
) -> cs.Function:
    """Compiled (obs, mean, inv_std, clip) -> action of a network without hidden layers:
    clip(a_ss + W' [z; 1], -1, 1) (residual) or tanh(W' [z; 1]); ``weights`` (n + 1, 8)
    with the bias as the last row. A few hundred multiply-adds: as CasADi expressions
    they cost less than one numpy call."""
    args, z, ff, tag = inputs_sx(features, object_key, dim)
    out = cs.mtimes(cs.DM(np.asarray(weights, dtype=float).T), cs.vertcat(z, 1.0))
    act = cs.fmin(1.0, cs.fmax(-1.0, ff + out)) if residual else cs.tanh(out)
    name = f"cloned_linear_{tag}_{layers_digest([weights])}"
    return compile_function(cs.Function(name, args, [act], {"cse": True}))


_MLP_CACHE: dict[tuple, cs.Function] = {}


def network_graph(name: str, z: cs.SX, widths: tuple[int, ...]) -> tuple[cs.SX, cs.SX]:
    """The layers of a network of ``widths`` (``dense_c``) applied to the network input
    ``z``: (the packed weights' symbol (``pack_layers``), the network's output). The
    layers are one call node of the SX graph: the generated code hands the node the
    weights input's own pointer (no copy per call) and ``z`` from its work array."""
    weights = cs.SX.sym("weights", packed_size(widths))
    layers_fn = cs.Function.jit(
        f"{name}_layers",
        dense_c(widths),
        ["z", "weights"],
        ["y"],
        [cs.Sparsity.dense(widths[0]), weights.sparsity()],
        [cs.Sparsity.dense(widths[-1])],
        # generated code only (see the module docstring), reading its inputs in place
        {"jit": False, "buffered": False},
    )
    return weights, layers_fn.call([z, weights], False, True)[0]


def mlp_decision_function(
    features: str, object_key: float, widths: tuple[int, ...], residual: bool, dim: int
) -> cs.Function | None:
    """Compiled (obs, mean, inv_std, clip, weights) -> action of an MLP of ``widths``
    (the last 8; ``weights``: its ``pack_layers``), or None where nothing is compiled.
    One library per feature set, object, widths and output: every network of that
    architecture decides through it with its own weights."""
    key = (features, object_key, dim, residual, widths)
    if key in _MLP_CACHE:  # spares generating and hashing the source again per robot
        return _MLP_CACHE[key]
    args, z, ff, tag = inputs_sx(features, object_key, dim)
    name = f"cloned_mlp_{tag}_{architecture_tag(widths)}{'_residual' if residual else ''}"
    weights, out = network_graph(name, z, widths)
    act = cs.fmin(1.0, cs.fmax(-1.0, ff + out)) if residual else cs.tanh(out)
    fn = cs.Function(name, [*args, weights], [act], {"cse": True})
    compiled = compile_function(fn)
    if compiled is fn:  # not compiled (see the module docstring)
        return None
    _MLP_CACHE[key] = compiled
    return compiled


def decision_function(
    features: str, object_key: float, layers: list[np.ndarray], residual: bool, dim: int
) -> tuple[cs.Function, tuple[np.ndarray, ...]] | None:
    """The whole decision of a network given by its ``layers`` (see ``pack_layers``): one
    compiled function of (obs, mean, inv_std, clip, *inputs) and those further inputs
    (the packed weights of an MLP; none for a linear map, whose weights are in its
    code), or None (see the module docstring)."""
    if len(layers) == 1:
        return linear_decision_function(features, object_key, layers[0], residual, dim), ()
    fn = mlp_decision_function(features, object_key, layer_widths(layers), residual, dim)
    return None if fn is None else (fn, (pack_layers(layers),))
