"""Publishing a training run as a ready-to-use checkpoint with its evaluation card.

``cuboidlib train ... --release data_samples/checkpoints/chair.pt`` ends with :func:`publish_run`: the run's
``best.pt`` without optimizer state, scored on the test split beside the k-means + oriented-box baseline, and
a JSON card beside it (``chair.json``) with the keys

* ``command``, ``git_commit``: how it was trained and published;
* ``machine``: CPUs, training processes, torch threads, torch and Python versions, device, ``gpu`` (or None);
* ``training``: steps, selected step, seconds, the validation curve and its values at :data:`CURVE_MARKS`;
* ``initialised_from`` (two-stage recipes): the first stage's checkpoint, config and training summary;
* ``config``: the complete :class:`~cuboidlib.train_config.TrainConfig`;
* ``translation_head`` (centroid-centre networks only): the refit of :func:`fit_translation_head`;
* ``test``: the metrics of network and baseline (:func:`cuboidlib.evaluation.evaluate_model`) and their table;
* ``command_seconds`` (``cuboidlib train --release`` only): the wall time from the command's start to the card,
  making the data, every stage and this scoring included.

The checkpoint itself also holds ``latent_statistics``: where the network puts its training shapes in the
latent space (:func:`cuboidlib.applications.latent_statistics`), for the check of :func:`cuboidlib.abstract`;
not for a training split of at most ``latent_dim`` shapes, too few to estimate their spread.
"""

from __future__ import annotations

import csv
import json
import os
import platform
import subprocess
import time
from pathlib import Path

import torch

from .applications import latent_statistics
from .checkpoint import load_checkpoint, load_model, save_checkpoint
from .config import resolve_device
from .dataset import load_splits
from .evaluation import evaluate_baseline, evaluate_model, format_table
from .files import read_json, write_text_atomic
from .losses import allocation_weighted_centers
from .model import CuboidAbstractionNet
from .train_config import SELECTIONS, TrainConfig

__all__ = ["CARD_FORMAT", "CURVE_MARKS", "card_path", "fit_translation_head", "translation_head_error", "git_commit",
           "publish_run", "add_latent_statistics", "read_card", "cards_markdown", "training_curve", "curve_marks"]

CARD_FORMAT = "cuboidlib-checkpoint-card"


def card_path(checkpoint: str | os.PathLike) -> Path:
    """The JSON card that belongs to a checkpoint file: ``chair.pt`` -> ``chair.json``.

    Args:
        checkpoint: the checkpoint path.

    Returns:
        The card's path.
    """
    return Path(checkpoint).with_suffix(".json")


def git_commit(folder: str | os.PathLike | None = None) -> str | None:
    """The commit of the git work tree holding ``folder``.

    Args:
        folder: a folder in the work tree (default: this package's).

    Returns:
        The commit hash, with ``+dirty`` when tracked files have uncommitted changes; None outside a work tree.
    """
    where = Path(folder) if folder is not None else Path(__file__).resolve().parent
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True, check=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=where,
                               capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


#: Wall-clock marks (minutes) at which a card reports the validation scores of its run.
CURVE_MARKS = (15, 30, 60)


def _training_summary(run_dir: Path, selected_step: int | None, selection: str) -> dict:
    """Steps and wall-clock seconds of a run and its validation curve, from its ``log.csv``.

    ``validation``: one entry per validation row (step, seconds, loss, N_AC, mIoU, box distance,
    saturation; the scores that the log holds); ``at_minutes``: the last validation at or before each
    of :data:`CURVE_MARKS` that the run reached, so a card tells what a shorter budget gives.
    """
    last, curve = None, []
    with open(run_dir / "log.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["split"] == "train":
                last = row
            elif row["split"] == "val":
                entry = {"step": int(row["step"]), "seconds": round(float(row["seconds"]), 1),
                         "loss": float(row["total"])}
                for key in ("n_ac", "miou", "box_distance", "saturated"):
                    if row.get(key):
                        entry[key] = float(row[key])
                curve.append(entry)
    if last is None:
        raise ValueError(f"{run_dir / 'log.csv'}: no training step logged")
    seconds = round(float(last["seconds"]), 1)
    return {"steps": int(last["step"]), "selected_step": selected_step, "selection": SELECTIONS[selection],
            "seconds": seconds, "validation": curve, "at_minutes": curve_marks(curve, seconds)}


def curve_marks(curve: list[dict], seconds: float) -> dict:
    """The last validation at or before each of :data:`CURVE_MARKS` minutes that the run reached.

    Args:
        curve: validation entries with their ``seconds``, in order.
        seconds: the run's length in seconds.

    Returns:
        ``{"15": entry, ...}`` for the marks the run lasted (about) that long.
    """
    marks = {}
    for minutes in CURVE_MARKS:
        before = [e for e in curve if e["seconds"] <= 60 * minutes]
        if before and seconds >= 60 * minutes - 60:  # the run lasted (about) this long
            marks[str(minutes)] = before[-1]
    return marks


def training_curve(card: dict) -> tuple[list[dict], float, list[float]]:
    """The validation curve of all the stages a card records (``initialised_from``, then its own run).

    Args:
        card: a card of :func:`read_card`.

    Returns:
        ``(curve, total seconds, start seconds of each later stage)``; every curve entry is a validation
        with ``seconds`` counted from the start of the first stage, and its ``stage`` (0, 1, ...).
    """
    earlier = card.get("initialised_from", {})
    stages = ([earlier["training"]] if "training" in earlier else []) + [card["training"]]
    curve, offset, starts = [], 0.0, []
    for k, stage in enumerate(stages):
        if k:
            starts.append(offset)
        curve += [{**e, "seconds": round(e["seconds"] + offset, 1), "stage": k} for e in stage["validation"]]
        offset += stage["seconds"]
    return curve, round(offset, 1), starts


@torch.no_grad()
def _features_and_centroids(model: CuboidAbstractionNet, points: torch.Tensor, normals: torch.Tensor | None = None,
                            batch_size: int = 32):
    """Cuboid features f^c (K, C) and allocation centroids c_m (K, 3) of the existing cuboids of ``points``
    (S, N, 3); ``normals`` (S, N, 3) for a network that reads them (``ModelConfig.input_normals`` not "none")."""
    was_training = model.training
    model.eval()
    device = next(model.parameters()).device  # the shapes move there batch by batch
    try:
        features, centroids = [], []
        for start in range(0, len(points), batch_size):
            chunk = points[start:start + batch_size].to(device)
            chunk_normals = None if normals is None else normals[start:start + batch_size].to(device)
            out = model(chunk, chunk_normals, sample_latent=False)
            exists = out.exist_probs > 0.5
            features.append(out.cuboid_features[exists])  # (K, C): the existing cuboids of the chunk
            centroids.append(allocation_weighted_centers(out.W, chunk)[exists])  # (K, 3)
    finally:
        model.train(was_training)
    return torch.cat(features), torch.cat(centroids)


@torch.no_grad()
def _head_rms(model: CuboidAbstractionNet, features: torch.Tensor, centroids: torch.Tensor) -> float:
    """RMS distance between tanh(translation head(features)) and the centroids, (K, C) and (K, 3)."""
    if len(features) == 0:
        raise ValueError("no cuboid exists on these shapes; the translation head cannot be compared")
    predicted = torch.tanh(model.abstraction.D_cp.translation(features))
    return float((predicted - centroids).square().sum(dim=-1).mean().sqrt())


def translation_head_error(model: CuboidAbstractionNet, points: torch.Tensor,
                           normals: torch.Tensor | None = None) -> float:
    """RMS distance between the predicted translations t_m and the allocation centroids c_m.

    Args:
        model: the network, run in evaluation mode with z = mu.
        points: (S, N, 3) shapes; their existing cuboids are compared.
        normals: (S, N, 3), for a network that reads them (``ModelConfig.input_normals`` not "none").

    Returns:
        The RMS distance, in the shapes' units.
    """
    return _head_rms(model, *_features_and_centroids(model, points, normals))


def fit_translation_head(model: CuboidAbstractionNet, points: torch.Tensor, ridge: float = 1e-5,
                         normals: torch.Tensor | None = None) -> None:
    """Fit the translation head t_m = tanh(A f^c_m + b) of D_cp to the allocation centroids c_m, in place.

    A network trained with centroid centres (``LossConfig(centers_from_allocation=True)``) never trains this
    head, yet decoding a code alone (generation, interpolation, Sec. 4.4) needs it. The fit is closed-form
    ridge least squares of atanh(c_m) on [f^c_m, 1] over the existing cuboids (existence > 0.5).

    Args:
        model: the network; only the head changes.
        points: (S, N, 3) training shapes.
        ridge: the ridge weight, times the number of cuboids.
        normals: (S, N, 3), for a network that reads them (``ModelConfig.input_normals`` not "none").
    """
    features, centroids = _features_and_centroids(model, points, normals)
    if len(features) == 0:
        raise ValueError("no cuboid exists on these shapes; the translation head cannot be fitted")
    x = torch.cat([features, torch.ones(len(features), 1, dtype=features.dtype, device=features.device)], dim=1)
    y = torch.atanh(centroids.clamp(-0.999, 0.999))
    x, y = x.double(), y.double()  # (K, C + 1), (K, 3)
    gram = x.T @ x + ridge * len(x) * torch.eye(x.shape[1], dtype=x.dtype, device=x.device)
    solution = torch.linalg.solve(gram, x.T @ y)  # (C + 1, 3)
    head = model.abstraction.D_cp.translation
    with torch.no_grad():
        head.weight.copy_(solution[:-1].T.to(head.weight))
        head.bias.copy_(solution[-1].to(head.bias))


def _earlier_stage(config: TrainConfig) -> dict | None:
    """For a run started from another run's weights (``init_from``): that checkpoint, its run's config
    and training summary (when its folder still holds them), and the seconds of both stages together."""
    if config.init_from is None:
        return None
    path = Path(config.init_from)
    out: dict = {"checkpoint": str(path)}
    if (path.parent / "config.json").is_file() and (path.parent / "log.csv").is_file():
        step = load_checkpoint(path).get("step")
        earlier = TrainConfig.load_json(path.parent / "config.json")
        out["config"] = earlier.to_dict()
        out["training"] = _training_summary(path.parent, step, earlier.selection)
    return out


def publish_run(
    run_dir: str | os.PathLike,
    dest: str | os.PathLike,
    command: str,
    seed: int = 0,
    started: float | None = None,
) -> dict:
    """Copy ``run_dir/best.pt`` to ``dest`` (weights and config), score it on the test split and write its card.

    Args:
        run_dir: the training run folder.
        dest: the released ``.pt`` file; the card goes to ``card_path(dest)``.
        command: the command line recorded in the card.
        seed: seed of the evaluation's surface samples and label-transfer shapes.
        started: when ``command`` started (``time.time()``), to record its wall time as ``command_seconds``;
            None records none.

    Returns:
        The card, a dict of JSON types (module docstring).
    """
    run_dir, dest = Path(run_dir), Path(dest)
    if dest.suffix != ".pt":
        raise ValueError(f"{dest}: a released checkpoint must be a .pt file")
    commit = git_commit()  # before dest is written: replacing a committed checkpoint must not read as "+dirty"
    state = load_checkpoint(run_dir / "best.pt")
    config = TrainConfig.from_dict(state["config"])
    training = _training_summary(run_dir, state.get("step"), config.selection)
    earlier = _earlier_stage(config)
    splits = load_splits(config)
    device = resolve_device("auto")  # the network runs on a GPU when there is one (the baseline on the CPU)
    translation = None
    if config.loss_config.centers_from_allocation:
        model = CuboidAbstractionNet(config.model_config)
        model.load_state_dict(state["model"])
        model.to(device)
        val = _features_and_centroids(model, splits["val"].points, splits["val"].normals)  # unchanged by the fit
        before = _head_rms(model, *val)
        fit_translation_head(model, splits["train"].points, normals=splits["train"].normals)
        translation = {"fitted_on": f"train split ({len(splits['train'])} shapes), existing cuboids",
                       "method": "ridge least squares of atanh(centroid) on the cuboid features (fit_translation_head)",
                       "rms_error_validation_before": round(before, 5),
                       "rms_error_validation_after": round(_head_rms(model, *val), 5)}
        state["model"] = model.state_dict()
    statistics = _training_latent_statistics(config, state["model"], splits["train"], device)
    save_checkpoint(dest, state["config"], state["model"], step=state.get("step"),
                    **({"latent_statistics": statistics} if statistics else {}))
    model, _ = load_model(dest, device=device)
    shapes = splits["test"]
    start = time.perf_counter()
    centroids = config.loss_config.centers_from_allocation
    network = evaluate_model(model, shapes, seed=seed, centers_from_allocation=centroids,
                             name=f"network (M = {config.model_config.num_cuboids})")
    boxes = max(1, round(network["n_ac"]))
    baseline = evaluate_baseline(shapes, boxes, seed=seed)
    title = (f"{dest.name}: {config.category} test split ({len(shapes)} shapes, {config.n_points} points each), "
             f"network step {state.get('step')}")
    card = {
        "format": CARD_FORMAT,
        "checkpoint": dest.name,
        "command": command,
        "git_commit": commit,
        "machine": {"cpus": os.cpu_count(), "processes": state.get("world_size", 1),
                    "torch_threads": config.num_threads or torch.get_num_threads(),
                    "torch": torch.__version__, "python": platform.python_version(),
                    "device": config.device,
                    "gpu": torch.cuda.get_device_name(device) if device.type == "cuda" else None},
        "training": training,
        **({"initialised_from": earlier} if earlier else {}),
        "config": config.to_dict(),
        **({"translation_head": translation} if translation else {}),
        "test": {"split": "test", "n_shapes": len(shapes), "evaluation_seconds": round(time.perf_counter() - start, 1),
                 "results": [network, baseline], "table": format_table([network, baseline], title)},
    }
    if started is not None:
        card["command_seconds"] = round(time.time() - started, 1)
    write_text_atomic(card_path(dest), json.dumps(card, indent=2) + "\n")
    return card


def _training_latent_statistics(config: TrainConfig, weights: dict, train, device) -> dict[str, torch.Tensor] | None:
    """:func:`~cuboidlib.applications.latent_statistics` of the network ``weights`` on its training split, or None
    when the split holds at most ``latent_dim`` shapes (too few codes for their covariance: no latent check)."""
    if len(train) <= config.model_config.latent_dim:
        return None
    model = CuboidAbstractionNet(config.model_config).to(device)
    model.load_state_dict(weights)
    return latent_statistics(model, train.points.to(device), train.normals.to(device))


def add_latent_statistics(checkpoint: str | os.PathLike) -> dict[str, torch.Tensor] | None:
    """Store :func:`~cuboidlib.applications.latent_statistics` of a released network's training split in its
    checkpoint, as :func:`publish_run` does, for a network released before it did. The weights are unchanged.

    Args:
        checkpoint: the released ``.pt`` file; it is rewritten atomically.

    Returns:
        The statistics stored; None (the file unchanged) when the training split is too small for them.
    """
    state = load_checkpoint(checkpoint)
    config = TrainConfig.from_dict(state["config"])
    statistics = _training_latent_statistics(config, state["model"], load_splits(config)["train"], "cpu")
    if statistics is not None:
        extra = {k: v for k, v in state.items()
                 if k not in ("format", "format_version", "library_version", "config", "model")}
        save_checkpoint(checkpoint, state["config"], state["model"], **{**extra, "latent_statistics": statistics})
    return statistics


def read_card(checkpoint: str | os.PathLike) -> dict:
    """The JSON card of a released checkpoint.

    Args:
        checkpoint: ``chair.pt`` or ``chair.json``.

    Returns:
        The card dict (module docstring).

    Raises:
        FileNotFoundError: the checkpoint has no card.
    """
    path = card_path(checkpoint)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no checkpoint card (written by 'cuboidlib train --release')")
    card = read_json(path)
    if not isinstance(card, dict) or card.get("format") != CARD_FORMAT:
        raise ValueError(f"{path}: not a cuboidlib checkpoint card (no format tag {CARD_FORMAT!r})")
    return card



def _short_cards_markdown(checkpoints: list[str | os.PathLike]) -> str:
    rows = ["| network | M | CD x1000: network / k-means boxes | mIoU %: network / k-means boxes | N_AC |",
            "| --- | --- | --- | --- | --- |"]
    for checkpoint in checkpoints:
        card = read_card(checkpoint)
        network, baseline = card["test"]["results"]
        cd = [1000 * r["chamfer"][0]["value"] for r in (network, baseline)]
        rows.append(f"| {Path(checkpoint).stem} | {card['config']['model']['num_cuboids']} "
                    f"| {cd[0]:.2f} / {cd[1]:.2f} | {100 * network['miou']:.1f} / {100 * baseline['miou']:.1f} "
                    f"| {network['n_ac']:.2f} |")
    return "\n".join(rows)


def cards_markdown(checkpoints: list[str | os.PathLike], short: bool = False) -> str:
    """A Markdown table of released checkpoints, one row per card, for README files.

    Columns: checkpoint (the file's name), M, training (steps, minutes, "a + b" for two stages, and the whole
    command's minutes when the card records them; processes), test shapes (and their generator version, 1 for a
    config without one), then network / baseline Chamfer
    distance x 1000 (the card's first convention), normal consistency and mIoU %, and the network's N_AC and box
    distance ("-" on a card scored before the box distance existed). The short table, for a front page, keeps
    the network's name, M, the Chamfer distance, the mIoU and N_AC.

    Args:
        checkpoints: the released ``.pt`` files (or their cards).
        short: the front page's five columns instead of all nine.

    Returns:
        The table, lines joined by newlines.
    """
    if short:
        return _short_cards_markdown(checkpoints)
    rows = ["| checkpoint | M | training | test shapes, generator | CD x1000: network / baseline | NC: network / baseline "
            "| mIoU %: network / baseline | N_AC | box distance |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for checkpoint in checkpoints:
        card = read_card(checkpoint)
        network, baseline = card["test"]["results"]
        cd = [1000 * r["chamfer"][0]["value"] for r in (network, baseline)]
        stages = [card["initialised_from"]["training"]] if "training" in card.get("initialised_from", {}) else []
        stages.append(card["training"])
        steps = " + ".join(str(t["steps"]) for t in stages)
        minutes = " + ".join(f"{t['seconds'] / 60:.1f}" for t in stages)
        processes = card["machine"].get("processes", 1)
        box = "-" if network.get("box_distance") is None else f"{network['box_distance']:.4f}"
        whole = f" (the command: {card['command_seconds'] / 60:.1f} min)" if "command_seconds" in card else ""
        rows.append(
            f"| `{Path(checkpoint).with_suffix('.pt').name}` | {card['config']['model']['num_cuboids']} "
            f"| {steps} steps, {minutes} min{whole}, {processes} process{'es' if processes > 1 else ''} "
            f"| {card['test']['n_shapes']}, version {card['config'].get('generator_version', 1)} "
            f"| {cd[0]:.2f} / {cd[1]:.2f} | {network['normal_consistency']:.3f} / {baseline['normal_consistency']:.3f} "
            f"| {100 * network['miou']:.1f} / {100 * baseline['miou']:.1f} | {network['n_ac']:.2f} | {box} |"
        )
    return "\n".join(rows)
