"""Compiled kernels for the CPU, used by default: the kNN selection and EdgeConv's per-edge loops.

``kernels.cpp`` beside this file holds C++ versions of three hot spots, each replacing a labelled piece of
Python that stays the reference (``tests/test_kernels.py`` compares values and gradients):

- ``smallest_k`` for the top-k selection in :func:`cuboidlib.neighbors.knn_indices`;
- ``edge_mlp_forward`` / ``edge_mlp_backward`` for the chunk loops of :mod:`cuboidlib.edgeconv_fast`;
- ``edge_stats`` for the first BatchNorm's statistics of ``FastEdgeConv``.

The first call of :func:`enabled` in a process decides: where a C++ compiler and ninja are found, the kernels
are built on first use (once per machine, about a minute on 2 cores, under ``~/.cache/torch_extensions`` or
``$TORCH_EXTENSIONS_DIR``, in a folder named by a hash of the source, the flags, the compiler, torch and Python)
and used for CPU tensors; otherwise one line on stderr says why and the PyTorch code runs. A build runs under
the project's own lock (:class:`_BuildLock`): a lock left by a process that is gone is taken over, a live
build is waited for at most :data:`LOCK_WAIT_SECONDS`. ``CUBOIDLIB_COMPILED_KERNELS=0`` (or :func:`disable`)
turns them off, ``=1`` asks for them (an error where they cannot be built); :func:`enable` asks for them and
raises :class:`KernelsUnavailable` where they cannot be built.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
import time
from pathlib import Path
from types import ModuleType

from .files import atomic_path

try:
    import fcntl  # POSIX file locks
except ImportError:  # pragma: no cover (Windows)
    fcntl = None

__all__ = ["KernelsUnavailable", "available", "build_root", "enable", "disable", "enabled", "ops", "ENV",
           "LOCK_WAIT_SECONDS", "LOCK_NOTICE_SECONDS"]

#: The environment variable that turns the kernels off ("0", "off", "false", "no") or asks for them ("1", "on", "true",
#: "yes"); unset, empty or "auto": used where they build. Any other value is an error.
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
    """The build's name and compiler flags.

    The flags: optimised, vectorised for the instruction set PyTorch uses on this CPU, and on Linux with
    OpenMP, the threading that PyTorch itself uses (its library is already loaded). The name holds that
    instruction set and a hash of everything the library depends on: the source, the flags, the compiler,
    the torch version, the C++ ABI and the Python version. So two checkouts, two versions or two
    environments sharing one build cache each get a folder of their own, and never rebuild or load
    another's library."""
    import torch

    capability = torch.backends.cpu.get_cpu_capability()
    flags = ["-O3"]
    if sys.platform == "linux":
        flags.append("-fopenmp")
    flags += _VECTOR_FLAGS.get(capability, [])
    key = hashlib.sha256(_SOURCE.read_bytes())
    for part in (" ".join(flags), str(_compiler()), torch.__version__, str(torch.compiled_with_cxx11_abi()),
                 f"{sys.implementation.name}{sys.version_info[0]}.{sys.version_info[1]}"):
        key.update(b"\0" + part.encode())
    return f"cuboidlib_kernels_{capability.lower()}_{key.hexdigest()[:12]}", flags


def build_root() -> Path:
    """The folder that holds the builds: ``$TORCH_EXTENSIONS_DIR``, else PyTorch's default
    (``~/.cache/torch_extensions/<python and torch tags>``)."""
    from torch.utils.cpp_extension import get_default_build_root

    return Path(os.environ.get("TORCH_EXTENSIONS_DIR") or get_default_build_root())


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
        from torch.utils.cpp_extension import is_ninja_available

        if not is_ninja_available():
            raise KernelsUnavailable("ninja is not installed; `pip install ninja`, or run without the compiled kernels")
        name, flags = _build_flags()
        folder = build_root() / name
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise KernelsUnavailable(f"the build folder {folder} cannot be made ({error})") from error
        with _BuildLock(folder.with_name(name + ".lock")):
            _module = _load(name, flags, folder)
    return _module


def _load(name: str, flags: list[str], folder: Path) -> ModuleType:
    """Build (where needed) and import the module; called while this process holds the build lock."""
    from torch.utils.cpp_extension import load

    if not (folder / f"{name}.so").is_file():
        print("cuboidlib: building the compiled kernels (once per machine, about a minute)", file=sys.stderr)
    # PyTorch's own lock file records no process, so one left by a killed build makes load() wait forever.
    # Every build of this folder holds the project's lock first, so a file found now is such a leftover.
    (folder / "lock").unlink(missing_ok=True)
    try:
        source = _source_copy(folder)
        return load(name, [str(source)], extra_cflags=flags, build_directory=str(folder), verbose=False)
    except Exception as error:  # a compiler or linker failure: say so, then the Python code still works
        raise KernelsUnavailable(f"building {_SOURCE.name} failed: {error}") from error


def _source_copy(folder: Path) -> Path:
    """The source, copied into the build folder once: ninja rebuilds when a command line changes, and the
    command names the source's path, so checkouts in different folders would otherwise rebuild the same kernels
    in turn. The folder's name holds the source's hash, so the copy is the same for every checkout."""
    copy = folder / _SOURCE.name
    if not copy.is_file() or copy.read_bytes() != _SOURCE.read_bytes():
        with atomic_path(copy) as tmp:
            tmp.write_bytes(_SOURCE.read_bytes())
    return copy


#: How long a process waits for another's build of the same kernels before it runs the PyTorch code.
LOCK_WAIT_SECONDS = 180.0
#: After how long the wait is announced, with the lock file's name.
LOCK_NOTICE_SECONDS = 30.0


class _BuildLock:
    """The project's build lock: an exclusive ``flock`` on ``path``, which records the holder's process id.

    The operating system releases the lock when its process ends, however it ends (SIGTERM, SIGKILL, a
    crash), so a lock left by a process that is gone is taken over at once. A lock held by a live process
    is waited for at most :data:`LOCK_WAIT_SECONDS`, with one line on stderr after
    :data:`LOCK_NOTICE_SECONDS` naming the file; then :class:`KernelsUnavailable` is raised. Where ``fcntl``
    does not exist (Windows), builds are not serialised."""

    def __init__(self, path: Path):
        self.path = path
        self._file = None

    def __enter__(self) -> "_BuildLock":
        if fcntl is None:  # pragma: no cover (not POSIX)
            return self
        try:
            self._file = open(self.path, "a+")
        except OSError as error:
            raise KernelsUnavailable(f"the build lock {self.path} cannot be opened ({error})") from error
        start, noticed = time.monotonic(), False
        while True:
            try:
                fcntl.flock(self._file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except OSError:
                waited = time.monotonic() - start
                if waited >= LOCK_WAIT_SECONDS:
                    holder = self._holder()
                    self._file.close()
                    raise KernelsUnavailable(
                        f"another process{holder} has held the build lock {self.path} for {waited:.0f} s; "
                        "if no build is running, delete that file") from None
                if not noticed and waited >= LOCK_NOTICE_SECONDS:
                    print(f"cuboidlib: waiting for another process{self._holder()} that is building the compiled "
                          f"kernels (lock file {self.path}); at most {LOCK_WAIT_SECONDS:.0f} s in all", file=sys.stderr)
                    noticed = True
                time.sleep(0.2)
        self._file.seek(0)
        self._file.truncate()
        self._file.write(f"{os.getpid()}\n")
        self._file.flush()
        return self

    def _holder(self) -> str:
        try:
            pid = Path(self.path).read_text().split()[0]
        except (OSError, IndexError):
            return ""
        return f" (pid {pid})" if pid.isdigit() else ""

    def __exit__(self, *exc) -> None:
        if self._file is not None:
            fcntl.flock(self._file.fileno(), fcntl.LOCK_UN)
            self._file.close()
            self._file = None


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


def _setting() -> bool | None:
    """The choice made by :data:`ENV`: False (off), True (asked for) or None (not set: use them where they build).

    Raises:
        ValueError: any other value, which would otherwise be read as a silent "on" or "off".
    """
    value = os.environ.get(ENV, "").strip().lower()
    if value in ("", "auto"):
        return None
    if value in _OFF:
        return False
    if value in _ON:
        return True
    raise ValueError(f"{ENV}={os.environ[ENV]!r} is not understood; expected one of "
                     f"{', '.join(_OFF)} (off), {', '.join(_ON)} (on) or auto (the default)")


_OFF = ("0", "off", "false", "no")
_ON = ("1", "on", "true", "yes")


def enabled() -> bool:
    """Whether the kernels are in use; the first call decides (see the module docstring).

    Raises:
        ValueError: :data:`ENV` holds a value that is neither on, off nor auto.
        KernelsUnavailable: :data:`ENV` asks for the kernels and they cannot be built.
    """
    global _enabled
    if _enabled is None:
        setting = _setting()
        if setting is False:
            _enabled = False
        elif setting is True:
            enable()
        else:
            try:
                enable()
            except KernelsUnavailable as error:
                print(f"cuboidlib: the compiled kernels are not used ({error}); the PyTorch code runs instead",
                      file=sys.stderr)
                _enabled = False
    return _enabled
