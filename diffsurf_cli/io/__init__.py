"""File input and output for diffsurf: target surfaces, contactor points and results.

Only this package touches files (and imports meshio and polars). Every failure at this
boundary is reported as a :class:`ReadError` or :class:`WriteError` whose message is one line
naming the file and what was expected; no traceback from meshio, polars or numpy leaks out.

Modules: :mod:`.mesh` (meshio: targets, mesh outputs), :mod:`.abaqus` (Abaqus/CalculiX decks
meshio cannot read or misreads), :mod:`.abaqus_surface` (their *SURFACE faces),
:mod:`.boundary` (the boundary of volume cells), :mod:`.table` (CSV and Parquet through
polars), :mod:`.contactors` (contactors in, results out), :mod:`.atomic` (atomic writes,
output batches), :mod:`.paths` (what an input or output name means), :mod:`.formats`
(which mesh format reads or writes a file name), :mod:`.pairs` (frozen pairings, Matrix
Market), :mod:`.figure` (writing a figure), :mod:`.plot` (the pictures of ``project --plot``
and ``smooth --plot``), :mod:`.errors`.
"""
from __future__ import annotations

from .atomic import OutputBatch, output_batch
from .contactors import Contactors, read_contactors, result_clashes, write_result
from .errors import ReadError, WriteError
from .figure import write_figure
from .mesh import SURFACE_CELL_TYPES, Target, read_target, write_mesh
from .pairs import (
    elements_from_core,
    load_pairs,
    pairing_from_core,
    pairing_to_core,
    save_elements,
    save_pairs,
    write_matrix,
)
from .paths import check_output_path
from .plot import check_plot, project_figure, smooth_figure

__all__ = [
    "SURFACE_CELL_TYPES",
    "ReadError",
    "WriteError",
    "Target",
    "Contactors",
    "read_target",
    "read_contactors",
    "result_clashes",
    "write_result",
    "check_output_path",
    "output_batch",
    "OutputBatch",
    "write_mesh",
    "write_matrix",
    "save_pairs",
    "save_elements",
    "load_pairs",
    "pairing_from_core",
    "pairing_to_core",
    "elements_from_core",
    "write_figure",
    "check_plot",
    "project_figure",
    "smooth_figure",
]
