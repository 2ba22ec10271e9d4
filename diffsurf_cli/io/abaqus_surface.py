"""Element-face and node ``*SURFACE`` definitions of Abaqus/CalculiX decks (.inp), which
meshio's reader leaves out: the faces they name as outward surface cells (the sides of shells
as their cells, turned over for SNEG), on the deck as `abaqus.read_deck` reads it (its
includes, element numbers and sets). Pure numpy.

Face numbering: Abaqus Analysis User's Guide, "Three-dimensional solid element library" (the
same in CalculiX's manual, "Element face numbering"); node numbers are 1-based and Abaqus's
orderings of C3D4/C3D10, C3D6/C3D15 and C3D8/C3D20 are meshio's (VTK's), which its reader keeps.
"""
from __future__ import annotations

import numpy as np

from .abaqus import _NUMBER_MAX, SHELL_TYPES, Deck, Surface, _find, read_deck
from .boundary import cell_faces, corner_faces, reversed_cells
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
    elements whose faces were taken). A volume element's face is oriented outward (away from
    its element's centroid), with its mid-side nodes; a shell's side is the shell cell, as it
    is (SPOS, S2) or turned over (SNEG, S1); elements without a face id, their free faces
    (`_free_faces`). A face named twice is taken once. ReadError for an unknown element or
    set, a face id the element type does not have, or both sides of one shell."""
    points = deck.points
    # (block, face index into corner_faces, or _POS / _NEG for a shell's side) -> cell rows
    picked = {}
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
        blocks, rows = deck.element_index(ids)
        if np.any(blocks < 0):
            raise ReadError(f"{at}: unknown element {int(ids[np.argmax(blocks < 0)])}")
        face_id = face.strip().upper()
        if not face_id:  # Abaqus's free faces of the elements (CalculiX wants a face id)
            _free_faces(at, deck, ids, blocks, rows, picked)
            continue
        for e, b, i in zip(ids.tolist(), blocks.tolist(), rows.tolist()):
            etype = deck.blocks[b].etype
            kind = deck.blocks[b].kind or etype
            if etype in SHELL_TYPES:
                side = _SHELL_SIDES.get(face_id)
                if side is None:
                    raise ReadError(f"{at}: element {e} ({kind}, a shell) has no face {face} "
                                    f"(expected SPOS or S2, SNEG or S1: S3 and above are "
                                    f"the shell's edges, not surface cells)")
                _add(picked, b, side, i, at, e, kind)
                continue
            table = _FACES.get(kind, {})
            n = int(face_id[1:]) if face_id[:1] == "S" and face_id[1:].isdigit() else None
            if n not in table:
                sides = "; SPOS and SNEG are the sides of shells" if face_id in (
                    "SPOS", "SNEG") else ""
                hint = f" (expected S1 to S{len(table)}{sides})" if table else \
                    _no_faces_hint(etype)
                raise ReadError(f"{at}: element {e} ({kind}) has no face {face}{hint}")
            corners = frozenset(c - 1 for c in table[n])
            w = [frozenset(f) for f in corner_faces(kind)].index(corners)
            picked.setdefault((b, w), set()).add(i)
    blocks, used = {}, {}
    for (b, w), cells in sorted(picked.items()):
        kind = deck.blocks[b].kind
        rows = np.array(sorted(cells), dtype=np.int64)
        conn = deck.blocks[b].conn[rows]
        if w == _POS:
            face_kind, faces = kind, np.ascontiguousarray(conn)
        elif w == _NEG:
            face_kind, faces = kind, reversed_cells(kind, conn)
        else:
            face_kind, faces = cell_faces(points, kind, conn, np.full(len(rows), w))
            used.setdefault(kind, set()).update((b, r) for r in rows.tolist())
        blocks.setdefault(face_kind, []).append(faces)
    cells = [(k, np.ascontiguousarray(np.concatenate(v))) for k, v in blocks.items()]
    return cells, {k: len(v) for k, v in used.items()}


#: the sides of a shell in ``picked`` (face indices of volume cells are 0 and above)
_POS, _NEG = -1, -2
#: a shell's face id -> its side. CalculiX's manual, *SURFACE, "for quadrilateral shell
#: elements: Face NEG or 1: in negative normal direction; Face POS or 2: in positive normal
#: direction; Face 3: 1-2, ..." (the same for triangular shells; its surfaces.f reads SNEG and
#: SPOS as S1 and S2); Abaqus's SPOS and SNEG alike ("the side in the direction of the
#: positive element normal is called SPOS ... the connectivity of an element defines the
#: positive element normal"). The positive normal is the right-hand rule on the element's node
#: order (CalculiX's figures of the S3, S4, S6 and S8 elements), so SPOS is the shell cell as
#: it is and SNEG the cell turned over. S3 and above are the shell's edges, not cells.
_SHELL_SIDES = {"SPOS": _POS, "S2": _POS, "SNEG": _NEG, "S1": _NEG}


def _no_faces_hint(etype: str) -> str:
    if etype.startswith(("CPS", "CPE", "CAX")):
        return " (the faces of plane and axisymmetric elements are their edges, not surface " \
               "cells)"
    return " (faces are read for tetra, wedge and hexahedron elements, first and second " \
           "order, and the sides SPOS/SNEG of shells and membranes)"


def _add(picked: dict, b: int, side: int, row: int, at: str, element: int, kind: str):
    """A shell's side into ``picked``; ReadError if its other side is there."""
    other = _NEG if side == _POS else _POS
    if row in picked.get((b, other), ()):
        raise ReadError(f"{at}: element {element} ({kind}, a shell): both its sides (SPOS and "
                        f"SNEG) in one surface, expected one side (a target has one side)")
    picked.setdefault((b, side), set()).add(row)


def _free_faces(at: str, deck: Deck, ids, blocks, rows, picked: dict):
    """The faces of a data line naming elements without a face id, into ``picked``.

    CalculiX requires a face id: its manual, *SURFACE, "Following line for element face
    surfaces: Element or element set (maximum 1 entry per line); Surface label", and its
    surfaces.f stops at an input error on a line without one. Abaqus does not: its Analysis
    User's Guide, "Element-based surface definition": "In an input file you need only specify
    an element number or element set name and all exposed element faces of these elements
    (or 'contact edges' of beam, pipe, and truss elements) will be included in the surface".
    Read as Abaqus reads it: the faces of the line's volume elements that no other element of
    the line has (the line's exterior, each face outward), and its shells and membranes as
    they are (their SPOS side: a target has one side, where Abaqus may take both). Lines,
    springs, masses (no faces) are left out; plane and axisymmetric elements, whose faces are
    edges, are a ReadError."""
    keys = {3: [], 4: []}  # per corner count: (sorted corners, block, face index, row)
    for b in np.unique(blocks).tolist():
        block = deck.blocks[b]
        mine = rows[blocks == b]
        if block.etype in SHELL_TYPES:
            for i, e in zip(mine.tolist(), ids[blocks == b].tolist()):
                _add(picked, b, _POS, i, at, e, block.kind)
        elif block.kind in _FACES:
            conn = block.conn[mine]
            for w, corners in enumerate(corner_faces(block.kind)):
                key = np.sort(conn[:, list(corners)], axis=1)
                keys[len(corners)].append((key, b, w, mine))
        elif block.etype.startswith(("CPS", "CPE", "CAX")):
            e = int(ids[blocks == b][0])
            raise ReadError(f"{at}: element {e} ({block.kind}, no face id): the faces of plane "
                            f"and axisymmetric elements are their edges, not surface cells")
    for parts in keys.values():
        if not parts:
            continue
        _, inverse, count = np.unique(np.concatenate([p[0] for p in parts]), axis=0,
                                      return_inverse=True, return_counts=True)
        free = count[inverse.ravel()] == 1
        start = 0
        for _, b, w, mine in parts:
            keep = mine[free[start:start + len(mine)]]
            start += len(mine)
            if len(keep):
                picked.setdefault((b, w), set()).update(keep.tolist())


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
