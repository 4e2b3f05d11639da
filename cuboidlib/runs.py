"""Run bookkeeping around the loop of :mod:`cuboidlib.train`: processes, threads, full-state checkpoints, log,
divergence.

It lives apart so that train.py reads as the paper's Sec. 3.4.5. ``last.pt`` holds the weights, the Adam state,
the step and every rank's generator states (Eq. (5) offsets, Eq. (1) noise; the shape order is seeded by
``(seed, epoch)``), so a resumed run ends with bitwise the weights of an uninterrupted one (float32 on the CPU,
same thread count). Under ``torchrun`` rank r takes items r, r + W, ... of each global batch, only rank 0
validates and writes, and a run resumes with the number of processes that wrote it.
"""

from __future__ import annotations

import csv
import io
import os
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from .checkpoint import check_config_matches, save_checkpoint
from .files import write_text_atomic

__all__ = ["CoreShare", "Distributed", "TrainingDiverged", "TrainResult", "RunLog", "gather_rng_states", "check_finite_weights",
           "save_last", "check_resumable"]


class Distributed:
    """Rank, world size and whether this process started the process group.

    Read from the ``WORLD_SIZE``, ``RANK`` and ``LOCAL_RANK`` variables that ``torchrun`` sets (1, 0, 0 without it).
    """

    def __init__(self) -> None:
        self.world_size = int(os.environ.get("WORLD_SIZE", "1"))
        self.rank = int(os.environ.get("RANK", "0"))
        self.local_rank = int(os.environ.get("LOCAL_RANK", "0"))
        self.owns_group = False

    @property
    def enabled(self) -> bool:
        """Whether several processes train."""
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        """Whether this is rank 0, the process that validates and writes."""
        return self.rank == 0

    def start(self, device: torch.device) -> None:
        """Start the process group with several processes, unless one is started already.

        Args:
            device: this process's device; CUDA uses the nccl backend, the CPU gloo.
        """
        import torch.distributed as dist

        if not self.enabled or dist.is_initialized():
            return
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
        self.owns_group = True

    def wait(self) -> None:
        """Wait until every process gets here (a barrier; nothing without a process group).

        A run ends with it: rank 0 validates and saves after the last step, and no other process may go on
        (read that checkpoint for a second stage, or tear the group down) before it has.
        """
        import torch.distributed as dist

        if self.enabled and dist.is_initialized():
            dist.barrier()

    def stop(self) -> None:
        """Destroy the process group if this object started it."""
        import torch.distributed as dist

        if self.owns_group and dist.is_initialized():
            dist.destroy_process_group()
            self.owns_group = False


def _first_names(names: list[str]) -> str:
    return ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")


class TrainingDiverged(RuntimeError):
    """Raised when a loss term, a gradient or a weight becomes NaN or infinite; nothing is saved.

    Args:
        step: the step count at which the run diverged.
        bad: what became non-finite, e.g. ``["kl"]`` or ``["gradients (conv1.weight)"]``.
        values: the loss terms of that step, shown in the message.
        last_checkpoint: the sentence saying which checkpoint is kept (from :func:`save_last`).
    """

    def __init__(self, step: int, bad: list[str], values: dict[str, float] | None = None, last_checkpoint: str = ""):
        self.step, self.bad, self.values = step, bad, values or {}
        shown = ", ".join(f"{k}={v:.4g}" for k, v in self.values.items())
        msg = f"training diverged at step {step}: non-finite {', '.join(bad)}"
        if shown:
            msg += f" ({shown})"
        msg += f". Nothing was saved for this step; {last_checkpoint or 'no checkpoint had been written yet'}. "
        msg += "Try a smaller learning rate or check the data."
        super().__init__(msg)


@dataclass
class TrainResult:
    """Summary of :meth:`cuboidlib.train.Trainer.run`.

    Attributes:
        step, epoch: where the run stopped.
        stopped: why, "finished" or "time budget".
        best_val, best_step: the validation loss ``best.pt`` holds and its step (None before a validation).
        seconds: training seconds of every session of the run.
        last_terms: the loss terms and diagnostics of the last step.
        out_dir: the run folder.
    """

    step: int
    epoch: int
    stopped: str
    best_val: float | None
    best_step: int | None
    seconds: float
    last_terms: dict[str, float]
    out_dir: str


def check_finite_weights(model: torch.nn.Module, step: int, values: dict[str, float], last_saved: str) -> None:
    """Raise :class:`TrainingDiverged` if the update of ``step`` made a weight NaN or infinite.

    Args:
        model: the network after the optimiser step.
        step: the step's number, for the message.
        values: the step's loss terms, for the message.
        last_saved: the sentence on the kept checkpoint (:func:`save_last`).
    """
    params = list(model.parameters())
    if bool(torch.stack([torch.isfinite(p).all() for p in params]).all()):
        return
    bad = [name for name, p in model.named_parameters() if not bool(torch.isfinite(p).all())]
    raise TrainingDiverged(step, [f"weights after the update ({_first_names(bad)})"], values, last_saved)


def check_gradients(model: torch.nn.Module, step: int, values: dict[str, float], last_saved: str) -> None:
    """Raise :class:`TrainingDiverged` if a gradient is NaN or infinite; arguments as :func:`check_finite_weights`."""
    grads = [p.grad for p in model.parameters() if p.grad is not None]
    if bool(torch.stack([torch.isfinite(g).all() for g in grads]).all()):
        return
    names = [n for n, p in model.named_parameters() if p.grad is not None and not bool(torch.isfinite(p.grad).all())]
    raise TrainingDiverged(step, [f"gradients ({_first_names(names)})"], values, last_saved)


def gather_rng_states(generators: dict[str, torch.Generator], dist: Distributed,
                      device: torch.device) -> dict[str, list[torch.Tensor]]:
    """Every rank's state of each generator (a collective call when several processes train).

    Args:
        generators: ``{name: generator}`` of this rank.
        dist: the process group's :class:`Distributed`.
        device: this rank's device (nccl gathers CUDA tensors).

    Returns:
        ``{name: [state of rank 0, rank 1, ...]}``, uint8 CPU tensors.
    """
    mine = {k: g.get_state() for k, g in generators.items()}
    if not dist.enabled:
        return {k: [v] for k, v in mine.items()}
    import torch.distributed as tdist  # only with several processes

    out = {}
    for key, state in mine.items():
        state = state.to(device)  # nccl gathers CUDA tensors, gloo CPU ones
        gathered = [torch.empty_like(state) for _ in range(dist.world_size)]
        tdist.all_gather(gathered, state)
        out[key] = [g.cpu() for g in gathered]
    return out


def save_last(path: Path, config: dict, model: torch.nn.Module, optimizer, step: int, epoch: int,
              rng: dict, best_val, best_step, world_size: int, elapsed_seconds: float) -> str:
    """Write the full training state to ``path`` (``last.pt``) with :func:`cuboidlib.checkpoint.save_checkpoint`.

    Args:
        path: the file to write.
        config: the training config as a dict.
        model, optimizer: the network and its Adam optimiser.
        step, epoch: optimiser steps done and the current epoch.
        rng: the generator states of :func:`gather_rng_states`.
        best_val, best_step: the validation loss of ``best.pt`` and its step, or None.
        world_size: the number of training processes.
        elapsed_seconds: training seconds of every session so far.

    Returns:
        The sentence a :class:`TrainingDiverged` message uses to name the kept checkpoint.
    """
    save_checkpoint(path, config, model.state_dict(), optimizer=optimizer.state_dict(), step=step, epoch=epoch,
                    rng=rng, best_val=best_val, best_step=best_step, world_size=world_size,
                    elapsed_seconds=elapsed_seconds)
    return f"the last checkpoint (step {step}, {path}) is kept"


def check_resumable(state: dict, path: Path, stored: dict, requested: dict, resumable: tuple[str, ...],
                    stored_total: float, total_steps: int, lr_schedule: str, world_size: int) -> None:
    """Refuse to resume ``state`` (read from ``path``) unless only fields of ``resumable`` changed.

    Args:
        state: the checkpoint dict of ``last.pt``; path: its file, for messages.
        stored, requested: the checkpoint's training config and this run's, as dicts.
        resumable: the config fields that may differ.
        stored_total, total_steps: the step budgets of both, which the "cosine" schedule must share (as
            "cosine_minutes" must share ``max_minutes``).
        lr_schedule: this run's learning-rate schedule.
        world_size: this run's number of processes, which must equal the checkpoint's.

    Raises:
        ValueError: the checkpoint holds no training state, or the schedule's span or the process count differs.
        cuboidlib.checkpoint.CheckpointMismatch: a model or training field outside ``resumable`` differs.
    """
    missing = [k for k in ("optimizer", "step", "rng", "best_val", "elapsed_seconds") if k not in state]
    if missing:
        raise ValueError(f"{path} holds no training state (missing {missing}); "
                         "only a last.pt written by the trainer can be resumed")
    check_config_matches(stored["model"], requested["model"], "model config")
    check_config_matches({k: v for k, v in stored.items() if k not in resumable},
                         {k: v for k, v in requested.items() if k not in resumable}, "training config")
    if lr_schedule == "cosine" and stored_total != total_steps:
        raise ValueError(
            f"the {lr_schedule} learning-rate schedule spans the run's {stored_total} steps; "
            f"resume it with the same epochs / max_steps (this run asks for {total_steps} steps)"
        )
    if lr_schedule == "cosine_minutes" and stored.get("max_minutes") != requested.get("max_minutes"):
        raise ValueError(
            f"the {lr_schedule} learning-rate schedule spans the run's time budget of {stored.get('max_minutes')} "
            f"minutes; resume it with the same max_minutes (this run asks for {requested.get('max_minutes')})"
        )
    if state.get("world_size", 1) != world_size:
        raise ValueError(
            f"the checkpoint was written by a run of {state.get('world_size', 1)} process(es); resume it with "
            f"the same number (this run has {world_size}) to continue it exactly"
        )


class RunLog:
    """``log.csv``: one row per training step and one per validation, written by rank 0 only."""

    def __init__(self, path: Path, fields: tuple[str, ...], resume_step: int | None, enabled: bool):
        """Start the file, or on resume keep the rows up to ``resume_step`` and drop the later ones.

        Args:
            path: the ``log.csv`` file.
            fields: its columns.
            resume_step: the step a resumed run continues from; None for a new run.
            enabled: False on ranks other than 0, which write nothing.
        """
        self.path, self.fields, self.enabled = path, fields, enabled
        if not enabled:
            return
        rows = []
        if resume_step is not None and path.is_file() and not path.is_symlink():
            with path.open(newline="") as f:
                rows = [r for r in csv.DictReader(f) if int(r["step"]) <= resume_step]
        text = io.StringIO(newline="")
        writer = csv.DictWriter(text, fields, lineterminator="\r\n")
        writer.writeheader()
        writer.writerows(rows)
        write_text_atomic(path, text.getvalue())  # replaces a link there, never writes through it

    def write(self, step: int, epoch: int, split: str, values: dict[str, float], seconds: float) -> None:
        """Append one row.

        Args:
            step, epoch: where the run is.
            split: "train" or "val".
            values: loss terms, diagnostics and scores, by column name.
            seconds: training seconds of the run so far.
        """
        if not self.enabled:
            return
        row = {"step": step, "epoch": epoch, "split": split, **{k: f"{v:.6g}" for k, v in values.items()},
               "seconds": f"{seconds:.1f}"}
        text = io.StringIO(newline="")
        csv.DictWriter(text, self.fields, lineterminator="\r\n").writerow(row)
        try:  # O_NOFOLLOW: a link put there after the run started is refused, not written through
            fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | getattr(os, "O_NOFOLLOW", 0))
        except OSError as exc:
            raise OSError(f"{self.path}: cannot append to the run's log ({exc.strerror or exc}); it must stay the "
                          "plain file the run made (not a symbolic link)") from exc
        with os.fdopen(fd, "a", newline="") as f:
            f.write(text.getvalue())


class CoreShare:
    """Keeps torch's thread count at the number of cores that other processes leave free (at least 1).

    A thread on a core another process holds makes the others wait at every operation. The load of the other
    processes is read from ``/proc/stat`` (all busy time less this process's own); where it cannot be read
    (not Linux), torch's count is left as it is.

    Args:
        every_seconds: how often the load is read.
        cores: the cores to share (default: ``os.cpu_count()``).
    """

    def __init__(self, every_seconds: float = 2.0, cores: int | None = None):
        self.every = every_seconds
        self.cores = cores or os.cpu_count() or 1
        self.tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
        self.counts: dict[int, int] = {}  # thread count -> steps trained with it
        self._last = self._sample()

    def _sample(self) -> tuple[float, float, float] | None:
        """(wall seconds, busy seconds of all cores, this process's CPU seconds), or None without /proc/stat."""
        try:
            with open("/proc/stat") as f:
                fields = [float(v) for v in f.readline().split()[1:]]
        except (OSError, ValueError):
            return None
        busy = sum(fields) - fields[3] - (fields[4] if len(fields) > 4 else 0.0)  # all but idle and iowait
        return time.monotonic(), busy / self.tick, time.process_time()

    def step(self) -> int:
        """Count one training step and adjust the thread count for the next ones; call once per step.

        Returns:
            The thread count the step ran with.
        """
        threads = torch.get_num_threads()
        self.counts[threads] = self.counts.get(threads, 0) + 1
        now = self._sample()
        if now is None or self._last is None or now[0] - self._last[0] < self.every:
            return threads
        wall, busy, own = (a - b for a, b in zip(now, self._last))
        self._last = now
        others = max(0.0, (busy - own) / wall)  # cores in use by other processes
        wanted = max(1, min(self.cores, int(self.cores - others + 0.25)))
        if wanted != threads:
            torch.set_num_threads(wanted)
        return threads
