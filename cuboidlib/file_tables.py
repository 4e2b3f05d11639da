"""The tables of numbers in users' files: rows of numeric text, and the elements of PLY files.

A file is read exactly as it is written or refused with a ``ValueError`` that names the file, the problem and
what was expected; a file shorter than its header's counts is truncated, whatever byte it stops at (the last
row of an ASCII table whose header counts its rows ends with a line end). Text is parsed by numpy in blocks of
lines, one pass, so that reading needs memory for the numbers and not for Python strings.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .files import read_file_bytes

__all__ = ["NUMBER_TOKEN", "LINE_END", "NumberRows", "parse_numbers", "read_number_rows", "after_line_end",
           "strip_comments", "check_row_counts", "concat_ranges", "are_whole", "PlyElement", "parse_ply_header",
           "read_ply", "ply_vertex_table", "LABEL_NAMES", "as_labels"]

# ------------------------------------------------------------------------------------- numeric text

#: The bytes C's isspace() accepts: numpy's text parser skips exactly these between numbers.
_SPACE = np.zeros(256, dtype=bool)
_SPACE[[9, 10, 11, 12, 13, 32]] = True

#: Bytes of text parsed at once: the memory a block needs is a few times this, whatever the file's size.
_BLOCK = 1 << 20

#: A number as numpy's text parser reads it (used to name the first value it could not read).
NUMBER_TOKEN = re.compile(rb"[+-]?((\d+\.?\d*|\.\d+)([eE][+-]?\d+)?|inf(inity)?|nan)", re.IGNORECASE)

#: A line end: LF, CRLF or CR alone.
LINE_END = re.compile(rb"\r\n|\r|\n")


@dataclass
class NumberRows:
    """The numbers of a block of text lines, one row per line that holds any.

    Attributes:
        values: (K,) float64, every number in the order of the text.
        widths: (R,) int64, the numbers on each row (blank lines are no rows).
        starts: (R,) int64, the index in ``values`` of each row's first number.
        lines: (R,) int64, the 1-based line number of each row in the file.
        complete: whether the last row ends with a line end (a file cut inside its last row does not).
    """

    values: np.ndarray
    widths: np.ndarray
    starts: np.ndarray
    lines: np.ndarray
    complete: bool

    def __len__(self) -> int:
        return int(self.widths.shape[0])


def after_line_end(data: bytes, stop: int) -> int:
    """Where the line after ``stop`` starts.

    Args:
        data: text.
        stop: an offset into it.

    Returns:
        The offset just after the first line end (LF, CRLF or CR) at or after ``stop``, or ``len(data)``.
    """
    ends = [k for k in (data.find(b"\n", stop), data.find(b"\r", stop)) if k >= 0]
    if not ends:
        return len(data)
    k = min(ends)
    return k + 2 if data[k:k + 2] == b"\r\n" else k + 1


def _bad_number(path, block: bytes, first_line: int, what: str) -> ValueError:
    """The error for the first value of ``block`` that is not a number."""
    for k, line in enumerate(LINE_END.split(block)):
        for token in line.split():
            if not NUMBER_TOKEN.fullmatch(token):
                shown = token[:40].decode("utf-8", errors="replace")
                return ValueError(f"{path}: non-numeric value {shown!r} on line {first_line + k} of the {what}; "
                                  "expected numbers separated by spaces")
    return ValueError(f"{path}: non-numeric value in the {what} (lines {first_line} to "
                      f"{first_line + len(LINE_END.findall(block))})")


def parse_numbers(text: bytes) -> np.ndarray | None:
    """The numbers of a text of numbers separated by whitespace, parsed by numpy's C parser.

    Args:
        text: ASCII text holding at least one number.

    Returns:
        (K,) float64, or None if a value is not a number.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # numpy < 2 warns and stops early where numpy 2 raises
        try:
            return np.fromstring(text, dtype=np.float64, sep=" ")
        except (ValueError, DeprecationWarning):
            return None


def _parse_block(path, block: bytes, first_line: int, what: str) -> tuple[np.ndarray, np.ndarray, int]:
    """Numbers and numbers per line of ``block``, which ends with a line end unless it ends the file.

    Returns:
        ``(values, per_line, tail)``: the float64 numbers, the count of numbers on each terminated line, and the
        count on an unterminated last line.
    """
    buf = np.frombuffer(block, dtype=np.uint8)
    space = _SPACE[buf]
    first = ~space
    first[1:] &= space[:-1]
    starts = np.flatnonzero(first)
    del first
    ends = buf == 10
    ends[:-1] |= (buf[:-1] == 13) & (buf[1:] != 10)
    ends[-1:] |= buf[-1:] == 13
    ends = np.flatnonzero(ends)
    before = np.searchsorted(starts, ends)
    per_line = np.diff(before, prepend=0)
    tail = len(starts) - (int(before[-1]) if len(before) else 0)
    if not len(starts):  # numpy reads text of spaces alone as [-1.0]
        return np.zeros(0), per_line, tail
    values = parse_numbers(block)
    if values is None or len(values) != len(starts):
        raise _bad_number(path, block, first_line, what)
    return values, per_line, tail


def read_number_rows(path, data: bytes, start: int = 0, first_line: int = 1, what: str = "file") -> NumberRows:
    """Parse the numbers of ``data[start:]``, line by line, in one pass of numpy's text parser.

    Lines end with LF, CRLF or CR alone. Memory: the numbers as float64 (twice, while they are joined) and a few
    bytes per byte of one block of text, not of the file.

    Args:
        path: the file, for messages.
        data: its bytes.
        start: where the numbers begin (after a header).
        first_line: the 1-based line number of ``data[start:]``'s first line, for messages.
        what: names the text in messages ("vertex and face rows").

    Returns:
        The rows.

    Raises:
        ValueError: a value is not a number (naming it and its line).
    """
    values, counts, pos, line, tail = [], [], start, first_line, 0
    while pos < len(data):
        stop = after_line_end(data, min(pos + _BLOCK, len(data)))
        v, per_line, tail = _parse_block(path, data[pos:stop], line, what)
        values.append(v)
        counts.append(per_line)
        line += len(per_line)
        pos = stop
    counts.append(np.array([tail], dtype=np.int64) if tail else np.zeros(0, dtype=np.int64))
    per_line = np.concatenate(counts) if counts else np.zeros(0, dtype=np.int64)
    rows = np.flatnonzero(per_line)
    widths = per_line[rows]
    all_values = np.concatenate(values) if values else np.zeros(0)
    return NumberRows(all_values, widths, np.cumsum(widths) - widths, rows + first_line, tail == 0)


def strip_comments(data: bytes) -> bytes:
    """Text without its comments, which run from '#' to the line end; the line ends stay, so line numbers do too.

    Args:
        data: text.

    Returns:
        The text without comments (``data`` itself when it holds no '#').
    """
    return re.sub(rb"#[^\r\n]*", b"", data) if b"#" in data else data


def _plural(name: str, count: int) -> str:
    return name if count == 1 else {"vertex": "vertices"}.get(name, name + "s")


def check_row_counts(path, rows: NumberRows, blocks: list[tuple[str, int]], fmt: str) -> None:
    """Refuse rows fewer or more than a header declares, or a last row cut off (no line end after it).

    Args:
        path: the file, for messages.
        rows: its rows after the header.
        blocks: ``(name, count)`` of each kind of row the header declares, in order ("vertex", 1082).
        fmt: the format's name ("PLY").

    Raises:
        ValueError: naming the counts promised and found.
    """
    have = len(rows) - (not rows.complete)
    done = 0
    for name, count in blocks:
        if have - done < count:
            found = max(have - done, 0)
            cut = " and part of another" if not rows.complete else ""
            raise ValueError(f"{path}: the {fmt} header promises {count} {_plural(name, count)}, the file holds "
                             f"{found}{cut}: it is truncated")
        done += count
    if not rows.complete:
        raise ValueError(f"{path}: the {fmt} file ends inside a row (its last line has no line end): it is cut off "
                         "or damaged")
    if len(rows) > done:
        raise ValueError(f"{path}: the file holds {len(rows) - done} more rows (from line {int(rows.lines[done])}) "
                         f"than its {fmt} header declares; the header's counts are wrong or the file is damaged")


def concat_ranges(starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Indices of consecutive runs.

    Args:
        starts: (R,) the first index of each run.
        lengths: (R,) the length of each run (>= 0).

    Returns:
        (lengths.sum(),) int64, the concatenation of ``arange(s, s + n)`` over the runs.
    """
    lengths = lengths.astype(np.int64)
    total = int(lengths.sum())
    offsets = np.repeat(starts.astype(np.int64) - (np.cumsum(lengths) - lengths), lengths)
    return offsets + np.arange(total, dtype=np.int64)


def are_whole(values: np.ndarray, low: int, high: int) -> bool:
    """Whether every value is a whole number in [low, high].

    Args:
        values: a float array.
        low, high: the bounds.

    Returns:
        True if so (and for no values).
    """
    return bool(values.size == 0 or (np.all(values == np.round(values)) and values.min() >= low
                                     and values.max() <= high))


# ---------------------------------------------------------------------------------------------- PLY

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8", "int64": "i8", "uint64": "u8",
}
_PLY_FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")


@dataclass
class PlyElement:
    """One element of a PLY header and, once read, its data.

    Attributes:
        name: the element's name ("vertex", "face").
        count: the number of rows the header declares.
        props: ``(name, type)`` of each property, type a numpy type code ("f4"), or for a list property
            ``(name, ("list", count type, item type))``.
        data: property name -> (count,) array, or for a list property ``(lengths, items)``: (count,) int64
            and the items of every row, concatenated. Empty until the body is read.
    """

    name: str
    count: int
    props: list
    data: dict


def _header_end(path, data: bytes) -> tuple[bytes, list[bytes], int]:
    """The line end of a PLY header, its lines between 'ply' and 'end_header', and where the body starts."""
    if not data.startswith(b"ply"):
        raise ValueError(f"{path}: not a PLY file (it does not start with 'ply')")
    eol = next((e for e in (b"\r\n", b"\n", b"\r") if data.startswith(e, 3)), None)
    if eol is None:
        raise ValueError(f"{path}: not a PLY file (its first line is not 'ply')")
    pos, lines = 3 + len(eol), []
    while True:
        nxt = data.find(eol, pos)
        if nxt < 0:
            raise ValueError(f"{path}: PLY header has no 'end_header' line")
        line = data[pos:nxt]
        pos = nxt + len(eol)
        if line.strip() == b"end_header":
            return eol, lines, pos
        lines.append(line)


def _header_element(path, tok: list[str], elements: list[PlyElement]) -> None:
    if not re.fullmatch(r"\d+", tok[2]):
        raise ValueError(f"{path}: PLY element {tok[1]!r} has count {tok[2]!r}; expected a whole number >= 0")
    if any(e.name == tok[1] for e in elements):
        raise ValueError(f"{path}: the PLY header declares element {tok[1]!r} twice; each element needs its own name")
    elements.append(PlyElement(tok[1], int(tok[2]), [], {}))


def _header_property(path, tok: list[str], elements: list[PlyElement]) -> None:
    if not elements:
        raise ValueError(f"{path}: PLY property before any element")
    element = elements[-1]
    types = tok[2:4] if tok[1] == "list" else tok[1:2]
    for t in types:
        if t not in _PLY_TYPES:
            raise ValueError(f"{path}: unknown PLY property type {t!r} (expected one of {', '.join(_PLY_TYPES)})")
    if tok[1] == "list" and _PLY_TYPES[tok[2]][0] not in "iu":
        raise ValueError(f"{path}: PLY list {tok[4]!r} has count type {tok[2]!r}; expected an integer type")
    name = tok[-1]
    if any(p[0] == name for p in element.props):
        raise ValueError(f"{path}: PLY element {element.name!r} declares property {name!r} twice; each property "
                         "needs its own name")
    kind = ("list", _PLY_TYPES[tok[2]], _PLY_TYPES[tok[3]]) if tok[1] == "list" else _PLY_TYPES[tok[1]]
    element.props.append((name, kind))


def parse_ply_header(path, data: bytes) -> tuple[str, list[PlyElement], int, int]:
    """The format, elements and body offset of a PLY file: the header ends at a line that is 'end_header'.

    Args:
        path: the file, for messages.
        data: its bytes.

    Returns:
        ``(format, elements, body offset, number of header lines)``.
    """
    eol, lines, body = _header_end(path, data)
    fmt, elements = None, []
    expected = {"format": 3, "element": 3, "property": 3}  # words of each header line (a list property: 5)
    for raw in lines:
        try:
            line = raw.decode("ascii")
        except UnicodeDecodeError:
            raise ValueError(f"{path}: PLY header line {raw[:60]!r} is not ASCII text") from None
        tok = line.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] not in expected:
            raise ValueError(f"{path}: unknown PLY header line {line.strip()!r}")
        wanted = 5 if tok[:2] == ["property", "list"] else expected[tok[0]]
        if len(tok) != wanted:
            raise ValueError(f"{path}: malformed PLY header line {line.strip()!r} (expected {wanted} words)")
        if tok[0] == "format":
            if fmt is not None:
                raise ValueError(f"{path}: the PLY header has two 'format' lines")
            fmt = tok[1]
        elif tok[0] == "element":
            _header_element(path, tok, elements)
        else:
            _header_property(path, tok, elements)
    if fmt not in _PLY_FORMATS:
        raise ValueError(f"{path}: unsupported PLY format {fmt!r} (expected one of {', '.join(_PLY_FORMATS)})")
    return fmt, elements, body, len(lines) + 2


def _ascii_element(path, element: PlyElement, rows: NumberRows, r: int) -> None:
    """Fill ``element.data`` from its rows ``r .. r + count`` of an ASCII PLY body."""
    n, values = element.count, rows.values
    pos = rows.starts[r:r + n].copy()
    end = pos + rows.widths[r:r + n]
    fixed = not any(isinstance(kind, tuple) for _, kind in element.props)

    def malformed(bad: np.ndarray, why: str) -> ValueError:
        k = int(np.flatnonzero(bad)[0])
        declared = f"the {len(element.props)} values" if fixed else "the values"
        return ValueError(f"{path}: {int(bad.sum())} ASCII PLY {element.name} row(s) do not hold {declared} the "
                          f"header declares (first: line {int(rows.lines[r + k])}, {element.name} {k}, with "
                          f"{int(rows.widths[r + k])} values{why}); the file is malformed")

    if fixed and np.any(end - pos != len(element.props)):
        raise malformed(end - pos != len(element.props), "")
    for name, kind in element.props:
        if not isinstance(kind, tuple):
            column = values[pos]
            if np.dtype(kind).kind in "iu":
                info = np.iinfo(kind)
                bad = (column != np.round(column)) | (column < info.min) | (column > info.max)
                if bad.any():
                    raise malformed(bad, f": {name!r} is declared {np.dtype(kind).name} but holds "
                                         f"{column[np.flatnonzero(bad)[0]]!r}")
            element.data[name] = column
            pos += 1
            continue
        if np.any(pos >= end):
            raise malformed(pos >= end, f": no length for list {name!r}")
        lengths = values[pos]
        bad = (lengths != np.round(lengths)) | (lengths < 0)
        if bad.any():
            raise malformed(bad, f": list {name!r} has length {lengths[np.flatnonzero(bad)[0]]!r}")
        lengths = lengths.astype(np.int64)
        if np.any(pos + 1 + lengths > end):
            raise malformed(pos + 1 + lengths > end, f": fewer than list {name!r} declares")
        element.data[name] = (lengths, values[concat_ranges(pos + 1, lengths)])
        pos += 1 + lengths
    if np.any(pos != end):
        raise malformed(pos != end, ", more than the header and the lists declare")


def _read_ascii_body(path, data: bytes, body: int, header_lines: int, elements: list[PlyElement]) -> None:
    rows = read_number_rows(path, data, body, header_lines + 1, "PLY body")
    check_row_counts(path, rows, [(e.name, e.count) for e in elements], "PLY")
    r = 0
    for element in elements:
        _ascii_element(path, element, rows, r)
        r += element.count


def _binary_dtype(element: PlyElement, order: str, lengths: list[int] | None) -> np.dtype:
    """The row type of an element, its lists of the given fixed lengths."""
    fields, k = [], 0
    for name, kind in element.props:
        if isinstance(kind, tuple):
            fields += [(f"{name}\0count", order + kind[1]), (name, order + kind[2], (lengths[k],))]
            k += 1
        else:
            fields.append((name, order + kind))
    return np.dtype(fields)


def _truncated_binary(path, element: PlyElement, rows: int) -> ValueError:
    return ValueError(f"{path}: the PLY header promises {element.count} {_plural(element.name, element.count)}, the "
                      f"file holds {rows}: it is truncated")


def _list_length(path, element: PlyElement, name: str, value) -> int:
    if value < 0:
        raise ValueError(f"{path}: a PLY {element.name} list {name!r} has length {value}; the file is malformed")
    return int(value)


def _binary_rows_walked(path, data: bytes, offset: int, element: PlyElement, order: str) -> int:
    """Read an element with lists of varying lengths row by row; returns the offset after it."""
    columns = {name: [] for name, _ in element.props}
    for row in range(element.count):
        for name, kind in element.props:
            code = kind[1] if isinstance(kind, tuple) else kind
            size = np.dtype(code).itemsize
            if offset + size > len(data):
                raise _truncated_binary(path, element, row)
            value = np.frombuffer(data, order + code, 1, offset)[0]
            offset += size
            if not isinstance(kind, tuple):
                columns[name].append(value)
                continue
            item, n = np.dtype(order + kind[2]), _list_length(path, element, name, value)
            if offset + n * item.itemsize > len(data):
                raise _truncated_binary(path, element, row)
            columns[name].append(np.frombuffer(data, item, n, offset))
            offset += n * item.itemsize
    for name, kind in element.props:
        if isinstance(kind, tuple):
            items = columns[name]
            lengths = np.array([len(i) for i in items], dtype=np.int64)
            element.data[name] = (lengths, np.concatenate(items) if items else np.zeros(0, order + kind[2]))
        else:
            element.data[name] = np.array(columns[name], dtype=order + kind)
    return offset


def _binary_element(path, data: bytes, offset: int, element: PlyElement, order: str) -> int:
    """Fill ``element.data`` from the binary body at ``offset``; returns the offset after the element."""
    lists = [name for name, kind in element.props if isinstance(kind, tuple)]
    lengths = [0] * len(lists)
    if lists and element.count:  # try every row with the first row's list lengths
        lengths, pos = [], offset
        for name, kind in element.props:
            code = kind[1] if isinstance(kind, tuple) else kind
            if pos + np.dtype(code).itemsize > len(data):
                raise _truncated_binary(path, element, 0)
            if isinstance(kind, tuple):
                lengths.append(_list_length(path, element, name, np.frombuffer(data, order + kind[1], 1, pos)[0]))
                pos += np.dtype(kind[1]).itemsize + lengths[-1] * np.dtype(kind[2]).itemsize
            else:
                pos += np.dtype(code).itemsize
    dtype = _binary_dtype(element, order, lengths)
    fits = offset + element.count * dtype.itemsize <= len(data)
    table = np.frombuffer(data, dtype, element.count, offset) if fits else None
    uniform = table is not None and all(np.all(table[f"{name}\0count"] == n) for name, n in zip(lists, lengths))
    if not uniform:
        if not lists:
            raise _truncated_binary(path, element, (len(data) - offset) // dtype.itemsize)
        return _binary_rows_walked(path, data, offset, element, order)
    for name, kind in element.props:
        if isinstance(kind, tuple):
            items = table[name]
            element.data[name] = (np.full(element.count, items.shape[1], dtype=np.int64), items.reshape(-1))
        else:
            element.data[name] = table[name]
    return offset + element.count * dtype.itemsize


def read_ply(path: str | Path, data: bytes | None = None) -> tuple[str, list[PlyElement]]:
    """Read every element of a PLY file (ASCII or binary) exactly as its header declares it.

    Args:
        path: the file.
        data: its bytes, if already read.

    Returns:
        ``(format, elements)``, each element's ``data`` filled (ASCII values as float64, binary ones in their
        declared type).

    Raises:
        ValueError: a malformed header (unknown lines or types, a property or element declared twice), a body
            shorter or longer than the header declares, malformed rows.
    """
    if data is None:
        data = read_file_bytes(path, "a PLY file")
    fmt, elements, body, header_lines = parse_ply_header(path, data)
    if fmt == "ascii":
        _read_ascii_body(path, data, body, header_lines, elements)
        return fmt, elements
    order = "<" if fmt == "binary_little_endian" else ">"
    offset = body
    for element in elements:
        offset = _binary_element(path, data, offset, element, order)
    if offset != len(data):
        raise ValueError(f"{path}: the binary PLY file holds {len(data) - offset} bytes after the last element its "
                         "header declares; the header's counts are wrong or the file is damaged")
    return fmt, elements


# -------------------------------------------------------------------------------------------- labels

#: Property names of part labels: per vertex in a point cloud, per face in a mesh.
LABEL_NAMES = ("label", "scalar_label", "part", "class")


def as_labels(values: np.ndarray, source: str, limit: int = 2**62) -> np.ndarray:
    """Labels as int64.

    Args:
        values: any array.
        source: names the labels in messages (a file name).
        limit: the labels' magnitude must stay below it.

    Returns:
        The labels as int64.

    Raises:
        ValueError: not whole numbers, or beyond ``limit``.
    """
    values = np.asarray(values)
    if values.dtype.kind not in "fiub":
        raise ValueError(f"{source}: labels must be whole numbers, got dtype {values.dtype}")
    if values.dtype.kind == "f":
        if not np.isfinite(values).all() or (values != np.round(values)).any():
            raise ValueError(f"{source}: labels must be whole numbers")
    if values.size and (np.abs(values.astype(np.float64)).max() >= limit):
        raise ValueError(f"{source}: labels must lie in ({-limit}, {limit}); got {values.max()} / {values.min()}")
    return values.astype(np.int64)


def ply_vertex_table(path, elements: list[PlyElement]) -> dict[str, np.ndarray]:
    """The vertex properties of a read PLY file (lists left out), x, y and z among them.

    Args:
        path: the file, for messages.
        elements: from :func:`read_ply`.

    Returns:
        Property name -> (N,) array in the machine's byte order: float64 for floating-point properties, integer
        ones in their type (a label keeps every digit).
    """
    vertex = next((e for e in elements if e.name == "vertex"), None)
    if vertex is None:
        raise ValueError(f"{path}: PLY file has no 'vertex' element")
    props = {k: np.asarray(v, dtype=np.float64 if v.dtype.kind == "f" else v.dtype.newbyteorder("="))
             for k, v in vertex.data.items() if not isinstance(v, tuple)}
    if not all(k in props for k in "xyz"):
        raise ValueError(f"{path}: PLY vertices lack x, y, z properties (found {sorted(props)})")
    return props
