"""Element-face ``*SURFACE`` definitions of Abaqus/CalculiX decks as targets (issue 11 item 4):
``--zone NAME`` naming an element-based surface gives the faces it lists (S1..S6, Abaqus face
numbering), oriented outward; a node-based surface acts as its node set.

The decks are written here by hand: hexahedra (C3D8, C3D20) numbered three ways (as usual,
upside down, turned about z) so the same geometric face has a different face id in each, a
tetra pair, a wedge. The expected faces are stated geometrically (the plane they lie in)."""
from __future__ import annotations

import itertools

import meshio
import numpy as np
import polars as pl
import pytest

from diffsurf_cli import io
from diffsurf_cli.io.errors import ReadError
from diffsurf_cli.mls.frame import facet_area_vectors, facet_corners
from samples import run

#: local corner order of a hexahedron over its cell (i, j, k): (di, dj, dk) per Abaqus node
#: 1..8, for the three numberings; each keeps a positive Jacobian
_B = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
_T = [(0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
_NUMBERINGS = {
    "usual": _B + _T,
    "flipped": [_T[0], _T[3], _T[2], _T[1], _B[0], _B[3], _B[2], _B[1]],  # upside down
    "turned": _B[1:] + _B[:1] + _T[1:] + _T[:1],  # node 1 at another corner
}
#: the face id of the top (z = max) and of the x = 0 side in each numbering
_TOP = {"usual": "S2", "flipped": "S1", "turned": "S2"}
_LEFT = {"usual": "S6", "flipped": "S3", "turned": "S5"}
#: mid-side nodes of a C3D20 (9..20) between these corners (1-based)
_C3D20_EDGES = [(1, 2), (2, 3), (3, 4), (4, 1), (5, 6), (6, 7), (7, 8), (8, 5),
                (1, 5), (2, 6), (3, 7), (4, 8)]


def hexa_deck(n, numbering, top=lambda x, y: 1.0 + 0 * x, order=1, extra=""):
    """Deck text of an n[0] x n[1] x 1 block of C3D8 (order 1) or C3D20 (order 2) over
    [0, n0] x [0, n1] (scaled by 1/max(n)), its top at z = top(x, y); ``numbering(i, j)``
    names each element's numbering. Nodes on the half-step grid, numbered from 1; element
    (i, j) is number 100 + 10 i + j. Returns (text, points by node number)."""
    nx, ny = n
    h = 1.0 / max(n)
    grid = list(itertools.product(range(2 * nx + 1), range(2 * ny + 1), range(3)))
    number = {g: k + 1 for k, g in enumerate(grid)}
    pts = {}
    for (a, b, c), k in number.items():
        x, y = a * h / 2, b * h / 2
        pts[k] = (x, y, c / 2 * top(x, y))
    lines = ["*HEADING", "hand-written block", "*NODE"]
    lines += [f"{k}, {x:.17g}, {y:.17g}, {z:.17g}" for k, (x, y, z) in pts.items()]
    lines.append(f"*ELEMENT, TYPE={'C3D8' if order == 1 else 'C3D20'}, ELSET=BLOCK")
    for i, j in itertools.product(range(nx), range(ny)):
        corners = [(2 * (i + di), 2 * (j + dj), 2 * dk)
                   for di, dj, dk in _NUMBERINGS[numbering(i, j)]]
        nodes = [number[c] for c in corners]
        if order == 2:
            nodes += [number[tuple((p + q) // 2 for p, q in zip(corners[a - 1], corners[b - 1]))]
                      for a, b in _C3D20_EDGES]
        ids = [100 + 10 * i + j] + nodes
        # 16 values a line at most, as Abaqus reads them: a C3D20 runs over two lines
        lines.append(", ".join(map(str, ids[:16])) + ("," if len(ids) > 16 else ""))
        if len(ids) > 16:
            lines.append(", ".join(map(str, ids[16:])))
    return "\n".join(lines) + "\n" + extra, pts


def _block_numbering(i, j):
    return {(0, 0): "usual", (1, 0): "flipped", (0, 1): "turned", (1, 1): "usual"}[(i, j)]


_BLOCK_SURFACES = """*ELSET, ELSET=Usual
100, 111
*SURFACE, NAME=TOP, TYPE=ELEMENT
usual, S2
110, S1
101, S2
*SURFACE, NAME=Left
100, S6
101, S5
*NSET, NSET=TOPNODES
{topnodes}
*SURFACE, NAME=NTOP, TYPE=NODE
TOPNODES
*SURFACE, NAME=NNUM, TYPE=NODE
{numbers}
"""


def _write(tmp_path, text, name="deck.inp"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _outward(target, volume_centroids):
    """Each face's area vector points away from the centroid of the element it came from,
    taken as the nearest of ``volume_centroids`` to the face's centroid."""
    corners = [facet_corners(c) for _, c in target.cells]
    areas = facet_area_vectors(target.points, corners)
    centroids = np.concatenate([target.points[f].mean(axis=1) for f in corners])
    owner = np.argmin(np.linalg.norm(centroids[:, None] - volume_centroids[None], axis=2),
                      axis=1)
    return np.einsum("ij,ij->i", areas, centroids - volume_centroids[owner])


def _face_centroids(target):
    return np.concatenate([target.points[facet_corners(c)].mean(axis=1)
                           for _, c in target.cells])


def _block_target(tmp_path, zone, order=1):
    text, pts = hexa_deck((2, 2), _block_numbering, order=order)
    top = [k for k, p in pts.items() if p[2] == 1.0]
    text += _BLOCK_SURFACES.format(topnodes=",\n".join(
        ", ".join(map(str, top[s:s + 8])) for s in range(0, len(top), 8)),
        numbers="\n".join(f"{k}, 1.0" for k in top))  # node number, area
    return io.read_target(_write(tmp_path, text), zone=zone)


_ELEMENT_CENTROIDS = np.array([(0.25 + 0.5 * i, 0.25 + 0.5 * j, 0.5)
                               for i in range(2) for j in range(2)])


@pytest.mark.parametrize("order", [1, 2])
def test_top_of_a_hexa_block_numbered_three_ways(tmp_path, order):
    target = _block_target(tmp_path, "TOP", order)  # on a set ("usual", case ignored) and numbers
    kind = "quad" if order == 1 else "quad8"
    assert [k for k, _ in target.cells] == [kind] and len(target.cells[0][1]) == 4
    assert target.boundary == {"hexahedron" if order == 1 else "hexahedron20": 4}
    assert np.all(target.points[target.nodes][:, 2] == 1.0)
    assert len(target.nodes) == (9 if order == 1 else 21)
    centres = sorted(map(tuple, _face_centroids(target)[:, :2].round(12)))
    assert centres == [(0.25, 0.25), (0.25, 0.75), (0.75, 0.25), (0.75, 0.75)]
    assert np.all(_outward(target, _ELEMENT_CENTROIDS) > 0)
    normals = facet_area_vectors(target.points, [facet_corners(target.cells[0][1])])
    assert np.all(normals[:, 2] > 0) and np.allclose(normals[:, :2], 0)
    if order == 2:  # mid-side nodes follow their corners (side j between corners j, j+1)
        conn = target.cells[0][1]
        for j in range(4):
            mid = 0.5 * (target.points[conn[:, j]] + target.points[conn[:, (j + 1) % 4]])
            np.testing.assert_array_equal(target.points[conn[:, 4 + j]], mid)


def test_side_of_a_hexa_block_and_a_node_surface(tmp_path):
    target = _block_target(tmp_path, "left")
    assert len(target.cells[0][1]) == 2
    assert np.all(target.points[target.nodes][:, 0] == 0.0)
    assert np.all(_outward(target, _ELEMENT_CENTROIDS) > 0)
    normals = facet_area_vectors(target.points, [facet_corners(target.cells[0][1])])
    assert np.all(normals[:, 0] < 0)
    # a node surface: the boundary faces whose nodes are all its nodes (the top)
    nodes = _block_target(tmp_path, "NTOP")
    assert np.all(nodes.points[nodes.nodes][:, 2] == 1.0) and len(nodes.cells[0][1]) == 4
    assert np.all(_outward(nodes, _ELEMENT_CENTROIDS) > 0)
    numbers = _block_target(tmp_path, "NNUM")  # the same nodes by their numbers
    assert np.array_equal(numbers.cells[0][1], nodes.cells[0][1])


#: a reference element of each family and the plane of each of its faces S1, S2, ...
#: (a, b) meaning a . x = b; from the manuals' figures
_UNIT_TET = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
_UNIT_WEDGE = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (0, 1, 1)]
_UNIT_HEX = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1),
             (0, 1, 1)]
_PLANES = {
    "C3D4": (_UNIT_TET, [((0, 0, 1), 0), ((0, 1, 0), 0), ((1, 1, 1), 1), ((1, 0, 0), 0)]),
    "C3D6": (_UNIT_WEDGE, [((0, 0, 1), 0), ((0, 0, 1), 1), ((0, 1, 0), 0), ((1, 1, 0), 1),
                           ((1, 0, 0), 0)]),
    "C3D8": (_UNIT_HEX, [((0, 0, 1), 0), ((0, 0, 1), 1), ((0, 1, 0), 0), ((1, 0, 0), 1),
                         ((0, 1, 0), 1), ((1, 0, 0), 0)]),
}


#: second-order elements: the first-order family and the corners (1-based) of the mid-side
#: nodes that follow the corners, in Abaqus's order
_SECOND = {
    "C3D10": ("C3D4", [(1, 2), (2, 3), (3, 1), (1, 4), (2, 4), (3, 4)]),
    "C3D15": ("C3D6", [(1, 2), (2, 3), (3, 1), (4, 5), (5, 6), (6, 4), (1, 4), (2, 5), (3, 6)]),
    "C3D20": ("C3D8", _C3D20_EDGES),
}


@pytest.mark.parametrize("etype", sorted(_PLANES) + sorted(_SECOND))
def test_each_face_id_of_a_reference_element(tmp_path, etype):
    first, edges = _SECOND.get(etype, (etype, []))
    corners, planes = _PLANES[first]
    coords = np.array(corners + [tuple(0.5 * (np.array(corners[a - 1]) + corners[b - 1]))
                                 for a, b in edges], float)
    nodes = "\n".join(f"{k + 1}, {x}, {y}, {z}" for k, (x, y, z) in enumerate(coords))
    surfaces = "".join(f"*SURFACE, NAME=F{s}\n7, S{s}\n" for s in range(1, len(planes) + 1))
    numbers = [str(k + 1) for k in range(len(coords))]
    path = _write(tmp_path, f"*NODE\n{nodes}\n*ELEMENT, TYPE={etype}\n7, "
                            f"{', '.join(numbers[:15])}{',' if len(numbers) > 15 else ''}\n"
                            f"{', '.join(numbers[15:])}\n{surfaces}")
    try:
        meshio.read(path)
    except KeyError as exc:  # meshio 5.3.5 maps C3D15 to wedge15 but has no size for it
        pytest.skip(f"meshio cannot read a {etype} deck ({exc!r})")
    centroid = np.mean(corners, axis=0)
    for s, (normal, offset) in enumerate(planes, start=1):
        target = io.read_target(path, zone=f"F{s}")
        (kind, conn), = target.cells
        face = target.points[target.nodes]
        k = 3 if kind.startswith("triangle") else 4
        assert len(face) == conn.shape[1] == (k if not edges else 2 * k)
        np.testing.assert_allclose(face @ np.array(normal, float), offset, atol=1e-15)
        # all the element's nodes in that plane are the face
        assert len(face) == np.sum(np.abs(coords @ normal - offset) < 1e-12)
        assert _outward(target, centroid[None])[0] > 0
        for j in range(k if edges else 0):  # side j between corners j and j + 1
            np.testing.assert_array_equal(target.points[conn[0, k + j]], 0.5 * (
                target.points[conn[0, j]] + target.points[conn[0, (j + 1) % k]]))


def test_a_tetra_pair(tmp_path):
    """Two C3D4 sharing the face x + y + z = 1; faces named on an element set and numbers."""
    text = """*NODE
1, 0, 0, 0
2, 1, 0, 0
3, 0, 1, 0
4, 0, 0, 1
5, 1, 1, 1
*ELEMENT, TYPE=C3D4
1, 1, 2, 3, 4
2, 2, 3, 4, 5
*ELSET, ELSET=SECOND
2
*SURFACE, NAME=OUTER
1, S1
1, S2
1, S4
SECOND, S2
SECOND, S3
SECOND, S4
*SURFACE, NAME=SHARED1
1, S3
*SURFACE, NAME=SHARED2
2, S1
"""
    path = _write(tmp_path, text)
    centroids = np.array([[0.25, 0.25, 0.25], [0.5, 0.5, 0.5]])
    target = io.read_target(path, zone="OUTER")
    assert target.boundary == {"tetra": 2}
    faces = {frozenset(f) for f in target.cells[0][1].tolist()}
    # the outer faces of the pair are the boundary of the two cells (meshio's boundary reader)
    whole = io.read_target(path)
    assert faces == {frozenset(f) for f in whole.cells[0][1].tolist()} and len(faces) == 6
    assert np.all(_outward(target, centroids) > 0)
    # the shared face, named from each side: each points away from its own element
    for zone, sign in (("SHARED1", 1), ("SHARED2", -1)):
        shared = io.read_target(path, zone=zone).cells[0][1]
        assert len(shared) == 1 and set(shared[0]) == {1, 2, 3}
        area = facet_area_vectors(whole.points, [shared])[0]
        np.testing.assert_allclose(area, sign * np.full(3, 0.5))  # area sqrt(3)/2


def test_project_on_a_deck_surface_equals_the_surface_mesh(tmp_path):
    """`diffsurf project deck.inp points.csv --zone TOP` gives the gaps of the same faces
    written as a surface mesh."""
    n = 6
    numbering = lambda i, j: ("usual", "flipped", "turned")[(i + 2 * j) % 3]  # noqa: E731
    bump = lambda x, y: 0.5 + 0.15 * np.sin(2.0 * x) * np.cos(1.5 * y)  # noqa: E731
    tops = {(i, j): _TOP[numbering(i, j)] for i in range(n) for j in range(n)}
    extra = "*SURFACE, NAME=TOP\n" + "".join(f"{100 + 10 * i + j}, {s}\n"
                                             for (i, j), s in tops.items())
    text, pts = hexa_deck((n, n), numbering, top=bump, extra=extra)
    deck = _write(tmp_path, text)
    # the surface mesh of the top, built from the grid (all the deck's points kept)
    points = np.array([pts[k] for k in sorted(pts)])
    top = lambda a, b: (a * (2 * n + 1) + b) * 3 + 2  # noqa: E731  (hexa_deck's numbering)
    quads = [[top(2 * i, 2 * j), top(2 * i + 2, 2 * j), top(2 * i + 2, 2 * j + 2),
              top(2 * i, 2 * j + 2)] for i in range(n) for j in range(n)]
    assert np.allclose(points[np.ravel(quads), 2],
                       bump(points[np.ravel(quads), 0], points[np.ravel(quads), 1]))
    surface = tmp_path / "top.vtu"
    meshio.write(surface, meshio.Mesh(points, [("quad", np.array(quads))]))

    rng = np.random.default_rng(3)
    x = rng.uniform(0.15, 0.85, (150, 2))
    z = bump(x[:, 0], x[:, 1]) + rng.uniform(-0.05, 0.05, 150)
    csv = tmp_path / "points.csv"
    np.savetxt(csv, np.column_stack([x, z]), delimiter=",", header="x,y,z", comments="")
    for method in ("diffuse", "facet"):
        out = {}
        for name, target, extra_args in (("deck", deck, ["--zone", "TOP"]),
                                         ("mesh", surface, [])):
            path = tmp_path / f"{name}.csv"
            result = run("project", target, csv, "-o", path, "-q", "--overwrite",
                         "--method", method, *extra_args)
            assert result.exit_code == 0, result.stderr
            out[name] = pl.read_csv(path)
        a, b = out["deck"], out["mesh"]
        assert (a["status"] == b["status"]).all()
        assert not a["status"].is_in(["outside", "failed"]).any()
        # the same faces, in another order and possibly from another corner: equal up to
        # round-off (2e-17 seen)
        np.testing.assert_allclose(a["gap"].to_numpy(), b["gap"].to_numpy(), rtol=0,
                                   atol=1e-14)
        # outward: the points above the top have positive gaps
        above = z - bump(x[:, 0], x[:, 1]) > 0.01
        assert np.all(a["gap"].to_numpy()[above] > 0)


def test_errors(tmp_path):
    text, _ = hexa_deck((2, 2), _block_numbering)
    deck = _write(tmp_path, text + "*SURFACE, NAME=TOP\n100, S2\n101, S7\n")
    with pytest.raises(ReadError) as info:
        io.read_target(deck, zone="TOP")
    message = str(info.value)
    assert deck in message and "'TOP'" in message and "line " in message and "S7" in message
    line = int(message.split("line ")[1].split(":")[0])
    assert text.count("\n") + 3 == line  # the line of "101, S7"
    # an unknown surface: the zones listed include the deck's surfaces
    with pytest.raises(ReadError, match=r"unknown zone 'NOPE'.*'BLOCK'.*'TOP'"):
        io.read_target(deck, zone="NOPE")
    # through the CLI: one line on stderr, exit 1
    csv = tmp_path / "p.csv"
    csv.write_text("x,y,z\n0.5,0.5,1.1\n")
    for zone, words in (("TOP", ["S7", "line"]), ("NOPE", ["NOPE", "TOP"])):
        result = run("project", deck, csv, "-q", "--zone", zone)
        assert result.exit_code == 1, result.stderr
        assert result.stdout == "" and len(result.stderr.splitlines()) == 1
        assert all(w in result.stderr for w in words), result.stderr
    # an unknown element, an unknown set
    for data, words in (("999, S1", ["unknown element 999"]),
                        ("NOSET, S1", ["unknown element set 'NOSET'"]),
                        ("NOSET", ["unknown element set 'NOSET'"])):
        bad = _write(tmp_path, text + f"*SURFACE, NAME=BAD\n{data}\n", name="bad.inp")
        with pytest.raises(ReadError) as info:
            io.read_target(bad, zone="BAD")
        assert all(w in str(info.value) for w in words), str(info.value)
    rigid = _write(tmp_path, text + "*SURFACE, NAME=RIGID, TYPE=SEGMENTS\nSTART, 0, 0\n",
                   name="rigid.inp")
    with pytest.raises(ReadError, match=r"surface 'RIGID' is of TYPE=SEGMENTS, expected ELEMENT"):
        io.read_target(rigid, zone="rigid")
    # a shell's sides are SPOS/SNEG (S2/S1); its S3... are edges, a solid has no SPOS
    shell = _write(tmp_path, "*NODE\n1, 0, 0, 0\n2, 1, 0, 0\n3, 0, 1, 0\n"
                             "*ELEMENT, TYPE=S3\n1, 1, 2, 3\n*SURFACE, NAME=S\n1, SPOS\n"
                             "*SURFACE, NAME=EDGE\n1, S3\n", name="shell.inp")
    (kind, conn), = io.read_target(shell, zone="S").cells
    assert kind == "triangle" and conn.tolist() == [[0, 1, 2]]
    with pytest.raises(ReadError, match=r"surface 'EDGE', line 10: element 1 \(triangle, a "
                                        r"shell\) has no face S3 \(expected SPOS or S2, SNEG "
                                        r"or S1: S3 and above are the shell's edges"):
        io.read_target(shell, zone="EDGE")
    solid = _write(tmp_path, text + "*SURFACE, NAME=BAD\n100, SPOS\n", name="solid.inp")
    with pytest.raises(ReadError, match=r"element 100 \(hexahedron\) has no face SPOS "
                                        r"\(expected S1 to S6; SPOS and SNEG are the sides of "
                                        r"shells\)"):
        io.read_target(solid, zone="BAD")
    # both sides of one shell: a target has one side
    both = _write(tmp_path, "*NODE\n1, 0, 0, 0\n2, 1, 0, 0\n3, 0, 1, 0\n*ELEMENT, TYPE=S3, "
                            "ELSET=E\n1, 1, 2, 3\n*SURFACE, NAME=S\nE, SPOS\n1, S1\n",
                  name="both.inp")
    with pytest.raises(ReadError, match=r"line 9: element 1 \(triangle, a shell\): both its "
                                        r"sides \(SPOS and SNEG\) in one surface"):
        io.read_target(both, zone="S")


# --------------------------------------------------------------------------------------------
# the sides of shells: SPOS (S2) the cell as it is, SNEG (S1) turned over
# --------------------------------------------------------------------------------------------

#: the plane of the shell patches: through the origin, normal N, axes E1, E2 (E1 x E2 = N)
N = np.array([0.2, -0.3, 1.0]) / np.linalg.norm([0.2, -0.3, 1.0])
E1 = np.cross([0.0, 1.0, 0.0], N)
E1 /= np.linalg.norm(E1)
E2 = np.cross(N, E1)

#: shell, membrane and rigid types with their meshio cell type
SHELL_TYPES = {"S3": "triangle", "S3R": "triangle", "M3D3": "triangle", "R3D3": "triangle",
               "S4": "quad", "S4R": "quad", "M3D4R": "quad", "R3D4": "quad",
               "S6": "triangle6", "STRI65": "triangle6", "M3D6": "triangle6",
               "S8": "quad8", "S8R": "quad8", "M3D8R": "quad8", "M3D9R": "quad9"}


def shell_deck(etype: str, against: bool = False, extra: str = ""):
    """Deck text of a 2 x 2 patch of shells of ``etype`` (quads, or each square as two
    triangles) on the plane through 0 of normal N, over u, v in [0, 2]; each element's corners
    counterclockwise about N (its right-hand normal is N), ``against``: clockwise (-N), and
    each starting at another corner; mid-side nodes halfway, a quad9's centre in the middle.
    Node numbers scrambled, in element set PATCH. Returns (text, right-hand unit normal of each
    element, its node coordinates in the element's order)."""
    kind = SHELL_TYPES[etype]
    squares = [[(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)] for i in range(2)
               for j in range(2)]
    polys = squares if kind.startswith("quad") else [
        t for q in squares for t in ([q[0], q[1], q[2]], [q[0], q[2], q[3]])]
    elements = []
    for k, c in enumerate(polys):
        c = [np.array(p, float) for p in c]
        c = c[k % len(c):] + c[:k % len(c)]  # another first corner for each element
        if against:
            c = c[:1] + c[1:][::-1]
        nodes = list(c)
        if kind in ("triangle6", "quad8", "quad9"):
            nodes += [(c[j] + c[(j + 1) % len(c)]) / 2 for j in range(len(c))]
        if kind == "quad9":
            nodes.append(np.mean(c, axis=0))
        elements.append([tuple(float(x) for x in u * E1 + v * E2) for u, v in nodes])
    points = sorted({p for e in elements for p in e})
    numbers = dict(zip(points, np.random.default_rng(7).permutation(len(points)) * 2 + 5))
    lines = ["*NODE"] + [f"{numbers[p]}, {p[0]!r}, {p[1]!r}, {p[2]!r}" for p in points]
    lines.append(f"*ELEMENT, TYPE={etype}, ELSET=PATCH")
    lines += [", ".join(str(v) for v in [50 + i] + [numbers[p] for p in e])
              for i, e in enumerate(elements)]
    normal = -N if against else N
    return "\n".join(lines) + "\n" + extra, normal, np.array(elements)


@pytest.mark.parametrize("etype", sorted(SHELL_TYPES))
@pytest.mark.parametrize("label,side", [("SPOS", 1), ("S2", 1), ("SNEG", -1), ("S1", -1)])
@pytest.mark.parametrize("against", [False, True])
def test_the_sides_of_shells(tmp_path, etype, label, side, against):
    """SPOS (S2) is the shell cell as written: its facets' normals are the elements'
    right-hand normals; SNEG (S1) the cell turned over: against them. On the element set, and
    on element numbers."""
    text, normal, elements = shell_deck(etype, against, f"*SURFACE, NAME=TOP\nPATCH, {label}\n"
                                                         f"*SURFACE, NAME=ONE\n51, {label}\n")
    path = _write(tmp_path, text)
    target = io.read_target(path, zone="top")
    kind = SHELL_TYPES[etype]
    assert [k for k, _ in target.cells] == [kind] and target.boundary == {}
    conn = target.cells[0][1]
    assert len(conn) == len(elements)
    corners = facet_corners(conn)
    area = facet_area_vectors(target.points, [corners])
    unit = area / np.linalg.norm(area, axis=1)[:, None]
    np.testing.assert_allclose(unit, np.tile(side * normal, (len(conn), 1)), atol=1e-12)
    # each cell has its element's nodes; the mid-side nodes follow its corners
    want = {frozenset(map(tuple, e.round(12))) for e in elements}
    assert {frozenset(map(tuple, target.points[c].round(12))) for c in conn} == want
    k = corners.shape[1]
    for j in range(k if conn.shape[1] > k else 0):
        np.testing.assert_allclose(target.points[conn[:, k + j]], 0.5 * (
            target.points[conn[:, j]] + target.points[conn[:, (j + 1) % k]]), atol=1e-15)
    if kind == "quad9":
        np.testing.assert_allclose(target.points[conn[:, 8]],
                                   target.points[conn[:, :4]].mean(axis=1), atol=1e-15)
    # SPOS is the element's own node order (not only its normal); SNEG keeps its first corner
    one = io.read_target(path, zone="ONE").cells[0][1]
    first = target.points[one[0]]
    order = elements[1] if side == 1 else elements[1][_turned(kind)]
    np.testing.assert_array_equal(first, order)


def _turned(kind: str) -> list:
    """The node order of a cell of ``kind`` turned over (corners c0 c(k-1) ... c1, the sides
    after them in the matching order, a centre kept)."""
    k = 3 if kind.startswith("triangle") else 4
    n = {"triangle": 3, "triangle6": 6, "quad": 4, "quad8": 8, "quad9": 9}[kind]
    cols = [0] + list(range(k - 1, 0, -1))
    if n >= 2 * k:
        cols += [k + j for j in range(k - 1, -1, -1)]
    return cols + list(range(2 * k, n))


@pytest.mark.parametrize("etype,against", [("S4", False), ("S8R", False), ("S3", True),
                                           ("STRI65", False)])
def test_project_on_the_sides_of_a_shell(tmp_path, etype, against):
    """`diffsurf project deck.inp points.csv --zone NAME`: the gap of a point on the side of
    the elements' right-hand normal is positive for their SPOS (S2) and negative for their SNEG
    (S1), its distance to the plane; the normal column is the side's normal."""
    surfaces = "".join(f"*SURFACE, NAME={label}\nPATCH, {label}\n"
                       for label in ("SPOS", "S2", "SNEG", "S1"))
    text, normal, _ = shell_deck(etype, against, surfaces)
    deck = _write(tmp_path, text)
    rng = np.random.default_rng(5)
    uv = rng.uniform(0.3, 1.7, (30, 2))
    distance = rng.uniform(0.02, 0.3, 30)
    xyz = uv[:, :1] * E1 + uv[:, 1:] * E2 + distance[:, None] * normal  # on the normal's side
    csv = tmp_path / "points.csv"
    np.savetxt(csv, xyz, delimiter=",", header="x,y,z", comments="")
    for label, side in (("SPOS", 1), ("S2", 1), ("SNEG", -1), ("S1", -1)):
        for method in ("facet", "diffuse"):
            out = tmp_path / f"{label}-{method}.csv"
            result = run("project", deck, csv, "--zone", label, "--method", method, "-o", out,
                         "-q")
            assert result.exit_code == 0, result.stderr
            gaps = pl.read_csv(out)
            assert not gaps["status"].is_in(["outside", "failed"]).any()
            np.testing.assert_allclose(gaps["gap"].to_numpy(), side * distance, rtol=0,
                                       atol=1e-9)
            normals = gaps.select(["nx", "ny", "nz"]).to_numpy()
            np.testing.assert_allclose(normals, np.tile(side * normal, (30, 1)), atol=1e-9)


# --------------------------------------------------------------------------------------------
# no face id: the free faces of the elements (Abaqus; CalculiX wants a face id)
# --------------------------------------------------------------------------------------------


def _faces(target):
    return {frozenset(f) for _, c in target.cells for f in facet_corners(c).tolist()}


@pytest.mark.parametrize("order", [1, 2])
def test_an_element_set_without_face_id(tmp_path, order):
    """`ESET` alone on a data line: the faces of its elements that no other element of the
    line has, outward (Abaqus's "all exposed element faces of these elements"); an element
    number alone: all its faces."""
    text, _ = hexa_deck((2, 2), _block_numbering, order=order)
    text += ("*ELSET, ELSET=PAIR\n100, 101\n*SURFACE, NAME=ALL\nBLOCK\n"
             "*SURFACE, NAME=PAIR\nPAIR\n*SURFACE, NAME=ONE\n110\n"
             "*SURFACE, NAME=TWICE\nPAIR\n100\n101, S2\n")
    path = _write(tmp_path, text)
    whole = io.read_target(path, zone="ALL")
    kind = "quad" if order == 1 else "quad8"
    assert [k for k, _ in whole.cells] == [kind]
    # the block's exterior: its boundary as the element set gives it, and as the file does
    for other in (io.read_target(path, zone="BLOCK"), io.read_target(path)):
        assert _faces(whole) == _faces(other) and len(_faces(whole)) == 16
        np.testing.assert_array_equal(np.sort(np.concatenate([c for _, c in whole.cells])
                                              .reshape(-1)),
                                      np.sort(np.concatenate([c for _, c in other.cells])
                                              .reshape(-1)))
    assert whole.boundary == {("hexahedron" if order == 1 else "hexahedron20"): 4}
    assert np.all(_outward(whole, _ELEMENT_CENTROIDS) > 0)
    # two elements sharing a face: their 10 other faces, those against 110 and 111 included
    pair = io.read_target(path, zone="PAIR")
    assert len(_faces(pair)) == 10 and np.all(_outward(pair, _ELEMENT_CENTROIDS[:2]) > 0)
    assert np.all(_face_centroids(pair)[:, 0] <= 0.5)
    assert np.sum(np.isclose(_face_centroids(pair)[:, 0], 0.5)) == 2  # against 110 and 111
    one = io.read_target(path, zone="one")
    assert len(_faces(one)) == 6 and np.all(_outward(one, _ELEMENT_CENTROIDS[2:3]) > 0)
    # each line on its own: 100's faces (all 6, the one against 101 too) with PAIR's
    twice = io.read_target(path, zone="twice")
    assert len(_faces(twice)) == 11


def test_no_face_id_on_shells_tetras_and_others(tmp_path):
    """Without a face id: tetrahedra's exterior faces, shells as they are (their SPOS side),
    springs left out; plane elements refused (their faces are edges)."""
    text = """*NODE
1, 0, 0, 0
2, 1, 0, 0
3, 0, 1, 0
4, 0, 0, 1
5, 1, 1, 1
6, 3, 0, 0
7, 4, 0, 0
8, 3, 1, 0
*ELEMENT, TYPE=C3D4, ELSET=MIXED
1, 1, 2, 3, 4
2, 2, 3, 4, 5
*ELEMENT, TYPE=S3, ELSET=MIXED
3, 6, 8, 7
*ELEMENT, TYPE=SPRINGA, ELSET=MIXED
4, 1, 6
*ELEMENT, TYPE=CPS3, ELSET=PLANE
5, 6, 7, 8
*SURFACE, NAME=MIXED
MIXED
*SURFACE, NAME=NEG
3, SNEG
MIXED
*SURFACE, NAME=PLANE
PLANE
"""
    path = _write(tmp_path, text)
    target = io.read_target(path, zone="mixed")
    assert [k for k, _ in target.cells] == ["triangle"]
    assert target.boundary == {"tetra": 2}
    faces = {frozenset(f) for _, c in target.cells for f in c.tolist()}
    assert len(faces) == 7 and frozenset({5, 6, 7}) in faces
    assert frozenset({1, 2, 3}) not in faces  # the face the tetrahedra share
    conn = target.cells[0][1]
    assert conn[(conn == 5).any(axis=1)].tolist() == [[5, 7, 6]]  # as written (normal -z)
    tets = conn[~(conn == 5).any(axis=1)]
    area = facet_area_vectors(target.points, [tets])
    centre = target.points[tets].mean(axis=1)
    owner = np.where(np.isin(tets, [0]).any(axis=1), 0, 1)  # the face's tetrahedron
    centroid = np.array([[0.25, 0.25, 0.25], [0.5, 0.5, 0.5]])[owner]
    assert np.all(np.einsum("ij,ij->i", area, centre - centroid) > 0)  # outward
    with pytest.raises(ReadError, match=r"line 23: element 3 \(triangle, a shell\): both its "
                                        r"sides"):
        io.read_target(path, zone="neg")
    with pytest.raises(ReadError, match=r"surface 'PLANE', line 25: element 5 \(triangle, no "
                                        r"face id\): the faces of plane and axisymmetric "
                                        r"elements are their edges"):
        io.read_target(path, zone="plane")
