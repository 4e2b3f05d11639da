"""cuboidlib: the tested support library of the cuboid-abstraction course.

It implements Yang & Chen, "Unsupervised Learning for Cuboid Shape Abstraction via Joint
Segmentation from Point Clouds" (SIGGRAPH 2021). Each module is named after a concept of the paper;
see docs/modules.md for the map from the paper's sections and equations to modules.

The public API, in three lines::

    import cuboidlib
    result = cuboidlib.abstract("my_chair.obj", model="chair")   # or model=None: fit this shape alone
    result.save("out")                                           # JSON, GLB and the segmented points

Names offered here (each documented in its module): :func:`abstract`, :class:`OrientationWarning` and
:class:`NetworkFitWarning` (:mod:`cuboidlib.abstraction`), :class:`Abstraction` (:mod:`cuboidlib.results`),
:func:`load_point_cloud` and :class:`PointCloud` (:mod:`cuboidlib.io`),
:func:`load_trained_model` (:mod:`cuboidlib.applications`), :class:`Cuboids`
(:mod:`cuboidlib.geometry`), :func:`fit_cuboids` and :class:`FitConfig` (:mod:`cuboidlib.fitting`).
They are imported on first use, so ``import cuboidlib`` (and the command-line tool) start quickly.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_PUBLIC = {
    "abstract": "abstraction",
    "Abstraction": "results",
    "OrientationWarning": "abstraction",
    "NetworkFitWarning": "abstraction",
    "load_point_cloud": "io",
    "PointCloud": "io",
    "load_trained_model": "applications",
    "Cuboids": "geometry",
    "fit_cuboids": "fitting",
    "FitConfig": "fitting",
}

__all__ = ["__version__", *_PUBLIC]


def __getattr__(name: str):
    if name in _PUBLIC:
        value = getattr(importlib.import_module(f".{_PUBLIC[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'cuboidlib' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
