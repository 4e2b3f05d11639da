"""Writing result files: atomically (a result is complete under its name or absent, never half-written), and
in which mesh formats. It imports no torch, so the command line uses it while it parses its arguments.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["MESH_FORMATS", "atomic_path", "write_text_atomic"]

#: The formats of cuboid meshes (:func:`cuboidlib.export.write_cuboid_mesh`, ``cuboidlib fit --mesh-format``).
MESH_FORMATS = ("glb", "obj", "ply")


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path beside ``path``: renamed to ``path`` when the block ends without error, else removed.

    Args:
        path: the file to write; its folder is created if missing.

    Returns:
        A context manager yielding the temporary Path (same suffix, so writers choose the same format).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=f".part{path.suffix}")
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically.

    Args:
        path: the file to write.
        text: its content.

    Returns:
        ``path`` as a Path.
    """
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)
