"""Plumbing shared by every configuration: the dict / JSON round trip, config files, seeds, devices, threads.

:class:`ConfigDict` gives the configuration dataclasses (:class:`~cuboidlib.model.ModelConfig`,
:class:`~cuboidlib.losses.LossConfig`, :class:`~cuboidlib.train_config.TrainConfig`) one ``to_dict`` /
``from_dict`` with one wording of its errors.

Example::

    >>> from cuboidlib.model import ModelConfig
    >>> ModelConfig.from_dict({"num_cuboids": 8}).num_cuboids
    8
"""

from __future__ import annotations

import dataclasses
import os
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch

from .files import read_json

__all__ = ["ConfigDict", "read_config_file", "derive_seed", "resolve_device", "torch_threads"]


def _json_types(value):
    """Tuples become lists, recursively (JSON has no tuples)."""
    if isinstance(value, (list, tuple)):
        return [_json_types(v) for v in value]
    if isinstance(value, dict):
        return {k: _json_types(v) for k, v in value.items()}
    return value


class ConfigDict:
    """Mixin for configuration dataclasses: ``to_dict`` (JSON types) and its inverse ``from_dict``."""

    def to_dict(self) -> dict:
        """The configuration as a dict of JSON types (tuples become lists)."""
        return _json_types(dataclasses.asdict(self))

    @classmethod
    def from_dict(cls, data: dict):
        """Inverse of :meth:`to_dict`; unknown keys are an error, missing keys take the defaults."""
        if not isinstance(data, dict):
            raise TypeError(f"{cls.__name__}.from_dict expects a dict, got {type(data).__name__}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown {cls.__name__} key(s) {unknown}; known keys are {sorted(known)}")
        return cls(**data)


def read_config_file(path: str | os.PathLike) -> dict:
    """The JSON object of a config file as it is: a partial config dict, checked where it is used.

    Args:
        path: the file.

    Returns:
        The dict.

    Raises:
        FileNotFoundError: no such file.
        ValueError: not UTF-8 text, not JSON, or not a JSON object.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such config file")
    data = read_json(path)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a config file must hold a JSON object, got {type(data).__name__}")
    return data


def derive_seed(*keys: int) -> int:
    """A 63-bit seed from non-negative integers; different keys give independent random streams.

    Args:
        *keys: non-negative integers.

    Returns:
        An int in [0, 2^63).
    """
    return int(np.random.SeedSequence([int(k) for k in keys]).generate_state(2, np.uint64)[0] >> np.uint64(1))


def resolve_device(name: str) -> torch.device:
    """The ``torch.device`` of a device name.

    Args:
        name: "auto" (CUDA when available, else the CPU), "cpu" or "cuda[:i]".

    Returns:
        The device.

    Raises:
        ValueError: another name, or CUDA asked for where there is none.
    """
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except (RuntimeError, TypeError) as exc:
        raise ValueError(f"device must be 'auto', 'cpu' or 'cuda[:i]', got {name!r}") from exc
    if device.type not in ("cpu", "cuda"):
        raise ValueError(f"device must be 'auto', 'cpu' or 'cuda[:i]', got {name!r}")
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {name!r} was requested but CUDA is not available; use 'cpu' or 'auto'")
    return device


@contextmanager
def torch_threads(count: int | None):
    """Run the block with ``count`` torch threads, then restore the count (a context manager).

    One shape is fitted or abstracted fastest with one thread; a second thread only waits when another
    process holds the other core (``python benchmarks/bench_abstract.py`` measures both).

    Args:
        count: the number of threads, or None to leave it as it is.
    """
    before = torch.get_num_threads()
    if count is not None and count != before:
        torch.set_num_threads(count)
    try:
        yield
    finally:
        if torch.get_num_threads() != before:
            torch.set_num_threads(before)
