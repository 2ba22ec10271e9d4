"""Element-face and node ``*SURFACE`` definitions of Abaqus/CalculiX decks (.inp), which
meshio's reader leaves out: the faces they name as outward surface cells, on the deck as
`abaqus.read_deck` reads it (its includes, element numbers and sets). Pure numpy.

Face numbering: Abaqus Analysis User's Guide, "Three-dimensional solid element library" (the
same in CalculiX's manual, "Element face numbering"); node numbers are 1-based and Abaqus's
orderings of C3D4/C3D10, C3D6/C3D15 and C3D8/C3D20 are meshio's (VTK's), which its reader keeps.
"""
from __future__ import annotations

import numpy as np

from .abaqus import _NUMBER_MAX, SHELL_TYPES, Deck, Surface, _find, read_deck
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


def read_surfaces(path: str) -> dict:
    """Name -> `Surface` of every ``*SURFACE`` of the deck ``path`` (and of the files it
    includes)."""
    return read_deck(path).surfaces


def _elset(path, deck: Deck, name: str):
    """Element numbers of element set ``name`` (nested sets expanded); None if no such set."""
    key = _find(deck.elsets, name)
    return None if key is None else deck.element_set(key)


def surface_cells(path: str, deck: Deck, surface: Surface) -> tuple[list, dict]:
    """The faces of element-based ``surface`` as surface cells: (list of (meshio surface cell
    type, (f, k) int64 connectivity into ``deck.points``), volume cell type -> number of
    elements whose faces were taken). Each face is oriented outward (away from its element's
    centroid), with its mid-side nodes; a face named twice is taken once. ReadError for an
    unknown element or set, or a face id the element type does not have."""
    points = deck.points
    picked = {}  # (block, face index into corner_faces) -> set of cell indices
    for ref, face, line in surface.lines:
        at = f"{path}: surface '{surface.name}', {line}"
        if ref.lstrip("-").isdigit():
            if not 0 < int(ref) <= _NUMBER_MAX:
                raise ReadError(f"{at}: unknown element {ref}")
            ids = np.array([int(ref)], np.int64)
        else:
            ids = _elset(path, deck, ref)
            if ids is None:
                raise ReadError(f"{at}: unknown element set '{ref}'")
        face_id = face.upper()
        if not face_id:
            raise ReadError(f"{at}: no face id after '{ref}' (expected S1, S2, ...; the free "
                            f"faces of a set are not read)")
        blocks, rows = deck.element_index(ids)
        for e, b, i in zip(ids.tolist(), blocks.tolist(), rows.tolist()):
            if b < 0:
                raise ReadError(f"{at}: unknown element {e}")
            kind = deck.blocks[b].kind or deck.blocks[b].etype
            table = _FACES.get(kind, {})
            n = int(face_id[1:]) if face_id[:1] == "S" and face_id[1:].isdigit() else None
            if n not in table:
                hint = (f" (expected S1 to S{len(table)})" if table else
                        " (the faces of shells are not read: the element set of the shells"
                        " is their positive side (SPOS), as their node order orients it)"
                        if deck.blocks[b].etype in SHELL_TYPES else
                        " (the faces of plane and axisymmetric elements are their edges, not "
                        "surface cells)" if deck.blocks[b].etype.startswith(("CPS", "CPE", "CAX"))
                        else " (faces are read for tetra, wedge and hexahedron elements, first "
                        "and second order)")
                raise ReadError(f"{at}: element {e} ({kind}) has no face {face}{hint}")
            corners = frozenset(c - 1 for c in table[n])
            w = [frozenset(f) for f in corner_faces(kind)].index(corners)
            picked.setdefault((b, w), set()).add(i)
    blocks, used = {}, {}
    for (b, w), cells in sorted(picked.items()):
        kind = deck.blocks[b].kind
        rows = np.array(sorted(cells), dtype=np.int64)
        conn = deck.blocks[b].conn[rows]
        face_kind, faces = cell_faces(points, kind, conn, np.full(len(rows), w))
        blocks.setdefault(face_kind, []).append(faces)
        used.setdefault(kind, set()).update((b, r) for r in rows.tolist())
    cells = [(k, np.ascontiguousarray(np.concatenate(v))) for k, v in blocks.items()]
    return cells, {k: len(v) for k, v in used.items()}


def surface_nodes(path: str, deck: Deck, surface: Surface) -> np.ndarray:
    """The point indices (into ``deck.points``) of node-based ``surface``: its node sets and
    node numbers. ReadError for an unknown set or node."""
    ids = []
    for ref, _, line in surface.lines:
        at = f"{path}: surface '{surface.name}', {line}"
        if ref.lstrip("-").isdigit():
            index = deck.node_index(np.array([int(ref) if 0 < int(ref) <= _NUMBER_MAX else 0]))
            if index[0] < 0:
                raise ReadError(f"{at}: unknown node {ref}")
            ids.append(index)
        else:
            key = _find(deck.nsets, ref)
            if key is None:
                raise ReadError(f"{at}: unknown node set '{ref}'")
            ids.append(deck.node_set(key))
    return np.unique(np.concatenate(ids)) if ids else np.zeros(0, np.int64)
