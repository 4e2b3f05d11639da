"""Writing result files: atomically (a result is complete under its name or absent, never half-written), and
in which mesh formats; reading the bytes and the JSON of a user's file, with compressed content and too deep
nesting refused by name. It imports no torch, so the command line uses it while it parses its arguments.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["MESH_FORMATS", "MANIFEST", "RESULT_FORMAT", "atomic_path", "write_text_atomic",
           "check_outputs_spare_inputs", "check_distinct_outputs", "result_files_in", "LOCK_FILE", "output_lock",
           "check_not_packed", "read_file_bytes", "parse_json", "read_json"]

#: The file in which a run records the files it wrote in its output folder (:func:`cuboidlib.export.write_manifest`).
MANIFEST = "cuboidlib-manifest.json"

#: The ``"format"`` of a result JSON (:func:`cuboidlib.export.write_cuboids_json`).
RESULT_FORMAT = "cuboidlib-cuboids"

#: The formats of cuboid meshes (:func:`cuboidlib.export.write_cuboid_mesh`, ``cuboidlib fit --mesh-format``).
MESH_FORMATS = ("glb", "obj", "ply")


def _umask() -> int:
    mask = os.umask(0o022)  # reading the umask means setting it; set straight back
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path beside ``path``: renamed to ``path`` when the block ends without error, else removed.

    Args:
        path: the file to write; its folder is created if missing.

    Returns:
        A context manager yielding the temporary Path (same suffix, so writers choose the same format); the
        file is made with mode 0666 less the umask, like any file the user makes. Where ``path`` is a symbolic
        link, the link itself is replaced: its target is never written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=f".part{path.suffix}")
    try:  # mkstemp makes 0600 files; a result gets the mode of any file the user makes (0666 less the umask)
        os.fchmod(fd, 0o666 & ~_umask())
    finally:
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


#: The first bytes of compressed and archive formats, what they are, and what to do instead.
_PACKED = (
    (b"\x1f\x8b", "gzip-compressed", "decompress it first (gunzip)"),
    (b"PK\x03\x04", "a zip archive (a NumPy .npz file is one)",
     "extract it first (for an .npz file: np.load it and np.save the array you want as .npy)"),
    (b"PK\x05\x06", "an empty zip archive", "extract it first"),
    (b"BZh", "bzip2-compressed", "decompress it first (bunzip2)"),
    (b"\xfd7zXZ\x00", "xz-compressed", "decompress it first (unxz)"),
    (b"(\xb5/\xfd", "zstd-compressed", "decompress it first (unzstd)"),
    (b"7z\xbc\xaf\x27\x1c", "a 7-Zip archive", "extract it first"),
)

#: The byte order mark some editors put at the start of a UTF-8 text file.
UTF8_BOM = b"\xef\xbb\xbf"


def check_not_packed(path: str | os.PathLike, head: bytes, expected: str) -> None:
    """Refuse a file whose first bytes are those of a compressed file or an archive.

    Args:
        path: the file, for the message.
        head: its first bytes (8 are enough).
        expected: what the file should hold, e.g. ``"a PLY file"``.

    Raises:
        ValueError: naming the file, what it holds and what to do.
    """
    for magic, what, remedy in _PACKED:
        if head.startswith(magic):
            raise ValueError(f"{path}: is {what}, not {expected}; {remedy}")


def read_file_bytes(path: str | os.PathLike, expected: str) -> bytes:
    """The content of a user's file, with a leading UTF-8 byte order mark dropped.

    Args:
        path: an existing file.
        expected: what it should hold, for messages (``"a PLY file"``).

    Returns:
        Its bytes.

    Raises:
        ValueError: the file is compressed or an archive (:func:`check_not_packed`).
    """
    data = Path(path).read_bytes()
    check_not_packed(path, data[:8], expected)
    return data[len(UTF8_BOM):] if data.startswith(UTF8_BOM) else data


def parse_json(text: str | bytes, source: str):
    """Parse JSON text, every failure a ``ValueError`` naming ``source``.

    Args:
        text: the JSON text, or its UTF-8 bytes (a leading byte order mark is dropped).
        source: names the text in messages (a file name).

    Returns:
        The parsed value.

    Raises:
        ValueError: not UTF-8, not valid JSON, or nested too deeply for Python's parser.
    """
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ValueError(f"{source}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from exc
    try:
        return json.loads(text.removeprefix("\ufeff"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{source}: not valid JSON ({exc})") from exc
    except RecursionError:
        raise ValueError(f"{source}: the JSON is nested too deeply to read (lists or objects inside one another "
                         "about a thousand levels deep or more)") from None


def read_json(path: str | os.PathLike):
    """Read a JSON file; a missing file raises ``FileNotFoundError``, anything else unreadable ``ValueError``.

    Args:
        path: the file.

    Returns:
        The parsed value.
    """
    return parse_json(read_file_bytes(path, "a JSON file"), str(path))


def _real(path: str | os.PathLike) -> str:
    return os.path.normcase(os.path.realpath(path))


def check_outputs_spare_inputs(outputs, inputs, what: str = "output") -> None:
    """Refuse, before any work, output paths that would write over or remove an input.

    An output conflicts with an input when it is the same file (after symlinks; hard links count too) or lies
    inside an input folder.

    Args:
        outputs: the paths a run will write or remove.
        inputs: the files and folders it reads.
        what: names the outputs in the message (e.g. "--out").

    Raises:
        ValueError: naming the output, the input and what to do.
    """
    sources = [(Path(i), _real(i)) for i in inputs]
    for output in outputs:
        real = _real(output)
        for given, source in sources:
            same = real == source
            if not same and os.path.exists(output) and given.exists():
                try:
                    same = os.path.samefile(output, given)
                except OSError:
                    same = False
            if same:
                raise ValueError(f"{what} {output}: is the input {given}; this run would write over or remove "
                                 "it. Choose another output (or copy the input elsewhere first)")
            if given.is_dir() and real.startswith(source.rstrip(os.sep) + os.sep):
                raise ValueError(f"{what} {output}: lies inside the input folder {given}; results written there "
                                 "would be read as inputs later. Choose an output outside it")


def check_distinct_outputs(named) -> None:
    """Refuse, before any work, two outputs of one run that are the same file (one would overwrite the other).

    Args:
        named: (label, path) pairs, the label saying what the path is (e.g. "--release", "the card of --release").

    Raises:
        ValueError: naming both outputs.
    """
    seen: dict[str, tuple[str, str]] = {}
    for label, path in named:
        real = _real(path)
        if real in seen and seen[real] != (label, str(path)):  # (the same output named twice is one output)
            other_label, other = seen[real]
            raise ValueError(f"{label} {path}: is also {other_label} {other}; this run would write both to one "
                             "file. Choose another output")
        seen[real] = (label, str(path))


def result_files_in(folder: str | os.PathLike) -> set[str]:
    """The names of the files in ``folder`` that cuboidlib wrote as results, so that no reader takes them for data.

    They are the files a manifest there lists, and beside every result JSON (``"format"`` :data:`RESULT_FORMAT`)
    of stem S: S.json, its meshes S.glb, S.obj, S.mtl and its points file (S_segmentation.ply). A mesh S.ply
    counts only when a manifest lists it, since the input of the result may have that name.

    Args:
        folder: a folder.

    Returns:
        File names (not paths); empty when there are none.
    """
    folder = Path(folder)
    names: set[str] = set()
    try:
        doc = read_json(folder / MANIFEST)
        listed = doc.get("files") if isinstance(doc, dict) else None
        names.update(f for f in listed or [] if isinstance(f, str))
        names.add(MANIFEST)
    except (OSError, ValueError):
        pass
    for result in folder.glob("*.json"):
        try:
            doc = read_json(result)
        except (OSError, ValueError):
            continue
        if isinstance(doc, dict) and doc.get("format") == RESULT_FORMAT:
            stem = result.stem
            names.update([result.name, *(f"{stem}.{x}" for x in ("glb", "obj", "mtl")), f"{stem}_segmentation.ply"])
            if isinstance(doc.get("points_file"), str):
                names.add(doc["points_file"])
    return names


#: The file that marks an output folder as in use by a running command (:func:`output_lock`).
LOCK_FILE = ".cuboidlib.lock"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextmanager
def output_lock(folder: str | os.PathLike) -> Iterator[Path]:
    """Hold ``folder`` for one run: a second run into it, while this one writes, is refused.

    The lock is the file :data:`LOCK_FILE` in ``folder`` holding the process id, made exclusively and removed when
    the block ends; one left by a process that no longer runs is taken over.

    Args:
        folder: the output folder; created if missing (and removed again if the run left it empty).

    Returns:
        A context manager yielding the folder as a Path.

    Raises:
        ValueError: another running process holds the folder.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{folder}: exists and is not a folder")
    made = not folder.exists()
    lock = folder / LOCK_FILE
    for _ in range(2):
        try:  # before any work: a folder that cannot be written is reported now, not after the run
            folder.mkdir(parents=True, exist_ok=True)
            fd = os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except PermissionError as exc:
            raise ValueError(f"{folder}: cannot write there ({exc.strerror}); choose a folder you can write to") from exc
        except FileExistsError:
            try:
                pid = int(lock.read_text().strip() or 0)
            except (OSError, ValueError):
                pid = 0
            if pid and pid != os.getpid() and _alive(pid):
                raise ValueError(f"{folder}: another cuboidlib run (process {pid}) is writing there; wait for it "
                                 f"to finish or choose another folder (if no run is going, remove {lock})") from None
            lock.unlink(missing_ok=True)  # left by a run that ended without removing it
            continue
        with os.fdopen(fd, "w") as f:
            f.write(f"{os.getpid()}\n")
        break
    else:
        raise ValueError(f"{folder}: could not take the lock {lock}; another run may be starting there")
    try:
        yield folder
    finally:
        lock.unlink(missing_ok=True)
        if made and not any(folder.iterdir()):  # a run that wrote nothing leaves no folder behind
            folder.rmdir()
