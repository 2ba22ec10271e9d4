"""File input and output for diffsurf: target surfaces, contactor points and results.

This is the only module that touches files. Every failure at this boundary is reported as a
:class:`ReadError` or :class:`WriteError` whose message is one line naming the file and what
was expected; no traceback from meshio or numpy leaks out.
"""
from __future__ import annotations

import codecs
import contextlib
import io as _io
import logging
import os
import sys
import tempfile
from dataclasses import dataclass, field

import meshio
import numpy as np
from meshio import _helpers as _meshio_helpers

__all__ = [
    "SURFACE_CELL_TYPES",
    "ReadError",
    "WriteError",
    "Target",
    "Contactors",
    "read_target",
    "read_contactors",
    "write_result",
    "check_output_path",
    "output_batch",
    "OutputBatch",
    "write_mesh",
    "write_matrix",
    "save_pairs",
    "load_pairs",
]

#: meshio cell types that make up a contact surface (linear and quadratic facets).
SURFACE_CELL_TYPES = ("triangle", "triangle6", "triangle7", "quad", "quad8", "quad9")

#: extensions read and written as comma separated text rather than through meshio.
_CSV_EXTENSIONS = (".csv", ".txt")

#: where a meshio extension maps to several formats, the one to *write*; meshio would take the
#: first (ansys for .msh), and gmsh 4.1 refuses meshes mixing cell types without entity info.
_PREFERRED_WRITER = {".msh": "gmsh22"}

#: where a meshio extension maps to several formats, the one to *read* first (its error is
#: the one that explains a damaged file).
_PREFERRED_READER = {".msh": "gmsh"}

#: each reader's reason for refusing a file is cut to this length in the one-line error.
_REASON_CHARS = 120

_log = logging.getLogger("diffsurf")

#: writers that produce companion files next to the named one, which a rename cannot keep
#: atomic.
_MULTI_FILE_WRITERS = ("tetgen",)

#: vector point data assembled from scalar columns when writing a mesh.
_VECTOR_GROUPS = {"normal": ("nx", "ny", "nz"), "proximal_point": ("px", "py", "pz")}


class ReadError(Exception):
    """An input file is missing, unreadable or not what diffsurf expects."""


class WriteError(Exception):
    """An output file cannot be (or must not be) written."""


@dataclass
class Target:
    """The faceted target surface.

    Attributes
    ----------
    path : str
        The file it was read from.
    points : (n, 3) float64
        All points of the file in file order; 2-D points are padded with z = 0.
    cells : list of (str, (c, k) int64)
        The selected surface cells as (meshio cell type, connectivity into ``points``).
    nodes : (m,) int64
        Sorted unique indices of the points referenced by ``cells``, mid-side nodes included.
    ignored : dict of str to int
        Cell type -> number of non-surface cells left out (vertex, line, volume, ...).
    """

    path: str
    points: np.ndarray
    cells: list
    nodes: np.ndarray
    ignored: dict = field(default_factory=dict)


@dataclass
class Contactors:
    """The contactor points and the columns carried through to the output.

    Attributes
    ----------
    path : str
        The file read, ``"-"`` for stdin.
    points : (p, 3) float64
        Contactor coordinates; NaN / inf are kept (the core flags such rows as failed).
    passthrough_names : list of str
        Names of the CSV columns other than x, y, z, in file order.
    passthrough : fastcsv.TextColumns
        Per row, the text of those columns with surrounding whitespace stripped: a read-only
        sequence of rows (each a list of str) held as one UTF-8 buffer and field offsets. A
        list of rows, or None for empty fields, is converted on construction.
    mesh : meshio.Mesh or None
        The mesh when the contactors were read from a mesh file, so a mesh output can reuse
        its cells; None for CSV input.
    """

    path: str
    points: np.ndarray
    passthrough_names: list = field(default_factory=list)
    passthrough: object = None
    mesh: object = None

    def __post_init__(self):
        if self.passthrough is None or isinstance(self.passthrough, (list, tuple)):
            from ..fastcsv import TextColumns

            ncols = len(self.passthrough_names)
            if self.passthrough is None:
                self.passthrough = TextColumns.empty(len(self.points), ncols)
            else:
                self.passthrough = TextColumns.from_rows(self.passthrough, ncols)


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------


def _first_line(exc: BaseException) -> str:
    if isinstance(exc, UnicodeDecodeError):
        return f"binary bytes where text was expected (offset {exc.start})"
    text = str(exc).strip()
    line = text.splitlines()[0].strip() if text else ""
    return line or type(exc).__name__


def _mesh_extension(path: str) -> tuple[str, list[str]]:
    """Return (matched extension, meshio formats) for ``path``; ("", []) if unknown.

    Mirrors meshio's own lookup so compound extensions such as ``.vol.gz`` are recognised.
    """
    name = os.path.basename(path)
    suffixes = []
    stem = name
    while True:
        stem, ext = os.path.splitext(stem)
        if not ext:
            break
        suffixes.insert(0, ext)
    best_ext, best = "", []
    ext = ""
    for suffix in reversed(suffixes):
        ext = (suffix + ext).lower()
        formats = meshio.extension_to_filetypes.get(ext)
        if formats:
            best_ext, best = ext, list(formats)
    return best_ext, best


def _known_mesh_extensions() -> str:
    exts = list(meshio.extension_to_filetypes)
    # the common FE formats first, so a truncated hint still shows them
    common = [".msh", ".vtu", ".vtk", ".stl", ".obj", ".ply", ".inp", ".med"]
    ordered = [e for e in common if e in exts] + [e for e in exts if e not in common]
    return ", ".join(ordered[:8]) + ", ..."


def _extension(path: str) -> str:
    return os.path.splitext(path)[1].lower()


def _check_input_file(path: str) -> None:
    if path == "-":
        raise ReadError("-: this file cannot be read from stdin, expected a file name")
    if os.path.isdir(path):
        raise ReadError(f"{path}: is a directory, expected a file")
    if not os.path.exists(path):
        raise ReadError(f"{path}: no such file")
    if not os.access(path, os.R_OK):
        raise ReadError(f"{path}: permission denied")


def _read_mesh(path: str) -> meshio.Mesh:
    """Read ``path`` with meshio, trying each format meshio associates with its extension.

    meshio.read is not used directly because, when every candidate format fails, it prints
    to stdout and calls sys.exit.
    """
    _check_input_file(path)
    ext, formats = _mesh_extension(path)
    if not formats:
        shown = os.path.splitext(path)[1] or "(none)"
        raise ReadError(
            f"{path}: unknown mesh format '{shown}' (meshio reads {_known_mesh_extensions()})"
        )
    if os.path.getsize(path) == 0:
        raise ReadError(f"{path}: empty file, expected a mesh")
    preferred = _PREFERRED_READER.get(ext)
    formats = sorted(formats, key=lambda f: f != preferred)
    failures = []
    for fmt in formats:
        reader = _meshio_helpers.reader_map.get(fmt)
        if reader is None:
            continue
        chatter = _io.StringIO()
        try:
            # readers probe binary headers with numpy scalars that may overflow harmlessly;
            # meshio prints its warnings on stderr, where only diffsurf's own lines belong
            with np.errstate(all="ignore"), contextlib.redirect_stderr(chatter):
                mesh = reader(path)
        except Exception as exc:  # meshio raises anything from ReadError to IndexError
            reason = _first_line(exc)
            if reason == "ReadError":  # meshio often raises it without a message
                reason = "not a valid file of this format"
            elif reason.startswith("zero-size array to reduction"):  # max() of no node tags
                reason = "an empty section where nodes or cells were expected"
            failures.append(f"as {fmt}: {reason[:_REASON_CHARS]}")
            continue
        if not isinstance(mesh, meshio.Mesh):
            failures.append(f"as {fmt}: reader returned no mesh")
            continue
        # a warning about a mesh that was read is worth a log line (not one of a failed read)
        for warning in " ".join(chatter.getvalue().split()).split("Warning: ")[1:]:
            _log.warning("%s: meshio: %s", path, warning.strip())
        return mesh
    reasons = "; ".join(failures) if failures else "no reader available"
    raise ReadError(f"{path}: cannot read mesh, expected a valid {ext} file ({reasons})")


def _points3(path: str, mesh: meshio.Mesh) -> np.ndarray:
    try:
        points = np.asarray(mesh.points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ReadError(f"{path}: non-numeric point coordinates ({_first_line(exc)})") from None
    if points.ndim != 2 or points.shape[0] == 0:
        raise ReadError(f"{path}: empty mesh, expected points")
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    elif points.shape[1] != 3:
        raise ReadError(f"{path}: expected 2-D or 3-D points, got {points.shape[1]} coordinates")
    return np.ascontiguousarray(points)


def _describe(counts: dict) -> str:
    if not counts:
        return "no cells"
    return ", ".join(f"{n} {t}" for t, n in counts.items())


def _zone_names(mesh: meshio.Mesh) -> list[str]:
    names = [n for n in mesh.cell_sets if not n.startswith("gmsh:")]
    if "gmsh:physical" in mesh.cell_data:
        for name, value in mesh.field_data.items():
            if np.size(value) >= 1 and name not in names:
                names.append(name)
    return names


def _zone_selection(path: str, mesh: meshio.Mesh, zone: str) -> list[np.ndarray]:
    """Per cell block, the indices of the cells in ``zone``."""
    nblocks = len(mesh.cells)
    if zone in mesh.cell_sets:
        sets = list(mesh.cell_sets[zone])
        sets += [None] * (nblocks - len(sets))
        out = []
        for block, ids in zip(mesh.cells, sets):
            if ids is None:
                out.append(np.zeros(0, dtype=np.int64))
                continue
            ids = np.asarray(ids).reshape(-1)
            if ids.dtype == bool:
                ids = np.flatnonzero(ids)
            ids = ids.astype(np.int64)
            if np.any((ids < 0) | (ids >= len(block.data))):
                raise ReadError(f"{path}: cell set '{zone}' refers to cells that do not exist")
            out.append(np.unique(ids))
        return out
    if zone in mesh.field_data and "gmsh:physical" in mesh.cell_data:
        value = np.asarray(mesh.field_data[zone]).reshape(-1)
        tag = int(value[0])
        # a Gmsh tag is unique per dimension only, so a 3-D group may share a surface's tag
        dim = int(value[1]) if value.size > 1 else None
        out = []
        for block, phys in zip(mesh.cells, mesh.cell_data["gmsh:physical"]):
            if dim is not None and block.dim != dim:
                out.append(np.zeros(0, dtype=np.int64))
                continue
            out.append(np.flatnonzero(np.asarray(phys).reshape(-1) == tag).astype(np.int64))
        return out
    names = _zone_names(mesh)
    listed = ", ".join(repr(n) for n in names) if names else "none (the file has no named zones)"
    raise ReadError(f"{path}: unknown zone '{zone}'; available zones: {listed}")


# --------------------------------------------------------------------------------------------
# target
# --------------------------------------------------------------------------------------------


def read_target(path: str, zone: str | None = None) -> Target:
    """Read the target surface from any mesh file meshio reads.

    Parameters
    ----------
    path : str
        Mesh file (.msh v2.2/v4.1, .vtu, .vtk, .stl, .obj, .ply, .inp, .med, ...).
    zone : str or None
        Keep only the surface cells of this named group: a ``mesh.cell_sets`` name (Abaqus
        elset, MED family, VTU cell set) or a Gmsh physical group name from ``field_data``.

    Returns
    -------
    target : Target
        ``ignored`` counts the non-surface cells of the file, or of the zone when given.

    Raises
    ------
    ReadError
        Missing or unreadable file, unknown format, unknown zone, no surface cells,
        non-finite coordinates of surface nodes or connectivity out of range.
    """
    path = str(path)
    if path == "-":
        raise ReadError("-: a mesh cannot be read from stdin, expected a mesh file name "
                        "(only CSV contactors can come on stdin)")
    mesh = _read_mesh(path)
    points = _points3(path, mesh)
    selection = _zone_selection(path, mesh, zone) if zone is not None else None

    cells = []
    ignored: dict[str, int] = {}
    for i, block in enumerate(mesh.cells):
        data = np.asarray(block.data)
        if selection is not None:
            data = data[selection[i]]
        if len(data) == 0:
            continue
        if block.type not in SURFACE_CELL_TYPES:
            ignored[block.type] = ignored.get(block.type, 0) + len(data)
            continue
        try:
            conn = np.asarray(data, dtype=np.int64).reshape(len(data), -1)
        except (TypeError, ValueError) as exc:
            raise ReadError(f"{path}: bad {block.type} connectivity ({_first_line(exc)})") from None
        cells.append((block.type, np.ascontiguousarray(conn)))

    where = f" in zone '{zone}'" if zone is not None else ""
    if not cells:
        raise ReadError(
            f"{path}: no surface cells (triangle/quad) found{where}; it has: {_describe(ignored)}"
        )

    nodes = np.unique(np.concatenate([c.reshape(-1) for _, c in cells]))
    if nodes[0] < 0 or nodes[-1] >= len(points):
        raise ReadError(
            f"{path}: cell connectivity refers to point {int(nodes[0] if nodes[0] < 0 else nodes[-1])}"
            f" but the file has {len(points)} points"
        )
    bad = ~np.isfinite(points[nodes]).all(axis=1)
    if bad.any():
        first = int(nodes[np.flatnonzero(bad)[0]])
        raise ReadError(
            f"{path}: non-finite coordinates (NaN/inf) at point {first} of a surface cell{where}"
            f" ({int(bad.sum())} such points)"
        )
    return Target(path=path, points=points, cells=cells, nodes=nodes.astype(np.int64), ignored=ignored)


# --------------------------------------------------------------------------------------------
# contactors
# --------------------------------------------------------------------------------------------


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


#: the UTF-8 byte order mark.
_BOM = b"\xef\xbb\xbf"


def _is_utf8(data: bytes) -> bool:
    """Whether ``data`` is valid UTF-8, checked in slices so no copy of the text is made."""
    if data.isascii():
        return True
    decoder = codecs.getincrementaldecoder("utf-8")()
    view = memoryview(data)
    step = 1 << 22
    try:
        for i in range(0, len(view), step):
            decoder.decode(view[i:i + step], i + step >= len(view))
    except UnicodeDecodeError:
        return False
    return True


def _csv_bytes(data: bytes, name: str, all_boms: bool = False) -> memoryview:
    """``data`` checked to be NUL-free UTF-8, without its byte order mark (every leading one
    if ``all_boms``); the errors are :func:`_decode`'s."""
    if b"\x00" in data or not _is_utf8(data):
        _decode(data, name)  # raises the ReadError that says what the bytes are
        raise ReadError(f"{name}: not a text CSV file")  # unreachable: _decode raised
    start = 0
    while data.startswith(_BOM, start):
        start += len(_BOM)
        if not all_boms:
            break
    return memoryview(data)[start:]


def _stdin_bytes(stream) -> bytes | None:
    """The raw bytes under a strict UTF-8 text stream (read once, without a decoded copy),
    or None when the stream must be read as text."""
    buffer = getattr(stream, "buffer", None)
    if buffer is None or getattr(stream, "errors", None) != "strict":
        return None
    try:
        if codecs.lookup(stream.encoding).name != "utf-8":
            return None
    except (LookupError, TypeError, AttributeError):
        return None
    return buffer.read()


def _parse_csv(data, name: str):
    """Contactor CSV text -> (points (p, 3) float64, pass-through names, TextColumns).

    ``data`` is UTF-8 bytes (NUL-free, BOM removed: see :func:`_csv_bytes`) or str. The rules
    are those of :func:`read_contactors`; rows are tokenised and converted by
    :mod:`diffsurf_cli.fastcsv` (exactly as ``str.strip``, ``str.split(",")`` and ``float()``
    on the decoded text), only the header line and the rare coordinates the compiled parser
    leaves to ``float()`` are handled here in Python.
    """
    from .. import fastcsv  # C via ctypes: loaded by the commands that read CSV only

    if isinstance(data, str):
        if "\x00" in data:
            raise ReadError(f"{name}: not a text CSV file (contains NUL bytes)")
        try:
            data = data.encode("utf-8")
        except UnicodeEncodeError:
            raise ReadError(f"{name}: not a text CSV file (bytes are not UTF-8 text)") from None
    buf = np.frombuffer(data, np.uint8)
    start, end, first_lineno, after = fastcsv.first_data_line(buf, 0)
    if start < 0:
        raise ReadError(f"{name}: no data rows, expected CSV lines x,y,z")
    first_fields = bytes(buf[start:end]).decode("utf-8").split(",")
    ncols = len(first_fields)

    if any(not _is_number(f) for f in first_fields):
        names = [f.strip().strip('"').strip() for f in first_fields]
        lower = [n.lower() for n in names]
        idx = []
        for axis in ("x", "y", "z"):
            n = lower.count(axis)
            if n != 1:
                what = "no" if n == 0 else "more than one"
                raise ReadError(
                    f"{name}, line {first_lineno}: header has {what} '{axis}' column, "
                    f"expected columns named x,y,z (got {','.join(names)!r})"
                )
            idx.append(lower.index(axis))
        pidx = [j for j in range(ncols) if j not in idx]
        pnames = [names[j] for j in pidx]
        pos, line0 = after, first_lineno
    else:
        if ncols < 3:
            raise ReadError(
                f"{name}, line {first_lineno}: expected 3 numeric columns x,y,z, got {ncols}"
            )
        idx = [ncols - 3, ncols - 2, ncols - 1]
        pidx = list(range(ncols - 3))
        pnames = [f"col{j + 1}" for j in pidx]
        pos, line0 = start, first_lineno - 1
    # the reader counts lines from `pos`: line n there is line line0 + n of the file
    rows = fastcsv.read_rows(buf, pos, ncols, idx, pidx)
    if rows.bad_columns is None and not len(rows.points):
        raise ReadError(f"{name}: no data rows after the header, expected CSV lines x,y,z")
    if rows.bad_columns is not None:
        lineno, got = rows.bad_columns
        raise ReadError(
            f"{name}, line {line0 + lineno}: expected {ncols} comma separated columns "
            f"(as on line {first_lineno}), got {got}"
        )

    # coordinates left to float(): any non-ASCII byte, subnormals, overflow, long mantissas
    bad = rows.bad_number
    hard = rows.hard if bad < 0 else rows.hard[rows.hard < bad]
    if len(hard):
        where = np.unique(hard // 3)
        lines = dict(zip(where.tolist(), rows.lines(where).tolist()))
        points = rows.points
        for h in hard.tolist():
            r, axis = divmod(h, 3)
            _, s, e = lines[r]
            token = bytes(buf[s:e]).decode("utf-8").split(",")[idx[axis]]
            try:
                points[r, axis] = float(token)
            except ValueError:
                bad = h
                break
    if bad >= 0:
        r, axis = divmod(bad, 3)
        lineno, s, e = rows.lines([r])[0].tolist()
        token = bytes(buf[s:e]).decode("utf-8").split(",")[idx[axis]]
        raise ReadError(
            f"{name}, line {line0 + lineno}: expected a number for {'xyz'[axis]}, "
            f"got {token.strip()!r}"
        )
    return rows.points, pnames, rows.text


#: First words of the text mesh formats, to tell a mesh piped as CSV contactors.
_MESH_SIGNATURES = (("$MeshFormat", "Gmsh"), ("$NOD", "Gmsh"), ("<?xml", "XML (VTK)"),
                    ("<VTKFile", "VTK XML"), ("# vtk DataFile", "legacy VTK"),
                    ("solid", "ASCII STL"), ("ply", "PLY"), ("OFF", "OFF"),
                    ("*HEADING", "Abaqus"), ("*NODE", "Abaqus"))


def _refuse_mesh_text(text, name: str) -> None:
    """A mesh on stdin cannot be read (meshio needs a file name): say so, rather than report
    its first line as a bad CSV header."""
    head = text[:4096]
    if not isinstance(head, str):  # bytes or a memoryview of them
        head = bytes(head).decode("utf-8", "replace")
    for lineno, line in enumerate(head.splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        for word, kind in _MESH_SIGNATURES:
            if line.upper().startswith(word.upper()) and "," not in line:
                raise ReadError(
                    f"{name}, line {lineno}: looks like a {kind} mesh ({line[:20]!r}); a mesh "
                    f"on stdin is not supported, expected CSV x,y,z (give the mesh file's name)")
        return


def read_contactors(path: str, stdin=None) -> Contactors:
    """Read contactor points from CSV text or from the points of a mesh file.

    Parameters
    ----------
    path : str
        ``"-"`` for CSV on ``stdin``; ``.csv`` / ``.txt`` for a CSV file; anything else is
        read with meshio and all its points (file order) are contactors.
    stdin : text stream, optional
        Stream read when ``path == "-"``; default ``sys.stdin``.

    Returns
    -------
    contactors : Contactors

    Notes
    -----
    CSV is comma separated without quoting; spaces around fields are ignored. Blank lines
    and lines whose first non-blank character is ``#`` are skipped. The first row is a
    header if any field is not a number: the columns named x, y, z (any case) are the
    coordinates and the others are passed through. Without a header, the last three columns
    are x, y, z and earlier ones are passed through as ``col1``, ``col2``, ... . Pass-through
    fields are kept as text with only surrounding whitespace stripped. NaN / inf coordinates
    are kept.
    """
    path = str(path)
    if path == "-":
        name = "<stdin>"
        stream = sys.stdin if stdin is None else stdin
        try:
            raw = _stdin_bytes(stream)
            text = stream.read() if raw is None else raw
        except UnicodeDecodeError:
            raise ReadError(f"{name}: not a text CSV file (bytes are not UTF-8 text)") from None
        except OSError as exc:
            raise ReadError(f"{name}: cannot read ({_first_line(exc)})") from None
        if raw is not None:
            # what a strict UTF-8 text stream would have said about these bytes
            if not _is_utf8(raw):
                raise ReadError(f"{name}: not a text CSV file (bytes are not UTF-8 text)")
            if b"\x00" in raw:
                raise ReadError(f"{name}: not a text CSV file (contains NUL bytes)")
            text = _csv_bytes(raw, name, all_boms=True)
        elif isinstance(text, bytes):
            text = _csv_bytes(text, name, all_boms=True)
        else:
            text = text.lstrip("\ufeff")
        _refuse_mesh_text(text, name)
        points, pnames, passthrough = _parse_csv(text, name)
        return Contactors(path, points, pnames, passthrough, None)

    if _extension(path) in _CSV_EXTENSIONS:
        _check_input_file(path)
        try:
            with open(path, "rb") as fh:
                data = fh.read()
        except OSError as exc:
            raise ReadError(f"{path}: cannot read ({_first_line(exc)})") from None
        points, pnames, passthrough = _parse_csv(_csv_bytes(data, path), path)
        return Contactors(path, points, pnames, passthrough, None)

    if not _mesh_extension(path)[1]:
        _check_input_file(path)
        shown = os.path.splitext(path)[1] or "(none)"
        raise ReadError(
            f"{path}: unknown contactor file format '{shown}' (expected .csv, .txt or a mesh "
            f"meshio reads: {_known_mesh_extensions()})"
        )
    mesh = _read_mesh(path)
    points = _points3(path, mesh)
    return Contactors(path, points, [], None, mesh)


def _decode(data: bytes, name: str) -> str:
    for bom, encoding in _UTF_BOMS:
        if data.startswith(bom) and _decodes(data, encoding):
            raise ReadError(f"{name}: {encoding} text, expected UTF-8 (or ASCII) CSV; convert it, "
                            f"e.g. iconv -f {encoding} -t UTF-8")
    newline = b"\n"
    if b"\x00" in data:
        line = data.count(newline, 0, data.index(b"\x00")) + 1
        raise ReadError(f"{name}: not a text CSV file (contains NUL bytes, the first on line "
                        f"{line})")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(newline, 0, exc.start) + 1
        raise ReadError(f"{name}: not a text CSV file (bytes at offset {exc.start}, on line "
                        f"{line}, are not UTF-8 text)") from None


def _decodes(data: bytes, encoding: str) -> bool:
    try:
        data.decode(encoding)
    except UnicodeDecodeError:
        return False
    return True


#: byte order marks of the encodings that Windows tools write and a CSV reader meets.
_UTF_BOMS = ((b"\xff\xfe\x00\x00", "UTF-32"), (b"\x00\x00\xfe\xff", "UTF-32"),
             (b"\xff\xfe", "UTF-16"), (b"\xfe\xff", "UTF-16"))


# --------------------------------------------------------------------------------------------
# output
# --------------------------------------------------------------------------------------------


def _output_kind(path: str) -> tuple[str, str | None]:
    """("csv", None) or ("mesh", meshio format) for ``path``; WriteError if neither."""
    if _extension(path) in _CSV_EXTENSIONS:
        return "csv", None
    ext, formats = _mesh_extension(path)
    writers = [f for f in formats if f in _meshio_helpers._writer_map]
    if not writers:
        shown = os.path.splitext(path)[1] or "(none)"
        raise WriteError(
            f"{path}: unknown output format '{shown}', expected .csv or a mesh format meshio "
            f"writes ({_known_mesh_extensions()})"
        )
    fmt = _PREFERRED_WRITER.get(ext, writers[0])
    if fmt not in _meshio_helpers._writer_map:
        fmt = writers[0]
    if fmt in _MULTI_FILE_WRITERS:
        raise WriteError(
            f"{path}: format '{fmt}' writes several files and cannot be written safely; "
            f"use .csv, .vtu, .vtk or .msh"
        )
    return "mesh", fmt


def check_output_path(path: str | None, overwrite: bool, kind: str = "result") -> None:
    """Check that ``path`` can be written before any work is done.

    Parameters
    ----------
    path : str or None
        Output file; None or ``"-"`` means stdout, which is always accepted.
    overwrite : bool
        Whether an existing file may be replaced.
    kind : {'result', 'mesh', 'matrix', 'pairs'}
        A result (.csv or a mesh format), a surface mesh (a mesh format), a Matrix Market
        file (.mtx) or a pairing (.npz).

    Raises
    ------
    WriteError
        The file exists and ``overwrite`` is False, or it is a directory, or the extension is
        neither .csv/.txt nor a meshio format, or the parent directory is missing or not
        writable.
    """
    if path is None or str(path) == "-":
        return
    path = str(path)
    if os.path.isdir(path):
        raise WriteError(f"{path}: is a directory, expected an output file name")
    if os.path.lexists(path) and not overwrite:
        raise WriteError(f"{path}: already exists (use --overwrite)")
    if kind == "result":
        _output_kind(path)
    elif kind == "mesh":
        if _output_kind(path)[0] != "mesh":
            raise WriteError(f"{path}: a surface mesh needs a mesh format (.vtu, .vtk, .msh, "
                             f".stl, ...), not {_extension(path)}")
    elif _extension(path) not in _KIND_EXTENSIONS[kind]:
        raise WriteError(f"{path}: expected a {' or '.join(_KIND_EXTENSIONS[kind])} file name")
    parent, base = os.path.split(os.path.abspath(path))
    if not os.path.isdir(parent):
        if os.path.exists(parent):
            raise WriteError(f"{path}: '{parent}' is not a directory, expected a directory")
        raise WriteError(f"{path}: directory '{parent}' does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise WriteError(f"{path}: directory '{parent}' is not writable")
    # access() says yes to root and knows nothing of read-only file systems: try it for real
    try:
        fd, probe = tempfile.mkstemp(prefix=f".{base}.probe", dir=parent)
    except OSError as exc:
        raise WriteError(
            f"{path}: cannot create a file in '{parent}' ({_os_reason(exc)})") from None
    os.close(fd)
    os.unlink(probe)


def _validate_columns(name: str, contactors: Contactors, columns: dict, labels: dict) -> int:
    p = len(contactors.points)
    if len(contactors.passthrough) != p:
        raise WriteError(f"{name}: {len(contactors.passthrough)} pass-through rows for {p} points")
    if contactors.passthrough.ncols != len(contactors.passthrough_names):
        raise WriteError(f"{name}: {contactors.passthrough.ncols} pass-through columns for "
                         f"{len(contactors.passthrough_names)} names")
    for col, values in columns.items():
        if not isinstance(col, str) or not col or any(c in col for c in ",\n\r"):
            raise WriteError(f"{name}: bad column name {col!r}, expected text without commas")
        arr = np.asarray(values)
        if arr.shape != (p,):
            raise WriteError(f"{name}: column '{col}' has shape {arr.shape}, expected ({p},)")
        if col in labels:
            words = labels[col]
            if arr.dtype.kind not in "iub":
                raise WriteError(f"{name}: label column '{col}' must hold integer codes")
            if p and (arr.min() < 0 or arr.max() >= len(words)):
                raise WriteError(
                    f"{name}: label column '{col}' has codes outside 0..{len(words) - 1}"
                )
        elif arr.dtype.kind not in "fiub":
            raise WriteError(f"{name}: column '{col}' is {arr.dtype}, expected numbers")
    return p


def _column_text(values: np.ndarray, words):
    """One output column as :func:`fastcsv.format_rows` spells it: floats as ``repr`` does
    (the shortest text that reads back to the same double: ``0.1``, ``1e-05``, ``-0.0``,
    ``nan``, ``inf``), ints as plain decimals, label codes as their words."""
    from .. import fastcsv

    return fastcsv.Column(values, words)


def _byte_sink(fh):
    """The binary stream under the text stream ``fh`` when bytes written there are exactly
    what ``fh.write`` would write (UTF-8, no newline translation); else None."""
    buffer = getattr(fh, "buffer", None)
    if buffer is None or os.linesep != "\n":
        return None
    try:
        if codecs.lookup(fh.encoding).name != "utf-8":
            return None
    except (LookupError, TypeError, AttributeError):
        return None
    fh.flush()
    return buffer


def _write_csv(fh, contactors: Contactors, columns: dict, labels: dict) -> None:
    from .. import fastcsv

    header = list(contactors.passthrough_names) + list(columns)
    fh.write(",".join(header) + "\n")
    columns = {k: np.asarray(v) for k, v in columns.items()}
    p = len(contactors.points)
    text = contactors.passthrough if contactors.passthrough_names else None
    parts = [_column_text(v, labels.get(k)) for k, v in columns.items()]
    sink = _byte_sink(fh)
    # chunks bound the memory of the text: 15 columns of 32768 rows are about 11 MB of slots
    chunk = 32768
    for start in range(0, p, chunk):
        rows = fastcsv.format_rows(text, parts, start, min(start + chunk, p))
        if sink is not None:
            sink.write(rows)
        else:
            fh.write(rows.tobytes().decode("utf-8"))


def _result_mesh(contactors: Contactors, columns: dict, labels: dict) -> meshio.Mesh:
    p = len(contactors.points)
    cols = {k: np.asarray(v) for k, v in columns.items()}
    used = set()
    if all(k in cols for k in ("x", "y", "z")):
        points = np.column_stack([cols["x"], cols["y"], cols["z"]]).astype(np.float64)
        used.update(("x", "y", "z"))
    else:
        points = np.asarray(contactors.points, dtype=np.float64)

    point_data = {}
    for vec, trio in _VECTOR_GROUPS.items():
        if all(k in cols for k in trio) and not any(k in labels for k in trio):
            point_data[vec] = np.column_stack([cols[k] for k in trio]).astype(np.float64)
            used.update(trio)
    for k, v in cols.items():
        if k in used:
            continue
        if v.dtype.kind == "b" or k in labels:
            v = v.astype(np.int64)
        point_data[k] = v
    for j, pname in enumerate(contactors.passthrough_names):
        if pname in point_data or pname in used:
            continue
        values = contactors.passthrough.numbers(j)
        if values is not None:  # text columns have no place in point data
            point_data[pname] = values

    mesh = contactors.mesh
    if mesh is not None and len(mesh.points) == p:
        cells = [(b.type, np.asarray(b.data)) for b in mesh.cells]
    else:
        cells = [("vertex", np.arange(p, dtype=np.int64).reshape(-1, 1))]
    return meshio.Mesh(points, cells, point_data=point_data)


def write_result(
    path: str | None,
    contactors: Contactors,
    columns: dict,
    *,
    labels: dict | None = None,
    overwrite: bool = False,
    stdout=None,
) -> None:
    """Write the result columns, as CSV or as point data of a mesh.

    Parameters
    ----------
    path : str or None
        ``None`` or ``"-"``: CSV on ``stdout``. ``.csv`` / ``.txt``: CSV file. Any other
        extension: a mesh written by meshio in the format of that extension.
    contactors : Contactors
        The input; supplies pass-through columns and, for mesh output, points and cells.
    columns : dict of str to (p,) array
        Ordered result columns: floats, ints, or integer codes of a column in ``labels``.
    labels : dict of str to tuple of str, optional
        Column name -> words for codes 0, 1, ...; CSV gets the words, meshes the codes.
    overwrite : bool
        Replace an existing file.
    stdout : text stream, optional
        Stream for CSV on stdout; default ``sys.stdout``.

    Raises
    ------
    WriteError
        See :func:`check_output_path`; also bad columns or a failing writer. A file output
        is written to a temporary file and renamed, so nothing half-written is ever left.

    Notes
    -----
    CSV floats use ``repr`` (shortest exact round trip: ``0.1``, ``1e-300``, ``nan``). In a
    mesh, ``x, y, z`` become the points, ``nx, ny, nz`` the vector ``normal`` and
    ``px, py, pz`` the vector ``proximal_point``; pass-through columns that are all numbers
    become point data, others are dropped.
    """
    labels = dict(labels or {})
    if path is None or str(path) == "-":
        name = "<stdout>"
        _validate_columns(name, contactors, columns, labels)
        stream = sys.stdout if stdout is None else stdout
        try:
            _write_csv(stream, contactors, columns, labels)
            stream.flush()
        except BrokenPipeError:
            raise
        except OSError as exc:
            raise WriteError(f"{name}: cannot write ({_first_line(exc)})") from None
        return

    path = str(path)
    check_output_path(path, overwrite)
    kind, fmt = _output_kind(path)
    _validate_columns(path, contactors, columns, labels)
    mesh = _result_mesh(contactors, columns, labels) if kind == "mesh" else None

    def write(tmp: str) -> None:
        if kind == "csv":
            with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
                _write_csv(fh, contactors, columns, labels)
            return
        _meshio_write(tmp, mesh, fmt)

    ext = _mesh_extension(path)[0] if kind == "mesh" else _extension(path)
    _write_atomically(path, overwrite, ext, write)


def _os_reason(exc: OSError) -> str:
    """The OS's words for ``exc`` without the (temporary) file name it quotes."""
    return exc.strerror or _first_line(exc)


class OutputBatch:
    """Outputs of one command written to temporary files, renamed into place together.

    See :func:`output_batch`. ``pending`` holds (temporary file, path, overwrite).
    """

    def __init__(self):
        self.pending: list[tuple[str, str, bool]] = []

    def commit(self) -> None:
        """Rename every pending output into place; WriteError (and nothing renamed) if one
        of them appeared meanwhile without ``overwrite``."""
        try:
            for tmp, path, overwrite in self.pending:
                if not overwrite and os.path.lexists(path):
                    raise WriteError(f"{path}: already exists (use --overwrite)")
            while self.pending:
                tmp, path, _ = self.pending[0]
                try:
                    os.replace(tmp, path)
                except OSError as exc:
                    raise WriteError(f"{path}: cannot write ({_os_reason(exc)})") from None
                self.pending.pop(0)
        finally:
            self.discard()

    def discard(self) -> None:
        """Remove the temporary files of the outputs not renamed yet."""
        for tmp, _, _ in self.pending:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        self.pending.clear()


#: the batch of the command running now, if any (see output_batch).
_batch: OutputBatch | None = None


@contextlib.contextmanager
def output_batch():
    """Defer the final rename of every file written inside the block until ``commit()``.

    A command with several outputs (``-o``, ``--residual``, ``--tangent``, ``--save-pairs``)
    then leaves all of them or none: a failure while writing the last one leaves neither new
    files nor replaced old ones. Leaving the block without ``commit()`` removes the temporary
    files.

    Yields
    ------
    batch : OutputBatch
    """
    global _batch
    previous, _batch = _batch, OutputBatch()
    try:
        yield _batch
    finally:
        _batch.discard()
        _batch = previous


def _write_atomically(path: str, overwrite: bool, ext: str, write) -> None:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it to ``path``.

    Nothing half-written is ever left: on any failure the temporary file is removed and a
    WriteError naming ``path`` is raised; an existing ``path`` is kept unless ``overwrite``.
    Inside :func:`output_batch` the rename waits for the batch's ``commit()``.
    """
    directory, base = os.path.split(os.path.abspath(path))
    if _batch is not None and any(os.path.abspath(p) == os.path.abspath(path)
                                  for _, p, _ in _batch.pending):
        raise WriteError(f"{path}: named for two outputs, expected a file name per output")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{base}.tmp", suffix=ext, dir=directory)
    except OSError as exc:
        raise WriteError(
            f"{path}: cannot create a file in '{directory}' ({_os_reason(exc)})") from None
    try:
        os.close(fd)
        write(tmp)
        # mkstemp makes the file private; give it the permissions a plain open() would
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        if not overwrite and os.path.lexists(path):
            raise WriteError(f"{path}: already exists (use --overwrite)")
        if _batch is not None:
            _batch.pending.append((tmp, path, overwrite))
            return
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(exc, WriteError):
            raise
        if isinstance(exc, Exception):
            raise WriteError(f"{path}: cannot write ({_first_line(exc)})") from None
        raise


def write_mesh(path: str, vertices: np.ndarray, faces: list, point_data: dict,
               overwrite: bool = False) -> None:
    """Write a surface mesh of triangles and quads, with point data, atomically.

    The format follows the extension (any format meshio writes). Formats that hold triangles
    only (STL) get each quad split into two triangles.
    """
    path = str(path)
    check_output_path(path, overwrite, kind="mesh")
    kind, fmt = _output_kind(path)
    blocks = [f for f in faces if len(f)]
    if fmt.startswith("stl"):
        blocks = [f if f.shape[1] == 3 else np.concatenate([f[:, [0, 1, 2]], f[:, [0, 2, 3]]])
                  for f in blocks]
    cells = [("triangle" if f.shape[1] == 3 else "quad", f) for f in blocks]
    mesh = meshio.Mesh(vertices, cells, point_data=point_data)

    _write_atomically(path, overwrite, _mesh_extension(path)[0],
                      lambda tmp: _meshio_write(tmp, mesh, fmt))


def _meshio_write(tmp: str, mesh: meshio.Mesh, fmt: str) -> None:
    kwargs = {}
    if fmt == "xdmf":
        kwargs["data_format"] = "XML"  # HDF would put the data in a second file
    if fmt.startswith("gmsh"):
        # gmsh writers warn on stderr for every block missing these tags
        mesh.cell_data = {key: [np.zeros(len(b.data), dtype=np.int64) for b in mesh.cells]
                          for key in ("gmsh:physical", "gmsh:geometrical")}
    meshio.write(tmp, mesh, file_format=fmt, **kwargs)


# --------------------------------------------------------------------------------------------
# contact element outputs: Matrix Market matrices and frozen pairings
# --------------------------------------------------------------------------------------------

#: extensions of the element outputs, checked by :func:`check_output_path` with ``kind``.
_KIND_EXTENSIONS = {"matrix": (".mtx",), "pairs": (".npz",)}
#: arrays a stored pairing holds, per method.
_PAIR_ARRAYS = {"diffuse": ("origin", "axes", "radius", "spacing", "index"), "facet": ("facet",)}


def write_matrix(path: str, matrix, overwrite: bool = False, comment: str = "") -> None:
    """Write a dense (n, 1) vector or a sparse matrix in Matrix Market format, atomically.

    scipy.io.mmread and FE codes read it back; values keep full precision.
    """
    import scipy.io

    path = str(path)
    check_output_path(path, overwrite, kind="matrix")
    _write_atomically(path, overwrite, ".mtx",
                      lambda tmp: scipy.io.mmwrite(tmp, matrix, comment=comment, precision=17))


def save_pairs(path: str, pairing: dict, overwrite: bool = False) -> None:
    """Store a frozen pairing (``method``, counts and the method's arrays) as .npz, atomically."""
    path = str(path)
    check_output_path(path, overwrite, kind="pairs")
    arrays = {k: np.asarray(v) for k, v in pairing.items()}

    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    _write_atomically(path, overwrite, ".npz", write)


def load_pairs(path: str, *, method: str, n_contactors: int, n_target: int) -> dict:
    """Read a pairing stored by :func:`save_pairs` and check it matches the inputs.

    Raises ReadError when the file is not a pairing (not an .npz archive, arrays missing or of
    the wrong type or shape, non-finite frames or radii), was made with another method, was
    made for other counts of contactors or target points, or refers to target points that do
    not exist. The facet indices of a ``facet`` pairing are only checked to be >= -1 here: the
    number of facets is known to the caller.
    """
    path = str(path)
    _check_input_file(path)
    expected = "expected a pairing file written by --save-pairs"
    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise ReadError(f"{path}: cannot read ({_os_reason(exc)})") from None
    if magic not in (b"PK\x03\x04", b"PK\x05\x06"):  # every .npz is a zip archive
        raise ReadError(f"{path}: not an .npz archive, {expected}")
    try:
        with np.load(path, allow_pickle=False) as data:
            pairing = {k: data[k] for k in data.files}
    except Exception as exc:  # noqa: BLE001 - any failure here means "not a pairing file"
        raise ReadError(f"{path}: unreadable .npz archive ({_first_line(exc)[:_REASON_CHARS]}), "
                        f"{expected}") from None
    stored = pairing.get("method")
    if stored is None or stored.shape != () or stored.dtype.kind != "U" \
            or str(stored) not in _PAIR_ARRAYS:
        raise ReadError(f"{path}: no pairing method (diffuse or facet) stored, {expected}")
    stored = str(stored)
    missing = [k for k in ("n_contactors", "n_target") + _PAIR_ARRAYS[stored] if k not in pairing]
    if missing:
        raise ReadError(f"{path}: no '{missing[0]}' array, {expected}")
    if stored != method:
        raise ReadError(f"{path}: pairing made with --method {stored}, not {method}")
    for key in ("n_contactors", "n_target"):
        if pairing[key].shape != () or pairing[key].dtype.kind not in "iu":
            raise ReadError(f"{path}: '{key}' is not a count, {expected}")
    counts = (int(pairing["n_contactors"]), int(pairing["n_target"]))
    if counts != (n_contactors, n_target):
        raise ReadError(
            f"{path}: pairing made for {counts[0]} contactors and {counts[1]} target points, "
            f"the inputs have {n_contactors} and {n_target}")
    p = n_contactors
    shapes = {"origin": (p, 3), "axes": (p, 3, 3), "radius": (p,), "spacing": (p,),
              "index": (p, None), "facet": (p,)}
    for key in _PAIR_ARRAYS[stored]:
        arr, shape = pairing[key], shapes[key]
        integer = key in ("index", "facet")
        if arr.ndim != len(shape) or any(n is not None and n != m for n, m in zip(shape, arr.shape)) \
                or arr.dtype.kind not in ("iu" if integer else "f"):
            want = "x".join("k" if n is None else str(n) for n in shape)
            raise ReadError(f"{path}: '{key}' is {arr.dtype} of shape {arr.shape}, expected "
                            f"{'integers' if integer else 'floats'} of shape ({want}); "
                            f"{expected}")
        if not integer and not np.isfinite(arr).all():
            raise ReadError(f"{path}: '{key}' holds NaN or inf, {expected}")
        if integer and arr.min(initial=-1) < -1:
            raise ReadError(f"{path}: '{key}' holds negative indices, {expected}")
    if stored == "diffuse" and pairing["index"].max(initial=-1) >= n_target:
        raise ReadError(f"{path}: pairing refers to target points that do not exist")
    return pairing


# --------------------------------------------------------------------------------------------
# figures (diffsurf tune --plot)
# --------------------------------------------------------------------------------------------

#: a figure is written by matplotlib in the format its extension names.
_KIND_EXTENSIONS["figure"] = (".png", ".svg", ".pdf")


def write_figure(path: str, fig, overwrite: bool = False) -> None:
    """Write a matplotlib figure (.png, .svg or .pdf, from the extension), atomically.

    An existing file is kept unless ``overwrite``; see :func:`check_output_path` (kind
    'figure').
    """
    path = str(path)
    check_output_path(path, overwrite, kind="figure")
    ext = _extension(path)
    _write_atomically(path, overwrite, ext,
                      lambda tmp: fig.savefig(tmp, format=ext[1:], dpi=150))
