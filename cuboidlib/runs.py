"""Run bookkeeping around the training loop: processes, checkpoints of the full state, the log, divergence.

:mod:`cuboidlib.train` reads as the paper's Sec. 3.4.5; what a run needs besides (resuming bitwise, several
processes under ``torchrun``, ``log.csv``) lives here.

Determinism: randomness comes from the shape order (a permutation per epoch, seeded by ``(seed, epoch)``), the
offsets along the normals of Eq. (5) and the VAE noise of Eq. (1) (one generator each). ``last.pt`` stores the
weights, the Adam state, the step and every rank's generator states, so a resumed run ends with bitwise the
weights of an uninterrupted one (float32 on the CPU, same thread count).

Several processes: rank r takes the items r, r + W, ... of every global batch; gradients are averaged, only
rank 0 validates and writes, and a run is resumed with the number of processes that wrote it.
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from pathlib import Path

import torch

from .checkpoint import check_config_matches, save_checkpoint

__all__ = ["Distributed", "TrainingDiverged", "TrainResult", "RunLog", "gather_rng_states", "check_finite_weights",
           "save_last", "check_resumable"]


class Distributed:
    """Rank, world size and whether this process started the process group."""

    def __init__(self) -> None:
        self.world_size = int(os.environ.get("WORLD_SIZE", "1"))
        self.rank = int(os.environ.get("RANK", "0"))
        self.local_rank = int(os.environ.get("LOCAL_RANK", "0"))
        self.owns_group = False

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    def start(self, device: torch.device) -> None:
        import torch.distributed as dist

        if not self.enabled or dist.is_initialized():
            return
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
        self.owns_group = True

    def stop(self) -> None:
        import torch.distributed as dist

        if self.owns_group and dist.is_initialized():
            dist.destroy_process_group()
            self.owns_group = False


def _first_names(names: list[str]) -> str:
    return ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")


class TrainingDiverged(RuntimeError):
    """Raised when a loss term, a gradient or a weight becomes NaN or infinite; nothing is saved."""

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
    """Summary of :meth:`Trainer.run`: where it stopped and why ("finished" or "time budget")."""

    step: int
    epoch: int
    stopped: str
    best_val: float | None
    best_step: int | None
    seconds: float
    last_terms: dict[str, float]
    out_dir: str


def check_finite_weights(model: torch.nn.Module, step: int, values: dict[str, float], last_saved: str) -> None:
    """Raise :class:`TrainingDiverged` if the update of ``step`` made a weight NaN or infinite."""
    params = list(model.parameters())
    if bool(torch.stack([torch.isfinite(p).all() for p in params]).all()):
        return
    bad = [name for name, p in model.named_parameters() if not bool(torch.isfinite(p).all())]
    raise TrainingDiverged(step, [f"weights after the update ({_first_names(bad)})"], values, last_saved)


def check_gradients(model: torch.nn.Module, step: int, values: dict[str, float], last_saved: str) -> None:
    """Raise :class:`TrainingDiverged` if a gradient is NaN or infinite."""
    grads = [p.grad for p in model.parameters() if p.grad is not None]
    if bool(torch.stack([torch.isfinite(g).all() for g in grads]).all()):
        return
    names = [n for n, p in model.named_parameters() if p.grad is not None and not bool(torch.isfinite(p.grad).all())]
    raise TrainingDiverged(step, [f"gradients ({_first_names(names)})"], values, last_saved)


def gather_rng_states(generators: dict[str, torch.Generator], dist: Distributed,
                      device: torch.device) -> dict[str, list[torch.Tensor]]:
    """Every rank's state of each generator, {name: [state of rank 0, rank 1, ...]} (collective with DDP)."""
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
    """Write the full training state to ``path`` (``last.pt``); returns the sentence a divergence message uses."""
    save_checkpoint(path, config, model.state_dict(), optimizer=optimizer.state_dict(), step=step, epoch=epoch,
                    rng=rng, best_val=best_val, best_step=best_step, world_size=world_size,
                    elapsed_seconds=elapsed_seconds)
    return f"the last checkpoint (step {step}, {path}) is kept"


def check_resumable(state: dict, path: Path, stored: dict, requested: dict, resumable: tuple[str, ...],
                    stored_total: float, total_steps: int, lr_schedule: str, world_size: int) -> None:
    """Refuse to resume ``state`` (read from ``path``) unless only fields of ``resumable`` changed.

    Args:
        stored, requested: the checkpoint's training config and this run's, as dicts.
        stored_total, total_steps: the step budgets of both, which a non-constant schedule must share.
    """
    missing = [k for k in ("optimizer", "step", "rng", "best_val", "elapsed_seconds") if k not in state]
    if missing:
        raise ValueError(f"{path} holds no training state (missing {missing}); "
                         "only a last.pt written by the trainer can be resumed")
    check_config_matches(stored["model"], requested["model"], "model config")
    check_config_matches({k: v for k, v in stored.items() if k not in resumable},
                         {k: v for k, v in requested.items() if k not in resumable}, "training config")
    if lr_schedule != "constant" and stored_total != total_steps:
        raise ValueError(
            f"the {lr_schedule} learning-rate schedule spans the run's {stored_total} steps; "
            f"resume it with the same epochs / max_steps (this run asks for {total_steps} steps)"
        )
    if state.get("world_size", 1) != world_size:
        raise ValueError(
            f"the checkpoint was written by a run of {state.get('world_size', 1)} process(es); resume it with "
            f"the same number (this run has {world_size}) to continue it exactly"
        )


class RunLog:
    """``log.csv``: one row per training step and one per validation, written by rank 0 only."""

    def __init__(self, path: Path, fields: tuple[str, ...], resume_step: int | None, enabled: bool):
        """Start the file, or on resume keep the rows up to ``resume_step`` and drop the later ones."""
        self.path, self.fields, self.enabled = path, fields, enabled
        if not enabled:
            return
        rows = []
        if resume_step is not None and path.is_file():
            with path.open(newline="") as f:
                rows = [r for r in csv.DictReader(f) if int(r["step"]) <= resume_step]
        with path.open("w", newline="") as f:
            writer = csv.DictWriter(f, fields)
            writer.writeheader()
            writer.writerows(rows)

    def write(self, step: int, epoch: int, split: str, values: dict[str, float], seconds: float) -> None:
        if not self.enabled:
            return
        row = {"step": step, "epoch": epoch, "split": split, **{k: f"{v:.6g}" for k, v in values.items()},
               "seconds": f"{seconds:.1f}"}
        with self.path.open("a", newline="") as f:
            csv.DictWriter(f, self.fields).writerow(row)
