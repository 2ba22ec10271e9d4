"""Decks as users have them (issue 19, item 6), and STL vertices merged (issue 20).

Abaqus/CalculiX decks that meshio's reader cannot read (shells S6/S8, membranes, *NODE lines
ending with a comma, *INCLUDE, GENERATE with two values, sets inside sets) or misreads
(several *NODE blocks, comments inside data, an element set given to several *ELEMENT
blocks) are read by `diffsurf_cli.io.abaqus`; decks meshio reads stay with meshio, and give the
same mesh through both. The decks are written here, a few elements each.

Two checks run on real files when given (they are not part of the repository):
``DIFFSURF_DECKS=folder`` reads every ``*.inp`` of a folder both ways, and every ``*SURFACE``
and ``*CONTACT PAIR`` surface of it as a zone (CalculiX's test decks: ``git --git-dir=... show
HEAD:test/NAME.inp``; ``python tests/test_decks.py FOLDER`` counts the targets and lists the
refusals); ``DIFFSURF_OCTAGONAL_POCKET=file.stl`` counts the wrong facet signs near
trimesh's models/octagonal_pocket.stl before and after merging (``python tests/test_decks.py
FILE.stl`` prints them).
"""
from __future__ import annotations

import glob
import logging
import os
import sys

import meshio
import numpy as np
import polars as pl
import pytest
from hypothesis import given

from diffsurf_cli import io
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.io import abaqus
from diffsurf_cli.io.errors import ReadError
from diffsurf_cli.io.mesh import read_mesh
from diffsurf_cli.mls.frame import facet_area_vectors, facet_corners
from samples import run

# --------------------------------------------------------------------------------------------
# small decks
# --------------------------------------------------------------------------------------------

#: the plane of the test patches: z = 0.25 x + 0.1 y
SLOPE = np.array([0.25, 0.1])
UP = np.array([-0.25, -0.1, 1.0]) / np.linalg.norm([-0.25, -0.1, 1.0])


def _z(x, y):
    return SLOPE[0] * x + SLOPE[1] * y


def shell_patch(etype: str, scramble: bool = True):
    """A patch of two shell (or membrane, plane) elements of ``etype`` on the plane
    z = 0.25 x + 0.1 y, nodes counterclockwise seen from above (so their right-hand normal
    points up), mid-side nodes (second-order types) halfway along each side. Node numbers are
    scrambled so that only the element's node order tells which node is where.

    Returns (*NODE and *ELEMENT text, element node lists as coordinates: (2, k, 3))."""
    kind = abaqus.CELL_TYPES[etype.upper()]
    if kind.startswith("quad"):
        squares = [[(0, 0), (1, 0), (1, 1), (0, 1)], [(1, 0), (2, 0), (2, 1), (1, 1)]]
        corners = squares
    else:
        corners = [[(0, 0), (1, 0), (0, 1)], [(1, 0), (1, 1), (0, 1)]]
    elements = []
    for c in corners:
        c = [np.array(p, float) for p in c]
        nodes = list(c)
        if kind in ("triangle6", "quad8"):
            nodes += [(c[j] + c[(j + 1) % len(c)]) / 2 for j in range(len(c))]
        elements.append([(float(x), float(y), float(_z(x, y))) for x, y in nodes])
    points = sorted({p for e in elements for p in e})
    rng = np.random.default_rng(len(etype))
    numbers = dict(zip(points, (rng.permutation(len(points)) if scramble else
                                np.arange(len(points))) * 3 + 11))
    lines = ["*NODE"] + [f"{numbers[p]}, {p[0]!r}, {p[1]!r}, {p[2]!r}" for p in points]
    lines.append(f"*ELEMENT, TYPE={etype}, ELSET=PATCH")
    for i, e in enumerate(elements):
        lines.append(", ".join(str(v) for v in [100 + i] + [numbers[p] for p in e]))
    return "\n".join(lines) + "\n", np.array(elements)


def write(tmp_path, text: str, name: str = "deck.inp") -> str:
    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return str(path)


def cells_as_points(target):
    """Each cell as the coordinates of its nodes, in its node order, cells sorted."""
    out = {}
    for kind, conn in target.cells:
        xyz = target.points[conn]
        order = np.lexsort(xyz.reshape(len(xyz), -1).T[::-1])
        out[kind] = xyz[order]
    return out


# --------------------------------------------------------------------------------------------
# shell elements
# --------------------------------------------------------------------------------------------

#: every shell, membrane and plane type read as surface cells, with the meshio type expected
SHELLS = {"S3": "triangle", "S3R": "triangle", "S4": "quad", "S4R": "quad",
          "S6": "triangle6", "S8": "quad8", "S8R": "quad8", "STRI65": "triangle6",
          "M3D3": "triangle", "M3D4": "quad", "M3D4R": "quad", "M3D6": "triangle6",
          "M3D8": "quad8", "M3D8R": "quad8", "US3": "triangle", "CPS3": "triangle",
          "CPS4": "quad", "CPE6": "triangle6", "CPS8R": "quad8", "CAX8": "quad8",
          "CPE4R": "quad"}


@pytest.mark.parametrize("etype", sorted(SHELLS))
def test_shell_elements_are_surface_cells(tmp_path, etype):
    text, elements = shell_patch(etype)
    target = io.read_target(write(tmp_path, text))
    kind = SHELLS[etype]
    assert [k for k, _ in target.cells] == [kind] and len(target.cells[0][1]) == 2
    # each cell has its element's nodes in the element's order: corners, then the mid-side
    # node of each side (c1 c2, c2 c3, ...), as in CalculiX's figures C2D6/C2D8 and meshio's
    # triangle6/quad8
    got = cells_as_points(target)[kind]
    want = elements[np.lexsort(elements.reshape(2, -1).T[::-1])]
    np.testing.assert_array_equal(got, want)
    k = 3 if kind.startswith("triangle") else 4
    conn = target.cells[0][1]
    for j in range(conn.shape[1] - k):  # mid-side nodes halfway along their side
        np.testing.assert_allclose(target.points[conn[:, k + j]], 0.5 * (
            target.points[conn[:, j]] + target.points[conn[:, (j + 1) % k]]), rtol=0,
            atol=1e-15)
    assert len(target.nodes) == len({tuple(p) for e in elements for p in e})
    # the facets face the side the node order's right-hand rule gives (up)
    area = facet_area_vectors(target.points, [facet_corners(conn)])
    np.testing.assert_allclose(area / np.linalg.norm(area, axis=1)[:, None], [UP, UP],
                               atol=1e-15)


def test_shell_s8_deck_in_lower_case(tmp_path):
    """The S8 floor of CalculiX's ball.inp, as written there: `*element, type=s8`; meshio
    refuses it ('Element type not available: s8'), the deck reader gives one quad8 with its
    mid-side nodes."""
    text = """*node, nset=nfloor
6001,   0.0, -50.0, -90.0
6002, 100.0, -50.0, -90.0
6003, 100.0,  50.0, -90.0
6004,   0.0,  50.0, -90.0
6005,  50.0, -50.0, -90.0
6006, 100.0,   0.0, -90.0
6007,  50.0,  50.0, -90.0
6008,   0.0,   0.0, -90.0
*element, type=s8, elset=efloor
800, 6001, 6002, 6003, 6004, 6005, 6006, 6007, 6008
"""
    path = write(tmp_path, text)
    with pytest.raises(ReadError, match="Element type not available: s8"):
        read_mesh(path)
    for zone in (None, "EFLOOR", "nfloor"):
        target = io.read_target(path, zone=zone)
        assert target.reader == "deck"
        (kind, conn), = target.cells
        assert kind == "quad8"
        np.testing.assert_array_equal(target.points[conn[0]][:, :2], [
            [0, -50], [100, -50], [100, 50], [0, 50], [50, -50], [100, 0], [50, 50], [0, 0]])
        assert np.all(target.points[conn[0]][:, 2] == -90)


# --------------------------------------------------------------------------------------------
# data lines as users write them
# --------------------------------------------------------------------------------------------

USERS_DECK = """** a deck as users write it: any case, trailing commas, blank fields, comments
*Heading
 written by hand
*Node, NSET=ALLNODES
1, 0., 0., 0.,
2, 1., 0., 0.,
** a comment inside the data
3, 1., 1.,  ,
4, , 1., 0
5, 0.5, 0.0, 0.0D0,
6, 1.0, 0.5, 0.d0
7, 0.5, 1.0, 0.e0
8, 0.0, 0.5
*ELEMENT, type=s8r, ELSET=Plate
1, 1, 2, 3, 4,
5, 6, 7, 8
*element,TYPE = S8R , elset = plate2
2, 2, 6, 3, 7, 1,
** the rest of element 2 (a second-order triangle of nodes 2-3-1 would not fit: an S8R)
   5, 4, 8
*boundary
ALLNODES, 1, 3
"""


def test_data_lines_as_users_write_them(tmp_path):
    path = write(tmp_path, USERS_DECK)
    with pytest.raises(ReadError, match="could not convert string to float"):
        read_mesh(path)  # meshio: the trailing comma
    target = io.read_target(path)
    assert target.reader == "deck"
    expected = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [.5, 0, 0], [1, .5, 0], [.5, 1, 0],
                [0, .5, 0]]
    np.testing.assert_array_equal(target.points, expected)
    assert [k for k, _ in target.cells] == ["quad8", "quad8"]  # one block per *ELEMENT
    conn = np.concatenate([c for _, c in target.cells])
    np.testing.assert_array_equal(conn, [[0, 1, 2, 3, 4, 5, 6, 7], [1, 5, 2, 6, 0, 4, 3, 7]])
    # the sets: ELSET= of *ELEMENT, NSET= of *NODE; zones ignore case
    np.testing.assert_array_equal(io.read_target(path, zone="PLATE").cells[0][1], conn[:1])
    np.testing.assert_array_equal(io.read_target(path, zone="Plate2").cells[0][1], conn[1:])
    assert sum(len(c) for _, c in io.read_target(path, zone="allnodes").cells) == 2


def test_elements_read_as_calculix_reads_them(tmp_path):
    """Each element starts a line; its nodes run on to the next lines; numbers beyond its
    nodes are left out (CalculiX's elements.f): meshio reads the numbers as one stream."""
    text = """*NODE
1, 0, 0, 0
2, 1, 0, 0
3, 1, 1, 0
4, 0, 1, 0
5, 2, 0, 0
6, 2, 1, 0
*ELEMENT, TYPE=S4
1, 1, 2, 3, 4, 99, 98,
2, 2, 5, 6, 3, 97, 96,
"""
    path = write(tmp_path, text)
    with pytest.raises(ReadError, match="Expected number of data items"):
        read_mesh(path)
    np.testing.assert_array_equal(io.read_target(path).cells[0][1],
                                  [[0, 1, 2, 3], [1, 4, 5, 2]])


# --------------------------------------------------------------------------------------------
# *INCLUDE
# --------------------------------------------------------------------------------------------


def test_include_is_followed_relative_to_the_including_file(tmp_path, monkeypatch):
    text, elements = shell_patch("S8")
    nodes, _, block = text.partition("*ELEMENT")
    main = write(tmp_path, "*HEADING\nmain\n*INCLUDE, INPUT=mesh/nodes.inp\n"
                           "*NSET, NSET=SOME\n11, 14\n", "model/main.inp")
    # nodes.inp includes elements.inp from its own folder (model/mesh), not main's
    write(tmp_path, nodes + "*include,input=elements.inp\n", "model/mesh/nodes.inp")
    write(tmp_path, "*ELEMENT" + block + "*ELSET, ELSET=FIRST\n100\n",
          "model/mesh/elements.inp")
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    with pytest.raises(ReadError):
        read_mesh(main)  # meshio: 'Expected NODE before ELEMENT' in elements.inp
    target = io.read_target(main)
    assert target.reader == "deck"
    np.testing.assert_array_equal(cells_as_points(target)["quad8"],
                                  elements[np.lexsort(elements.reshape(2, -1).T[::-1])])
    # the sets of the included files are zones
    assert len(io.read_target(main, zone="first").cells[0][1]) == 1
    assert len(io.read_target(main, zone="PATCH").cells[0][1]) == 2


def _block_with_include(tmp_path, include_surfaces: bool):
    """test_surface_def's 2 x 2 block of C3D8 numbered three ways, its sets and surfaces in
    the deck or in a file it includes."""
    from test_surface_def import _BLOCK_SURFACES, _block_numbering, hexa_deck

    text, pts = hexa_deck((2, 2), _block_numbering)
    top = [k for k, p in pts.items() if p[2] == 1.0]
    surfaces = _BLOCK_SURFACES.format(
        topnodes=",\n".join(", ".join(map(str, top[s:s + 8])) for s in range(0, len(top), 8)),
        numbers="\n".join(f"{k}, 1.0" for k in top))
    if not include_surfaces:
        return write(tmp_path, text + surfaces, "whole.inp")
    write(tmp_path, surfaces, "sets/surfaces.inp")
    return write(tmp_path, text + "*INCLUDE, INPUT=sets/surfaces.inp\n*STEP\n*STATIC\n"
                                  "*END STEP\n", "main.inp")


@pytest.mark.parametrize("zone", ["TOP", "left", "NTOP", "NNUM", "Usual", "TOPNODES"])
def test_surfaces_and_sets_of_an_included_file(tmp_path, zone):
    included = _block_with_include(tmp_path, True)
    whole = _block_with_include(tmp_path, False)
    a = io.read_target(included, zone=zone)
    b = io.read_target(whole, zone=zone)
    assert a.reader == "deck" and b.reader == ("deck" if zone in ("TOP", "left", "NTOP",
                                                                  "NNUM") else "meshio")
    assert [k for k, _ in a.cells] == [k for k, _ in b.cells]
    for (_, x), (_, y) in zip(a.cells, b.cells):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.points, b.points)


def test_surface_in_an_included_file_was_not_seen(tmp_path):
    """Before: the *SURFACE of an included file was no zone ('unknown zone')."""
    included = _block_with_include(tmp_path, True)
    target = io.read_target(included, zone="TOP")
    assert [k for k, _ in target.cells] == ["quad"] and len(target.cells[0][1]) == 4
    assert np.all(target.points[target.nodes][:, 2] == 1.0)


def test_a_node_and_an_element_surface_of_one_name(tmp_path):
    """CalculiX's metalforming.inp names a node surface (a contact pair's slave) and an
    element surface (its master) alike: the element one is the zone, in either order; a
    surface defined again gets the new faces."""
    from test_surface_def import _block_numbering, hexa_deck

    text, pts = hexa_deck((2, 2), _block_numbering)
    top = ", ".join(str(k) for k, p in pts.items() if p[2] == 1.0)
    node = f"*NSET, NSET=TOPN\n{top}\n*SURFACE, NAME=MASTER, TYPE=NODE\nTOPN\n"
    element = "*SURFACE, NAME=MASTER, TYPE=ELEMENT\n100, S6\n"
    again = "*SURFACE, NAME=MASTER\n101, S5\n"
    for order in (node + element + again, element + node + again):
        target = io.read_target(write(tmp_path, text + order), zone="master")
        assert len(target.cells[0][1]) == 2  # the x = 0 side of 100 and 101, not the top
        assert np.all(target.points[target.nodes][:, 0] == 0.0)


@pytest.mark.parametrize("sets", [
    "*NSET, NSET=MASTER\n{top}\n",  # metalforming.inp: sheetup, a node set and surfaces
    "*NSET, NSET=master\n{top}\n",
    "*ELSET, ELSET=Master\n110, 111\n",
    "*NSET, NSET=MASTER\n{top}\n*ELSET, ELSET=MASTER\n110\n"])
@pytest.mark.parametrize("first", [True, False])
def test_a_surface_comes_before_a_set_of_its_name(tmp_path, sets, first):
    """CalculiX keeps the names of sets and surfaces apart and its contact pairs name
    surfaces: a *SURFACE is the zone of its name (any case), before a node or element set of
    that name (which was the zone, and gave 'no surface cells' for metalforming.inp's
    'sheetup'); in a deck meshio reads or not."""
    from test_surface_def import _block_numbering, hexa_deck

    text, pts = hexa_deck((2, 2), _block_numbering)
    top = ", ".join(str(k) for k, p in pts.items() if p[2] == 1.0)
    sets = sets.format(top=top)
    surface = "*SURFACE, NAME=MASTER, TYPE=ELEMENT\n100, S6\n101, S5\n"
    for meshio_reads in (True, False):
        extra = "" if meshio_reads else "*NODE\n99999, 5, 5, 5\n"  # two *NODE blocks
        path = write(tmp_path, text + extra + (sets + surface if first else surface + sets))
        assert (abaqus.meshio_misreads(path) is None) == meshio_reads
        for zone in ("MASTER", "master", "Master"):
            target = io.read_target(path, zone=zone)
            assert target.reader == "deck" and target.boundary == {"hexahedron": 2}
            (kind, conn), = target.cells
            assert kind == "quad" and len(conn) == 2  # the x = 0 side of 100 and 101
            assert np.all(target.points[target.nodes][:, 0] == 0.0)
    # without the surface, the set is the zone: the boundary of the element set's hexahedra
    # (two: 10 faces, one: 6), else the top faces on the node set
    path = write(tmp_path, text + sets)
    cells = io.read_target(path, zone="master").cells
    assert sum(len(c) for _, c in cells) == (10 if "111" in sets else 6 if "110" in sets
                                             else 4)


def test_a_surface_of_a_set_name_through_the_cli(tmp_path):
    """`diffsurf project deck.inp points.csv --zone sheetup`, sheetup a node set, a node
    surface and an element surface (metalforming.inp): the element surface's faces."""
    from test_surface_def import _block_numbering, hexa_deck

    text, pts = hexa_deck((2, 2), _block_numbering)
    top = ", ".join(str(k) for k, p in pts.items() if p[2] == 1.0)
    deck = write(tmp_path, text + f"*NSET, NSET=sheetup\n{top}\n*SURFACE, TYPE=NODE, "
                                  f"NAME=sheetup\nsheetup\n*SURFACE, TYPE=ELEMENT, NAME=sheetup\n"
                                  f"100, S6\n101, S5\n")
    points = write(tmp_path, "x,y,z\n-0.25,0.5,0.5\n0.25,0.5,0.5\n", "p.csv")
    out = tmp_path / "out.csv"
    result = run("project", deck, points, "--zone", "sheetup", "--method", "facet", "-o", out)
    assert result.exit_code == 0, result.stderr
    gaps = pl.read_csv(out)
    # signed distances to the x = 0 side (outward: -x), not to the top (the node set's faces)
    np.testing.assert_allclose(gaps["gap"].to_numpy(), [0.25, -0.25], rtol=0, atol=1e-12)


# --------------------------------------------------------------------------------------------
# sets: GENERATE, sets of sets, defined again
# --------------------------------------------------------------------------------------------


def test_generate_and_sets_of_sets(tmp_path):
    text = """*NODE
1, 0, 0, 0
2, 1, 0, 0
3, 2, 0, 0
4, 3, 0, 0
5, 0, 1, 0
6, 1, 1, 0
7, 2, 1, 0
8, 3, 1, 0
*ELEMENT, TYPE=S4R
11, 1, 2, 6, 5
12, 2, 3, 7, 6
13, 3, 4, 8, 7
*NSET, NSET=LEFTNODES, GENERATE
1, 3
5, 7
*NSET, NSET=RIGHT
4, 8
*NSET, NSET=RIGHTNODES
RIGHT, 3, 7
*ELSET, ELSET=ODD, GENERATE
11, 13, 2
*ELSET, ELSET=MIDDLE
12
*ELSET, ELSET=ALL
ODD, middle
*ELSET, ELSET=Middle2
12,
*ELSET, ELSET=Middle2
13
"""
    path = write(tmp_path, text)
    with pytest.raises(ReadError):
        read_mesh(path)  # meshio: GENERATE with two values
    zone = lambda name: io.read_target(path, zone=name).cells[0][1]  # noqa: E731
    np.testing.assert_array_equal(zone("leftnodes"), [[0, 1, 5, 4], [1, 2, 6, 5]])
    np.testing.assert_array_equal(zone("RightNodes"), [[2, 3, 7, 6]])
    np.testing.assert_array_equal(zone("odd"), [[0, 1, 5, 4], [2, 3, 7, 6]])
    np.testing.assert_array_equal(zone("ALL"), [[0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6]])
    # a set defined again gets the new members (meshio kept the last definition only)
    np.testing.assert_array_equal(zone("MIDDLE2"), [[1, 2, 6, 5], [2, 3, 7, 6]])


# --------------------------------------------------------------------------------------------
# meshio where it reads the deck
# --------------------------------------------------------------------------------------------

from test_io import DECK  # noqa: E402  (a deck meshio reads)


def _same_mesh(a, b):
    np.testing.assert_array_equal(np.asarray(a.points, float), b.points)
    assert [c.type for c in a.cells] == [c.type for c in b.cells]
    for x, y in zip(a.cells, b.cells):
        np.testing.assert_array_equal(x.data, y.data)
    for name, ids in a.point_sets.items():
        np.testing.assert_array_equal(np.unique(ids), b.point_sets[name])
    for name, blocks in a.cell_sets.items():
        assert len(blocks) == len(b.cell_sets[name])
        for x, y in zip(blocks, b.cell_sets[name]):
            np.testing.assert_array_equal(np.unique(x), y)


def test_decks_meshio_reads_stay_with_meshio(tmp_path):
    path = write(tmp_path, DECK)
    assert abaqus.meshio_misreads(path) is None
    target = io.read_target(path)
    assert target.reader == "meshio"
    deck_mesh, read_past = abaqus.deck_mesh(abaqus.read_deck(path))
    _same_mesh(read_mesh(path), deck_mesh)
    assert read_past == {}


@pytest.mark.parametrize("change,why", [
    (lambda t: t.replace("4, 5, 6, 9, 8\n", "4, 5, 6, 9, 8\n** comment\n").replace(
        "*ELEMENT, TYPE=S4, ELSET=Cyl\n", "*ELEMENT, TYPE=S4, ELSET=Cyl\n1, 1, 2, 5, 4\n"
        "** a comment\n", 1).replace("1, 1, 2, 5, 4\n2,", "2,", 1), "comment line inside"),
    (lambda t: t.replace("ELSET=Plate", "ELSET=Cyl"), "'Cyl' is given to *ELEMENT blocks"),
    (lambda t: t + "*NSET, NSET=Top\n1\n", "defines the set 'Top' twice"),
    (lambda t: t + "*NODE\n13, 5, 5, 5\n", "several *NODE blocks"),
])
def test_decks_meshio_misreads_go_to_the_deck_reader(tmp_path, change, why):
    """What meshio 5.3 reads wrongly without failing: the deck reader reads it."""
    path = write(tmp_path, change(DECK))
    assert why in abaqus.meshio_misreads(path)
    assert io.read_target(path).reader == "deck"


def test_a_comment_inside_element_data(tmp_path):
    """meshio stops a block at a comment line: the elements after it are lost, silently."""
    text = DECK.replace("3, 4, 5, 8, 7\n", "** the top row\n3, 4, 5, 8, 7\n")
    path = write(tmp_path, text)
    assert sum(len(c.data) for c in read_mesh(path).cells) == 3  # 5 elements in the deck
    target = io.read_target(path)
    assert target.reader == "deck" and sum(len(c) for _, c in target.cells) == 5
    assert len(io.read_target(path, zone="cyl").cells[0][1]) == 4


def test_element_set_given_to_two_blocks(tmp_path):
    """meshio puts an ELSET= given to two *ELEMENT blocks on one block only."""
    path = write(tmp_path, DECK.replace("ELSET=Plate", "ELSET=Cyl"))
    assert sum(len(b) for b in read_mesh(path).cell_sets["Cyl"]) == 2  # 5 elements in it
    assert sum(len(c) for _, c in io.read_target(path, zone="Cyl").cells) == 5


def test_node_set_of_a_node_keyword(tmp_path):
    """A name meshio's reading of the deck does not have (NSET= of *NODE) is looked up in the
    deck reader's."""
    path = write(tmp_path, DECK.replace("*NODE\n", "*NODE, NSET=EVERY\n"))
    assert io.read_target(path).reader == "meshio"
    target = io.read_target(path, zone="every")
    assert target.reader == "deck" and sum(len(c) for _, c in target.cells) == 5


def _ball_and_floor(tmp_path, floor_type="S4"):
    """ball.inp in small: test_surface_def's 2 x 2 block of C3D8 (numbered three ways) over
    an S4 (or S8) floor at z = -0.5 (nodes 9001...), with node sets of the block's top, of all
    its nodes (NSET= of *NODE), of the floor; and node surfaces on them (ball.inp's 'ball')."""
    from test_surface_def import _block_numbering, hexa_deck

    text, pts = hexa_deck((2, 2), _block_numbering)
    top = ", ".join(str(k) for k, p in pts.items() if p[2] == 1.0)
    text = text.replace("*NODE\n", "*NODE, NSET=BLOCKNODES\n")
    corners = [(-1, -1), (2, -1), (2, 2), (-1, 2)]
    nodes = [(x, y) for x, y in corners]
    if floor_type == "S8":
        nodes += [(0.5, -1), (2, 0.5), (0.5, 2), (-1, 0.5)]
    floor = "*NODE, NSET=NFLOOR\n" + "".join(f"{9001 + i}, {x}, {y}, -0.5\n"
                                             for i, (x, y) in enumerate(nodes))
    floor += f"*ELEMENT, TYPE={floor_type}, ELSET=EFLOOR\n900, " + ", ".join(
        str(9001 + i) for i in range(len(nodes))) + "\n"
    sets = (f"*NSET, NSET=TOPNODES\n{top}\n*SURFACE, NAME=BALL, TYPE=NODE\nBLOCKNODES\n"
            f"*SURFACE, NAME=FLOOR\nEFLOOR, SPOS\n")
    return write(tmp_path, text + floor + sets)


@pytest.mark.parametrize("floor_type", ["S4", "S8"])
def test_node_sets_in_a_deck_of_shells_and_solids(tmp_path, floor_type):
    """A node set zone over a deck of shell and volume cells (ball.inp: a C3D8 ball, an S8
    floor, 'ball' a node surface on the ball's nodes) takes the boundary faces of the volume
    cells too (it found no cell: only the shells were looked at)."""
    path = _ball_and_floor(tmp_path, floor_type)
    shell = "quad" if floor_type == "S4" else "quad8"
    for zone in ("BLOCKNODES", "ball"):  # the node set, the node surface on it
        target = io.read_target(path, zone=zone)
        assert [k for k, _ in target.cells] == ["quad"] and len(target.cells[0][1]) == 16
        assert target.boundary == {"hexahedron": 4} and target.ignored == {}
        assert np.all(target.points[target.nodes][:, 2] >= 0)
        faces = [facet_corners(c) for _, c in target.cells]
        area = facet_area_vectors(target.points, faces)
        centre = np.concatenate([target.points[f].mean(axis=1) for f in faces])
        assert np.all(np.einsum("ij,ij->i", area, centre - [0.5, 0.5, 0.5]) > 0)  # outward
    top = io.read_target(path, zone="topnodes")
    assert len(top.cells[0][1]) == 4 and np.all(top.points[top.nodes][:, 2] == 1.0)
    floor = io.read_target(path, zone="NFLOOR")  # the shell, not the block
    assert [k for k, _ in floor.cells] == [shell] and len(floor.cells[0][1]) == 1
    assert floor.boundary == {} and floor.ignored == {"hexahedron": 4}
    # a whole file, an element set: as before (the shells; the block's boundary)
    assert [k for k, _ in io.read_target(path).cells] == [shell]
    assert io.read_target(path, zone="BLOCK").boundary == {"hexahedron": 4}


def test_a_node_set_that_covers_no_face(tmp_path):
    """A node-to-surface contact's slave (contact1.inp's 'Sslav': one node): said so."""
    path = _ball_and_floor(tmp_path)
    with open(path, "a") as f:
        f.write("*NSET, NSET=NSLAV\n1, 9001\n*SURFACE, NAME=SSLAV, TYPE=NODE\nNSLAV\n")
    for zone, what in (("nslav", "node set 'NSLAV'"), ("Sslav", "node surface 'SSLAV'")):
        with pytest.raises(ReadError) as info:
            io.read_target(path, zone=zone)
        assert str(info.value) == (f"{path}: no surface cell or boundary face has all its "
                                   f"nodes in the {what} (2 nodes), expected the nodes of "
                                   f"whole faces")


def test_project_on_the_ball_of_a_deck_of_shells_and_solids(tmp_path):
    """`diffsurf project` on ball.inp in small: --zone ball is the block (gaps to its top
    and sides, positive outside), --zone floor its S4 floor (gaps to z = -0.5)."""
    path = _ball_and_floor(tmp_path)
    points = write(tmp_path, "x,y,z\n0.5,0.5,1.25\n0.3,0.6,0.75\n", "p.csv")
    for zone, want in (("ball", [0.25, -0.25]), ("floor", [1.75, 1.25])):
        out = tmp_path / f"{zone}.csv"
        result = run("project", path, points, "--zone", zone, "--method", "facet", "-o", out)
        assert result.exit_code == 0, result.stderr
        np.testing.assert_allclose(pl.read_csv(out)["gap"].to_numpy(), want, rtol=0,
                                   atol=1e-12)


def test_elements_read_past(tmp_path, caplog):
    """Springs, masses, network elements: meshio refuses the deck; they are counted."""
    text = DECK + "*ELEMENT, TYPE=SPRINGA, ELSET=Springs\n20, 1, 10\n21, 2, 11\n" \
                  "*ELEMENT, TYPE=MASS\n30, 3\n*ELEMENT, TYPE=D\n40, 0, 1, 2\n" \
                  "*ELEMENT, TYPE=U77\n50, 1, 2, 3,\n 4, 5\n"
    path = write(tmp_path, text)
    with caplog.at_level(logging.INFO, logger="diffsurf"):
        target = io.read_target(path)
    assert target.reader == "deck" and "SPRINGA" in caplog.text  # meshio's reason, logged
    assert target.ignored == {"SPRINGA": 2, "MASS": 1, "D": 1, "U77": 1}
    assert sum(len(c) for _, c in target.cells) == 5
    with pytest.raises(ReadError, match=r"no surface cells .* in zone 'springs'; it has: "
                                        r"2 SPRINGA$"):
        io.read_target(path, zone="springs")


# --------------------------------------------------------------------------------------------
# errors: one line naming the file, where and what
# --------------------------------------------------------------------------------------------

NODES = "*NODE\n1, 0, 0, 0\n2, 1, 0, 0\n3, 0, 1, 0\n"


@pytest.mark.parametrize("text,words", [
    (NODES + "*INCLUDE, INPUT=missing/part.inp\n",
     ["line 5", "*INCLUDE, INPUT=missing/part.inp", "no such file",
      os.path.join("missing", "part.inp")]),
    (NODES + "*INCLUDE, INPUT=deck.inp\n", ["line 5", "includes itself"]),
    (NODES + "*INCLUDE\n", ["line 5", "*INCLUDE without INPUT="]),
    ("*NODE\n1, 0, zero, 0\n", ["line 2", "'1, 0, zero, 0'", "*NODE",
                                "expected a node number and its coordinates"]),
    ("*NODE\n0, 0, 0, 0,\n", ["line 2", "node number 0", "expected 1 to"]),
    (NODES + "*ELEMENT, TYPE=S3\n1, 1, 2, 4\n", ["line 6", "element 1 refers to node 4",
                                                  "does not define"]),
    (NODES + "*ELEMENT, TYPE=S3\n1, 1, 2, 99999999999999999999999\n",
     ["line 6", "refers to node beyond 2147483647"]),
    (NODES + "*ELEMENT\n1, 1, 2, 3\n", ["line 5", "*ELEMENT without TYPE="]),
    (NODES + "*ELEMENT, TYPE=S6\n1, 1, 2, 3\n", ["line 6", "element 1 has 3 nodes",
                                                  "expected 6"]),
    (NODES + "*ELEMENT, TYPE=S3\n1, 1, 2, x\n", ["line 6", "cannot read '1, 1, 2, x'"]),
    (NODES.replace("0\n", "0,\n") + "*ELEMENT, TYPE=S3\n1, 1, 2, 3\n*ELEMENT, TYPE=S3\n"
     "1, 3, 2, 1\n", ["line 7", "element 1 is defined twice", "line 5"]),
    (NODES + "*ELEMENT, TYPE=S3\n1, 1, 2, 3\n*NSET, NSET=A, GENERATE\n3, 1\n",
     ["line 8", "GENERATE", "last >= first"]),
    (NODES + "*ELEMENT, TYPE=S3\n1, 1, 2, 3\n*ELSET, ELSET=A\nNOPE\n",
     ["line 7", "*ELSET 'A' names 'NOPE'", "no element set"]),
    (NODES + "*NSET\n1\n", ["line 5", "*NSET without NSET="]),
    ("\x00\x01 garbage \xff\n" * 3, ["empty mesh, expected points"]),
    ("*NODE\n1, 0, 0, 0,\n*ELEMENT, TYPE=S3\n", ["no surface cells", "it has: no cells"]),
    ("** no nodes\n*HEADING\n*ELEMENT, TYPE=S3\n", ["no nodes (*NODE)"]),
])
def test_errors(tmp_path, text, words):
    path = write(tmp_path, text)
    with pytest.raises(ReadError) as info:
        io.read_target(path)
    message = str(info.value)
    assert message.startswith(path + ": ") and "\n" not in message, message
    assert all(w in message for w in words), message


def test_an_error_in_an_included_file_names_it(tmp_path):
    main = write(tmp_path, NODES + "*INCLUDE, INPUT=part/elements.inp\n")
    write(tmp_path, "** elements\n*ELEMENT, TYPE=S3\n1, 1, 2, 5\n", "part/elements.inp")
    with pytest.raises(ReadError) as info:
        io.read_target(main)
    assert str(info.value) == (f"{main}: {os.path.join('part', 'elements.inp')} line 3: "
                               f"element 1 refers to node 5, which the deck does not define")


def test_errors_through_the_cli(tmp_path):
    deck = write(tmp_path, NODES + "*INCLUDE, INPUT=gone.inp\n")
    points = write(tmp_path, "x,y,z\n0.2,0.2,1\n", "p.csv")
    result = run("project", deck, points)
    assert result.exit_code == 1 and result.stdout == ""
    assert len(result.stderr.splitlines()) == 1, result.stderr
    assert "gone.inp" in result.stderr and "no such file" in result.stderr


def test_shell_faces_are_the_shell_cells(tmp_path):
    """ball.inp's floor (`efloor, SPOS` on an S8): the shells' cells as their element set
    gives them (it was refused); SNEG the same cells turned over; an edge (S3) is refused
    with a hint."""
    text, _ = shell_patch("S8")
    path = write(tmp_path, text + "*SURFACE, NAME=FLOOR\nPATCH, SPOS\n*SURFACE, NAME=UNDER\n"
                                  "PATCH, SNEG\n*SURFACE, NAME=EDGE\nPATCH, S3\n")
    floor, patch = io.read_target(path, zone="floor"), io.read_target(path, zone="PATCH")
    np.testing.assert_array_equal(floor.cells[0][1], patch.cells[0][1])
    assert floor.cells[0][0] == "quad8" and floor.boundary == {}
    under = io.read_target(path, zone="under").cells[0][1]
    np.testing.assert_array_equal(under, patch.cells[0][1][:, [0, 3, 2, 1, 7, 6, 5, 4]])
    with pytest.raises(ReadError, match=r"element 100 \(quad8, a shell\) has no face S3 "
                                        r"\(expected SPOS or S2, SNEG or S1"):
        io.read_target(path, zone="edge")


# --------------------------------------------------------------------------------------------
# end to end
# --------------------------------------------------------------------------------------------


def test_project_on_a_shell_deck(tmp_path):
    """`diffsurf project deck.inp points.csv --zone NAME` on an S8 deck with an include and
    trailing commas: gaps are the distances to the patch's plane, positive above it."""
    text, _ = shell_patch("S8")
    nodes, _, block = text.partition("*ELEMENT")
    nodes = nodes.replace("\n", ",\n").replace("*NODE,", "*NODE")  # trailing commas
    deck = write(tmp_path, nodes + "*INCLUDE, INPUT=elements.inp\n", "deck.inp")
    write(tmp_path, "*ELEMENT" + block.replace("ELSET=PATCH", "ELSET=Floor"), "elements.inp")
    rng = np.random.default_rng(7)
    xy = rng.uniform([0.3, 0.3], [1.7, 0.7], (40, 2))
    offset = rng.uniform(-0.2, 0.2, 40)
    xyz = np.column_stack([xy, _z(xy[:, 0], xy[:, 1])]) + offset[:, None] * UP
    points = tmp_path / "points.csv"
    np.savetxt(points, xyz, delimiter=",", header="x,y,z", comments="")
    for method in ("facet", "diffuse"):
        out = tmp_path / f"{method}.csv"
        result = run("project", deck, points, "--zone", "FLOOR", "--method", method, "-o", out,
                     "-v")
        assert result.exit_code == 0, result.stderr
        assert "read by diffsurf's deck reader" in result.stderr
        gaps = pl.read_csv(out)
        np.testing.assert_allclose(gaps["gap"].to_numpy(), offset, rtol=0, atol=1e-9)


# --------------------------------------------------------------------------------------------
# fuzzing the deck reader
# --------------------------------------------------------------------------------------------


def _seed() -> bytes:
    text, _ = shell_patch("S8", scramble=False)
    return (USERS_DECK.split("*boundary")[0] + text.replace("*NODE", "*NODE, NSET=P")
            .replace("11,", "111,").replace(", 11,", ", 111,") +
            "*NSET, NSET=G, GENERATE\n1, 8\n*ELSET, ELSET=ALL\nPlate, PATCH, 2\n"
            "*SURFACE, NAME=N, TYPE=NODE\nG\n").encode()


DECK_SEED = _seed()


def test_fuzz_seed_is_read_by_the_deck_reader(tmp_path):
    path = write(tmp_path, DECK_SEED.decode())
    target = io.read_target(path)
    assert target.reader == "deck" and sum(len(c) for _, c in target.cells) == 4
    assert io.read_target(path, zone="n").cells


def _block_seed() -> bytes:
    from test_surface_def import _BLOCK_SURFACES, _block_numbering, hexa_deck

    text, pts = hexa_deck((2, 2), _block_numbering)
    top = [k for k, p in pts.items() if p[2] == 1.0]
    return (text + _BLOCK_SURFACES.format(topnodes=", ".join(map(str, top)),
                                          numbers="\n".join(map(str, top)))).encode()


def _include_seed(folder) -> bytes:
    """A deck of nodes including its S8 elements, a node surface and an element set, which
    it writes in ``folder``."""
    text, _ = shell_patch("S8")
    nodes, _, block = text.partition("*ELEMENT")
    write(folder, "*ELEMENT" + block + "*NSET, NSET=ALL, GENERATE\n11, 47, 3\n"
                  "*SURFACE, NAME=S, TYPE=NODE\nALL\n", "part.inp")
    return (nodes + "*INCLUDE, INPUT=part.inp\n*ELSET, ELSET=E\nPATCH\n").encode()


@pytest.mark.parametrize("seed,zone", [("shells", None), ("shells", "all"), ("shells", "N"),
                                       ("block", "TOP"), ("block", "NTOP"), ("include", None),
                                       ("include", "S")])
def test_fuzz_read_deck(seed, zone, tmp_path):
    """Mutated decks give a target or one clean line (as tests/test_fuzz_readers.py's
    targets). Found: an IndexError in an element lookup (the block's surfaces), a ValueError
    of a NUL in an included file's name."""
    from test_fuzz_readers import FUZZ, check_target, mutated, run_reader

    path = str(tmp_path / "deck.inp")
    data = {"shells": lambda: DECK_SEED, "block": _block_seed,
            "include": lambda: _include_seed(tmp_path)}[seed]()
    write(tmp_path, data.decode())
    assert io.read_target(path, zone=zone).cells  # the seed is a target

    @FUZZ
    @given(data=mutated(data))
    def read(data):
        with open(path, "wb") as f:
            f.write(data)
        run_reader(lambda p: io.read_target(p, zone=zone), check_target, path)

    read()


# --------------------------------------------------------------------------------------------
# STL: copies of one vertex merged (issue 20)
# --------------------------------------------------------------------------------------------

#: a regular tetrahedron, faces outward
TET = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
TET_FACES = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])


def _tet_stl(tmp_path, apart: float) -> str:
    """An ASCII STL of the tetrahedron whose facets' copies of each vertex are ``apart``
    times its size apart (about)."""
    size = np.linalg.norm(TET.max(0) - TET.min(0))
    rng = np.random.default_rng(0)
    soup = TET[TET_FACES] + rng.uniform(-1, 1, (4, 3, 3)) * apart * size / np.sqrt(3)
    path = str(tmp_path / "tet.stl")
    meshio.write(path, meshio.Mesh(soup.reshape(-1, 3), [("triangle",
                                                          np.arange(12).reshape(4, 3))]),
                 binary=False)
    return path


def _edge_points():
    """Points 0.05 outside each edge of the tetrahedron, in directions spanning the angle
    between the normals of its two facets (every one is outside: positive gap)."""
    normals = np.cross(TET[TET_FACES[:, 1]] - TET[TET_FACES[:, 0]],
                       TET[TET_FACES[:, 2]] - TET[TET_FACES[:, 0]])
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    out = []
    for i in range(4):
        for j in range(i + 1, 4):
            a, b = sorted(set(TET_FACES[i]) & set(TET_FACES[j]))
            for t in np.linspace(0.1, 0.9, 9):
                for w in np.linspace(0, 1, 11):
                    v = (1 - w) * normals[i] + w * normals[j]
                    out.append(TET[a] * (1 - t) + TET[b] * t + 0.05 * v / np.linalg.norm(v))
    return np.array(out)


def _facet_gaps(points, cells, contactors):
    nodes = np.unique(np.concatenate([c.reshape(-1) for c in cells]))
    faces = [np.searchsorted(nodes, facet_corners(c)) for c in cells]
    return FacetSurface(points[nodes], faces).project(contactors).gap


def test_stl_copies_of_a_vertex_are_merged(tmp_path, caplog):
    path = _tet_stl(tmp_path, 1e-9)
    points = _edge_points()
    raw = read_mesh(path)  # what read_target gave before: 12 nodes, no edge shared
    assert len(raw.points) == 12
    before = _facet_gaps(raw.points, [raw.cells[0].data], points)
    with caplog.at_level(logging.INFO, logger="diffsurf"):
        target = io.read_target(path)
    assert "8 nodes merged into another node" in caplog.text
    assert target.merged == 8 and len(target.nodes) == 4
    after = _facet_gaps(target.points, [c for _, c in target.cells], points)
    assert np.sum(before < 0) > 50  # wrong signs: 134 of 594 seen
    assert np.all(after > 0)


def test_soups_are_merged_and_meshes_are_not(tmp_path):
    # a triangle soup in another format: merged
    size = np.linalg.norm(TET.max(0) - TET.min(0))
    soup = TET[TET_FACES] + np.random.default_rng(1).uniform(-1, 1, (4, 3, 3)) * 1e-9 * size
    path = str(tmp_path / "soup.vtu")
    meshio.write(path, meshio.Mesh(soup.reshape(-1, 3), [("triangle",
                                                          np.arange(12).reshape(4, 3))]))
    assert io.read_target(path).merged == 8
    # a mesh whose cells share nodes keeps its coincident nodes (the two faces of a crack)
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [1, 0, 0]], float)
    path = str(tmp_path / "crack.vtu")
    meshio.write(path, meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2], [2, 4, 3]]))]))
    target = io.read_target(path)
    assert target.merged == 0 and len(target.nodes) == 5
    # an STL without near copies: nothing merged, nothing logged
    meshio.write(str(tmp_path / "clean.stl"), meshio.Mesh(TET, [("triangle", TET_FACES)]))
    assert io.read_target(str(tmp_path / "clean.stl")).merged == 0


# --------------------------------------------------------------------------------------------
# real files, when given
# --------------------------------------------------------------------------------------------


def pocket_signs(path: str, n: int = 20000, seed: int = 0) -> dict:
    """Wrong facet signs near an STL (trimesh's octagonal_pocket.stl) before and after its
    vertices are merged: ``n`` points on its facets (area-weighted), moved ±2 % of its
    diagonal along their facet's normal; the reference side is trimesh's signed distance on
    the merged (watertight) mesh. Returns the counts."""
    import trimesh

    raw = read_mesh(path)
    target = io.read_target(path)
    faces = np.searchsorted(target.nodes, target.cells[0][1])
    ref = trimesh.Trimesh(target.points[target.nodes], faces, process=False)
    rng = np.random.default_rng(seed)
    diag = float(np.linalg.norm(ref.bounds[1] - ref.bounds[0]))
    f = rng.choice(len(ref.faces), n, p=ref.area_faces / ref.area_faces.sum())
    a, b = rng.random((2, n))
    flip = a + b > 1
    a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
    tri = ref.triangles[f]
    on = tri[:, 0] + a[:, None] * (tri[:, 1] - tri[:, 0]) + b[:, None] * (tri[:, 2] - tri[:, 0])
    side = rng.choice([-1.0, 1.0], n)
    points = on + (side * 0.02 * diag)[:, None] * ref.face_normals[f]
    outside = trimesh.proximity.signed_distance(ref, points) < 0  # trimesh: > 0 inside
    before = _facet_gaps(raw.points, [raw.cells[0].data], points)
    after = _facet_gaps(target.points, [c for _, c in target.cells], points)
    return {"points": n, "nodes before": len(raw.points), "nodes after": len(target.nodes),
            "merged": target.merged, "watertight after": bool(ref.is_watertight),
            "wrong before": int(np.sum((before > 0) != outside)),
            "wrong after": int(np.sum((after > 0) != outside)),
            "other side of the part": int(np.sum((side > 0) != outside))}


@pytest.mark.skipif(not os.environ.get("DIFFSURF_OCTAGONAL_POCKET"),
                    reason="DIFFSURF_OCTAGONAL_POCKET=path/to/octagonal_pocket.stl not set")
def test_octagonal_pocket():
    figures = pocket_signs(os.environ["DIFFSURF_OCTAGONAL_POCKET"])
    assert figures["wrong before"] > 0 and figures["wrong after"] == 0, figures


def deck_outcome(path: str) -> dict:
    """How a deck is read: by meshio and by the deck reader; when both read it and it is not
    one meshio misreads, whether they give the same mesh and target."""
    out = {"misreads": abaqus.meshio_misreads(path)}
    try:
        mesh = read_mesh(path)
    except ReadError as exc:
        mesh, out["meshio"] = None, str(exc)
    try:
        deck_mesh, _ = abaqus.deck_mesh(abaqus.read_deck(path))
    except ReadError as exc:
        deck_mesh, out["deck"] = None, str(exc)
    if mesh is not None and deck_mesh is not None and out["misreads"] is None \
            and len(deck_mesh.points):
        _same_mesh(mesh, deck_mesh)
        out["same"] = True
    try:
        target = io.read_target(path)
        out["target"] = target.reader
    except ReadError as exc:
        message = str(exc)
        assert message.startswith(path) and "\n" not in message, message
        out["target"] = "refused: " + message[len(path) + 2:]
    return out


def contact_pairs(path: str) -> list:
    """The (slave, master) surface names of the deck's ``*CONTACT PAIR`` data lines (its
    included files followed)."""
    pairs, keyword = [], None
    for line, _ in abaqus._Lines(path):
        if line.startswith("*"):
            keyword = abaqus._keyword(line)
        elif keyword == "CONTACT PAIR":
            names = [f.strip() for f in line.split(",") if f.strip()]
            pairs.append(tuple(names[:2]))
    return pairs


def zone_outcome(path: str, zone: str) -> str:
    """"target" or "refused: <the one-line error, its file name left out>"."""
    try:
        io.read_target(path, zone=zone)
        return "target"
    except ReadError as exc:
        message = str(exc)
        assert message.startswith(path) and "\n" not in message, message
        return "refused: " + message[len(path) + 2:]


def surface_outcomes(path: str) -> tuple[dict, dict]:
    """(every *SURFACE name of the deck -> `zone_outcome`, every surface name of its contact
    pairs -> `zone_outcome`)."""
    surfaces = {name: zone_outcome(path, name) for name in abaqus.read_deck(path).surfaces}
    pairs = {}
    for pair in contact_pairs(path):
        for name in pair:
            if name not in pairs:
                pairs[name] = surfaces.get(name) or zone_outcome(path, name)
    return surfaces, pairs


@pytest.mark.skipif(not os.environ.get("DIFFSURF_DECKS"),
                    reason="DIFFSURF_DECKS=folder of .inp decks (CalculiX's test/) not set")
def test_real_decks():
    paths = sorted(glob.glob(os.path.join(os.environ["DIFFSURF_DECKS"], "*.inp")))
    assert paths
    outcomes = {p: deck_outcome(p) for p in paths}
    for path, out in outcomes.items():
        if "deck" not in out:  # every *SURFACE and contact pair: a target or one clean line
            surface_outcomes(path)


def report(folder: str):
    """What `python tests/test_decks.py FOLDER` prints: how the decks are read, then every
    *SURFACE and contact pair surface name, a target or refused (each refusal, one line)."""
    from collections import Counter

    paths = sorted(glob.glob(os.path.join(folder, "*.inp")))
    outs = {p: deck_outcome(p) for p in paths}
    print(f"{len(paths)} decks")
    print(Counter(o["target"] if not o["target"].startswith("refused")
                  else "refused" for o in outs.values()))
    for p, o in outs.items():
        if o["target"].startswith("refused"):
            print(os.path.basename(p), o["target"])
    surfaces, pairs = {}, {}
    for p, o in outs.items():
        if "deck" not in o:
            s, c = surface_outcomes(p)
            surfaces.update({(os.path.basename(p), n): v for n, v in s.items()})
            pairs.update({(os.path.basename(p), n): v for n, v in c.items()})
    for title, found in (("*SURFACE names", surfaces), ("contact pair surfaces", pairs)):
        refused = {k: v for k, v in found.items() if v != "target"}
        print(f"{title}: {len(found)} in {len({k[0] for k in found})} decks, "
              f"{len(found) - len(refused)} targets, {len(refused)} refused")
        for (deck, name), why in refused.items():
            print(f"  {deck} {name!r}: {why}")


if __name__ == "__main__":  # python tests/test_decks.py octagonal_pocket.stl | folder
    for arg in sys.argv[1:]:
        if os.path.isdir(arg):
            report(arg)
        else:
            for key, value in pocket_signs(arg).items():
                print(f"{key}: {value}")
