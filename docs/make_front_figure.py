"""Draw the README's front figure: a point cloud, the cuboids a committed network gives it, and its parts.

Each row is one sample mesh of ``data_samples/meshes/``, abstracted by the committed network of its category
(``cuboidlib.abstract(mesh, model=category)``, 1024 points sampled on the mesh):

1. the points the network reads;
2. the existing cuboids, each point coloured by its cuboid index (the same index, the same colour, in every shape);
3. the parts: each point coloured by the part name its cuboid carries, learned by the label transfer of
   Sec. 4.2 and stored in the network's card (the colours of ``data_samples/samples.png``).

Example::

    python docs/make_front_figure.py                       # writes docs/front.png
    python docs/make_front_figure.py --shapes table_0 airplane_0 --out /tmp/front.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
MESHES = ROOT / "data_samples" / "meshes"
COLUMNS = ("1. the point cloud", "2. the network's cuboids", "3. the parts they name")
#: (elevation, azimuth) in degrees per category: airplanes seen from above, the rest from the front left.
VIEWS = {"airplane": (55.0, -60.0), "animal": (20.0, -20.0)}


def abstract_sample(name: str):
    """Abstract one sample mesh with the committed network of its category.

    Args:
        name: a mesh of ``data_samples/meshes/`` without its suffix, "<category>_<i>", e.g. "chair_0".

    Returns:
        ``(category, Abstraction)``: the abstraction holds the normalised points (1024, 3), their cuboid
        indices (1024,) and each cuboid's part label (M,).
    """
    import cuboidlib
    from cuboidlib.shapes import PART_NAMES

    path = MESHES / f"{name}.ply"
    category = name.rsplit("_", 1)[0]
    if category not in PART_NAMES or not path.is_file():
        known = sorted(p.stem for p in MESHES.glob("*.ply"))
        raise SystemExit(f"no sample mesh {name!r}: expected one of {known}")
    return category, cuboidlib.abstract(path, model=category, up="y")


def _parts_legend(ax, category: str) -> None:
    """A legend of the category's part names in their colours (label k: ``PALETTE[k]``)."""
    from matplotlib.lines import Line2D

    from cuboidlib.shapes import PART_NAMES
    from cuboidlib.viz import cuboid_color

    handles = [Line2D([], [], marker="o", linestyle="", color=cuboid_color(k), label=part)
               for k, part in enumerate(PART_NAMES[category])]
    ax.legend(handles=handles, loc="lower right", fontsize=7, frameon=False, handletextpad=0.1, borderaxespad=0)


def draw(names: list[str], panel_size: float = 2.7):
    """The figure: one row per sample mesh, the three columns of :data:`COLUMNS`.

    Args:
        names: sample meshes, e.g. ``["chair_0", "airplane_0"]``, at least one.
        panel_size: width and height of one panel in inches.

    Returns:
        A matplotlib ``Figure``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cuboidlib.viz import plot_cuboids_matplotlib

    if not names:
        raise ValueError("names is empty: give at least one sample mesh, e.g. chair_0")
    fig = plt.figure(figsize=(panel_size * len(COLUMNS), panel_size * len(names)))
    for row, name in enumerate(names):
        category, result = abstract_sample(name)
        cuboids, labels = result.cuboids, result.labels
        parts = np.asarray(result.part_labels)[labels]
        hidden = np.zeros(cuboids.num_cuboids, dtype=bool)
        panels = ((None, hidden), (labels, None), (parts, hidden))
        for col, (colours, exists) in enumerate(panels):
            ax = fig.add_subplot(len(names), len(COLUMNS), row * len(COLUMNS) + col + 1, projection="3d",
                                 proj_type="ortho")
            plot_cuboids_matplotlib(ax, result.points, colours, cuboids, exists=exists, alpha=0.25, point_size=3.0,
                                    title=COLUMNS[col] if row == 0 else None, view=VIEWS.get(category, (25.0, -60.0)))
            ax.set_box_aspect((1, 1, 1), zoom=1.35)  # the shape fills more of its panel
        _parts_legend(ax, category)
        fig.text(0.005, 1 - (row + 0.5) / len(names), f"{category}\n{result.num_existing} cuboids", fontsize=8,
                 va="center")
    fig.subplots_adjust(left=0.03, right=1, bottom=0, top=0.95, wspace=0, hspace=0)
    return fig


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", nargs="+", default=["chair_0", "animal_0"], metavar="NAME",
                        help="sample meshes of data_samples/meshes/, one row each (default: chair_0 animal_0)")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "front.png", help="the PNG to write")
    parser.add_argument("--dpi", type=int, default=100, help="dots per inch (default 100)")
    args = parser.parse_args(argv)
    if not 30 <= args.dpi <= 600:
        parser.error(f"--dpi must lie in [30, 600], got {args.dpi}")
    if args.out.suffix.lower() != ".png":
        parser.error(f"--out must name a .png file, got {args.out}")
    from cuboidlib.files import atomic_path

    fig = draw(args.shapes)
    with atomic_path(args.out) as tmp:  # a reader never sees half a file
        fig.savefig(tmp, dpi=args.dpi)
    print(f"wrote {args.out} ({', '.join(args.shapes)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
