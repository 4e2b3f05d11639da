"""Compiled kernels for the CPU, used by default: the kNN selection and EdgeConv's per-edge loops.

``kernels.cpp`` beside this file holds C++ versions of three hot spots, each replacing a labelled piece of
Python that stays the reference (``tests/test_kernels.py`` compares values and gradients):

- ``smallest_k`` for the top-k selection in :func:`cuboidlib.neighbors.knn_indices`;
- ``edge_mlp_forward`` / ``edge_mlp_backward`` for the chunk loops of :mod:`cuboidlib.edgeconv_fast`;
- ``edge_stats`` for the first BatchNorm's statistics of ``FastEdgeConv``.

The first call of :func:`enabled` in a process decides: where a C++ compiler and ninja are found, the kernels
are built on first use (once per machine, about a minute on 2 cores; PyTorch caches the build under
``~/.cache/torch_extensions`` or ``$TORCH_EXTENSIONS_DIR``) and used for CPU tensors; otherwise one line on
stderr says why and the PyTorch code runs. ``CUBOIDLIB_COMPILED_KERNELS=0`` (or :func:`disable`) turns them
off; :func:`enable` asks for them and raises :class:`KernelsUnavailable` where they cannot be built.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path
from types import ModuleType

__all__ = ["KernelsUnavailable", "available", "enable", "disable", "enabled", "ops", "ENV"]

#: The environment variable that turns the kernels off ("0", "off", "false" or "no").
ENV = "CUBOIDLIB_COMPILED_KERNELS"

_SOURCE = Path(__file__).with_name("kernels.cpp")
_VECTOR_FLAGS = {  # by torch.backends.cpu.get_cpu_capability()
    "AVX2": ["-mavx2", "-mfma"],
    "AVX512": ["-mavx2", "-mfma", "-mavx512f", "-mavx512bw", "-mavx512vl", "-mavx512dq"],
}
_module: ModuleType | None = None
_enabled: bool | None = None  # None: not decided yet in this process


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
        if not _built(name):
            print("cuboidlib: building the compiled kernels (once per machine, about a minute)", file=sys.stderr)
        try:
            _module = load(name, [str(_SOURCE)], extra_cflags=flags, verbose=False)
        except Exception as error:  # a compiler or linker failure: say so, then the Python code still works
            raise KernelsUnavailable(f"building {_SOURCE.name} failed: {error}") from error
    return _module


def _built(name: str) -> bool:
    """Whether a build of ``name`` is already in PyTorch's extension cache (then loading takes a fraction of a second)."""
    from torch.utils.cpp_extension import _get_build_directory  # noqa: PLC2701 (where load() looks)

    try:
        return (Path(_get_build_directory(name, verbose=False)) / f"{name}.so").is_file()
    except Exception:  # the cache folder cannot be made: load() will say so
        return False


def enable() -> None:
    """Use the compiled kernels for CPU tensors from now on in this process (builds them if needed).

    Raises:
        KernelsUnavailable: no C++ compiler or ninja, or the build failed.
    """
    global _enabled
    ops()
    _enabled = True


def disable() -> None:
    """Use the PyTorch code from now on in this process."""
    global _enabled
    _enabled = False


def enabled() -> bool:
    """Whether the kernels are in use; the first call decides (see the module docstring)."""
    global _enabled
    if _enabled is None:
        if os.environ.get(ENV, "").strip().lower() in ("0", "off", "false", "no"):
            _enabled = False
        else:
            try:
                enable()
            except KernelsUnavailable as error:
                print(f"cuboidlib: the compiled kernels are not used ({error}); the PyTorch code runs instead",
                      file=sys.stderr)
                _enabled = False
    return _enabled
