"""Checkpoints of the network: weights, configuration and training state (Sec. 3.4.5).

A checkpoint is a ``torch.save`` file of tensors, dicts, lists, tuples, strings, numbers, booleans and None
only, so it loads with ``torch.load(path, weights_only=True)``, which runs no code hidden in a file. Keys:

* ``format`` (``"cuboidlib-checkpoint"``), ``format_version``, ``library_version``;
* ``config``: the training config as JSON types (:class:`cuboidlib.train_config.TrainConfig`), whose ``"model"``
  entry is the :class:`~cuboidlib.model.ModelConfig` dict;
* ``model``: the network's ``state_dict``;
* training state (from the trainer): ``optimizer``, ``step``, ``epoch``, ``rng`` (generator states as uint8
  tensors), ``best_val``, ``best_step``, ``world_size``, ``elapsed_seconds``.

Files are written atomically (temporary file, then rename). Loading refuses a stored model config that
differs from the requested one, and loads weights with ``strict=True``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import torch

from . import __version__
from .files import atomic_path
from .model import CuboidAbstractionNet, ModelConfig

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "CheckpointMismatch",
    "config_differences",
    "check_config_matches",
    "check_checkpoint_values",
    "save_checkpoint",
    "load_checkpoint",
    "load_model",
]

FORMAT = "cuboidlib-checkpoint"
FORMAT_VERSION = 1
_REQUIRED = ("format", "format_version", "library_version", "config", "model")


class CheckpointMismatch(ValueError):
    """A checkpoint's stored configuration differs from the one requested."""


def config_differences(stored: dict, requested: dict, prefix: str = "") -> list[str]:
    """The entries where two (nested) config dicts differ, as readable lines.

    Lists and tuples compare equal when their items do (JSON turns tuples into lists).

    Args:
        stored: the checkpoint's config dict.
        requested: the config asked for.
        prefix: prepended to every key name (``"model."`` for a nested dict).

    Returns:
        One line per difference, e.g. ``"k: checkpoint has 20, requested 16"``; empty if the dicts agree.
    """
    out = []
    for key in sorted(set(stored) | set(requested)):
        name = f"{prefix}{key}"
        if key not in stored:
            out.append(f"{name}: missing in the checkpoint, requested {requested[key]!r}")
        elif key not in requested:
            out.append(f"{name}: {stored[key]!r} in the checkpoint, not in the requested config")
        elif isinstance(stored[key], dict) and isinstance(requested[key], dict):
            out.extend(config_differences(stored[key], requested[key], name + "."))
        elif _normalise(stored[key]) != _normalise(requested[key]):
            out.append(f"{name}: checkpoint has {stored[key]!r}, requested {requested[key]!r}")
    return out


def _normalise(value):
    if isinstance(value, (list, tuple)):
        return [_normalise(v) for v in value]
    return value


def check_config_matches(stored: dict, requested: dict, what: str) -> None:
    """Raise :class:`CheckpointMismatch` listing every difference between ``stored`` and ``requested``.

    Args:
        stored, requested: config dicts, as for :func:`config_differences`.
        what: the name of the config in the message, e.g. ``"model config"``.
    """
    diffs = config_differences(stored, requested)
    if diffs:
        raise CheckpointMismatch(
            f"{what} does not match the checkpoint ({len(diffs)} difference(s)): " + "; ".join(diffs)
        )


def _check_plain(value, where: str) -> None:
    """Refuse anything ``torch.load(weights_only=True)`` could not read back (or that needs code)."""
    if value is None or isinstance(value, (bool, int, float, str, torch.Tensor)):
        return
    if isinstance(value, dict):
        for k, v in value.items():
            if not isinstance(k, (str, int)):
                raise TypeError(f"checkpoint entry {where} has a key of type {type(k).__name__}; use str or int keys")
            _check_plain(v, f"{where}.{k}")
        return
    if isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            _check_plain(v, f"{where}[{i}]")
        return
    raise TypeError(
        f"checkpoint entry {where} is a {type(value).__name__}; only tensors, dicts, lists, tuples, str, "
        "int, float, bool and None may be stored"
    )


def check_checkpoint_values(state: dict) -> None:
    """Raise ``ValueError`` if a floating-point value of ``state["model"]`` or ``state["optimizer"]`` is NaN or inf.

    Used before writing, so that a diverged state is never saved over a good checkpoint.

    Args:
        state: a checkpoint dict; its other entries are not looked at.
    """

    def visit(value, where: str) -> None:
        if isinstance(value, torch.Tensor):
            if value.is_floating_point() and not bool(torch.isfinite(value).all()):
                raise ValueError(f"checkpoint entry {where} holds NaN or infinite values; refusing to save it")
        elif isinstance(value, float):
            if not math.isfinite(value):
                raise ValueError(f"checkpoint entry {where} is {value}; refusing to save it")
        elif isinstance(value, dict):
            for k, v in value.items():
                visit(v, f"{where}.{k}")
        elif isinstance(value, (list, tuple)):
            for i, v in enumerate(value):
                visit(v, f"{where}[{i}]")

    for key in ("model", "optimizer"):
        if key in state:
            visit(state[key], key)


def save_checkpoint(path: str | os.PathLike, config: dict, model_state: dict, **extra) -> Path:
    """Write a checkpoint atomically.

    Args:
        path: the file to write; its folder is created if missing.
        config: the training config dict (JSON types, with a ``"model"`` entry).
        model_state: the network's ``state_dict``; its tensors are stored on the CPU.
        **extra: further entries (optimizer state, step, generator states, ...).

    Returns:
        ``path`` as a Path.

    Raises:
        TypeError: a value that ``torch.load(weights_only=True)`` could not read back.
        ValueError: NaN or infinite weights or optimizer moments.
    """
    path = Path(path)
    state = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "library_version": __version__,
        "config": config,
        "model": {k: v.detach().cpu() for k, v in model_state.items()},
        **extra,
    }
    _check_plain(state, "checkpoint")
    check_checkpoint_values(state)
    with atomic_path(path) as tmp:  # a unique temporary name: two writers never share one
        torch.save(state, tmp)
    return path


def load_checkpoint(path: str | os.PathLike, map_location: str | torch.device = "cpu") -> dict:
    """Read a checkpoint with ``torch.load(weights_only=True)`` and check that it is one of ours.

    Args:
        path: the checkpoint file.
        map_location: where its tensors are loaded.

    Returns:
        The checkpoint dict (keys in the module docstring).

    Raises:
        FileNotFoundError: no such file.
        ValueError: not a readable cuboidlib checkpoint, or one of a newer format version.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such checkpoint file")
    try:
        state = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any failure to read means: not a checkpoint we can load safely
        raise ValueError(
            f"{path}: not a readable cuboidlib checkpoint (it must load with torch.load(weights_only=True)): {exc}"
        ) from exc
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise ValueError(f"{path}: not a cuboidlib checkpoint (no format tag {FORMAT!r})")
    missing = [k for k in _REQUIRED if k not in state]
    if missing:
        raise ValueError(f"{path}: checkpoint misses the entries {missing}")
    version = state["format_version"]
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise ValueError(f"{path}: checkpoint format_version must be a whole number >= 1, got {version!r}; "
                         "the file is damaged or not written by cuboidlib")
    if state["format_version"] > FORMAT_VERSION:
        raise ValueError(
            f"{path}: checkpoint format version {state['format_version']} is newer than this library's "
            f"({FORMAT_VERSION}); update cuboidlib"
        )
    if not isinstance(state["config"], dict) or not isinstance(state["config"].get("model"), dict):
        raise ValueError(f"{path}: checkpoint config has no 'model' entry")
    return state


def load_model(
    path: str | os.PathLike,
    config: ModelConfig | None = None,
    device: str | torch.device = "cpu",
) -> tuple[CuboidAbstractionNet, dict]:
    """Build the network stored in a checkpoint and load its weights (strict), in evaluation mode.

    Args:
        path: the checkpoint file.
        config: the model config you expect; a checkpoint whose stored one differs is refused with
            :class:`CheckpointMismatch`. None: use the stored one.
        device: where the network is built.

    Returns:
        ``(model, checkpoint dict)``.
    """
    state = load_checkpoint(path, map_location=device)
    stored = state["config"]["model"]
    try:
        model_config = ModelConfig.from_dict(stored)  # sizes are bounded here, before any allocation
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: the stored model config is not usable: {exc}") from exc
    if config is not None:  # compared with defaults filled in, so older checkpoints compare equal
        check_config_matches(model_config.to_dict(), config.to_dict(), f"model config requested for {path}")
    model = CuboidAbstractionNet(model_config).to(device)
    try:
        model.load_state_dict(state["model"], strict=True)
    except RuntimeError as exc:
        raise ValueError(f"{path}: the stored weights do not fit the stored model config: {exc}") from exc
    broken = [name for name, value in state["model"].items()
              if isinstance(value, torch.Tensor) and value.is_floating_point() and not bool(torch.isfinite(value).all())]
    if broken:
        raise ValueError(f"{path}: the checkpoint's weights hold NaN or infinite values ({len(broken)} tensor(s), "
                         f"first {broken[0]!r}); the checkpoint is damaged (its run diverged), not your input")
    model.eval()
    return model, state
