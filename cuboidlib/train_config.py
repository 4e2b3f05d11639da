"""The training configuration (Sec. 3.4.5): :class:`TrainConfig` and the committed networks' recipes.

The paper trains each category separately with Adam, learning rate 6e-4 and batch 32 for 1000 epochs: the
defaults of :class:`TrainConfig`. A recipe file (``data_samples/checkpoints/configs/<category>.json``) changes
some fields; :func:`course_config` reads it. The loop that uses the configuration is :mod:`cuboidlib.train`.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from ._checks import MAX_THREADS, check_int, check_seed, check_size
from .applications import checkpoint_dir
from .config import read_config_file
from .dataset import DataConfig
from .files import write_text_atomic
from .losses import LossConfig
from .model import ModelConfig

__all__ = [
    "TrainConfig",
    "course_config",
    "LR_SCHEDULES",
    "SELECTIONS",
    "RESUMABLE_CHANGES",
    "WEIGHT_NEUTRAL_FIELDS",
]

#: Learning-rate schedules: the paper's constant rate, or a half cosine down to ``lr_final`` over the run's steps
#: or over its time budget.
LR_SCHEDULES = ("constant", "cosine", "cosine_minutes")
#: Model selection (which weights ``best.pt`` holds): those of the lowest validation loss, or the last
#: validated ones (the end of a falling learning rate), with how a card names each.
SELECTIONS = {"validation_loss": "lowest validation loss", "last": "last weights"}
#: Fields of :class:`TrainConfig` that may change when a run is resumed (they do not change the
#: weights a step produces); every other field must equal the checkpoint's.
RESUMABLE_CHANGES = (
    "epochs", "max_steps", "max_minutes", "checkpoint_every", "validate_every", "device", "num_threads",
    "compiled_kernels",
)

#: Model settings that change no weight, so ``init_from`` may differ in them.
WEIGHT_NEUTRAL_FIELDS = ("affinity_temperature",)


@dataclass
class TrainConfig(DataConfig):
    """Everything a training run depends on; the defaults are the paper's (Sec. 3.4.5, Sec. 4.1).

    It extends :class:`~cuboidlib.dataset.DataConfig` (the data fields), so config files stay flat.

    Attributes:
        model, loss: :class:`ModelConfig` and :class:`LossConfig` as dicts (objects accepted; missing keys
            take their defaults).
        lr: Adam's learning rate (paper: 6e-4).
        lr_schedule: "constant" (the paper's); "cosine", a half cosine from ``lr`` to ``lr_final`` over the run's
            steps; or "cosine_minutes", the same over its ``max_minutes`` of training time, for a run that the
            clock ends (:meth:`Trainer.learning_rate`). Only the first two give the same run on every machine.
        lr_final: the last rate of the cosine schedules.
        lr_warmup_steps: W >= 0, a linear warm-up (the course's, not the paper's): step k's rate is the schedule's
            times (k + 1) / W for the first W steps, so that Adam's first steps from random weights are small.
            0: none.
        selection: the weights ``best.pt`` holds: "validation_loss", those of the lowest validation loss, or
            "last", the last validated ones (for a falling learning rate).
        temperature_start, temperature_steps: the allocation warm-up (the course's, not the paper's): the
            affinity of Eq. (2) is divided by a temperature falling geometrically from T_0 >= 1 to the model's
            ``affinity_temperature`` over S steps (:meth:`Trainer.affinity_temperature`); ``best.pt`` is
            chosen from step S on. S = 0: no warm-up.
        init_from: optional checkpoint whose weights start the run (a second stage).
        batch_size: shapes per step, the global batch under ``torchrun`` (paper: 32).
        epochs: passes over the training split (paper: 1000); max_steps: an optional cap on the steps.
        max_minutes: stop cleanly (and checkpoint) after this much training time, over every session of the run.
        checkpoint_every, validate_every: in steps.
        seed: of the initial weights, data order, loss and VAE sampling.
        device: "auto" (CUDA when available, else CPU), "cpu" or "cuda[:i]".
        num_threads: for ``torch.set_num_threads``; None: torch's default; "auto" (the command line's
            default): the cores other processes leave free (:class:`~cuboidlib.runs.CoreShare`); under
            ``torchrun``, an equal share of the cores for each process.
        compiled_kernels: run the CPU hot spots with :mod:`cuboidlib.kernels` (same results, faster);
            None: wherever a C++ compiler can build them; False: never.
    """

    model: dict = field(default_factory=lambda: ModelConfig().to_dict())
    loss: dict = field(default_factory=lambda: LossConfig().to_dict())
    lr: float = 6e-4
    lr_schedule: str = "constant"
    lr_final: float = 0.0
    lr_warmup_steps: int = 0
    selection: str = "validation_loss"
    temperature_start: float = 1.0
    temperature_steps: int = 0
    init_from: str | None = None
    batch_size: int = 32
    epochs: int = 1000
    max_steps: int | None = None
    max_minutes: float | None = None
    checkpoint_every: int = 100
    validate_every: int = 100
    seed: int = 0
    device: str = "auto"
    num_threads: int | str | None = None
    compiled_kernels: bool | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if isinstance(self.model, ModelConfig):
            self.model = self.model.to_dict()
        if isinstance(self.loss, LossConfig):
            self.loss = self.loss.to_dict()
        if not isinstance(self.model, dict) or not isinstance(self.loss, dict):
            raise ValueError("TrainConfig.model and TrainConfig.loss must be dicts (or ModelConfig / LossConfig)")
        self.model = ModelConfig.from_dict(self.model).to_dict()  # validates and fills in defaults
        self.loss = LossConfig.from_dict(self.loss).to_dict()
        for name in ("batch_size", "epochs", "checkpoint_every", "validate_every"):
            check_int(getattr(self, name), f"TrainConfig.{name}", minimum=1)
        check_int(self.seed, "TrainConfig.seed", minimum=0)
        check_seed(self.seed, "TrainConfig.seed")
        if self.compiled_kernels is not None and not isinstance(self.compiled_kernels, bool):
            raise ValueError(f"TrainConfig.compiled_kernels must be true, false or null (the default: used where they "
                             f"can be built), got {self.compiled_kernels!r}")
        if self.max_steps is not None:
            check_int(self.max_steps, "TrainConfig.max_steps", minimum=1)
        if self.num_threads is not None and self.num_threads != "auto":
            check_int(self.num_threads, "TrainConfig.num_threads (or \"auto\")", minimum=1)
            check_size(self.num_threads, "TrainConfig.num_threads", MAX_THREADS)
        if not (isinstance(self.lr, (int, float)) and math.isfinite(self.lr) and self.lr > 0):
            raise ValueError(f"TrainConfig.lr must be a positive number, got {self.lr!r}")
        self.lr = float(self.lr)
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValueError(f"TrainConfig.lr_schedule must be one of {LR_SCHEDULES}, got {self.lr_schedule!r}")
        if self.lr_schedule == "cosine_minutes" and self.max_minutes is None:
            raise ValueError('TrainConfig.lr_schedule "cosine_minutes" falls over max_minutes, which is None; '
                             'set max_minutes, or use "cosine" to fall over the steps')
        if not (isinstance(self.lr_final, (int, float)) and 0 <= self.lr_final <= self.lr):
            raise ValueError(f"TrainConfig.lr_final must be a number between 0 and lr ({self.lr}), got {self.lr_final!r}")
        self.lr_final = float(self.lr_final)
        if self.selection not in SELECTIONS:
            raise ValueError(f"TrainConfig.selection must be one of {tuple(SELECTIONS)}, got {self.selection!r}")
        t0 = self.temperature_start
        if isinstance(t0, bool) or not isinstance(t0, (int, float)) or not 1.0 <= t0 <= 100.0:
            raise ValueError(f"TrainConfig.temperature_start must be a number in [1, 100], got {t0!r}")
        self.temperature_start = float(t0)
        check_int(self.temperature_steps, "TrainConfig.temperature_steps", minimum=0)
        check_int(self.lr_warmup_steps, "TrainConfig.lr_warmup_steps", minimum=0)
        if self.init_from is not None:
            self.init_from = str(self.init_from)
        if self.max_minutes is not None:
            if not (isinstance(self.max_minutes, (int, float)) and self.max_minutes > 0):
                raise ValueError(f"TrainConfig.max_minutes must be a positive number or None, got {self.max_minutes!r}")
            self.max_minutes = float(self.max_minutes)
        if not isinstance(self.device, str) or not (self.device in ("auto", "cpu") or self.device.startswith("cuda")):
            raise ValueError(f"TrainConfig.device must be 'auto', 'cpu' or 'cuda[:i]', got {self.device!r}")

    @property
    def model_config(self) -> ModelConfig:
        """``model`` as a :class:`ModelConfig`."""
        return ModelConfig.from_dict(self.model)

    @property
    def loss_config(self) -> LossConfig:
        """``loss`` as a :class:`LossConfig`."""
        return LossConfig.from_dict(self.loss)

    def replace(self, **changes) -> "TrainConfig":
        """A copy with some fields changed.

        Args:
            **changes: new field values; ``model`` / ``loss`` dicts are merged into the current ones.

        Returns:
            A new, validated TrainConfig.
        """
        data = self.to_dict()
        for key in ("model", "loss"):
            if key in changes and isinstance(changes[key], dict):
                changes[key] = {**data[key], **changes[key]}
        data.update(changes)
        return TrainConfig.from_dict(data)

    def save_json(self, path: str | os.PathLike) -> Path:
        """Write the config as JSON.

        Args:
            path: the file to write (atomically; a symbolic link there is replaced, its target never written);
                its folder is created if missing.

        Returns:
            ``path`` as a Path.
        """
        return write_text_atomic(path, self.to_json())

    def to_json(self) -> str:
        """The text :meth:`save_json` writes.

        Returns:
            The config as indented JSON, with a final newline.
        """
        return json.dumps(self.to_dict(), indent=2) + "\n"

    @classmethod
    def load_json(cls, path: str | os.PathLike) -> "TrainConfig":
        """Read a JSON config file.

        Args:
            path: a JSON file of any subset of the fields (``model`` / ``loss`` may be partial).

        Returns:
            The config, defaults filled in.
        """
        return cls.from_dict(read_config_file(path))

    def run_defining(self) -> dict:
        """The fields that determine the weights of every step, as a dict (all but :data:`RESUMABLE_CHANGES`)."""
        return {k: v for k, v in self.to_dict().items() if k not in RESUMABLE_CHANGES}


def course_config(category: str, **changes) -> TrainConfig:
    """The recipe of the committed network of ``category``.

    Args:
        category: a category with a ``configs/<category>.json`` beside the committed checkpoints
            (:func:`cuboidlib.applications.checkpoint_dir`).
        **changes: fields to change, as :meth:`TrainConfig.replace`.

    Returns:
        The recipe file over the defaults of :class:`TrainConfig`, with ``changes`` on top.

    Example::

        >>> course_config("chair", max_minutes=5).model_config.num_cuboids
        16
    """
    path = checkpoint_dir() / "configs" / f"{category}.json"
    if not path.is_file():
        raise ValueError(f"no committed recipe for {category!r} ({path} does not exist); "
                         f"the categories with one: {sorted(p.stem for p in path.parent.glob('*.json'))}")
    config = TrainConfig.load_json(path)
    return config.replace(**changes) if changes else config
