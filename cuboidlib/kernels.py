"""Optional compiled kernels for the CPU: the kNN selection and EdgeConv's per-edge loops.

**COMPILED VERSION, opt-in.** ``kernels.cpp`` beside this file holds C++ versions of two hot spots
of a CPU training step, each replacing a labelled piece of Python that stays the reference:

- ``smallest_k`` for the top-k selection in :func:`cuboidlib.neighbors.knn_indices` (``torch.topk``);
- ``edge_mlp_forward`` / ``edge_mlp_backward`` for the chunk loops of ``_EdgeMLP`` in
  :mod:`cuboidlib.model` (the gathers, LeakyReLU, max over neighbours, BatchNorm sums and scatters
  around the matrix products, fused into single passes over memory; the backward pass needs two
  products per chunk instead of three);
- ``edge_stats`` for ``FastEdgeConv._edge_stats`` (the first BatchNorm's statistics, in float64
  without float64 copies of the inputs).

They compute the same functions (``tests/test_kernels.py`` compares values and gradients with the
Python versions and with the readable network in float64) and change only the speed:
``python benchmarks/bench_model.py --variant fast compiled`` times both. Nothing uses them unless
asked::

    import cuboidlib.kernels
    cuboidlib.kernels.enable()   # compiles on first use (about 30 s on 2 cores), then cached

or ``cuboidlib train ... --compiled-kernels``. Compiling needs a C++ compiler and ``ninja`` (a
dependency of cuboidlib); PyTorch caches the build under ``~/.cache/torch_extensions`` (or
``$TORCH_EXTENSIONS_DIR``) and rebuilds it when the source changes. Where no compiler is found,
:func:`enable` raises :class:`KernelsUnavailable` with the reason and everything keeps working without
them. They run on CPU tensors only; on a GPU the PyTorch code runs as before.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path
from types import ModuleType

__all__ = ["KernelsUnavailable", "available", "enable", "disable", "enabled", "ops"]

_SOURCE = Path(__file__).with_name("kernels.cpp")
_VECTOR_FLAGS = {  # by torch.backends.cpu.get_cpu_capability()
    "AVX2": ["-mavx2", "-mfma"],
    "AVX512": ["-mavx2", "-mfma", "-mavx512f", "-mavx512bw", "-mavx512vl", "-mavx512dq"],
}
_module: ModuleType | None = None
_enabled = False


class KernelsUnavailable(RuntimeError):
    """The compiled kernels cannot be built here (no C++ compiler, no ninja, or a build error)."""


def _compiler() -> str | None:
    return shutil.which(os.environ.get("CXX", "c++")) or shutil.which("g++") or shutil.which("clang++")


def _build_flags() -> tuple[str, list[str]]:
    """The build's name and compiler flags: optimised, vectorised for the instruction set PyTorch uses
    on this CPU (named after it, so that a build cache shared between machines holds one per set), and
    on Linux with OpenMP, the threading that PyTorch itself uses (its library is already loaded)."""
    import torch

    capability = torch.backends.cpu.get_cpu_capability()
    flags = ["-O3"]
    if sys.platform == "linux":
        flags.append("-fopenmp")
    flags += _VECTOR_FLAGS.get(capability, [])
    return f"cuboidlib_kernels_{capability.lower()}", flags


def available() -> bool:
    """Whether a C++ compiler and ninja are present, so that :func:`enable` can build the kernels."""
    from torch.utils.cpp_extension import is_ninja_available

    return _compiler() is not None and is_ninja_available()


def ops() -> ModuleType:
    """The compiled module (building it on first call). Raises :class:`KernelsUnavailable`."""
    global _module
    if _module is None:
        if _compiler() is None:
            raise KernelsUnavailable("no C++ compiler found (looked for $CXX, c++, g++, clang++); "
                                     "install one (e.g. build-essential) or run without the compiled kernels")
        from torch.utils.cpp_extension import is_ninja_available, load

        if not is_ninja_available():
            raise KernelsUnavailable("ninja is not installed; `pip install ninja`, or run without the compiled kernels")
        name, flags = _build_flags()
        try:
            _module = load(name, [str(_SOURCE)], extra_cflags=flags, verbose=False)
        except Exception as error:  # a compiler or linker failure: say so, then the Python code still works
            raise KernelsUnavailable(f"building {_SOURCE.name} failed: {error}") from error
    return _module


def enable() -> None:
    """Use the compiled kernels for CPU tensors from now on in this process (builds them if needed)."""
    global _enabled
    ops()
    _enabled = True


def disable() -> None:
    """Go back to the PyTorch code."""
    global _enabled
    _enabled = False


def enabled() -> bool:
    """Whether :func:`enable` is in effect."""
    return _enabled
