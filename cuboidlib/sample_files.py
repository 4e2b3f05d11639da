"""The course's sample files, the committed ``data_samples/`` folder: a few procedural shapes per category as
meshes and point clouds, their index and a figure (``cuboidlib samples``). Every file is written atomically.
"""

from __future__ import annotations

import csv
import os
import sys
from pathlib import Path

from .files import atomic_path
from .io import write_point_cloud
from .shapes import CATEGORIES, GENERATOR_VERSION, PART_NAMES, check_generator_version, make_shape, plot_shapes

__all__ = ["write_shape_mesh", "sample_figure_name", "data_sample_files", "write_data_samples"]


def write_shape_mesh(path: str | os.PathLike, shape) -> Path:
    """Write a :class:`cuboidlib.shapes.Shape` as a binary PLY mesh.

    The parts' meshes are concatenated (not boolean-merged), vertices coloured by part (``PART_COLORS``),
    with an int ``label`` per face, which :func:`cuboidlib.io.load_mesh_as_point_cloud` carries to the sampled points.

    Args:
        path: the ``.ply`` file.
        shape: the procedural shape.

    Returns:
        ``path`` as a Path.
    """
    path = Path(path)
    with atomic_path(path) as tmp:
        shape.mesh().export(str(tmp), file_type="ply", encoding="binary")
    return path


def _sample_name(category: str, i: int) -> str:
    return f"{category}_{i}"


def sample_figure_name(version: int) -> str:
    """The file name of the samples' figure: ``samples.png`` for generator version 1, ``samples_v<version>.png``
    for the others (the committed ``data_samples/`` holds version 1's files and ``samples_v2.png``)."""
    return "samples.png" if check_generator_version(version) == 1 else f"samples_v{version}.png"


def data_sample_files(out_dir: str | os.PathLike, n_per_category: int = 3, figure: bool = True,
                      version: int = GENERATOR_VERSION, categories=CATEGORIES, figure_only: bool = False) -> list[Path]:
    """The files :func:`write_data_samples` writes, so that a caller can check them before any work.

    Args:
        out_dir, n_per_category, figure, version, categories, figure_only: as in :func:`write_data_samples`.

    Returns:
        Their paths: the meshes, the point clouds, ``index.csv`` (not with ``figure_only``) and (with ``figure``)
        the figure, :func:`sample_figure_name`.
    """
    out = Path(out_dir)
    names = [_sample_name(c, i) for c in categories for i in range(n_per_category)]
    drawn = [out / sample_figure_name(version)] if figure or figure_only else []
    if figure_only:
        return drawn
    return [out / "meshes" / f"{n}.ply" for n in names] + [out / "points" / f"{n}.ply" for n in names] + [
        out / "index.csv"] + drawn


def write_data_samples(out_dir: str | os.PathLike, n_per_category: int = 3, n_points: int = 2048,
                       seed: int = 0, figure: bool = True, version: int = GENERATOR_VERSION,
                       categories=CATEGORIES, figure_only: bool = False) -> list[Path]:
    """Write the course's sample files (the committed ``data_samples/`` folder, generator version 1).

    Per category, the first shapes of collection ``seed`` whose coarse structure is not taken yet:
    ``meshes/<category>_<i>.ply`` (:func:`write_shape_mesh`), ``points/<category>_<i>.ply`` (points with
    normals and labels), then ``index.csv`` (files, category, collection index, structure, part names) and
    the figure :func:`sample_figure_name` (a part-coloured scatter of every sample).

    Args:
        out_dir: the folder to write.
        n_per_category: shapes per category.
        n_points: points per shape.
        seed: the procedural collection.
        figure: also draw the figure.
        version: the generator (:data:`cuboidlib.shapes.GENERATOR_VERSIONS`).
        categories: the categories, some of :data:`cuboidlib.shapes.CATEGORIES`.
        figure_only: draw the figure and write nothing else.

    Returns:
        The paths written.
    """
    version = check_generator_version(version)
    unknown = [c for c in categories if c not in CATEGORIES]
    if unknown or not categories:
        raise ValueError(f"categories must be some of {CATEGORIES}, got {list(categories)!r}")
    out = Path(out_dir)
    written, rows, chosen = [], [], []
    for category in categories:
        seen, index, found = set(), 0, 0
        while found < n_per_category:
            shape = make_shape(category, index, n_points, seed, version)
            if shape.structure_id not in seen or index >= 50 * n_per_category:
                seen.add(shape.structure_id)
                chosen.append(shape)
                found += 1
                if not figure_only:
                    name = _sample_name(category, found - 1)
                    written.append(write_shape_mesh(out / "meshes" / f"{name}.ply", shape))
                    written.append(write_point_cloud(out / "points" / f"{name}.ply", shape.points, shape.normals,
                                                     shape.labels))
                    rows.append([f"points/{name}.ply", f"meshes/{name}.ply", category, index, shape.structure,
                                 shape.structure_id, " ".join(PART_NAMES[category])])
            index += 1
    if figure_only:
        return _draw_samples(out / sample_figure_name(version), chosen, n_per_category)
    index_file = out / "index.csv"
    with atomic_path(index_file) as tmp, open(tmp, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["points", "mesh", "category", "collection_index", "structure", "structure_id", "part_names"])
        w.writerows(rows)
    written.append(index_file)
    if figure:
        written += _draw_samples(out / sample_figure_name(version), chosen, n_per_category)
    return written


def _draw_samples(path: Path, chosen: list, ncols: int) -> list[Path]:
    """The samples' figure, one row of ``ncols`` shapes per category, titled with their structures."""
    import matplotlib

    if "matplotlib.pyplot" not in sys.modules:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plot_shapes(chosen, titles=[s.structure for s in chosen], ncols=ncols, point_size=1.5)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
    return [path]
