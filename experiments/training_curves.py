"""What a shorter training budget gives: validation mIoU and N_AC of the committed networks over wall time.

Reads the validation curve that ``cuboidlib train --release`` stores in each checkpoint card
(``data_samples/checkpoints/<category>.json``, ``training.validation``: the validation split scored every
``validate_every`` steps, mIoU by label transfer within that split) and draws, for the four categories,
mIoU and the number of existing cuboids against minutes of training, with the 15 / 30 / 60 minute marks.
A network trained in two stages (``init_from``) shows both, the second from the dashed line on.
No training happens here; the cards are the record.

Example::

    python experiments/training_curves.py            # writes experiments/results/training_curves.png
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from cuboidlib.release import CURVE_MARKS, curve_marks, read_card, training_curve  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CATEGORIES = ("chair", "table", "airplane", "animal")


def draw(checkpoints: Path) -> plt.Figure:
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    for i, category in enumerate(CATEGORIES):
        card = read_card(checkpoints / f"{category}.pt")
        curve, _, starts = training_curve(card)
        curve = [e for e in curve if "miou" in e]
        minutes = [e["seconds"] / 60 for e in curve]
        color = f"C{i}"
        processes = card["machine"].get("processes", 1)
        label = f"{category} ({processes} process{'es' if processes > 1 else ''})"
        axes[0].plot(minutes, [100 * e["miou"] for e in curve], "-", color=color, label=label)
        axes[1].plot(minutes, [e["n_ac"] for e in curve], "-", color=color, label=label)
        for ax in axes:  # where the second stage (falling learning rate) starts
            for start in starts:
                ax.axvline(start / 60, color=color, lw=0.8, ls="--")
    for ax, label in zip(axes, ("validation mIoU (%)", "cuboids per shape (N_AC)")):
        for mark in CURVE_MARKS:
            ax.axvline(mark, color="grey", lw=0.6, ls=":")
        ax.set(xlabel="training time (wall-clock minutes; one thread per process)", ylabel=label)
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle("Committed networks: validation scores over their training (from the checkpoint cards)")
    fig.tight_layout()
    return fig


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoints", type=Path, default=ROOT / "data_samples" / "checkpoints")
    parser.add_argument("--out", type=Path, default=ROOT / "experiments" / "results" / "training_curves.png")
    args = parser.parse_args(argv)
    fig = draw(args.checkpoints)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=args.out.parent, suffix=".png", delete=False) as tmp:
        fig.savefig(tmp.name, dpi=110)
    os.replace(tmp.name, args.out)  # atomic: a reader never sees half a file
    for category in CATEGORIES:
        marks = curve_marks(*training_curve(read_card(args.checkpoints / f"{category}.pt"))[:2])
        text = ", ".join(f"{m} min: mIoU {100 * e['miou']:.1f} %, N_AC {e['n_ac']:.1f}" for m, e in marks.items())
        print(f"{category:9s} {text}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
