"""The contactor points a command reads (a table or the points of a mesh) and the result
columns it writes for them (a table or a mesh), with the input's other columns carried
through."""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field

import numpy as np

from ..projection import COLUMNS
from . import table
from .atomic import write_atomically, write_reason
from .errors import ReadError, WriteError, first_line
from .paths import (
    TABLE_EXTENSIONS,
    check_input_file,
    check_output_path,
    extension,
    output_kind,
    writes_in_place,
)

__all__ = ["Contactors", "read_contactors", "write_result"]


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
        Names of the input's columns other than x, y, z, in file order.
    passthrough : list of polars.Series
        Those columns, each of length p: text with surrounding whitespace stripped for CSV,
        the stored types for Parquet. Rows of str (a list of p lists) are converted on
        construction; None means no columns.
    mesh : meshio.Mesh or None
        The mesh when the contactors were read from a mesh file, so a mesh output can reuse
        its cells; None for table input.
    """

    path: str
    points: np.ndarray
    passthrough_names: list = field(default_factory=list)
    passthrough: list = None
    mesh: object = None

    def __post_init__(self):
        columns = self.passthrough
        if columns is None:
            self.passthrough = []
        elif len(columns) and not hasattr(columns[0], "dtype"):  # rows of text
            self.passthrough = table.text_columns(columns, len(self.passthrough_names))
        elif not len(columns) and self.passthrough_names:  # no rows
            self.passthrough = table.text_columns([], len(self.passthrough_names))
        else:
            self.passthrough = list(columns)

    def passthrough_rows(self) -> list[list]:
        """The pass-through columns as rows (a list per point): for tests and small inputs."""
        if not self.passthrough:
            return [[] for _ in range(len(self.points))]
        return [list(r) for r in zip(*(s.to_list() for s in self.passthrough))]


#: The names a result writes besides x, y, z: its columns (`projection.COLUMNS`), and in a
#: mesh its vectors (named after their fields: normal, proximal_point).
RESULT_NAMES = tuple(
    [c.name for c in COLUMNS if c.field != "points"]
    + list(dict.fromkeys(c.field for c in COLUMNS
                         if c.component is not None and c.field != "points")))


def result_clashes(contactors: Contactors) -> list:
    """The contactors' pass-through columns (or a mesh's point data) named as a result's own
    (`RESULT_NAMES`): a result fed back as POINTS. Every output format would then hold a name
    twice, or drop one of the two."""
    names = list(contactors.passthrough_names)
    if contactors.mesh is not None:
        names += list(getattr(contactors.mesh, "point_data", {}) or {})
    return [n for n in RESULT_NAMES if n in names]


def read_contactors(path: str, stdin=None) -> Contactors:
    """Read contactor points from a table (CSV or Parquet) or from the points of a mesh.

    Parameters
    ----------
    path : str
        ``"-"`` for CSV on ``stdin``; ``.csv``, ``.tsv`` or ``.txt`` for CSV text;
        ``.parquet`` for a Parquet file; anything else is read with meshio and all its points
        (file order) are contactors, their point data the pass-through columns (see
        :func:`diffsurf_cli.io.mesh.point_data_columns`).
    stdin : text stream, optional
        Stream read when ``path == "-"``; default ``sys.stdin``.

    Returns
    -------
    contactors : Contactors

    Notes
    -----
    CSV text: see :func:`diffsurf_cli.io.table.read_csv` (separator comma, semicolon, tab or
    whitespace, sniffed; an optional header; comments; RFC 4180 quoting). Parquet: the columns named
    x, y, z (any case) are the coordinates, the others are passed through. NaN / inf
    coordinates are kept.
    """
    path = str(path)
    if path == "-":
        return _read_stdin(sys.stdin if stdin is None else stdin)
    kind = TABLE_EXTENSIONS.get(extension(path))
    if kind is not None:
        check_input_file(path)
        if kind == "parquet":
            points, names, columns = table.read_parquet(path)
            return Contactors(path, points, names, columns, None)
        try:
            with open(path, "rb") as fh:
                data = fh.read()
        except OSError as exc:
            raise ReadError(f"{path}: cannot read ({first_line(exc)})") from None
        points, names, columns = table.read_csv(data, table.csv_start(data, path), path)
        return Contactors(path, points, names, columns, None)

    from . import mesh as _mesh

    if not _mesh.mesh_extension(path)[1]:
        check_input_file(path)
        shown = os.path.splitext(path)[1] or "(none)"
        raise ReadError(
            f"{path}: unknown contactor file format '{shown}' (expected .csv, .txt, .parquet or "
            f"a mesh meshio reads: {_mesh.known_mesh_extensions()})"
        )
    m = _mesh.read_mesh(path)
    points = _mesh.points3(path, m)
    names, columns = _mesh.point_data_columns(path, m, len(points))
    return Contactors(path, points, names, columns, m)


def _read_stdin(stream) -> Contactors:
    name = "<stdin>"
    try:
        raw = table.stdin_bytes(stream)
        text = stream.read() if raw is None else raw
    except UnicodeDecodeError:
        raise ReadError(f"{name}: not a text CSV file (bytes are not UTF-8 text)") from None
    except OSError as exc:
        raise ReadError(f"{name}: cannot read ({first_line(exc)})") from None
    if raw is not None:
        # what a strict UTF-8 text stream would have said about these bytes
        if not table.is_utf8(raw):
            raise ReadError(f"{name}: not a text CSV file (bytes are not UTF-8 text)")
        if b"\x00" in raw:
            raise ReadError(f"{name}: not a text CSV file (contains NUL bytes)")
        data = raw
    elif isinstance(text, bytes):
        data = text
    else:
        if "\x00" in text:
            raise ReadError(f"{name}: not a text CSV file (contains NUL bytes)")
        try:
            data = text.encode("utf-8")
        except UnicodeEncodeError:
            raise ReadError(f"{name}: not a text CSV file (bytes are not UTF-8 text)") from None
    start = table.csv_start(data, name, all_boms=True)
    table.refuse_mesh_text(data[start:start + 4096], name)
    points, names, columns = table.read_csv(data, start, name)
    return Contactors("-", points, names, columns, None)


# --------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------


def _validate_columns(name: str, contactors: Contactors, columns: dict, labels: dict,
                      kind: str) -> None:
    p = len(contactors.points)
    if len(contactors.passthrough) != len(contactors.passthrough_names):
        raise WriteError(f"{name}: {len(contactors.passthrough)} pass-through columns for "
                         f"{len(contactors.passthrough_names)} names")
    for pname, col in zip(contactors.passthrough_names, contactors.passthrough):
        if len(col) != p:
            raise WriteError(f"{name}: pass-through column '{pname}' has {len(col)} rows for "
                             f"{p} points")
        if kind in ("csv", "tsv"):
            table.check_csv_column(name, col, pname, "\t" if kind == "tsv" else ",")
    if kind == "mesh" and contactors.mesh is None:
        mesh_columns(name, contactors, output_kind(name)[1])
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
    if kind == "parquet":
        twice = table.duplicate_name(list(contactors.passthrough_names) + list(columns))
        if twice is not None:
            raise WriteError(f"{name}: two columns named '{twice}' (an input column passed "
                             f"through and a result), which Parquet cannot hold; rename the "
                             f"input column or write .csv")


def mesh_columns(path: str, contactors: Contactors, fmt: str) -> dict:
    """The pass-through columns of table contactors as the point data of the result mesh
    ``path`` (meshio format ``fmt``): name -> (p,) array (`table.point_data`). WriteError,
    naming every column that has no place there and its type, if any has none: a result
    never drops a column silently."""
    out, refused = {}, []
    for pname, col in zip(contactors.passthrough_names, contactors.passthrough):
        values, why = table.point_data(col, fmt)
        if values is None:
            refused.append(f"'{pname}' ({col.dtype}{': ' + why if why else ''})")
        else:
            out[pname] = values
    if refused:
        many = len(refused) > 1
        raise WriteError(
            f"{path}: a {extension(path)} mesh cannot hold the pass-through column"
            f"{'s' if many else ''} {', '.join(refused)} (its point data are numbers, one per "
            f"point, without gaps); write .csv, .tsv or .parquet, or drop "
            f"{'them' if many else 'it'} from POINTS")
    return out


def check_passthrough(path: str | None, contactors: Contactors) -> None:
    """WriteError, before any work, if a pass-through column of ``contactors`` cannot be
    written to the result ``path`` (None or '-': CSV on stdout): one line naming the file,
    the column, its type and the format."""
    if path is None or str(path) == "-":
        kind, name = "csv", "<stdout>"
    else:
        name = str(path)
        kind = output_kind(name)[0]
    for pname, col in zip(contactors.passthrough_names, contactors.passthrough):
        if kind in ("csv", "tsv"):
            table.check_csv_column(name, col, pname, "\t" if kind == "tsv" else ",")
    if kind == "mesh" and contactors.mesh is None:
        mesh_columns(name, contactors, output_kind(name)[1])


def write_result(
    path: str | None,
    contactors: Contactors,
    columns: dict,
    *,
    labels: dict | None = None,
    overwrite: bool = False,
    stdout=None,
) -> None:
    """Write the result columns, as a table (CSV, Parquet) or as point data of a mesh.

    Parameters
    ----------
    path : str or None
        ``None`` or ``"-"``: CSV on ``stdout``. ``.csv``: CSV file. ``.tsv`` / ``.txt``:
        tab-separated text. ``.parquet``: Parquet file. A mesh format that holds point data
        (.vtu, .vtk, .msh, .avs): a mesh written by meshio; other mesh formats are refused
        (they would lose columns). A file that is not a regular file (/dev/null, /dev/stdout,
        a FIFO) is written in place, as CSV (TSV if named .tsv / .txt).
    contactors : Contactors
        The input; supplies pass-through columns and, for mesh output, points and cells.
    columns : dict of str to (p,) array
        Ordered result columns: floats, ints, or integer codes of a column in ``labels``.
    labels : dict of str to tuple of str, optional
        Column name -> words for codes 0, 1, ...; tables get the words, meshes the codes.
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
    Tables hold the pass-through columns, then the result columns. CSV floats are the
    shortest text that reads back to the same double (``0.1``, ``1e-300``, ``nan``); Parquet
    keeps float64, and labels as dictionary-encoded words. In a mesh, ``x, y, z`` become the
    points, ``nx, ny, nz`` the vector ``normal`` and ``px, py, pz`` the vector
    ``proximal_point``; pass-through columns become point data (`mesh_columns`): a column
    that cannot (text, dates, nulls) is refused, with a WriteError naming it, never dropped;
    the point data of contactors read from a mesh keep their names and shapes. A Duration
    is written to CSV as its ISO 8601 text (PT1.5S).
    """
    labels = dict(labels or {})
    if path is None or str(path) == "-":
        name = "<stdout>"
        _validate_columns(name, contactors, columns, labels, "csv")
        stream = sys.stdout if stdout is None else stdout
        sink = _byte_sink(stream)
        try:
            table.write_csv(stream if sink is None else sink, contactors.passthrough_names,
                            contactors.passthrough, columns, labels)
            (stream if sink is None else sink).flush()
        except BrokenPipeError:
            raise
        except Exception as exc:  # noqa: BLE001 - the OS's or polars' reason, on one line
            raise WriteError(f"{name}: cannot write ({write_reason(exc)})") from None
        return

    path = str(path)
    check_output_path(path, overwrite)
    kind, fmt = output_kind(path)
    _validate_columns(path, contactors, columns, labels, kind)
    names, passthrough = contactors.passthrough_names, contactors.passthrough
    separator = "\t" if kind == "tsv" else ","

    if writes_in_place(path):
        # a device or a pipe: a rename would replace it, and it takes text as it comes
        try:
            with open(path, "ab") as fh:
                table.write_csv(fh, names, passthrough, columns, labels, separator)
        except BrokenPipeError:
            raise
        except Exception as exc:  # noqa: BLE001 - the OS's or polars' reason, on one line
            raise WriteError(f"{path}: cannot write ({write_reason(exc)})") from None
        return

    if kind == "mesh":
        from . import mesh as _mesh

        extra = {}
        if contactors.mesh is not None:  # a mesh's point data, vectors whole
            extra.update(_mesh.point_data_arrays(contactors.mesh, len(contactors.points)))
        else:  # every column, or a WriteError (checked in _validate_columns)
            for pname, values in mesh_columns(path, contactors, fmt).items():
                extra.setdefault(pname, values)
        result = _mesh.result_mesh(contactors.points, columns, labels, extra, contactors.mesh)
        write_atomically(path, overwrite, _mesh.mesh_extension(path)[0],
                         lambda tmp: _mesh.meshio_write(tmp, result, fmt))
        return

    def write(tmp: str) -> None:
        if kind == "parquet":
            table.write_parquet(tmp, names, passthrough, columns, labels)
        else:
            table.write_csv(tmp, names, passthrough, columns, labels, separator)

    write_atomically(path, overwrite, extension(path), write)


def _byte_sink(stream):
    """The binary stream under the text stream ``stream`` when bytes written there are
    exactly what ``stream.write`` would write (UTF-8, no newline translation); else None."""
    import codecs

    buffer = getattr(stream, "buffer", None)
    if buffer is None or os.linesep != "\n":
        return None
    try:
        if codecs.lookup(stream.encoding).name != "utf-8":
            return None
    except (LookupError, TypeError, AttributeError):
        return None
    stream.flush()
    return buffer
