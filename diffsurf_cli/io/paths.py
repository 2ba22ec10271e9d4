"""What a file name means: which inputs can be read and which kind of output an extension
asks for, checked before any work is done."""
from __future__ import annotations

import os
import stat

from .atomic import check_directory, check_new
from .errors import ReadError, WriteError
from .formats import result_format, writer_format

__all__ = ["TABLE_EXTENSIONS", "RESULT_TABLES", "check_input_file", "check_output_path",
           "output_kind", "writes_in_place"]

#: table extensions and their format when read: contactors in (text with a sniffed separator,
#: or Parquet), not meshes.
TABLE_EXTENSIONS = {".csv": "csv", ".tsv": "csv", ".txt": "csv", ".parquet": "parquet"}

#: table extensions and their format when written: comma separated for .csv; tab separated for
#: .tsv and .txt (what ``cut``, ``awk``, ``sort -k``, ``column -t``, ``numpy.loadtxt`` and
#: gnuplot split by default); Parquet.
RESULT_TABLES = {".csv": "csv", ".tsv": "tsv", ".txt": "tsv", ".parquet": "parquet"}

#: the names of open streams: written where they point, never replaced.
_STREAM_NAMES = ("/dev/stdout", "/dev/stderr")
_STREAM_DIRS = ("/dev/fd/", "/proc/self/fd/")

#: extensions of the outputs that are neither results nor meshes, by kind.
KIND_EXTENSIONS = {"matrix": (".mtx",), "pairs": (".npz",), "figure": (".png", ".svg", ".pdf")}


def extension(path: str) -> str:
    """The last extension of ``path``, lower case, with its dot ('' if none)."""
    return os.path.splitext(path)[1].lower()


def check_input_file(path: str) -> None:
    """ReadError unless ``path`` names a readable file (stdin is not one)."""
    if path == "-":
        raise ReadError("-: this file cannot be read from stdin, expected a file name")
    if os.path.isdir(path):
        raise ReadError(f"{path}: is a directory, expected a file")
    if not os.path.exists(path):
        raise ReadError(f"{path}: no such file")
    if not os.access(path, os.R_OK):
        raise ReadError(f"{path}: permission denied")


def writes_in_place(path: str) -> bool:
    """Whether ``path`` is written directly, without a temporary file and a rename (which
    would replace it): an existing file that is not a regular file or a directory (a
    character device such as /dev/null, a FIFO, a socket), or the name of an open stream
    (/dev/stdout, /dev/stderr, /dev/fd/N), whatever it points to."""
    path = str(path)
    absolute = os.path.abspath(path)
    if absolute in _STREAM_NAMES or absolute.startswith(_STREAM_DIRS):
        return True
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return not stat.S_ISREG(mode) and not stat.S_ISDIR(mode)


def output_kind(path: str) -> tuple[str, str | None]:
    """("csv", None), ("tsv", None), ("parquet", None) or ("mesh", meshio format) for the
    result file ``path``; WriteError if its extension is none of these, or names a mesh
    format that cannot hold the results (:func:`.formats.result_format`).

    A file written in place (:func:`writes_in_place`: /dev/null, /dev/stdout, a FIFO) gets
    text: tab separated for .tsv and .txt, else comma separated.
    """
    ext = extension(path)
    if writes_in_place(path):
        if ext == ".parquet":
            raise WriteError(f"{path}: not a regular file, and Parquet needs one (a device or "
                             f"a pipe gets CSV or TSV text: name it .csv or .tsv)")
        return ("tsv" if RESULT_TABLES.get(ext) == "tsv" else "csv"), None
    table = RESULT_TABLES.get(ext)
    if table is not None:
        return table, None
    return "mesh", result_format(path)


def check_not_input(path: str, inputs=()) -> None:
    """WriteError if the output ``path`` is one of the input files ``inputs`` (pairs of the
    input's role, as 'POINTS', and its name): writing it would replace what is being read,
    --overwrite or not. The same file whatever its name (``./x`` and ``x``, a symlink, a
    hard link: the same device and inode); a name that does not exist, or is stdin ('-') or
    a glob, is no input file."""
    try:
        out = os.stat(path)
    except (OSError, ValueError):
        return
    for role, name in inputs:
        if not name or str(name) == "-":
            continue
        try:
            same = os.path.samestat(out, os.stat(str(name)))
        except (OSError, ValueError):
            continue
        if same:
            shown = f"{role} ({name})" if str(name) != str(path) else role
            raise WriteError(f"{path}: is the input {shown}, expected another file name for "
                             f"the output (writing it would replace the input)")


def check_output_path(path: str | None, overwrite: bool, kind: str = "result",
                      inputs=()) -> None:
    """Check that ``path`` can be written before any work is done.

    Parameters
    ----------
    path : str or None
        Output file; None or ``"-"`` means stdout, which is always accepted.
    overwrite : bool
        Whether an existing file may be replaced.
    kind : {'result', 'mesh', 'matrix', 'pairs', 'figure'}
        A result (.csv, .tsv/.txt, .parquet or a mesh format that holds point data: .vtu,
        .vtk, .msh, .avs), a surface mesh (a mesh format), a Matrix Market file (.mtx), a
        pairing (.npz) or a figure (.png, .svg, .pdf).
    inputs : sequence of (str, str)
        The command's input files, as (role, name): ``path`` must be none of them
        (:func:`check_not_input`).

    Raises
    ------
    WriteError
        ``path`` is one of ``inputs`` (whatever ``overwrite``; a symlink or another name of
        it too); the file exists and ``overwrite`` is False, or it is a directory, or the extension
        does not fit ``kind`` (a result in a mesh format that would lose some of its
        columns), or the parent directory is missing or not writable.

    Notes
    -----
    A result may go to a file that is written in place (:func:`writes_in_place`): /dev/null,
    /dev/stdout, /dev/stderr, a FIFO; it is then CSV (TSV if named .tsv/.txt), and neither
    ``overwrite`` nor the directory matters. Other kinds refuse such files.
    """
    if path is None or str(path) == "-":
        return
    path = str(path)
    check_not_input(path, inputs)
    if writes_in_place(path):
        if kind != "result":
            raise WriteError(f"{path}: not a regular file (a device or a pipe), expected a "
                             f"file name; only the results (-o) can be written there")
        output_kind(path)
        if os.path.exists(path) and not os.access(path, os.W_OK):
            raise WriteError(f"{path}: permission denied")
        return
    check_new(path, overwrite)
    if kind == "result":
        output_kind(path)
    elif kind == "mesh":
        if extension(path) in RESULT_TABLES:
            raise WriteError(f"{path}: a surface mesh needs a mesh format (.vtu, .vtk, .msh, "
                             f".stl, ...), not {extension(path)}")
        writer_format(path)
    elif extension(path) not in KIND_EXTENSIONS[kind]:
        raise WriteError(f"{path}: expected a {' or '.join(KIND_EXTENSIONS[kind])} file name")
    check_directory(path)
