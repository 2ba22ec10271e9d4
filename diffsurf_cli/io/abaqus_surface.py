"""Element-face and node ``*SURFACE`` definitions of Abaqus/CalculiX decks (.inp), which
meshio's reader leaves out: a small text pass over the deck for the surfaces, the element
numbers and the element sets, and the faces they name as outward surface cells. Pure numpy.

Face numbering: Abaqus Analysis User's Guide, "Three-dimensional solid element library" (the
same in CalculiX's manual, "Element face numbering"); node numbers are 1-based and Abaqus's
orderings of C3D4/C3D10, C3D6/C3D15 and C3D8/C3D20 are meshio's (VTK's), which its reader keeps.
"""
from __future__ import annotations

import functools
import os
from dataclasses import dataclass, field

import numpy as np

from .boundary import cell_faces, corner_faces
from .errors import ReadError

__all__ = ["Surface", "read_surfaces", "surface_cells", "surface_nodes"]

#: Abaqus face id -> the element's corner nodes (1-based) on that face, per element family
_TET_FACES = {1: (1, 2, 3), 2: (1, 4, 2), 3: (2, 4, 3), 4: (3, 4, 1)}
_WEDGE_FACES = {1: (1, 2, 3), 2: (4, 6, 5), 3: (1, 4, 5, 2), 4: (2, 5, 6, 3), 5: (3, 6, 4, 1)}
_HEX_FACES = {1: (1, 2, 3, 4), 2: (5, 8, 7, 6), 3: (1, 5, 6, 2), 4: (2, 6, 7, 3),
              5: (3, 7, 8, 4), 6: (4, 8, 5, 1)}
#: meshio cell type -> its Abaqus face table
_FACES = {"tetra": _TET_FACES, "tetra10": _TET_FACES, "wedge": _WEDGE_FACES,
          "wedge15": _WEDGE_FACES, "hexahedron": _HEX_FACES, "hexahedron20": _HEX_FACES}


@dataclass
class Surface:
    """One ``*SURFACE`` of a deck: its name, TYPE (ELEMENT or NODE) and data lines as
    (element or node number or set name, face id string or "", line number)."""

    name: str
    type: str
    lines: list = field(default_factory=list)


@dataclass
class _Deck:
    surfaces: dict
    elements: list  # per *ELEMENT block: its data lines as lists of ints
    elsets: dict  # name -> parts: lists of element numbers, set names, ("block", index)
    nodes: list  # node numbers in file order


def _params(line: str) -> dict:
    out = {}
    for word in line.split(",")[1:]:
        key, _, value = word.partition("=")
        out[key.strip().upper()] = value.strip()
    return out


def _ints(fields) -> list:
    return [int(f) for f in fields if f]


def _read_deck(path: str) -> _Deck:
    """The deck's surfaces, element numbers and sets, read once per file version (a zone
    lookup and the surface's faces both need them)."""
    try:
        stat = os.stat(path)
    except OSError as exc:
        raise ReadError(f"{path}: cannot read ({exc.strerror or exc})") from None
    return _parse_deck(path, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=2)
def _parse_deck(path: str, mtime: int, size: int) -> _Deck:
    surfaces, elements, elsets, nodes = {}, [], {}, []
    keyword, params, block, surface = None, {}, None, None
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            lines = f.read().splitlines()
    except OSError as exc:
        raise ReadError(f"{path}: cannot read ({exc.strerror or exc})") from None
    for number, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line or line.startswith("**"):
            continue
        if line.startswith("*"):
            keyword = line[1:].partition(",")[0].strip().upper()
            params = _params(line)
            if keyword == "ELEMENT":
                block = []
                elements.append(block)
                if params.get("ELSET"):  # the elements of this block, by its index
                    elsets.setdefault(params["ELSET"], []).append(("block", len(elements) - 1))
            elif keyword == "ELSET":
                elsets.setdefault(params.get("ELSET", ""), [])
            elif keyword == "SURFACE":
                name = params.get("NAME", "")
                surface = surfaces[name] = Surface(name,
                                                   (params.get("TYPE") or "ELEMENT").upper())
            continue
        fields = [f.strip() for f in line.split(",")]
        try:
            if keyword == "NODE":
                nodes.append(int(fields[0]))
            elif keyword == "ELEMENT":
                # an element's nodes may run over several lines: its number starts a line
                # only where the previous element is complete, so numbers are read below
                block.append(_ints(fields))
            elif keyword == "ELSET":
                ids = elsets[params.get("ELSET", "")]
                if "GENERATE" in params:
                    start, stop, *step = _ints(fields)
                    ids.append(list(range(start, stop + 1, step[0] if step else 1)))
                else:
                    ids.extend(f if not f.lstrip("-").isdigit() else [int(f)]
                               for f in fields if f)
            elif keyword == "SURFACE":
                surface.lines.append((fields[0], fields[1] if len(fields) > 1 else "", number))
        except (ValueError, IndexError):
            raise ReadError(f"{path}: line {number}: cannot read '{line[:60]}' in *{keyword}")\
                from None
    return _Deck(surfaces, elements, elsets, nodes)


def read_surfaces(path: str) -> dict:
    """Name -> `Surface` of every ``*SURFACE`` of the deck ``path``."""
    return _read_deck(path).surfaces


def _find(names, name: str):
    """The name of ``names`` that ``name`` is: the same, else the one differing by case."""
    if name in names:
        return name
    same = [n for n in names if n.casefold() == name.casefold()]
    return same[0] if len(same) == 1 else None


def _element_numbers(deck: _Deck, sizes: list) -> list:
    """Per *ELEMENT block, its element numbers, from its data read as rows of ``size``+1."""
    out = []
    for rows, size in zip(deck.elements, sizes):
        flat = np.array([v for row in rows for v in row], dtype=np.int64)
        out.append(flat.reshape(-1, size + 1)[:, 0] if len(flat) % (size + 1) == 0 else None)
    return out


def _elset(path, deck, name, numbers, seen=()) -> np.ndarray:
    """Element numbers of element set ``name`` (nested sets expanded)."""
    key = _find(deck.elsets, name)
    if key is None or key in seen:
        return None
    ids = []
    for part in deck.elsets[key]:
        if isinstance(part, str):  # an element set named inside another
            inner = _elset(path, deck, part, numbers, seen + (key,))
            if inner is None:
                raise ReadError(f"{path}: element set '{key}' names an unknown set '{part}'")
            ids.append(inner)
        elif isinstance(part, tuple):  # the elements of an *ELEMENT, ELSET= block
            ids.append(numbers[part[1]])
        else:
            ids.append(np.asarray(part, dtype=np.int64).reshape(-1))
    return np.concatenate(ids) if ids else np.zeros(0, np.int64)


def surface_cells(path: str, mesh, points: np.ndarray, surface: Surface) -> tuple[list, dict]:
    """The faces of element-based ``surface`` as surface cells: (list of (meshio surface cell
    type, (f, k) int64 connectivity into ``points``), volume cell type -> number of
    elements whose faces were taken). Each face is oriented outward (away from its element's
    centroid), with its mid-side nodes; a face named twice is taken once. ReadError for an
    unknown element or set, or a face id the element type does not have."""
    deck = _read_deck(path)
    sizes = [np.asarray(b.data).shape[1] for b in mesh.cells]
    if len(deck.elements) != len(mesh.cells):
        raise ReadError(f"{path}: surface '{surface.name}': the deck's *ELEMENT blocks "
                        f"({len(deck.elements)}) are not the mesh's cell blocks "
                        f"({len(mesh.cells)}; *INCLUDE files are not read for surfaces)")
    numbers = _element_numbers(deck, sizes)
    where = {}  # element number -> (block, index)
    for b, ids in enumerate(numbers):
        if ids is None:
            raise ReadError(f"{path}: *ELEMENT block {b + 1} does not hold whole "
                            f"{mesh.cells[b].type} elements")
        where.update(zip(ids.tolist(), ((b, i) for i in range(len(ids)))))
    picked = {}  # (block, face index into corner_faces) -> set of cell indices
    for ref, face, number in surface.lines:
        at = f"{path}: surface '{surface.name}', line {number}"
        if ref.lstrip("-").isdigit():
            ids = np.array([int(ref)], np.int64)
        else:
            ids = _elset(path, deck, ref, numbers)
            if ids is None:
                raise ReadError(f"{at}: unknown element set '{ref}'")
        face_id = face.upper()
        if not face_id:
            raise ReadError(f"{at}: no face id after '{ref}' (expected S1, S2, ...; the free "
                            f"faces of a set are not read)")
        for e in ids.tolist():
            if e not in where:
                raise ReadError(f"{at}: unknown element {e}")
            b, i = where[e]
            kind = mesh.cells[b].type
            table = _FACES.get(kind, {})
            n = int(face_id[1:]) if face_id[:1] == "S" and face_id[1:].isdigit() else None
            if n not in table:
                raise ReadError(f"{at}: element {e} ({kind}) has no face {face}"
                                + (f" (expected S1 to S{len(table)})" if table else
                                   " (faces are read for tetra, wedge and hexahedron "
                                   "elements, first and second order)"))
            corners = frozenset(c - 1 for c in table[n])
            w = [frozenset(f) for f in corner_faces(kind)].index(corners)
            picked.setdefault((b, w), set()).add(i)
    blocks, used = {}, {}
    for (b, w), cells in sorted(picked.items()):
        kind = mesh.cells[b].type
        rows = np.array(sorted(cells), dtype=np.int64)
        conn = np.asarray(mesh.cells[b].data, dtype=np.int64)[rows]
        face_kind, faces = cell_faces(points, kind, conn, np.full(len(rows), w))
        blocks.setdefault(face_kind, []).append(faces)
        used.setdefault(kind, set()).update((b, r) for r in rows.tolist())
    cells = [(k, np.ascontiguousarray(np.concatenate(v))) for k, v in blocks.items()]
    return cells, {k: len(v) for k, v in used.items()}


def surface_nodes(path: str, mesh, surface: Surface) -> np.ndarray:
    """The point indices of node-based ``surface``: its node sets (``mesh.point_sets``) and
    node numbers. ReadError for an unknown set or node."""
    deck = None
    ids = []
    for ref, _, number in surface.lines:
        at = f"{path}: surface '{surface.name}', line {number}"
        if ref.lstrip("-").isdigit():
            if deck is None:
                deck = _read_deck(path)
                if len(deck.nodes) != len(mesh.points):
                    raise ReadError(f"{at}: node numbers cannot be matched to the mesh's "
                                    f"points (several *NODE blocks or *INCLUDE files)")
                index = {n: i for i, n in enumerate(deck.nodes)}
            if int(ref) not in index:
                raise ReadError(f"{at}: unknown node {ref}")
            ids.append(np.array([index[int(ref)]], np.int64))
        else:
            key = _find(mesh.point_sets, ref)
            if key is None:
                raise ReadError(f"{at}: unknown node set '{ref}'")
            ids.append(np.asarray(mesh.point_sets[key], dtype=np.int64).reshape(-1))
    return np.unique(np.concatenate(ids)) if ids else np.zeros(0, np.int64)
