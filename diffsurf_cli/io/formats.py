"""Mesh formats by file name: which meshio format reads or writes a name (its extension,
compound ones such as ``.vol.gz`` too), and which of them can hold a result. What both the
meshes (`.mesh`) and the output names (`.paths`) ask, so that neither imports the other."""
from __future__ import annotations

import os

import meshio
from meshio import _helpers as _meshio_helpers

from .errors import WriteError

#: where a meshio extension maps to several formats, the one to *write*; meshio would take the
#: first (ansys for .msh), and gmsh 4.1 refuses meshes mixing cell types without entity info.
_PREFERRED_WRITER = {".msh": "gmsh22"}

#: writers that produce companion files next to the named one, which a rename cannot keep
#: atomic.
_MULTI_FILE_WRITERS = ("tetgen",)


def mesh_extension(path: str) -> tuple[str, list[str]]:
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


def known_mesh_extensions() -> str:
    exts = list(meshio.extension_to_filetypes)
    # the common FE formats first, so a truncated hint still shows them
    common = [".msh", ".vtu", ".vtk", ".stl", ".obj", ".ply", ".inp", ".med"]
    ordered = [e for e in common if e in exts] + [e for e in exts if e not in common]
    return ", ".join(ordered[:8]) + ", ..."


def writer_format(path: str, hint: str | None = None) -> str:
    """The meshio format that writes ``path`` (by its extension); WriteError if none does,
    suggesting `hint` (the formats that would do), or every mesh format meshio writes."""
    ext, formats = mesh_extension(path)
    writers = [f for f in formats if f in _meshio_helpers._writer_map]
    if not writers:
        shown = os.path.splitext(path)[1] or "(none)"
        raise WriteError(
            f"{path}: unknown output format '{shown}', expected "
            + (hint or f".csv, .tsv, .parquet or a mesh format meshio writes "
                       f"({known_mesh_extensions()})"))
    fmt = _PREFERRED_WRITER.get(ext, writers[0])
    if fmt not in _meshio_helpers._writer_map:
        fmt = writers[0]
    if fmt in _MULTI_FILE_WRITERS:
        raise WriteError(
            f"{path}: format '{fmt}' writes several files and cannot be written safely; "
            f"use .csv, .parquet, .vtu, .vtk or .msh"
        )
    return fmt


#: the meshio formats that hold a result: the points and every point data array, scalar and
#: vector, read back whole. tests/test_io.py writes a result in every format meshio writes,
#: as a cloud of points and over a source mesh's cells, reads it back and checks this list.
RESULT_FORMATS = ("vtu", "vtk", "gmsh22", "avsucd")

#: what a result written in one of the other formats would lose, as measured by that test.
_RESULT_LOSS = {
    "ply": "the vectors normal and proximal_point (PLY keeps scalar point data only)",
    "tecplot": "a result of points without cells, and the vectors normal and proximal_point "
               "(split into scalars)",
}
#: the formats whose writers need a module that is not installed here: not checked.
_NEEDS_MODULE = {"xdmf": "h5py", "cgns": "h5py", "h5m": "h5py", "hmf": "h5py", "med": "h5py",
                 "exodus": "netCDF4"}
#: the file extensions of the result formats, in the hint of a refusal.
RESULT_HINT = ".csv, .tsv, .parquet, .vtu, .vtk, .msh or .avs"


def result_format(path: str) -> str:
    """The meshio format that writes the result file ``path``; WriteError, naming the file
    and what it would lose, if that format cannot hold the results (see RESULT_FORMATS)."""
    fmt = writer_format(path, RESULT_HINT)
    if fmt in RESULT_FORMATS:
        return fmt
    if fmt in _RESULT_LOSS:
        lost = _RESULT_LOSS[fmt]
    elif fmt in _NEEDS_MODULE:
        lost = (f"possibly the point data: not checked to hold it (the check needs "
                f"{_NEEDS_MODULE[fmt]})")
    else:
        lost = "every result column (gap, normal, proximal_point, status, ...): it keeps no " \
               "point data"
    raise WriteError(f"{path}: the {fmt} format cannot hold the results, it would lose {lost}; "
                     f"expected {RESULT_HINT}")
