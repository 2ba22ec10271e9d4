"""What a file name means: which inputs can be read and which kind of output an extension
asks for, checked before any work is done."""
from __future__ import annotations

import os

from .atomic import check_directory, check_new
from .errors import ReadError, WriteError

__all__ = ["TABLE_EXTENSIONS", "check_input_file", "check_output_path", "output_kind"]

#: table extensions and their format: contactors in, results out (not meshes).
TABLE_EXTENSIONS = {".csv": "csv", ".txt": "csv", ".parquet": "parquet"}

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


def output_kind(path: str) -> tuple[str, str | None]:
    """("csv", None), ("parquet", None) or ("mesh", meshio format) for the result file
    ``path``; WriteError if its extension is none of these."""
    table = TABLE_EXTENSIONS.get(extension(path))
    if table is not None:
        return table, None
    from .mesh import writer_format

    return "mesh", writer_format(path)


def check_output_path(path: str | None, overwrite: bool, kind: str = "result") -> None:
    """Check that ``path`` can be written before any work is done.

    Parameters
    ----------
    path : str or None
        Output file; None or ``"-"`` means stdout, which is always accepted.
    overwrite : bool
        Whether an existing file may be replaced.
    kind : {'result', 'mesh', 'matrix', 'pairs', 'figure'}
        A result (.csv/.txt, .parquet or a mesh format), a surface mesh (a mesh format), a
        Matrix Market file (.mtx), a pairing (.npz) or a figure (.png, .svg, .pdf).

    Raises
    ------
    WriteError
        The file exists and ``overwrite`` is False, or it is a directory, or the extension
        does not fit ``kind``, or the parent directory is missing or not writable.
    """
    if path is None or str(path) == "-":
        return
    path = str(path)
    check_new(path, overwrite)
    if kind == "result":
        output_kind(path)
    elif kind == "mesh":
        if output_kind(path)[0] != "mesh":
            raise WriteError(f"{path}: a surface mesh needs a mesh format (.vtu, .vtk, .msh, "
                             f".stl, ...), not {extension(path)}")
    elif extension(path) not in KIND_EXTENSIONS[kind]:
        raise WriteError(f"{path}: expected a {' or '.join(KIND_EXTENSIONS[kind])} file name")
    check_directory(path)
