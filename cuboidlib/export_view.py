"""HTML views of results: self-contained pages (plotly.js embedded) of the result files that
:mod:`cuboidlib.export` writes (``cuboidlib view``).
"""

from __future__ import annotations

import html
import os
import urllib.parse
from pathlib import Path

import numpy as np

from .export import JSON_FORMAT, read_cuboids_json, read_manifest
from .files import check_outputs_spare_inputs, read_json, write_text_atomic
from .geometry import Cuboids
from .io import read_point_cloud
from .viz import plot_cuboids_plotly, plot_cuboids_plotly_grid

__all__ = ["cuboid_part_names", "write_view_html"]


def _result_jsons(path: Path) -> list[Path]:
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: no such result folder or JSON file")
    manifest = read_manifest(path)
    candidates = ([path / f for f in manifest["files"] if f.endswith(".json")] if manifest is not None
                  else sorted(path.glob("*.json")))
    found = []
    for candidate in candidates:
        try:
            doc = read_json(candidate)
        except (OSError, ValueError):
            continue
        if isinstance(doc, dict) and doc.get("format") == JSON_FORMAT:
            found.append(candidate)
    if not found:
        raise ValueError(f"{path}: holds no cuboidlib result (no JSON file with \"format\": \"{JSON_FORMAT}\")")
    return found


def cuboid_part_names(meta: dict) -> list[str | None] | None:
    """The part name of every cuboid index of a result.

    Args:
        meta: the metadata of :func:`read_cuboids_json`.

    Returns:
        M names (None where unknown), or None if the result names no parts.
    """
    names, labels = meta.get("part_names"), meta.get("part_labels")
    if not names or labels is None:
        return None
    return [names[k] if 0 <= k < len(names) else None for k in labels]


def _points_file(json_path: Path) -> str | None:
    """The ``points_file`` a result JSON names (a file name beside it), or None."""
    try:
        name = read_json(json_path).get("points_file")
    except (OSError, ValueError, AttributeError):
        return None
    return name if isinstance(name, str) and name and Path(name).name == name else None


def _result_item(json_path: Path) -> tuple[str, Cuboids, np.ndarray, np.ndarray | None, list | None]:
    cuboids, meta = read_cuboids_json(json_path)
    points, labels = np.zeros((0, 3)), None
    if meta.get("points_file"):
        name = meta["points_file"]
        if not isinstance(name, str) or Path(name).name != name or name in (".", ".."):
            raise ValueError(f"{json_path}: points_file {name!r} must be the name of a file beside the JSON (as "
                             "cuboidlib writes it); a result never reads points from another folder")
        cloud = read_point_cloud(json_path.parent / name)
        points, labels = cloud.points, cloud.labels
    title = f"{meta.get('source') or json_path.stem}: {meta['num_existing']} of {meta['num_cuboids']} cuboids"
    return title, cuboids, points, labels, cuboid_part_names(meta)


def _href(name: str) -> str:
    """A file name beside the page as a link target: percent-encoded (markup, quotes and spaces included), so
    that no character of a name becomes markup on the page."""
    return html.escape(urllib.parse.quote(name, safe=""), quote=True)


def write_view_html(
    result: str | os.PathLike,
    out: str | os.PathLike | None = None,
    max_points: int = 4000,
    cols: int = 4,
    per_page: int = 48,
) -> list[Path]:
    """Self-contained HTML pages of results (plotly.js embedded: they open offline in any browser).

    One result is drawn with :func:`cuboidlib.viz.plot_cuboids_plotly` (a legend toggles each cuboid),
    several as grids (:func:`cuboidlib.viz.plot_cuboids_plotly_grid`) with links between the pages.

    Args:
        result: a result JSON file, or a folder of them (as :meth:`cuboidlib.abstraction.Abstraction.save` and
            ``cuboidlib fit / abstract / generate / interpolate`` write; a folder's manifest says which).
        out: the first page (default: ``view.html`` in the folder, or beside the JSON file); page k > 1 is
            ``<out stem>_k.html`` beside it.
        max_points: points drawn per page (shared among the results of a grid).
        cols: grid columns.
        per_page: results per page.

    Returns:
        The paths of the pages written.
    """
    if isinstance(per_page, bool) or not isinstance(per_page, int) or per_page < 1:
        raise ValueError(f"per_page must be a positive integer, got {per_page!r}")
    source = Path(result)
    jsons = _result_jsons(source)
    first = Path(out) if out is not None else (source if source.is_dir() else source.parent) / "view.html"
    chunks = [jsons[i:i + per_page] for i in range(0, len(jsons), per_page)]
    pages = [first] + [first.with_name(f"{first.stem}_{k}{first.suffix}") for k in range(2, len(chunks) + 1)]
    inputs = [*jsons, *[p.parent / _points_file(p) for p in jsons if _points_file(p)]]
    check_outputs_spare_inputs(pages, [p for p in inputs if p.exists()], "the page")
    if first.suffix.lower() not in (".html", ".htm"):
        raise ValueError(f"{first}: the page must be an .html file (it is written as HTML); got "
                         f"{first.suffix or 'no suffix'!r}")
    for k, (chunk, page) in enumerate(zip(chunks, pages)):
        items = [_result_item(p) for p in chunk]
        if len(items) == 1:
            title, cuboids, points, labels, names = items[0]
            fig = plot_cuboids_plotly(points, labels, cuboids, max_points=max_points, title=title, width=900,
                                      height=760, names=names)
        else:
            fig = plot_cuboids_plotly_grid([(p, lab, c) for _, c, p, lab, _ in items], titles=[t for t, *_ in items],
                                           cols=cols, max_points=max(1, max_points // len(items)))
        html = fig.to_html(include_plotlyjs=True, full_html=True)
        if len(pages) > 1:
            links = " ".join(f"<b>{i + 1}</b>" if i == k else f'<a href="{_href(p.name)}">{i + 1}</a>'
                             for i, p in enumerate(pages))
            nav = f'<p style="font-family:sans-serif">{len(jsons)} results, page {k + 1} of {len(pages)}: {links}</p>'
            html = html.replace("<body>", "<body>" + nav, 1)
        write_text_atomic(page, html)
    return pages
