"""Input validation shared by every cuboidlib module, called once at a public function's entry.

Each check raises ``ValueError`` (``TypeError`` for a non-array) with a message that names the argument,
what was expected and what was received, so that bad input never becomes a silent wrong answer or a
stack trace from deep inside torch.
"""

from __future__ import annotations

from typing import Sequence

import torch

__all__ = [
    "as_float_tensor",
    "check_shape",
    "check_finite",
    "check_unit_vectors",
    "check_positive",
    "check_same_leading",
    "check_int",
    "check_size",
    "MAX_SHAPE_POINTS",
    "MAX_SHAPES",
    "MAX_COLLECTION_POINTS",
]

# The size limits: every path that samples, generates or allocates points or shapes checks its size with
# check_size before any work, so that a size too large is a clear error, not an allocator failure or an unbounded
# run. They admit the paper's scale (4,096 points per shape, 2,000 shapes) with a wide margin.

#: Points per shape: sampled on a mesh, kept of a point cloud, or a config's n_points; the same bound as normal
#: estimation (cuboidlib.normals.MAX_POINTS). Sampling an open mesh (normals oriented by visibility) costs most.
MAX_SHAPE_POINTS = 20_000
#: Shapes in one collection: a config's n_shapes, ``cuboidlib generate --count``.
MAX_SHAPES = 20_000
#: Points in one collection in all (n_shapes x n_points): 2^24, 4,096 shapes of 4,096 points, about 0.5 GB of
#: points, normals and labels.
MAX_COLLECTION_POINTS = 2**24


def as_float_tensor(x, name: str, dtype: torch.dtype | None = None, device=None) -> torch.Tensor:
    """``x`` as a floating-point tensor; numpy arrays and lists are converted.

    Args:
        x: a tensor or array-like of numbers. Integers become the default float dtype; float tensors keep
            their dtype and gradient history.
        name: the argument's name, for the message.
        dtype, device: convert to these (None: keep).

    Returns:
        The tensor (``x`` itself when it is a float tensor and nothing is converted).

    Raises:
        TypeError: ``x`` is not array-like.
    """
    if isinstance(x, torch.Tensor):
        t = x
    else:
        try:
            t = torch.as_tensor(x)
        except Exception as exc:  # noqa: BLE001 - re-raised with a clear message
            raise TypeError(f"{name} must be a tensor or array-like of numbers, got {type(x).__name__}") from exc
    if not t.is_floating_point():
        t = t.to(torch.get_default_dtype())
    if dtype is not None or device is not None:
        t = t.to(dtype=dtype or t.dtype, device=device or t.device)
    return t


def _fmt_shape(spec: Sequence) -> str:
    return "(" + ", ".join(str(s) for s in spec) + ")"


def check_shape(t: torch.Tensor, spec: Sequence, name: str) -> dict:
    """Check ``t.shape`` against ``spec`` and return the sizes bound to its symbols.

    Args:
        t: the tensor.
        spec: ints (exact sizes) and strings (symbols such as "B", "N"; a symbol twice must match).
        name: the argument's name, for the message.

    Returns:
        {symbol: size}. Example::

            sizes = check_shape(points, ("B", "N", 3), "points")   # -> {"B": 4, "N": 1024}
    """
    if t.dim() != len(spec):
        raise ValueError(
            f"{name} must have shape {_fmt_shape(spec)} ({len(spec)} dimensions), "
            f"got shape {tuple(t.shape)} ({t.dim()} dimensions)"
        )
    sizes: dict = {}
    for axis, (want, got) in enumerate(zip(spec, t.shape)):
        if isinstance(want, int):
            if got != want:
                raise ValueError(
                    f"{name} must have shape {_fmt_shape(spec)}, got {tuple(t.shape)} "
                    f"(dimension {axis} is {got}, expected {want})"
                )
        else:
            if want in sizes and sizes[want] != got:
                raise ValueError(
                    f"{name} must have shape {_fmt_shape(spec)}, got {tuple(t.shape)} "
                    f"(size {want} is both {sizes[want]} and {got})"
                )
            sizes[want] = got
    return sizes


def check_same_leading(named: dict, sizes: dict, what: str) -> None:
    """Check that the symbolic sizes of several arguments agree.

    Args:
        named: {argument name: the size dict :func:`check_shape` returned for it}.
        sizes: updated in place with every symbol.
        what: the operation's name, for the message.
    """
    for arg, s in named.items():
        for key, value in s.items():
            if key in sizes and sizes[key] != value:
                owner = next((a for a, d in named.items() if d.get(key) == sizes[key]), "another argument")
                raise ValueError(
                    f"{what}: size {key} of {arg} is {value} but {key} of {owner} is {sizes[key]}; "
                    "they must agree"
                )
            sizes[key] = value


def check_finite(t: torch.Tensor, name: str) -> None:
    """Raise if ``t`` holds NaN or infinite values, saying how many and where the first one is."""
    bad = ~torch.isfinite(t.detach())
    if bad.any():
        idx = tuple(int(i) for i in torch.nonzero(bad)[0])
        raise ValueError(
            f"{name} contains {int(bad.sum())} NaN or infinite value(s) (first at index {idx}); "
            "clean or drop those entries first"
        )


def check_unit_vectors(t: torch.Tensor, name: str, tol: float = 1e-3) -> None:
    """Raise if the last axis of ``t`` is not unit length within ``tol`` (zero vectors named)."""
    norms = torch.linalg.vector_norm(t.detach(), dim=-1)
    if (norms < 1e-12).any():
        idx = tuple(int(i) for i in torch.nonzero(norms < 1e-12)[0])
        raise ValueError(f"{name} contains zero-length vectors (first at index {idx}); unit vectors are required")
    err = (norms - 1).abs()
    if (err > tol).any():
        idx = tuple(int(i) for i in torch.nonzero(err > tol)[0])
        raise ValueError(
            f"{name} must hold unit vectors along the last axis; the vector at index {idx} has "
            f"length {float(norms[idx]):.6g} (normalise it first, e.g. x / x.norm(dim=-1, keepdim=True))"
        )


def check_positive(t: torch.Tensor, name: str, allow_zero: bool = False) -> None:
    """Raise if any entry of ``t`` is negative (or zero unless ``allow_zero``)."""
    bad = (t.detach() < 0) if allow_zero else (t.detach() <= 0)
    if bad.any():
        idx = tuple(int(i) for i in torch.nonzero(bad)[0])
        rule = "non-negative" if allow_zero else "positive"
        raise ValueError(f"{name} must be {rule}; the entry at index {idx} is {float(t.detach()[idx]):.6g}")


def check_int(value, name: str, minimum: int) -> None:
    """An integer (not a bool) of at least ``minimum``, else ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")


_LIMIT_NAMES = {MAX_SHAPE_POINTS: "MAX_SHAPE_POINTS", MAX_SHAPES: "MAX_SHAPES",
                MAX_COLLECTION_POINTS: "MAX_COLLECTION_POINTS"}


def check_size(value, name: str, limit: int, unit: str = "points") -> int:
    """A size to sample, generate or allocate: a whole number from 1 to ``limit``, checked before any work.

    Args:
        value: the size (an int, or a whole-valued integer type such as numpy's).
        name: the argument's name, for the message.
        limit: the largest accepted, one of the limits above.
        unit: what is counted, for the message.

    Returns:
        ``value`` as an int.

    Raises:
        ValueError: not a whole number, below 1 or above ``limit`` (naming the limit).
    """
    if isinstance(value, bool) or not hasattr(value, "__index__"):
        raise ValueError(f"{name} must be a whole number of {unit} from 1 to {limit:,}, got {value!r}")
    value = int(value.__index__())
    if value < 1:
        raise ValueError(f"{name} must be a positive number of {unit}, got {value}")
    if value > limit:
        where = _LIMIT_NAMES.get(limit)
        raise ValueError(f"{name} is {value:,} {unit}, above the limit of {limit:,}"
                         + (f" (cuboidlib._checks.{where})" if where else "")
                         + "; the work and memory grow with it. Use a smaller size")
    return value
