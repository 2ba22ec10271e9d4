"""The boundary of volume cells as surface cells: the faces used by exactly one cell, oriented
outward, with their mid-side (and centre) nodes for second-order cells. Pure numpy.

Node orderings are meshio's (VTK's; meshio's readers convert Gmsh's and Abaqus's)."""
from __future__ import annotations

import numpy as np

__all__ = ["VOLUME_CELL_TYPES", "boundary_faces", "cell_faces", "corner_faces",
           "facing_inward", "reversed_cells"]

# corner faces of each linear cell (local corner indices, any orientation: outward is decided
# per face from the cell's centroid)
_TETRA = ((0, 1, 2), (0, 1, 3), (1, 2, 3), (0, 2, 3))
_HEXA = ((0, 1, 2, 3), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7))
_WEDGE = ((0, 1, 2), (3, 4, 5), (0, 1, 4, 3), (1, 2, 5, 4), (2, 0, 3, 5))
_PYRAMID = ((0, 1, 2, 3), (0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 0, 4))

# mid-side node of each edge (corner, corner, node) of the second-order cells
_TETRA_EDGES = ((0, 1, 4), (1, 2, 5), (0, 2, 6), (0, 3, 7), (1, 3, 8), (2, 3, 9))
_HEXA_EDGES = ((0, 1, 8), (1, 2, 9), (2, 3, 10), (0, 3, 11), (4, 5, 12), (5, 6, 13),
               (6, 7, 14), (4, 7, 15), (0, 4, 16), (1, 5, 17), (2, 6, 18), (3, 7, 19))
_WEDGE_EDGES = ((0, 1, 6), (1, 2, 7), (0, 2, 8), (3, 4, 9), (4, 5, 10), (3, 5, 11),
                (0, 3, 12), (1, 4, 13), (2, 5, 14))
_PYRAMID_EDGES = ((0, 1, 5), (1, 2, 6), (2, 3, 7), (0, 3, 8), (0, 4, 9), (1, 4, 10),
                  (2, 4, 11), (3, 4, 12))
# centre node of each quadrilateral face (its corners as a set, node) of the cells that have them
_HEXA27_CENTRES = (((0, 3, 4, 7), 20), ((1, 2, 5, 6), 21), ((0, 1, 4, 5), 22),
                   ((2, 3, 6, 7), 23), ((0, 1, 2, 3), 24), ((4, 5, 6, 7), 25))
_WEDGE18_CENTRES = (((0, 1, 3, 4), 15), ((1, 2, 4, 5), 16), ((0, 2, 3, 5), 17))

#: meshio volume cell type -> (corners, corner faces, edges with mid-side nodes or None,
#: quad face centres or None)
_CELLS = {
    "tetra": (4, _TETRA, None, None),
    "tetra10": (4, _TETRA, _TETRA_EDGES, None),
    "hexahedron": (8, _HEXA, None, None),
    "hexahedron20": (8, _HEXA, _HEXA_EDGES, None),
    "hexahedron27": (8, _HEXA, _HEXA_EDGES, _HEXA27_CENTRES),
    "wedge": (6, _WEDGE, None, None),
    "wedge15": (6, _WEDGE, _WEDGE_EDGES, None),
    "wedge18": (6, _WEDGE, _WEDGE_EDGES, _WEDGE18_CENTRES),
    "pyramid": (5, _PYRAMID, None, None),
    "pyramid13": (5, _PYRAMID, _PYRAMID_EDGES, None),
}
#: meshio cell types whose boundary makes a target surface
VOLUME_CELL_TYPES = tuple(_CELLS)


def _templates(kind: str):
    """Per face of a cell of `kind`: (surface cell type, local node columns), corners first in
    cyclic order, then the mid-side node of each side (c0 c1, c1 c2, ...), then the centre."""
    _, faces, edges, centres = _CELLS[kind]
    mid = {frozenset(e[:2]): e[2] for e in edges} if edges else {}
    centre = {frozenset(c[0]): c[1] for c in centres} if centres else {}
    out = []
    for face in faces:
        cols = list(face)
        if mid:
            cols += [mid[frozenset((face[i], face[(i + 1) % len(face)]))]
                     for i in range(len(face))]
        if len(face) == 4 and frozenset(face) in centre:
            cols.append(centre[frozenset(face)])
        kind_out = {3: "triangle", 6: "triangle6", 4: "quad", 8: "quad8", 9: "quad9"}[len(cols)]
        out.append((kind_out, cols))
    return out


def _reverse(ncols: int, corners: int) -> list[int]:
    """Columns reversing a face's orientation: corners c0 c(k-1) ... c1, sides in the matching
    order, the centre kept."""
    cols = [0] + list(range(corners - 1, 0, -1))
    if ncols >= 2 * corners:
        cols += [corners + j for j in range(corners - 1, -1, -1)]
    return cols + list(range(2 * corners, ncols))


def reversed_cells(kind: str, conn: np.ndarray) -> np.ndarray:
    """Surface cells of meshio type ``kind`` (triangle, triangle6, quad, quad8, quad9) turned
    over: the same nodes, their right-hand normal reversed (`_reverse`)."""
    conn = np.asarray(conn, dtype=np.int64)
    corners = 3 if kind.startswith("triangle") else 4
    return np.ascontiguousarray(conn[:, _reverse(conn.shape[1], corners)])


def facing_inward(points: np.ndarray, face: np.ndarray, k: int,
                  centroid: np.ndarray) -> np.ndarray:
    """(f,) bool: the faces ((f, m) nodes, k corners first) whose area vector (as
    frame.facet_area_vectors) points towards their cell's ``centroid`` (f, 3)."""
    p = points[face[:, :k]]
    area = (np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]) if k == 3
            else np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1]))
    return np.einsum("ij,ij->i", area, p.mean(axis=1) - centroid) < 0


def _outward(points: np.ndarray, face: np.ndarray, k: int, centroid: np.ndarray) -> np.ndarray:
    """``face`` reordered where needed so that it faces away from its cell's ``centroid``
    (`facing_inward`)."""
    inward = facing_inward(points, face, k, centroid)
    face[inward] = face[inward][:, _reverse(face.shape[1], k)]
    return face


def corner_faces(kind: str) -> tuple:
    """The corner faces of a volume cell type (local corner indices), in the order that
    `cell_faces` numbers them."""
    return _CELLS[kind][1]


def cell_faces(points: np.ndarray, kind: str, conn: np.ndarray, which: np.ndarray) -> tuple:
    """One face of each given cell, as a surface cell oriented outward.

    Parameters
    ----------
    points : (n, 3) float
    kind : str
        meshio volume cell type (a key of VOLUME_CELL_TYPES).
    conn : (c, k) int
        The cells.
    which : (c,) int
        Per cell, its face as an index into ``corner_faces(kind)``.

    Returns
    -------
    face_kind : str
        Surface cell type of those faces (a cell type whose faces differ, the wedge, takes
        one call per face shape).
    faces : (c, m) int64
        The faces, mid-side and centre nodes included, each oriented outward.
    """
    conn = np.asarray(conn, dtype=np.int64)
    which = np.asarray(which, dtype=np.int64)
    templates = _templates(kind)
    shapes = {templates[w][0] for w in np.unique(which)}
    if len(shapes) > 1:
        raise ValueError(f"faces of several shapes ({', '.join(sorted(shapes))}) in one call")
    if conn.ndim != 2 or conn.shape[1] < max(max(c) for _, c in templates) + 1:
        raise ValueError(f"{kind} cells of {conn.shape[-1]} nodes")
    face_kind = templates[int(which[0])][0] if len(which) else "triangle"
    cols = np.array([templates[w][1] for w in which], dtype=np.int64).reshape(len(which), -1)
    face = np.take_along_axis(conn, cols, axis=1)
    centroid = points[conn[:, :_CELLS[kind][0]]].mean(axis=1)
    k = 3 if face_kind.startswith("triangle") else 4
    return face_kind, np.ascontiguousarray(_outward(points, face, k, centroid))


def boundary_faces(points: np.ndarray, cells) -> tuple[list, dict]:
    """The faces of volume cells that no other cell shares, as surface cells.

    Parameters
    ----------
    points : (n, 3) float
    cells : list of (str, (c, k) int)
        Volume cells as (meshio cell type, connectivity); other types are left out.

    Returns
    -------
    faces : list of (str, (f, k) int64)
        Boundary faces by surface cell type (triangle, triangle6, quad, quad8, quad9), each
        oriented outward (its right-hand normal points away from its cell's centroid).
    used : dict of str to int
        Volume cell type -> number of cells whose boundary was taken.

    A face is matched by its corner nodes, across cell types (a wedge's triangle against a
    tetra's). Faces shared by more than two cells (a non-manifold mesh) are not boundary.
    """
    keys, blocks, used = {3: [], 4: []}, {}, {}
    for kind, conn in cells:
        if kind not in _CELLS or len(conn) == 0:
            continue
        conn = np.asarray(conn, dtype=np.int64)
        ncorners = _CELLS[kind][0]
        if conn.ndim != 2 or conn.shape[1] < max(max(c) for _, c in _templates(kind)) + 1:
            raise ValueError(f"{kind} cells of {conn.shape[-1]} nodes")
        used[kind] = used.get(kind, 0) + len(conn)
        centroid = points[conn[:, :ncorners]].mean(axis=1)
        for face_kind, cols in _templates(kind):
            k = 3 if face_kind.startswith("triangle") else 4
            face = _outward(points, conn[:, cols], k, centroid)
            keys[k].append(np.sort(face[:, :k], axis=1))
            blocks.setdefault(k, []).append((face_kind, face))
    out = {}
    for k, parts in blocks.items():
        key = np.concatenate(keys[k])
        _, inverse, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        single = count[inverse.ravel()] == 1
        start = 0
        for face_kind, face in parts:
            keep = single[start:start + len(face)]
            start += len(face)
            if keep.any():
                out.setdefault(face_kind, []).append(face[keep])
    faces = [(kind, np.ascontiguousarray(np.concatenate(parts))) for kind, parts in out.items()]
    return faces, used
