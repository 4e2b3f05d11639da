"""Training the network (Sec. 3.4.5): the loop, and the committed networks' two stages.

The configuration is :class:`cuboidlib.train_config.TrainConfig` (the paper's Adam, learning rate 6e-4, batch 32,
1000 epochs, by default). :meth:`Trainer.run` is the loop: shuffle, one Adam step on Eq. (9) per
batch, validate, keep ``best.pt``. Model selection reads the validation split only; the test split is scored
by ``cuboidlib evaluate``. Resuming, several processes, checkpoints and the log are :mod:`cuboidlib.runs`.
"""

from __future__ import annotations

import math
import os
import sys
import time
from pathlib import Path

import torch

from . import kernels
from ._checks import check_int
from .checkpoint import check_config_matches, load_checkpoint, save_checkpoint
from .config import derive_seed, resolve_device
from .dataset import DATA_FIELDS, ShapeSet, load_splits
from .evaluation import predict_cuboids, segmentation_scores
from .losses import LOSS_TERMS, LossConfig, total_loss
from .model import CuboidAbstractionNet, ModelConfig, allocation_saturation, read_normals_from_start
from .runs import (CoreShare, Distributed, RunLog, TrainingDiverged, TrainResult, check_finite_weights, check_gradients,
                   check_resumable, gather_rng_states, save_last)
from .train_config import RESUMABLE_CHANGES, TrainConfig, WEIGHT_NEUTRAL_FIELDS

__all__ = [
    "validation_loss",
    "TrainingDiverged",
    "TrainResult",
    "Trainer",
    "Distributed",
    "train_then_finetune",
    "train_with_snapshots",
    "FINETUNE_DIR",
    "DIAGNOSTICS",
    "VALIDATION_SCORES",
]

#: Diagnostics logged beside the loss terms: the mean number of cuboids with existence above 0.5, the
#: fraction of points whose allocation is saturated (largest weight above 0.999) and the median gap
#: between the best and second-best affinity logit (see :func:`cuboidlib.model.allocation_saturation`).
DIAGNOSTICS = ("n_existing", "saturated", "affinity_gap")
#: Scores of the validation split logged at every validation when its shapes carry part labels: the
#: mIoU by the paper's label transfer, N_AC and the box distance (:func:`cuboidlib.evaluation.segmentation_scores`).
VALIDATION_SCORES = ("miou", "n_ac", "box_distance")
#: The columns of ``log.csv``.
LOG_FIELDS = ("step", "epoch", "split") + LOSS_TERMS + DIAGNOSTICS + ("seconds",) + VALIDATION_SCORES
# Network outputs checked for NaN / inf before the loss is computed.
_OUTPUTS = ("centers", "quaternions", "half_sizes", "exist_logits", "W", "mu", "logvar")
# Streams of the seed derivation (see derive_seed).
_ORDER, _LOSS, _LATENT, _VALIDATION = range(4)


# ----------------------------------------------------------------------------------------------
# Validation loss (model selection)
# ----------------------------------------------------------------------------------------------


@torch.no_grad()
def validation_loss(
    model: CuboidAbstractionNet, shapes: ShapeSet, loss_config: LossConfig, batch_size: int, seed: int
) -> dict[str, float]:
    """The loss terms (Eq. (9)) averaged over the shapes, in evaluation mode (running BatchNorm, z = mu).

    The model's training flag is restored afterwards.

    Args:
        model: the network.
        shapes: the validation shapes.
        loss_config: the loss settings.
        batch_size: shapes per forward pass.
        seed: seeds the offsets along the normals (Eq. (5)), so the value depends on the weights only.

    Returns:
        ``{name: mean}`` over :data:`LOSS_TERMS` and :data:`DIAGNOSTICS`.
    """
    was_training = model.training
    model.eval()
    device = next(model.parameters()).device
    generator = torch.Generator(device).manual_seed(seed)
    sums = torch.zeros(len(LOSS_TERMS) + len(DIAGNOSTICS), dtype=torch.float64)
    try:
        for start in range(0, len(shapes), batch_size):
            points = shapes.points[start:start + batch_size].to(device)
            normals = shapes.normals[start:start + batch_size].to(device)
            out = model(points, normals)
            terms = total_loss(out, points, normals, loss_config, generator=generator)
            values = torch.stack([getattr(terms, k) for k in LOSS_TERMS] + _diagnostics(out))
            sums += values.double().cpu() * points.shape[0]
    finally:
        model.train(was_training)
    means = (sums / len(shapes)).tolist()
    return dict(zip(LOSS_TERMS + DIAGNOSTICS, means))


def _diagnostics(out) -> list[torch.Tensor]:
    """The :data:`DIAGNOSTICS` of one batch's network output, as 0-d tensors."""
    n_exist = (out.exist_logits.detach() > 0).sum(dim=1).to(out.W.dtype).mean()
    saturated, gap = allocation_saturation(out.affinity.detach())
    return [n_exist, saturated, gap]


# ----------------------------------------------------------------------------------------------
# The trainer
# ----------------------------------------------------------------------------------------------


class Trainer:
    """The training loop of the paper's network (Sec. 3.4.5) with checkpoints, resume and DDP.

    Rank 0 writes ``config.json``, ``last.pt`` (the full training state, every ``checkpoint_every`` steps
    and at the end), ``best.pt`` (weights and config of the selected validation) and ``log.csv``.

    Args:
        config: the run.
        out_dir: the run folder; a new run refuses one that holds a ``last.pt``.
        resume: continue from ``out_dir/last.pt``, refused if its config differs in a field outside
            :data:`RESUMABLE_CHANGES`.
        quiet: print no progress.
        splits: already loaded data, as from :func:`load_splits`; None loads it.
    """

    def __init__(
        self,
        config: TrainConfig,
        out_dir: str | os.PathLike,
        resume: bool = False,
        quiet: bool = False,
        splits: dict[str, ShapeSet] | None = None,
    ):
        self.config = config
        self.out_dir = Path(out_dir)
        self.quiet = quiet
        self.dist = Distributed()
        self._set_up_compute(config)
        if config.batch_size % self.dist.world_size:
            raise ValueError(
                f"batch_size {config.batch_size} must be divisible by the number of processes {self.dist.world_size}"
            )
        last = self.out_dir / "last.pt"
        if resume and not last.is_file():
            raise FileNotFoundError(f"{last}: nothing to resume (no checkpoint in {self.out_dir})")
        if not resume and last.is_file():
            raise FileExistsError(f"{self.out_dir} already holds a run ({last}); resume it or choose another folder")
        if not resume:
            _check_new_run_folder(self.out_dir, config)

        show = not quiet and self.dist.is_main and sys.stderr.isatty()
        splits = splits if splits is not None else load_splits(config, progress=show)
        self.train_set = splits["train"].to(self.device)
        self.val_set = splits["val"]
        self.steps_per_epoch = len(self.train_set) // config.batch_size
        if self.steps_per_epoch == 0:
            raise ValueError(
                f"the training split has {len(self.train_set)} shapes, fewer than batch_size {config.batch_size}; "
                "use more shapes or a smaller batch"
            )
        self.total_steps = config.epochs * self.steps_per_epoch
        if config.max_steps is not None:
            self.total_steps = min(self.total_steps, config.max_steps)
        self.loss_config = config.loss_config
        self.final_temperature = config.model_config.affinity_temperature  # read once, not at every step

        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed)
            self.model = CuboidAbstractionNet(config.model_config)
        if config.init_from is not None and not resume:
            self._initialise_from(Path(config.init_from))
        self.model.to(self.device).train()
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=config.lr)
        self.loss_generator = torch.Generator(self.device).manual_seed(derive_seed(config.seed, _LOSS, self.dist.rank))
        self.latent_generator = torch.Generator(self.device).manual_seed(
            derive_seed(config.seed, _LATENT, self.dist.rank)
        )
        self.step = 0
        self.best_val: float | None = None
        self.best_step: int | None = None
        self.elapsed = 0.0  # training seconds of earlier sessions of this run
        self.last_terms: dict[str, float] = {}
        self._last_saved = "no checkpoint had been written yet"
        if resume:
            self._restore(load_checkpoint(last))  # on the CPU: generator states must stay there

        self.dist.start(self.device)
        self.net: torch.nn.Module = self.model
        if self.dist.enabled:
            from torch.nn.parallel import DistributedDataParallel

            self.net = DistributedDataParallel(
                self.model, device_ids=[self.device.index] if self.device.type == "cuda" else None
            )
        if self.dist.is_main:
            config.save_json(self.out_dir / "config.json")
        self.log = RunLog(self.out_dir / "log.csv", LOG_FIELDS, self.step if resume else None, self.dist.is_main)

    def _set_up_compute(self, config: TrainConfig) -> None:
        """This process's device, thread count (fixed, or following the free cores) and compiled kernels."""
        self.device = resolve_device(config.device)
        if self.device.type == "cuda" and self.dist.enabled:
            self.device = torch.device("cuda", self.dist.local_rank)
            torch.cuda.set_device(self.device)
        follow = config.num_threads == "auto" and self.device.type == "cpu"
        self.core_share = CoreShare() if follow and not self.dist.enabled else None
        if follow and self.dist.enabled:  # several processes share the cores: a fixed share each
            torch.set_num_threads(max(1, (os.cpu_count() or 1) // self.dist.world_size))
        if isinstance(config.num_threads, int):
            torch.set_num_threads(config.num_threads)
        if config.compiled_kernels is True:
            kernels.enable()
        elif config.compiled_kernels is False:
            kernels.disable()

    # ------------------------------------------------------------------------------ state

    def _initialise_from(self, path: Path) -> None:
        """Start from the weights of the checkpoint ``path``.

        The model configuration must match, except ``affinity_temperature``, which changes no
        weight: a second stage may soften the allocation of the first one; and ``input_normals``
        where the checkpoint's is "none": a second stage may start reading the normals, with zero
        weights on them at first (:func:`cuboidlib.model.read_normals_from_start`).
        """
        state = load_checkpoint(path)
        stored = ModelConfig.from_dict(state["config"]["model"]).to_dict()
        requested = ModelConfig.from_dict(self.config.model).to_dict()
        for name in WEIGHT_NEUTRAL_FIELDS:
            stored.pop(name), requested.pop(name)
        weights = state["model"]
        if stored["input_normals"] == "none" and requested["input_normals"] != "none":
            weights = read_normals_from_start(weights, requested["input_normals"])
            stored["input_normals"] = requested["input_normals"]
        check_config_matches(stored, requested, f"model config of init_from {path}")
        self.model.load_state_dict(weights, strict=True)

    def learning_rate(self, step: int, time_used: float = 0.0) -> float:
        """The learning rate of an optimiser step: constant, or a half cosine from ``lr`` to ``lr_final`` over the run.

        "cosine" follows the steps, so that a run is the same on every machine. "cosine_minutes" follows the
        time budget, so that a run stopped by ``max_minutes`` ends at ``lr_final`` on a slow machine as on a fast one.
        During the first ``lr_warmup_steps`` steps the rate is scaled by (step + 1) / ``lr_warmup_steps``.

        Args:
            step: the step, 0-based.
            time_used: the fraction of ``max_minutes`` used so far ("cosine_minutes" only).

        Returns:
            The rate.
        """
        config = self.config
        warm_up = min(1.0, (step + 1) / config.lr_warmup_steps) if config.lr_warmup_steps else 1.0
        by_minutes = config.lr_schedule == "cosine_minutes"
        if config.lr_schedule == "constant" or (not by_minutes and self.total_steps <= 1):
            return warm_up * config.lr
        progress = min(time_used if by_minutes else step / (self.total_steps - 1), 1.0)
        return warm_up * (config.lr_final + 0.5 * (config.lr - config.lr_final) * (1 + math.cos(math.pi * progress)))

    def affinity_temperature(self, step: int) -> float:
        """The affinity temperature of an optimiser step: T_0 (T / T_0)^(step / S) during the warm-up, then T.

        Args:
            step: the step, 0-based.

        Returns:
            The temperature; S = ``temperature_steps``, T_0 = ``temperature_start``, T the model's
            ``affinity_temperature``.
        """
        final, config = self.final_temperature, self.config
        if step >= config.temperature_steps:
            return final
        return config.temperature_start * (final / config.temperature_start) ** (step / config.temperature_steps)

    def _restore(self, state: dict) -> None:
        """Continue from ``last.pt``'s state, refusing a checkpoint of another run."""
        stored = TrainConfig.from_dict(state["config"]).to_dict() if "config" in state else {}
        stored_total = min(stored.get("epochs", 0) * self.steps_per_epoch, stored.get("max_steps") or math.inf)
        check_resumable(state, self.out_dir / "last.pt", stored, self.config.to_dict(), RESUMABLE_CHANGES,
                        stored_total, self.total_steps, self.config.lr_schedule, self.dist.world_size)
        self.model.load_state_dict(state["model"], strict=True)
        self.optimizer.load_state_dict(state["optimizer"])
        self.step = int(state["step"])
        self.best_val, self.best_step = state["best_val"], state["best_step"]
        self.elapsed = float(state["elapsed_seconds"])
        self.loss_generator.set_state(state["rng"]["loss"][self.dist.rank])
        self.latent_generator.set_state(state["rng"]["latent"][self.dist.rank])
        self._last_saved = f"the last checkpoint (step {self.step}) is kept"

    def save(self, seconds: float) -> None:
        """Write ``last.pt`` (rank 0; every rank takes part in gathering the generator states).

        Args:
            seconds: training seconds of this session so far.
        """
        rng = gather_rng_states({"loss": self.loss_generator, "latent": self.latent_generator}, self.dist,
                                self.device)
        if self.dist.is_main:
            self._last_saved = save_last(
                self.out_dir / "last.pt", self.config.to_dict(), self.model, self.optimizer, self.step,
                self.step // self.steps_per_epoch, rng, self.best_val, self.best_step, self.dist.world_size,
                self.elapsed + seconds)

    def _log(self, split: str, values: dict[str, float], seconds: float) -> None:
        self.log.write(self.step, self.step // self.steps_per_epoch, split, values, self.elapsed + seconds)

    # ------------------------------------------------------------------------------ steps

    def _permutation(self, epoch: int) -> torch.Tensor:
        """The order of the training shapes in ``epoch``, the same on every rank and after a resume."""
        g = torch.Generator().manual_seed(derive_seed(self.config.seed, _ORDER, epoch))
        return torch.randperm(len(self.train_set), generator=g)

    def _train_step(self, index: torch.Tensor, time_used: float) -> tuple[dict[str, float], bool]:
        """One Adam step on the shapes ``index``, ``time_used`` being the fraction of the time budget used; returns
        the (process-averaged) loss terms and whether any process has used up its time budget."""
        points = self.train_set.points[index]
        normals = self.train_set.normals[index]
        self.model.segmentation.temperature = self.affinity_temperature(self.step)
        out = self.net(points, normals, generator=self.latent_generator)
        bad_outputs = [k for k in _OUTPUTS if not bool(torch.isfinite(getattr(out, k).detach()).all())]
        if bad_outputs:  # the loss would refuse them; all ranks learn of it through the NaN values
            terms = None
            values = torch.full((len(LOSS_TERMS) + len(DIAGNOSTICS),), math.nan, device=points.device)
        else:
            terms = total_loss(out, points, normals, self.loss_config, generator=self.loss_generator)
            values = torch.stack([getattr(terms, k).detach() for k in LOSS_TERMS] + _diagnostics(out))
        # Every process takes the same rate (the mean time used) and stops with the first one out of time.
        clock = torch.tensor([time_used, float(time_used >= 1.0)], dtype=values.dtype, device=values.device)
        if self.dist.enabled:
            import torch.distributed as dist

            packed = torch.cat([values, clock]) / self.dist.world_size
            dist.all_reduce(packed)
            values, clock = packed[:-2], packed[-2:]
        numbers = dict(zip(LOSS_TERMS + DIAGNOSTICS, values.tolist()))
        time_used, over = clock.tolist()
        if bad_outputs:
            raise TrainingDiverged(self.step + 1, [f"network outputs ({', '.join(bad_outputs)})"],
                                   last_checkpoint=self._last_saved)
        bad = [k for k in LOSS_TERMS if not math.isfinite(numbers[k])]
        if bad:
            raise TrainingDiverged(self.step + 1, bad, {k: numbers[k] for k in LOSS_TERMS}, self._last_saved)
        self.optimizer.zero_grad(set_to_none=True)
        terms.total.backward()
        losses = {k: numbers[k] for k in LOSS_TERMS}
        check_gradients(self.model, self.step + 1, losses, self._last_saved)
        for group in self.optimizer.param_groups:
            group["lr"] = self.learning_rate(self.step, time_used)
        self.optimizer.step()
        check_finite_weights(self.model, self.step + 1, losses, self._last_saved)
        return numbers, over > 0

    def _validation_scores(self) -> dict[str, float]:
        """mIoU (label transfer within the validation split), N_AC and box distance of the network now."""
        if self.val_set.labels is None or len(self.val_set) < 2:
            return {}
        pred, _ = predict_cuboids(self.model, self.val_set, self.config.batch_size,
                                  self.loss_config.centers_from_allocation)
        scores = segmentation_scores(self.val_set, pred)
        return {k: scores[k] for k in VALIDATION_SCORES}

    def _validate(self, seconds: float) -> None:
        """Validation loss on the validation split (rank 0); keep ``best.pt`` at its minimum (from the end of
        the temperature warm-up on), or at the latest weights with ``selection="last"``."""
        if not self.dist.is_main:
            return
        self.model.segmentation.temperature = self.affinity_temperature(self.step)
        values = validation_loss(self.model, self.val_set, self.loss_config, self.config.batch_size,
                                 derive_seed(self.config.seed, _VALIDATION))
        scores = self._validation_scores()
        self._log("val", {**values, **scores}, seconds)
        if not math.isfinite(values["total"]):
            raise TrainingDiverged(self.step, ["validation loss"], values, self._last_saved)
        warm_up = self.config.temperature_steps
        if self.step < warm_up or self.config.selection == "last":  # best.pt follows the latest weights
            improved = True
        else:
            improved = self.best_val is None or self.best_step < warm_up or values["total"] < self.best_val
        if improved:
            self.best_val, self.best_step = values["total"], self.step
            save_checkpoint(self.out_dir / "best.pt", self.config.to_dict(), self.model.state_dict(),
                            step=self.step, best_val=self.best_val, best_step=self.step,
                            world_size=self.dist.world_size)
        if not self.quiet:
            from tqdm import tqdm

            tqdm.write(
                f"step {self.step}: validation loss {values['total']:.5f} (reconstruction "
                f"{values['reconstruction']:.5f}, {values['n_existing']:.1f} cuboids, "
                f"{100 * values['saturated']:.0f} % of points saturated"
                + (f", mIoU {100 * scores['miou']:.1f} %)" if scores.get("miou") is not None else ")")
                + (" - best so far, saved best.pt" if improved
                   else f"; best {self.best_val:.5f} at step {self.best_step}")
            )

    def run(self) -> TrainResult:
        """Train until the step budget (``epochs`` / ``max_steps``) or the time budget is used up.

        Returns:
            The :class:`TrainResult`; the run validates and writes ``last.pt`` where it stops.
        """
        from tqdm import tqdm

        config = self.config
        start = time.monotonic()
        # The budget counts the training time of earlier sessions of this run (a resumed run gets what is left).
        total_budget = 60 * config.max_minutes if config.max_minutes is not None else math.inf
        budget = total_budget - self.elapsed
        if budget <= 0:  # resumed after the time budget was used up: last.pt is final (validated at the stop)
            self.dist.stop()
            return TrainResult(self.step, self.step // self.steps_per_epoch, "time budget", self.best_val,
                               self.best_step, self.elapsed, self.last_terms, str(self.out_dir))
        shard = slice(self.dist.rank, None, self.dist.world_size)
        bar = tqdm(total=self.total_steps, initial=self.step, desc="training", unit="step", dynamic_ncols=True,
                   disable=True if (self.quiet or not self.dist.is_main) else None, file=sys.stderr)
        stopped = "finished"
        validated_at = None
        try:
            perm, perm_epoch = None, None
            while self.step < self.total_steps:
                epoch, position = divmod(self.step, self.steps_per_epoch)
                if perm_epoch != epoch:
                    perm, perm_epoch = self._permutation(epoch), epoch
                batch = perm[position * config.batch_size:(position + 1) * config.batch_size][shard]
                time_used = (self.elapsed + time.monotonic() - start) / total_budget
                self.last_terms, over = self._train_step(batch.to(self.device), time_used)
                if self.core_share is not None:
                    self.core_share.step()
                self.step += 1
                self._log("train", self.last_terms, time.monotonic() - start)
                bar.update(1)
                bar.set_postfix(
                    loss=f"{self.last_terms['total']:.4f}", rec=f"{self.last_terms['reconstruction']:.4f}",
                    comp=f"{self.last_terms['compactness']:.2f}", exist=f"{self.last_terms['existence']:.3f}",
                    kl=f"{self.last_terms['kl']:.1f}", cuboids=f"{self.last_terms['n_existing']:.1f}", refresh=False,
                )
                if self.step % config.validate_every == 0:
                    self._validate(time.monotonic() - start)
                    validated_at = self.step
                if over:
                    stopped = "time budget"
                    break
                if self.step % config.checkpoint_every == 0 and self.step < self.total_steps:
                    self.save(time.monotonic() - start)
            if validated_at != self.step:
                self._validate(time.monotonic() - start)
            self.save(time.monotonic() - start)
            self.dist.wait()  # rank 0 has validated and saved: the processes go on together
        finally:
            bar.close()
            self.dist.stop()
        seconds = time.monotonic() - start
        if not self.quiet and self.dist.is_main:
            tqdm.write(f"stopped at step {self.step} ({stopped}) after {seconds:.0f} s; "
                       f"best validation loss {self.best_val:.5f} at step {self.best_step}")
        return TrainResult(self.step, self.step // self.steps_per_epoch, stopped, self.best_val, self.best_step,
                           self.elapsed + seconds, self.last_terms, str(self.out_dir))


#: The folder, inside a two-stage run's folder, of its second stage (:func:`train_then_finetune`).
FINETUNE_DIR = "finetune"


#: The files a run writes in its folder; a new run refuses a folder where one of them is another's.
RUN_FILES = ("config.json", "log.csv", "best.pt", "last.pt")


def _check_new_run_folder(out_dir: Path, config: TrainConfig) -> None:
    """Refuse to start a run in a folder holding files it would overwrite (or links it would write through).

    The one exception is the same run started again before its first checkpoint: a ``config.json`` with
    exactly this config's text (its ``log.csv`` and ``best.pt`` are then this run's own).

    Args:
        out_dir: the run folder.
        config: the run's config.

    Raises:
        FileExistsError: naming the files and what to do.
    """
    present = [name for name in RUN_FILES if os.path.lexists(out_dir / name)]
    if not present:
        return
    stored = out_dir / "config.json"
    try:
        same = not stored.is_symlink() and stored.read_text(encoding="utf-8") == config.to_json()
    except (OSError, UnicodeDecodeError):
        same = False
    links = [name for name in present if (out_dir / name).is_symlink()]
    if same and not links:
        return
    raise FileExistsError(
        f"{out_dir} already holds {', '.join(present)} but no run to resume (no last.pt of this config); a new run "
        "would overwrite them" + (f" ({', '.join(links)}: symbolic link(s), which cuboidlib never writes through)"
                                  if links else "") + ". Choose another --out folder, or move those files away"
    )


def train_then_finetune(config: TrainConfig, finetune: TrainConfig, out_dir: str | os.PathLike,
                        resume: bool = False, quiet: bool = False) -> tuple[TrainResult | None, TrainResult]:
    """The committed networks' two-stage recipe: ``config`` in ``out_dir``, then ``finetune`` from its ``best.pt``.

    Under ``torchrun`` both stages share one process group.

    Args:
        config: the first stage.
        finetune: the second stage, run in ``out_dir/finetune``; its ``init_from`` becomes ``out_dir/best.pt``.
            It must select the same shapes (the fields of :data:`DATA_FIELDS`), else ``ValueError`` before
            any training.
        out_dir: the first stage's run folder.
        resume: continue the second stage if it has begun (the first is then skipped), else resume the first.
        quiet: print no progress.

    Returns:
        The two stages' :class:`TrainResult`, the first None when it was skipped; the released network is
        the second stage's ``best.pt``.

    Example::

        first = TrainConfig.load_json("data_samples/checkpoints/configs/chair.json")
        second = TrainConfig.load_json("data_samples/checkpoints/configs/finetune/chair.json")
        train_then_finetune(first, second, "runs/chair")   # runs/chair/finetune/best.pt
    """
    data = [(key, getattr(config, key), getattr(finetune, key)) for key in DATA_FIELDS]
    differ = [f"{key} {a!r} / {b!r}" for key, a, b in data if a != b]
    if differ:
        raise ValueError("the second stage must train on the first stage's shapes, but the two configs select "
                         f"different data (first / second: {'; '.join(differ)}); give both the same values (with "
                         "cuboidlib train --finetune, the data flags apply to both stages, --set to the first only)")
    out_dir = Path(out_dir)
    second_dir = out_dir / FINETUNE_DIR
    second = finetune.replace(init_from=str(out_dir / "best.pt"))
    group = Distributed()
    group.start(resolve_device(config.device))  # the Trainers below then find it and leave it open
    try:
        first_result = None
        second_begun = resume and (second_dir / "last.pt").is_file()
        if not second_begun:  # every process leaves run() after rank 0 has written best.pt
            first_result = Trainer(config, out_dir, resume=resume, quiet=quiet).run()
        second_result = Trainer(second, second_dir, resume=second_begun, quiet=quiet).run()
    finally:
        group.stop()
    return first_result, second_result


def train_with_snapshots(config: TrainConfig, out_dir: str | os.PathLike, stops: tuple[int, ...] | list[int],
                         splits: dict[str, ShapeSet] | None = None,
                         quiet: bool = True) -> tuple[TrainResult | None, dict[int, dict[str, torch.Tensor]]]:
    """Train ``config`` for ``stops[-1]`` steps in ``out_dir``, keeping the weights at step 0 and at each stop.

    The run stops and resumes at every stop, which gives the weights of one uninterrupted run; each is
    written to ``out_dir/snapshot_<step>.pt``. A second call with the same config reuses the folder (a
    finished run is read back, an interrupted one continues); a run of another config is refused.

    Args:
        config: the run; ``max_steps`` is replaced by ``stops[-1]``, ``max_minutes`` must be None and the
            learning rate constant.
        out_dir: the run folder.
        stops: increasing step counts.
        splits: as for :class:`Trainer`.
        quiet: print no progress.

    Returns:
        ``(result, snapshots)``: the :class:`TrainResult` of the last piece trained (None when nothing was
        left to train) and ``{step: state_dict}`` for step 0 and every stop.

    Example::

        config = course_config("chair", n_shapes=128, n_points=512, max_minutes=None)
        result, snapshots = train_with_snapshots(config, "runs/lesson", stops=(100, 200, 400))
        sorted(snapshots)   # [0, 100, 200, 400]
    """
    stops = list(stops)
    if not stops:
        raise ValueError("stops is empty: give the steps at which to keep the weights, e.g. (100, 200, 400)")
    for stop in stops:
        check_int(stop, "every step of stops", 1)
    if any(b <= a for a, b in zip(stops, stops[1:])):
        raise ValueError(f"stops must increase, got {stops}")
    if config.max_minutes is not None:
        raise ValueError(f"max_minutes is {config.max_minutes}: a time budget could stop the run between two stops; "
                         "use max_minutes=None (the stops are the budget)")
    if config.lr_schedule != "constant":
        raise ValueError(f"lr_schedule {config.lr_schedule!r} depends on the length of the run, which changes at "
                         "every stop; train_with_snapshots needs the constant schedule")
    final = config.replace(max_steps=stops[-1])
    out_dir = Path(out_dir)
    stored_path = out_dir / "config.json"
    if stored_path.is_file() and TrainConfig.load_json(stored_path).run_defining() != final.run_defining():
        raise FileExistsError(f"{out_dir} holds a run of another configuration; choose another folder "
                              "(or delete it to train this one there)")

    def snapshot(step: int) -> Path:
        return out_dir / f"snapshot_{step}.pt"

    result = None
    for stop in stops:
        if snapshot(stop).is_file():
            continue
        splits = splits if splits is not None else load_splits(final)
        resume = (out_dir / "last.pt").is_file()
        trainer = Trainer(final.replace(max_steps=stop), out_dir, resume=resume, quiet=quiet, splits=splits)
        if not resume:
            save_checkpoint(snapshot(0), final.to_dict(), trainer.model.state_dict(), step=0)
        result = trainer.run()
        save_checkpoint(snapshot(stop), final.to_dict(), trainer.model.state_dict(), step=stop)
    return result, {step: load_checkpoint(snapshot(step))["model"] for step in (0, *stops)}
