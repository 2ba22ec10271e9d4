"""Meshes through meshio: the target surface, contactors given as the points of a mesh, and
results or smoothed surfaces written as meshes."""
from __future__ import annotations

import contextlib
import io as _io
import itertools
import logging
import os
import re
import sys
import threading
from dataclasses import dataclass, field

import meshio
import numpy as np
from meshio import _files as _meshio_files
from meshio import _helpers as _meshio_helpers

from . import abaqus
from .abaqus_surface import read_surfaces, surface_cells, surface_nodes
from .atomic import write_atomically
from .boundary import VOLUME_CELL_TYPES, boundary_faces
from .errors import REASON_CHARS, ReadError, first_line, reader_reason
from .formats import known_mesh_extensions, mesh_extension, writer_format
from .paths import check_input_file, check_output_path

__all__ = ["SURFACE_CELL_TYPES", "Target", "read_target", "write_mesh"]

#: meshio cell types that make up a contact surface (linear and quadratic facets).
SURFACE_CELL_TYPES = ("triangle", "triangle6", "triangle7", "quad", "quad8", "quad9")
#: The nodes of a cell of each type the reader takes.
CELL_NODES = {"triangle": 3, "triangle6": 6, "triangle7": 7, "quad": 4, "quad8": 8, "quad9": 9,
              "tetra": 4, "tetra10": 10, "hexahedron": 8, "hexahedron20": 20,
              "hexahedron27": 27, "wedge": 6, "wedge15": 15, "wedge18": 18, "pyramid": 5,
              "pyramid13": 13}

#: where a meshio extension maps to several formats, the one to *read* first (its error is
#: the one that explains a damaged file).
_PREFERRED_READER = {".msh": "gmsh"}

#: vector point data assembled from scalar columns when writing a mesh.
_VECTOR_GROUPS = {"normal": ("nx", "ny", "nz"), "proximal_point": ("px", "py", "pz")}


_log = logging.getLogger("diffsurf")


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
    boundary : dict of str to int
        Volume cell type -> number of cells whose boundary faces make ``cells`` (a file or
        zone with volume cells and no surface cells); empty otherwise.
    tags : list of (c,) int64, or None
        Per block of ``cells``, the face or region tag of each cell (`cell_tags`: Gmsh
        geometrical entity, else physical group, else cell set; -1 in none), which bound the
        target's smooth patches; None where the file has none (or for a volume's boundary).
    faces_tagged : bool
        Whether ``tags`` are the Gmsh geometrical entities: each a CAD face (smooth inside:
        its edges are no features, whatever the angle of its coarse facets).
    reader : str
        What read the file: "meshio", or "deck" (an Abaqus/CalculiX deck meshio cannot read
        or would misread, read by `abaqus.read_deck`).
    merged : int
        Nodes of the cells that were made one with a nearby node (an STL's or a triangle
        soup's copies of one vertex: `merge_vertices`); 0 for other files.
    """

    path: str
    points: np.ndarray
    cells: list
    nodes: np.ndarray
    ignored: dict = field(default_factory=dict)
    boundary: dict = field(default_factory=dict)
    tags: list | None = None
    faces_tagged: bool = False
    reader: str = "meshio"
    merged: int = 0


def read_mesh(path: str) -> meshio.Mesh:
    """Read ``path`` with meshio, trying each format meshio associates with its extension.

    meshio.read is not used directly because, when every candidate format fails, it prints
    to stdout and calls sys.exit.
    """
    check_input_file(path)
    ext, formats = mesh_extension(path)
    if not formats:
        shown = os.path.splitext(path)[1] or "(none)"
        raise ReadError(
            f"{path}: unknown mesh format '{shown}' (meshio reads {known_mesh_extensions()})"
        )
    if os.path.getsize(path) == 0:
        raise ReadError(f"{path}: empty file, expected a mesh")
    preferred = _PREFERRED_READER.get(ext)
    formats = sorted(formats, key=lambda f: f != preferred)
    failures = []
    original = None  # the first reader's exception, kept for -v
    for fmt in formats:
        reader = _meshio_helpers.reader_map.get(fmt)
        if reader is None:
            continue
        if fmt in _PRECHECKS:  # what meshio's reader would hang on or silently misread
            _PRECHECKS[fmt](path)
        chatter = _io.StringIO()
        try:
            # readers probe binary headers with numpy scalars that may overflow harmlessly;
            # meshio prints its warnings on stderr, where only diffsurf's own lines belong
            with np.errstate(all="ignore"), contextlib.redirect_stderr(chatter), \
                    _hardened(reader, fmt):
                mesh = reader(path)
        except Exception as exc:  # noqa: BLE001 - meshio raises anything, ReadError to IndexError
            original = original or exc
            reason = reader_reason(exc)
            if reason == "ReadError":  # meshio often raises it without a message
                reason = "not a valid file of this format"
            elif reason.startswith("zero-size array to reduction"):  # max() of no node tags
                reason = "an empty section where nodes or cells were expected"
            elif isinstance(exc, MemoryError):  # numpy allocates what a count says first
                reason = "a count in the file is beyond any memory (a corrupt file)"
            failures.append(f"as {fmt}: {reason[:REASON_CHARS]}")
            continue
        if not isinstance(mesh, meshio.Mesh):
            failures.append(f"as {fmt}: reader returned no mesh")
            continue
        if fmt in _POSTCHECKS:  # what the reader read short without a word
            _POSTCHECKS[fmt](path, mesh)
        # a warning about a mesh that was read is worth a log line (not one of a failed read)
        for warning in " ".join(chatter.getvalue().split()).split("Warning: ")[1:]:
            _log.warning("%s: meshio: %s", path, warning.strip())
        return mesh
    reasons = "; ".join(failures) if failures else "no reader available"
    error = ReadError(f"{path}: cannot read mesh, expected a valid {ext} file ({reasons})")
    # the reader's own exception and traceback stay attached as the context, printed above
    # the one-line error where a traceback is shown (-v)
    error.__context__ = original
    raise error


# -------------------------------------------------------------------------------------------
# what meshio's readers do not check: files that make them hang or silently lose cells
# -------------------------------------------------------------------------------------------

#: reads in a row that return nothing (the file's end) after which a reader is taken to wait
#: for text that never comes: meshio's PLY header reader, the ANSYS reader's search for a
#: bracket (tried on every .msh that is no Gmsh file), ... loop for ever at the end of a file.
_EOF_READS = 1000


class _EofGuard:
    """A file object handed to a meshio reader, which raises a ReadError when the reader keeps
    reading at the end of the file (`_EOF_READS` empty reads in a row) instead of letting it
    loop for ever. Everything else is the file's own (numpy reads through its fileno)."""

    def __init__(self, file):
        self._file = file
        self._empty = 0

    def __getattr__(self, name):
        return getattr(self._file, name)

    def __repr__(self):  # in a reader's warnings
        return repr(self._file)

    def __iter__(self):
        return self

    def __next__(self):
        return next(self._file)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._file.close()

    def _counted(self, got, size):
        if got or size == 0:
            self._empty = 0
            return got
        self._empty += 1
        if self._empty > _EOF_READS:
            raise ReadError("the reader keeps reading at the end of the file, for data the file "
                            "announces and does not hold (a truncated file?)")
        return got

    def read(self, size=-1):
        return self._counted(self._file.read(size), size)

    def readline(self, size=-1):
        return self._counted(self._file.readline(size), size)


@contextlib.contextmanager
def _guarded_open_file(path_or_buf, mode="r"):
    """meshio's `_files.open_file`, its file in an `_EofGuard`."""
    with _meshio_files.open_file(path_or_buf, mode) as f:
        yield _EofGuard(f) if "r" in mode else f


def _guarded_open(file, mode="r", *args, **kwargs):
    """The built-in open, a file opened for reading in an `_EofGuard` (for the readers that
    open their file themselves)."""
    f = open(file, mode, *args, **kwargs)
    return _EofGuard(f) if "r" in mode and "+" not in mode else f


def _strict_end_block(original):
    """meshio's Gmsh `_fast_forward_to_end_block`, strict after the sections it has read by
    the counts they declare ($Nodes, $Elements): there it skipped, unread, whatever came
    before ``$EndNodes``/``$EndElements``, which is where the rest of a section goes whose
    entries were shifted (bytes inserted in a binary file, a line added to a text one): the
    entries read are then not those of the file."""
    def fast_forward(f, block):
        if block not in ("Nodes", "Elements"):
            return original(f, block)
        end = f"$End{block}".encode()
        for line in f:
            text = line.strip() if isinstance(line, bytes) else line.strip().encode()
            if text == end:
                return None
            if text:
                raise ReadError(f"${block} holds more than the entries it declares, a corrupt "
                                f"file (data where $End{block} was expected)")
        raise ReadError(f"${block} has no $End{block} (a truncated file)")
    return fast_forward


def _tags_from_one(original):
    """meshio's Gmsh 2.2 `_gmsh_to_meshio_order`, which gets the elements' node tags less one
    before they are mapped to points, refusing a node tag below 1: meshio's map, a numpy
    array, took tag 0 (index -1) for the last node and other negative ones for nodes counted
    from the end."""
    def order(cell_type, idx):
        low = int(np.min(idx, initial=0))
        if low < 0:
            raise ReadError(f"an element refers to node {low + 1}, which does not exist (node "
                            f"tags start at 1): a corrupt file")
        return original(cell_type, idx)
    return order


#: node tags up to this (or 16 times the number of nodes, if more) are read: meshio's Gmsh
#: readers map tags to points through a table as long as the largest tag, which a corrupt
#: tag (2**31, say) makes gigabytes long, filled at once (the process killed for its memory).
_MAX_NODE_TAG = 2**26


def _bounded_node_tags(original, offset: int):
    """meshio's Gmsh `_read_nodes`, refusing node tags below 1 (`_tags_from_one`) or so far
    beyond the number of nodes (`_MAX_NODE_TAG`) that their table would fill the memory;
    ``offset``: what to add to the tags it returns to have the file's (1 for 4.1, which
    returns them less one)."""
    def read_nodes(f, *args):
        out = original(f, *args)
        tags = np.asarray(out[1], dtype=np.float64) + offset
        if tags.size == 0:
            return out
        low, high = float(np.min(tags)), float(np.max(tags))
        if not (np.isfinite(low) and np.isfinite(high)) or low < 1:
            raise ReadError(f"node tag {low:g} in $Nodes: node tags are numbers from 1, a "
                            f"corrupt file")
        if high > max(16 * len(tags), _MAX_NODE_TAG):
            raise ReadError(f"node tag {high:.0f} in $Nodes is far beyond the {len(tags)} "
                            f"nodes (meshio would make a table that long), a corrupt file?")
        return out
    return read_nodes


#: the meshio readers that open their file with the built-in open (not `_files.open_file`).
_OPEN_READERS = ("gmsh", "vtk")

_MISSING = object()
#: module attributes are swapped while a reader runs: one read at a time.
_PATCH_LOCK = threading.RLock()


def _reader_patches(reader, fmt: str) -> list:
    """(module, name, value) to set in meshio while ``reader`` (of format ``fmt``) reads."""
    import importlib

    patches = []
    module = sys.modules.get(getattr(reader, "__module__", ""))
    if module is not None and hasattr(module, "open_file"):
        patches.append((module, "open_file", _guarded_open_file))
    elif module is not None and fmt in _OPEN_READERS:
        patches.append((module, "open", _guarded_open))
    if fmt == "gmsh":
        for name in ("_gmsh22", "_gmsh40", "_gmsh41"):
            try:
                gmsh = importlib.import_module(f"meshio.gmsh.{name}")
            except ImportError:  # another meshio: read as it reads
                continue
            original = getattr(gmsh, "_fast_forward_to_end_block", None)
            if original is not None:
                patches.append((gmsh, "_fast_forward_to_end_block", _strict_end_block(original)))
            if name == "_gmsh22" and hasattr(gmsh, "_gmsh_to_meshio_order"):
                patches.append((gmsh, "_gmsh_to_meshio_order",
                                _tags_from_one(gmsh._gmsh_to_meshio_order)))
            if name in ("_gmsh22", "_gmsh41") and hasattr(gmsh, "_read_nodes"):
                patches.append((gmsh, "_read_nodes", _bounded_node_tags(
                    gmsh._read_nodes, 0 if name == "_gmsh22" else 1)))
    return patches


@contextlib.contextmanager
def _hardened(reader, fmt: str):
    """meshio's ``reader`` made to fail (ReadError) where it would hang or silently misread
    a damaged file: its file object guarded against endless reads at the end (`_EofGuard`),
    and for Gmsh files stricter section ends and node tags (`_strict_end_block`,
    `_tags_from_one`)."""
    with _PATCH_LOCK:
        saved = []
        try:
            for module, name, value in _reader_patches(reader, fmt):
                saved.append((module, name, module.__dict__.get(name, _MISSING)))
                setattr(module, name, value)
            yield
        finally:
            for module, name, old in reversed(saved):
                if old is _MISSING:
                    delattr(module, name)
                else:
                    setattr(module, name, old)


def _shown(word: bytes, chars: int = 30) -> str:
    """A word of a file for a one-line message: at most ``chars`` characters, anything not
    printable escaped."""
    text = word[:chars].decode("utf-8", "replace")
    return "".join(c if c.isprintable() else f"\\x{ord(c) & 0xFF:02x}" for c in text) + (
        "..." if len(word) > chars else "")


def _ply_counts(path: str) -> dict | None:
    """The element counts (name -> count) that the header of the PLY file ``path`` declares;
    None if it is no PLY file or its header does not end (no ``end_header`` line)."""
    declared = {}
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            return None
        for line in f:
            words = line.split()
            if words[:1] == [b"end_header"]:
                return declared
            if len(words) == 3 and words[0] == b"element" and words[2].isdigit():
                declared[words[1].decode("ascii", "replace")] = int(words[2])
    return None


def _check_ply_header(path: str) -> None:
    """ReadError unless the header of the PLY file ``path`` ends (an ``end_header`` line),
    and declares no more elements than the file has bytes: meshio's header reader waits for
    the end for ever, and its face reader walks (in Python) and allocates (at once) as many
    faces as declared."""
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            return  # no PLY file: meshio's reader says so
    declared = _ply_counts(path)
    if declared is None:
        raise ReadError(f"{path}: the PLY header ends before 'end_header' (a truncated file?)")
    size = os.path.getsize(path)
    for name, count in declared.items():
        if count > size:  # an element takes a byte at least
            raise ReadError(f"{path}: the PLY header declares {count} {name} elements, more "
                            f"than the file's {size} bytes hold (a corrupt file)")


def _check_obj_faces(path: str) -> None:
    """ReadError naming the line of the first face of the OBJ file ``path`` whose vertex
    index is no number of one of its vertices: meshio's reader took an index beyond int64
    for an object (an OverflowError later), 0 for the last vertex, and had no vertex for a
    relative (negative) or too large one."""
    with open(path, "rb") as f:
        lines = f.read().splitlines()  # as meshio's text-mode file: \n, \r\n or \r
    vertices = sum(1 for line in lines if line.split(None, 1)[:1] == [b"v"])
    for number, line in enumerate(lines, 1):
        words = line.split()
        if not words or words[0] != b"f":
            continue
        for word in words[1:]:
            index = word.split(b"/")[0]
            try:
                value = int(index)
            except ValueError:
                value = None
            if value is None or not 1 <= value <= vertices:
                how = " (relative, negative indices are not read)" if value and value < 0 else ""
                raise ReadError(f"{path}: line {number}: face vertex '{_shown(index)}' is not a "
                                f"vertex number from 1 to {vertices}{how}")


#: the line kinds of an ASCII STL, by their first word.
_STL_WORDS = {b"solid": b"s", b"facet": b"f", b"outer": b"o", b"vertex": b"v", b"endloop": b"l",
              b"endfacet": b"e", b"endsolid": b"d"}
#: the first word of each line that is not blank.
_FIRST_WORDS = re.compile(rb"^[^\S\n]*(\S+)", re.MULTILINE)
#: an ASCII STL: solids of facets of three vertices.
_STL_FILE = re.compile(rb"(?:s(?:fovvvle)*d)+")
#: the longest start of an ASCII STL (where a file that is none goes wrong).
_STL_START = re.compile(rb"(?:s(?:fovvvle)*d)*(?:s(?:fovvvle)*(?:f(?:o(?:v(?:v(?:vl?)?)?)?)?)?)?")


def _check_ascii_stl(path: str) -> None:
    """ReadError unless the STL file ``path``, where meshio reads it as ASCII, is whole:
    solids of facets of three vertices, each solid closed by ``endsolid``. meshio's reader
    skips the keyword lines and takes the last three numbers of the others, so that a file
    cut at a facet's end read as the facets before the cut, without a word."""
    size = os.path.getsize(path)
    with open(path, "rb") as f:
        data = f.read()
    if size >= 84:  # meshio's test: a binary STL is as long as the facets it declares
        declared = int.from_bytes(data[80:84], "little")
        if 84 + 50 * declared == size:
            return
    words = _FIRST_WORDS.findall(data)  # of each line that is not blank
    kinds = b"".join(map(_STL_WORDS.get, words, itertools.repeat(b"x")))
    if _STL_FILE.fullmatch(kinds):
        return
    if not kinds.startswith(b"s") or b"\0" in data[:84]:
        declared = int.from_bytes(data[80:84], "little") if size >= 84 else 0
        raise ReadError(f"{path}: neither an ASCII STL (it does not start with 'solid') nor a "
                        f"binary one (of {size} bytes, not the {84 + 50 * declared} its header "
                        f"declares): a truncated or corrupt file")
    end = _STL_START.match(kinds).end()
    if end >= len(kinds) - 1:  # the whole file, or all but a last line cut short
        raise ReadError(f"{path}: the ASCII STL ends before 'endsolid', after "
                        f"{kinds[:end].count(b'e')} whole facets (a truncated file)")
    number = [n for n, line in enumerate(data.split(b"\n"), 1) if line.strip()][end]
    word = words[end]
    raise ReadError(f"{path}: line {number}: '{_shown(word)}' where an ASCII STL facet (facet "
                    f"normal, outer loop, 3 vertex lines, endloop, endfacet) or 'endsolid' "
                    f"was expected (a corrupt file)")


def _check_ply_counts(path: str, mesh: meshio.Mesh) -> None:
    """ReadError unless meshio read as many vertices and faces from the PLY file ``path`` as
    its header declares: from a binary file cut at the end of a face it read the faces
    before the cut, without a word."""
    declared = _ply_counts(path) or {}
    got = {"vertex": len(mesh.points), "face": sum(len(block.data) for block in mesh.cells)}
    for name, count in got.items():
        if name in declared and declared[name] != count:
            raise ReadError(f"{path}: the PLY header declares {declared[name]} {name} "
                            f"elements, the file holds {count} (a truncated or corrupt file)")


#: checks of a file before the meshio reader of a format reads it (ReadError naming the file).
_PRECHECKS = {"ply": _check_ply_header, "obj": _check_obj_faces, "stl": _check_ascii_stl}
#: checks of the mesh that the meshio reader of a format read from a file.
_POSTCHECKS = {"ply": _check_ply_counts}


def points3(path: str, mesh: meshio.Mesh) -> np.ndarray:
    try:
        points = np.asarray(mesh.points, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ReadError(f"{path}: non-numeric point coordinates ({first_line(exc)})") from None
    if points.ndim != 2 or points.shape[0] == 0:
        raise ReadError(f"{path}: empty mesh, expected points")
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    elif points.shape[1] != 3:
        raise ReadError(f"{path}: expected 2-D or 3-D points, got {points.shape[1]} coordinates")
    return np.ascontiguousarray(points)


def point_data_arrays(mesh: meshio.Mesh, p: int) -> dict:
    """The point data of ``mesh`` that a result carries through: name -> (p,) or (p, k...)
    numeric array (booleans as 0/1). Left out, with a log line: meshio's own bookkeeping
    (``gmsh:dim_tags``, ``medit:ref``, ...), arrays that are not numbers or not one row per
    point."""
    out = {}
    for name, values in mesh.point_data.items():
        if name.partition(":")[0] in _meshio_helpers.reader_map:
            continue  # written back by meshio itself where the format has it
        values = np.asarray(values)
        if values.ndim == 0 or values.shape[0] != p or values.dtype.kind not in "biuf":
            _log.info("point data '%s' (%s %s) not carried through: expected numbers, one row "
                      "per point", name, values.dtype, values.shape)
            continue
        out[name] = values.astype(np.int8) if values.dtype.kind == "b" else values
    return out


def point_data_columns(path: str, mesh: meshio.Mesh, p: int) -> tuple[list, list]:
    """The point data of contactors read from a mesh as pass-through columns (names, polars
    Series), in file order: a scalar array is one column of its name; a vector or tensor
    array NAME of k components is the columns NAME_0 ... NAME_{k-1} (the names meshio gives
    the components where a format splits them). Types are kept (an integer id stays an
    integer)."""
    import polars as pl

    names, columns = [], []
    for name, values in point_data_arrays(mesh, p).items():
        flat = values.reshape(p, -1)
        parts = [name] if values.ndim == 1 or flat.shape[1] == 1 and values.ndim == 2 else [
            f"{name}_{j}" for j in range(flat.shape[1])]
        for j, part in enumerate(parts):
            names.append(part)
            columns.append(pl.Series(part, np.ascontiguousarray(flat[:, j])))
    return names, columns


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
    names += [n for n in mesh.point_sets if n not in names and not n.startswith("gmsh:")]
    return names


def _is_zone(mesh: meshio.Mesh, zone: str) -> bool:
    return zone in mesh.cell_sets or (zone in mesh.field_data and "gmsh:physical" in
                                      mesh.cell_data) or zone in mesh.point_sets


def _node_set(path: str, mesh: meshio.Mesh, zone: str, npoints: int) -> np.ndarray | None:
    """The point indices of node set ``zone`` (Abaqus *NSET, meshio point sets) when it names
    one and no cell zone; None otherwise."""
    zone = _resolve_zone(path, mesh, zone)
    if zone not in mesh.point_sets or zone in mesh.cell_sets or (
            zone in mesh.field_data and "gmsh:physical" in mesh.cell_data):
        return None
    ids = np.asarray(mesh.point_sets[zone]).reshape(-1)
    if ids.dtype == bool:
        ids = np.flatnonzero(ids)
    ids = ids.astype(np.int64)
    if np.any((ids < 0) | (ids >= npoints)):
        raise ReadError(f"{path}: node set '{zone}' refers to points that do not exist")
    return ids


def _is_deck(path: str) -> bool:
    """Whether ``path`` is an Abaqus/CalculiX deck (by its extension, .inp)."""
    return "abaqus" in mesh_extension(path)[1]


def _resolve_zone(path: str, mesh: meshio.Mesh, zone: str) -> str:
    """The zone of ``mesh`` that ``zone`` names: the same name, or in an Abaqus/CalculiX deck
    (.inp), whose names ignore case, the one name that differs only by case; ReadError if
    several do."""
    if _is_zone(mesh, zone) or not _is_deck(path):
        return zone
    same = [n for n in _zone_names(mesh) if n.casefold() == zone.casefold()]
    if len(same) > 1:
        raise ReadError(f"{path}: zone '{zone}' matches {', '.join(repr(n) for n in same)}, "
                        f"which differ only by case (Abaqus names ignore it), expected one of "
                        f"them exactly")
    if same:
        _log.debug("%s: zone '%s' is '%s' (Abaqus names ignore case)", path, zone, same[0])
        return same[0]
    return zone


def _deck_surface(path: str, mesh: meshio.Mesh, zone: str):
    """(the `abaqus_surface.Surface` that ``zone`` names in an Abaqus/CalculiX deck, or None;
    the deck's surface names). A surface comes before a set (or any zone of the mesh) of the
    same name: CalculiX keeps the names of node sets, element sets and surfaces apart, its
    contact pairs, ties and loads name surfaces, and decks give a surface the name of the set
    it is made of (metalforming.inp's node set and surface 'sheetup')."""
    if not _is_deck(path):
        return None, []
    try:
        surfaces = read_surfaces(path)
    except ReadError:
        if _is_zone(mesh, _resolve_zone(path, mesh, zone)):  # meshio read it, zone and all
            return None, []
        raise
    if zone in surfaces:
        return surfaces[zone], list(surfaces)
    same = [n for n in surfaces if n.casefold() == zone.casefold()]
    if len(same) > 1:
        raise ReadError(f"{path}: zone '{zone}' matches surfaces "
                        f"{', '.join(repr(n) for n in same)}, which differ only by case "
                        f"(Abaqus names ignore it), expected one of them exactly")
    if same:
        _log.debug("%s: zone '%s' is the surface '%s' (Abaqus names ignore case)", path, zone,
                    same[0])
    return (surfaces[same[0]] if same else None), list(surfaces)


def _zone_selection(path: str, mesh: meshio.Mesh, zone: str,
                    more: list = ()) -> list[np.ndarray]:
    """Per cell block, the indices of the cells in ``zone``; ``more``: other names the error
    of an unknown zone lists (a deck's surfaces)."""
    zone = _resolve_zone(path, mesh, zone)
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
    names = _zone_names(mesh) + [n for n in more if n not in _zone_names(mesh)]
    listed = ", ".join(repr(n) for n in names) if names else "none (the file has no named zones)"
    raise ReadError(f"{path}: unknown zone '{zone}'; available zones: {listed}")


def cell_tags(mesh: meshio.Mesh) -> list | None:
    """Per cell block of ``mesh``, a face or region tag of each cell: the Gmsh geometrical
    entity (each OpenCASCADE face is one), else the Gmsh physical group, else the index of
    the first cell set holding it (-1 in none); None without any of them."""
    for key in ("gmsh:geometrical", "gmsh:physical"):
        if key in mesh.cell_data and len(mesh.cell_data[key]) == len(mesh.cells):
            try:
                return [np.asarray(t, dtype=np.int64).reshape(-1) for t in mesh.cell_data[key]]
            except (TypeError, ValueError):
                return None
    names = [n for n in mesh.cell_sets if not n.startswith("gmsh:")]
    if not names:
        return None
    tags = [np.full(len(b.data), -1, np.int64) for b in mesh.cells]
    try:
        for k, name in enumerate(names):
            for tag, ids in zip(tags, mesh.cell_sets[name]):
                ids = np.asarray(ids).reshape(-1)
                if ids.dtype == bool:
                    ids = np.flatnonzero(ids)
                ids = ids.astype(np.int64)
                ids = ids[(ids >= 0) & (ids < len(tag))]
                free = ids[tag[ids] < 0]
                tag[free] = k
    except (TypeError, ValueError):  # a malformed cell set: no tags (zones report it)
        return None
    return tags


def read_target(path: str, zone: str | None = None) -> Target:
    """Read the target surface from any mesh file meshio reads.

    Parameters
    ----------
    path : str
        Mesh file (.msh v2.2/v4.1, .vtu, .vtk, .stl, .obj, .ply, .inp, .med, ...).
    zone : str or None
        Keep only the surface cells of this named group: a ``mesh.cell_sets`` name (Abaqus
        elset, MED family, VTU cell set) or a Gmsh physical group name from ``field_data``;
        or, naming a node set (Abaqus nset, ``mesh.point_sets``), the surface cells and the
        boundary faces of the volume cells whose nodes are all in it. In an Abaqus/CalculiX
        deck it may also name a ``*SURFACE``, which comes before a set of the same name:
        element-based, the element faces it lists (S1..S6 of C3D4/C3D10, C3D6/C3D15,
        C3D8/C3D20, oriented outward; SPOS/SNEG of shells, their cells as written or turned
        over; no face id, the free faces: `abaqus_surface`); node-based, as its node set.
        In an Abaqus/CalculiX deck (.inp) the name's case does not matter, as in Abaqus (an
        exact match first; an error if several names differ only by case).

    A file (or zone) of volume cells and no surface cells gives the boundary of its volume
    cells (tetra, hexahedron, wedge, pyramid, first and second order: `boundary.boundary_faces`):
    the faces used by one cell, oriented outward, mid-side nodes included.

    Returns
    -------
    target : Target
        ``ignored`` counts the non-surface cells of the file, or of the zone when given, left
        out; ``boundary`` the volume cells whose boundary was taken.

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
    mesh, read_past, reader = target_mesh(path)
    surface, surface_names = (_deck_surface(path, mesh, zone) if zone is not None
                              else (None, []))
    if zone is not None and reader == "meshio" and _is_deck(path) and (
            surface is not None or not _is_zone(mesh, _resolve_zone(path, mesh, zone))):
        # a *SURFACE, or a name meshio's reader does not give (NSET= of *NODE, ...): the deck
        # as read here has it (and is the same mesh, as tests/test_decks.py checks on
        # CalculiX's decks), and the surface's node and element numbers
        mesh, read_past = abaqus.deck_mesh(abaqus.read_deck(path))
        reader = "deck"
    points = points3(path, mesh)
    if surface is not None and surface.type == "ELEMENT":
        return _surface_target(path, abaqus.read_deck(path), points, surface, zone, reader)
    if surface is not None and surface.type == "NODE":
        node_set = surface_nodes(path, abaqus.read_deck(path), surface)
    elif surface is not None:
        raise ReadError(f"{path}: surface '{surface.name}' is of TYPE={surface.type}, "
                        f"expected ELEMENT or NODE")
    else:
        node_set = _node_set(path, mesh, zone, len(points)) if zone is not None else None
    selection = (_zone_selection(path, mesh, zone, surface_names)
                 if zone is not None and node_set is None else None)

    all_tags = cell_tags(mesh)
    cells, volumes, tags = [], [], []
    # the elements the deck reader read past (springs, masses, ...): counted, in no zone
    ignored: dict[str, int] = (dict(read_past) if selection is None else abaqus.read_past(
        abaqus.read_deck(path), _resolve_zone(path, mesh, zone)) if reader == "deck" else {})
    for i, block in enumerate(mesh.cells):
        data = np.asarray(block.data)
        tag = (all_tags[i] if all_tags is not None and len(all_tags[i]) == len(data)
               else np.full(len(data), -1, np.int64))
        if selection is not None:
            data = data[selection[i]]
            tag = tag[selection[i]]
        if len(data) == 0:
            continue
        if block.type not in SURFACE_CELL_TYPES + VOLUME_CELL_TYPES:
            ignored[block.type] = ignored.get(block.type, 0) + len(data)
            continue
        try:
            conn = np.asarray(data, dtype=np.int64).reshape(len(data), -1)
        except (TypeError, ValueError, OverflowError) as exc:  # an index beyond int64
            raise ReadError(f"{path}: bad {block.type} connectivity ({first_line(exc)})") from None
        if conn.shape[1] != CELL_NODES[block.type]:  # a truncated or corrupt file
            raise ReadError(f"{path}: {block.type} cells of {conn.shape[1]} nodes, expected "
                            f"{CELL_NODES[block.type]} (a truncated or corrupt file?)")
        (cells if block.type in SURFACE_CELL_TYPES else volumes).append(
            (block.type, np.ascontiguousarray(conn)))
        if block.type in SURFACE_CELL_TYPES:
            tags.append(tag)

    boundary: dict[str, int] = {}
    # a node set over surface and volume cells (a deck's shell floor and solid ball): its faces
    # may be on either, so the volume cells' boundary faces are candidates too
    mixed = bool(volumes and cells and node_set is not None)
    shells = len(cells)  # the blocks of surface cells, before any boundary faces
    if volumes and (mixed or not cells):
        # a volume mesh: the target is the boundary of its cells
        used = np.unique(np.concatenate([c.reshape(-1) for _, c in volumes]))
        if used[0] < 0 or used[-1] >= len(points):
            raise ReadError(f"{path}: cell connectivity refers to point "
                            f"{int(used[0] if used[0] < 0 else used[-1])} but the file has "
                            f"{len(points)} points")
        try:
            faces, boundary = boundary_faces(points, volumes)
        except ValueError as exc:
            raise ReadError(f"{path}: bad volume cells ({exc})") from None
        if mixed:  # the boundary faces in a region of their own (no face tags of their own)
            fresh = max((int(t.max()) for t in tags if len(t)), default=-1) + 1
            tags = tags + [np.full(len(f), fresh, np.int64) for _, f in faces]
            cells = cells + faces
        else:
            cells = faces
            all_tags = None  # faces of volume cells carry no face tags
    else:
        for kind, conn in volumes:
            ignored[kind] = ignored.get(kind, 0) + len(conn)
    if node_set is not None:
        inside = np.zeros(len(points), dtype=bool)
        inside[node_set] = True
        keep = [inside[np.clip(conn, 0, len(points) - 1)].all(axis=1) for _, conn in cells]
        if mixed and not any(k.any() for k in keep[shells:]):  # none on the volume cells
            for kind, count in boundary.items():
                ignored[kind] = ignored.get(kind, 0) + count
            boundary = {}
        tags = [t[k] for t, k in zip(tags, keep) if k.any()]
        had = sum(len(c) for _, c in cells)
        cells = [(kind, conn[k]) for k, (kind, conn) in zip(keep, cells) if k.any()]
        if had and not cells:  # nodes that cover no face: a node-to-surface contact's slave
            what = (f"node surface '{surface.name}'" if surface is not None
                    else f"node set '{_resolve_zone(path, mesh, zone)}'")
            n = len(np.unique(node_set))
            raise ReadError(f"{path}: no surface cell or boundary face has all its nodes in "
                            f"the {what} ({n} node{'s' if n != 1 else ''}), expected the "
                            f"nodes of whole faces")

    merged = 0
    if cells and _soup(path, cells):
        cells, tags, merged = merge_vertices(path, points, cells, tags)
    target = _checked(path, points, cells, zone, ignored, boundary,
                      tags if all_tags is not None else None)
    target.reader, target.merged = reader, merged
    target.faces_tagged = target.tags is not None and "gmsh:geometrical" in mesh.cell_data \
        and len(mesh.cell_data["gmsh:geometrical"]) == len(mesh.cells)
    return target


def target_mesh(path: str) -> tuple[meshio.Mesh, dict, str]:
    """The mesh of a target file: (meshio.Mesh, element type -> number of elements read past
    by the deck reader, "meshio" or "deck").

    An Abaqus/CalculiX deck (.inp) is read by meshio unless a scan of its text finds what
    meshio's reader misreads without failing (`abaqus.meshio_misreads`: *INCLUDE, several
    *NODE blocks); where meshio fails or would misread, by `abaqus.read_deck`. Its failure is
    then the error (meshio's own exception kept as its context, for -v)."""
    if not _is_deck(path):
        return read_mesh(path), {}, "meshio"
    check_input_file(path)
    if os.path.getsize(path) == 0:
        raise ReadError(f"{path}: empty file, expected a mesh")
    why = abaqus.meshio_misreads(path)
    failure = None
    if why is None:
        try:
            return read_mesh(path), {}, "meshio"
        except ReadError as exc:
            failure = exc
            why = f"meshio cannot: {str(exc).partition('(as abaqus: ')[2][:-1] or exc}"
    try:
        deck = abaqus.read_deck(path)
        if len(deck.points) == 0:
            raise ReadError(f"{path}: no nodes (*NODE), expected an Abaqus/CalculiX deck")
        mesh, read_past = abaqus.deck_mesh(deck)
    except ReadError as exc:
        if failure is not None:  # -v shows meshio's own exception above the deck reader's
            exc.__context__ = failure.__context__ or failure
        raise
    _log.info("%s: read by diffsurf's deck reader (%s)", path, why)
    return mesh, read_past, "deck"


def _soup(path: str, cells: list) -> bool:
    """Whether the surface cells' nodes are to be merged (`merge_vertices`): an STL file (a
    list of facets, each with its own copies of its vertices), or cells of which no two share
    a node (a triangle soup in any format); not a mesh whose cells share nodes, where nodes at
    one place are deliberate (the two faces of a crack, two bodies in contact)."""
    if any(fmt.startswith("stl") for fmt in mesh_extension(path)[1]):
        return True
    total = sum(c.size for _, c in cells)
    return sum(len(c) for _, c in cells) > 1 and total == len(
        np.unique(np.concatenate([c.reshape(-1) for _, c in cells])))


def merge_vertices(path: str, points: np.ndarray, cells: list, tags: list):
    """The cells with each group of nodes closer than `tol.MERGE_VERTICES` times the size
    (bounding-box diagonal) of their nodes made one node (the first of the group): an STL
    stores every facet's own copy of its vertices, and meshio merges only bit-equal copies,
    so copies that round-off moved apart leave the facets unconnected (and signs wrong at
    their edges). Cells left with a repeated corner are dropped. Returns (cells, tags, the
    number of nodes merged into another); logs what was merged."""
    from scipy.spatial import cKDTree
    from trimesh.graph import connected_component_labels

    from .. import tol

    used = np.unique(np.concatenate([c.reshape(-1) for _, c in cells]))
    if used[0] < 0 or used[-1] >= len(points):
        return cells, tags, 0  # _checked names the bad connectivity
    xyz = points[used]
    if not np.isfinite(xyz).all():
        return cells, tags, 0  # _checked names the non-finite node
    size = float(np.linalg.norm(xyz.max(axis=0) - xyz.min(axis=0)))
    if size == 0.0:
        return cells, tags, 0
    pairs = cKDTree(xyz).query_pairs(tol.MERGE_VERTICES * size, output_type="ndarray")
    if len(pairs) == 0:
        return cells, tags, 0
    # the groups of nodes linked by close pairs (trimesh's graph, through scipy's csgraph)
    label = connected_component_labels(pairs, node_count=len(used))
    first = np.full(label.max() + 1, len(used))
    np.minimum.at(first, label, np.arange(len(used)))
    to = np.arange(len(points))
    to[used] = used[first[label]]
    merged = int(np.sum(to[used] != used))
    out, out_tags, dropped = [], [], 0
    for i, (kind, conn) in enumerate(cells):
        conn = to[conn]
        k = 3 if kind.startswith("triangle") else 4
        corners = np.sort(conn[:, :k], axis=1)
        keep = np.all(corners[:, 1:] != corners[:, :-1], axis=1)
        dropped += int(np.sum(~keep))
        if keep.any():
            out.append((kind, np.ascontiguousarray(conn[keep])))
            if tags is not None and i < len(tags):
                out_tags.append(tags[i][keep])
    _log.info("%s: %d nodes merged into another node within %.3g (%.0e of the target's "
              "size)%s", path, merged, tol.MERGE_VERTICES * size, tol.MERGE_VERTICES,
              f"; {dropped} cells left with a repeated corner dropped" if dropped else "")
    return out, (out_tags if tags is not None else None), merged


def _surface_target(path: str, deck, points: np.ndarray, surface, zone: str,
                    reader: str) -> Target:
    """The target made of the element faces of a deck's element-based *SURFACE."""
    cells, used = surface_cells(path, deck, surface)
    target = _checked(path, points, cells, zone, {}, used, None)
    target.reader = reader
    return target


def _checked(path, points, cells, zone, ignored, boundary, tags) -> Target:
    """The Target of ``cells``, after checking they exist and their nodes are finite."""
    where = f" in zone '{zone}'" if zone is not None else ""
    if not cells:
        raise ReadError(
            f"{path}: no surface cells (triangle/quad) or volume cells (tetra/hexahedron/wedge/"
            f"pyramid) found{where}; it has: {_describe(ignored)}"
        )

    nodes = np.unique(np.concatenate([c.reshape(-1) for _, c in cells]))
    if nodes[0] < 0 or nodes[-1] >= len(points):
        raise ReadError(
            f"{path}: cell connectivity refers to point "
            f"{int(nodes[0] if nodes[0] < 0 else nodes[-1])} but the file has {len(points)} points"
        )
    bad = ~np.isfinite(points[nodes]).all(axis=1)
    if bad.any():
        first = int(nodes[np.flatnonzero(bad)[0]])
        raise ReadError(
            f"{path}: non-finite coordinates (NaN/inf) at point {first} of a surface cell{where}"
            f" ({int(bad.sum())} such points)"
        )
    return Target(path=path, points=points, cells=cells, nodes=nodes.astype(np.int64),
                  ignored=ignored, boundary=boundary, tags=tags)


def result_mesh(points: np.ndarray, columns: dict, labels: dict, extra: dict,
                source=None) -> meshio.Mesh:
    """The result columns as point data of a mesh.

    ``x, y, z`` (when all given) become the points, else ``points``; ``nx, ny, nz`` the vector
    ``normal`` and ``px, py, pz`` the vector ``proximal_point``; label columns their integer
    codes. ``extra`` (name -> (p,) float64: the numeric pass-through columns) is added under
    names the result does not use. The cells are those of ``source`` (the contactors' mesh)
    when it has the same points, else one vertex per point.
    """
    p = len(points)
    cols = {k: np.asarray(v) for k, v in columns.items()}
    used = set()
    if all(k in cols for k in ("x", "y", "z")):
        points = np.column_stack([cols["x"], cols["y"], cols["z"]]).astype(np.float64)
        used.update(("x", "y", "z"))
    else:
        points = np.asarray(points, dtype=np.float64)

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
        elif v.dtype.kind in "iu" and v.dtype != np.int64:
            # meshio names an int8 or int32 'vtktypeint8/32' in .vtk, which VTK's legacy
            # reader refuses; its 64-bit 'vtktypeint64' it reads
            v = v.astype(np.int64)
        point_data[k] = v
    for name, values in extra.items():
        if name not in point_data and name not in used:
            point_data[name] = values

    if source is not None and len(source.points) == p:
        cells = [(b.type, np.asarray(b.data)) for b in source.cells]
    else:
        cells = [("vertex", np.arange(p, dtype=np.int64).reshape(-1, 1))]
    return meshio.Mesh(points, cells, point_data=point_data)


def write_mesh(path: str, vertices: np.ndarray, faces: list, point_data: dict,
               overwrite: bool = False) -> None:
    """Write a surface mesh of triangles and quads, with point data, atomically.

    The format follows the extension (any format meshio writes). Formats that hold triangles
    only (STL) get each quad split into two triangles.
    """
    path = str(path)
    check_output_path(path, overwrite, kind="mesh")
    fmt = writer_format(path)
    blocks = [f for f in faces if len(f)]
    if fmt.startswith("stl"):
        blocks = [f if f.shape[1] == 3 else np.concatenate([f[:, [0, 1, 2]], f[:, [0, 2, 3]]])
                  for f in blocks]
    cells = [("triangle" if f.shape[1] == 3 else "quad", f) for f in blocks]
    mesh = meshio.Mesh(vertices, cells, point_data=point_data)

    write_atomically(path, overwrite, mesh_extension(path)[0],
                     lambda tmp: meshio_write(tmp, mesh, fmt))


def meshio_write(tmp: str, mesh: meshio.Mesh, fmt: str) -> None:
    """``meshio.write`` in format ``fmt``, with what each format needs to write one file
    quietly."""
    kwargs = {}
    if fmt == "xdmf":
        kwargs["data_format"] = "XML"  # HDF would put the data in a second file
    if fmt.startswith("gmsh"):
        # gmsh writers warn on stderr for every block missing these tags
        mesh.cell_data = {key: [np.zeros(len(b.data), dtype=np.int64) for b in mesh.cells]
                          for key in ("gmsh:physical", "gmsh:geometrical")}
    meshio.write(tmp, mesh, file_format=fmt, **kwargs)


