"""One-element-wide strips (issue 11 item 2): the contact surface of an extruded 2D or
plane-strain model has two rows of nodes, across which the quadratic basis [14] cannot be
fitted (t² is a constant on two straight rows). The support's reduced basis (basis.REDUCED:
polynomial along the strip, linear or constant across) is fitted instead, and the points are
answered, with the number of terms fitted in `Projection.terms` and the CLI's terms column.

Scenes: strips along an arc of radius 10 (a cylinder 1 element long: shapes.Cylinder), first
order (quads, triangles: two rows), second order (quad8, quad9: three rows, built here), a
wide strip whose supports hold one row (a ruled extrusion), and a CalculiX-like deck: a
half annulus extruded one element thick (C3D8), its contact surface the boundary faces of an
*NSET. Points within ±5% of the part size; the exact gap is the signed distance to the
cylinder; the facets (FacetSurface, on the linear (sub-)facets) in the same run are the peer.
"""
from __future__ import annotations

import numpy as np
import pytest

from diffsurf_cli import tune
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.mls.frame import linear_facets
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.presets import PRESETS
from diffsurf_cli.projection import PENETRATION
from diffsurf_cli.testing.shapes import Cylinder
from samples import run

RADIUS = 10.0


def second_order_strip(shape, n, incomplete):
    """A strip of n quad9 (quad8 if `incomplete`) cells along `shape`'s arc, one across its
    length: rows of nodes at the two ends and the middle, oriented outward."""
    t0, t1 = shape.theta_range
    theta = t0 + (t1 - t0) * np.arange(2 * n + 1) / (2 * n)
    z = shape.center[2] + shape.length * np.array([-0.5, 0.0, 0.5])
    index = {}
    nodes = []
    for i, th in enumerate(theta):
        for j in range(3):
            if incomplete and j == 1 and i % 2:
                continue  # quad8: no centre nodes
            index[i, j] = len(nodes)
            nodes.append([RADIUS * np.cos(th), RADIUS * np.sin(th), z[j]])
    cells = []
    for e in range(n):
        i = 2 * e
        cell = [(i, 0), (i + 2, 0), (i + 2, 2), (i, 2),  # corners (outward: theta x z)
                (i + 1, 0), (i + 2, 1), (i + 1, 2), (i, 1)]  # mid-sides
        if not incomplete:
            cell.append((i + 1, 1))
        cells.append([index[c] for c in cell])
    return np.array(nodes), np.array(cells)


def strip(kind, arc=0.9 * np.pi, n=36, width=1.0):
    """(shape, nodes, faces for DiffuseSurface, linear facets for FacetSurface)."""
    shape = Cylinder(radius=RADIUS, length=width, theta_range=(0.0, arc))
    if kind == "quad":
        nodes, faces = shape.mesh_quads(n, 1)
    elif kind == "triangle":
        nodes, faces = shape.mesh(n, 1)
    else:
        nodes, faces = second_order_strip(shape, n // 2, incomplete=kind == "quad8")
    return shape, nodes, [faces], linear_facets([faces])


def near(shape, m=800, seed=0):
    """Points within ±5% of the part size (its chord, 2 R at most) of the strip, and their
    exact signed distances."""
    size = 2 * RADIUS * np.sin(min(0.5 * np.ptp(shape.theta_range), 0.5 * np.pi))
    pts = shape.sample_near(m, 0.05 * size, rng=seed)
    return pts, shape.closest(pts)[2]


def errors(result, dist):
    e = np.abs(result.gap - dist)
    return float(np.sqrt(np.mean(e**2))), float(e.max())


@pytest.mark.parametrize("arc", [0.9 * np.pi, np.pi / 3], ids=["local", "global"])
@pytest.mark.parametrize("kind", ["quad", "triangle", "quad8", "quad9"])
def test_strip_is_answered_and_beats_the_facets(kind, arc):
    """No point outside; a gap error below the facets' (RMS and max), at least 10x below on
    RMS (the strip's curvature is along it: the facets' chords against a quadratic along);
    two rows fit a reduced basis, three rows (second order) the full one."""
    shape, nodes, faces, facets = strip(kind, arc)
    surface = DiffuseSurface(nodes, faces)
    if kind in ("quad", "triangle"):  # (quad9's area vectors see its cells as flat: local)
        assert surface.frame == ("local" if arc > np.pi / 2 else "global")
    pts, dist = near(shape)
    got = surface.project(pts)
    assert np.all(got.status <= PENETRATION), np.unique(got.reason_names, return_counts=True)
    if kind in ("quad", "triangle"):
        assert np.all(got.terms < surface.nterms) and np.all(got.terms >= 3), \
            np.unique(got.terms, return_counts=True)
    else:
        assert np.mean(got.terms == surface.nterms) > 0.9, np.unique(got.terms, return_counts=True)
    peer = FacetSurface(nodes, facets).project(pts)
    rms, top = errors(got, dist)
    rms_f, top_f = errors(peer, dist)
    assert rms * 10 <= rms_f and top <= top_f, (rms, rms_f, top, top_f)


def test_before_every_point_of_a_strip_was_outside():
    """The control: without the reduced bases (REDUCED emptied: the full basis or nothing),
    every point of the two-row strip is 'outside' (ill-conditioned or few-nodes), as the issue
    observed on CalculiX's hueeber1 for every preset."""
    from diffsurf_cli.mls import basis

    shape, nodes, faces, _ = strip("quad")
    pts, _ = near(shape, 200)
    saved = basis.REDUCED["quadratic"]
    try:
        basis.REDUCED["quadratic"] = ()
        before = DiffuseSurface(nodes, faces).project(pts)
    finally:
        basis.REDUCED["quadratic"] = saved
    assert np.all(before.status > PENETRATION)
    assert set(before.reason_names) <= {"ill-conditioned", "few-nodes"}
    assert np.all(before.terms == 0)


def test_a_row_of_nodes_is_a_ruled_extrusion():
    """A strip much wider than its elements are long (4 against 0.44): supports near a row
    hold that row alone, and [1, a, a²] is fitted along it (3 terms), extruded across along
    e3 x a (the global frame, fixed by the whole strip); a point near a row is answered, ten
    times closer to the cylinder than the facets on RMS."""
    shape, nodes, faces, facets = strip("quad", np.pi / 3, n=24, width=4.0)
    surface = DiffuseSurface(nodes, faces)
    assert surface.frame == "global"
    rng = np.random.default_rng(3)
    m = 400
    theta = rng.uniform(0.05, np.pi / 3 - 0.05, m)
    z = np.where(rng.random(m) < 0.5, -2.0, 2.0) * (1 - rng.uniform(0.0, 0.02, m))
    r = RADIUS + rng.uniform(-0.5, 0.5, m)
    pts = np.column_stack([r * np.cos(theta), r * np.sin(theta), z])
    got = surface.project(pts)
    assert np.all(got.status <= PENETRATION), np.unique(got.reason_names, return_counts=True)
    np.testing.assert_array_equal(got.terms, 3)
    rms, top = errors(got, r - RADIUS)
    rms_f, top_f = errors(FacetSurface(nodes, facets).project(pts), r - RADIUS)
    assert rms * 10 <= rms_f and top <= top_f, (rms, rms_f, top, top_f)


@pytest.mark.parametrize("basis", ["quadratic", "cubic"])
def test_engine_and_reference_agree_on_strips(basis):
    """The reduced fits on every strip kind, engine against the slow reference (SVD,
    eigh; test_engine's comparison); the cubic's reduced bases on three rows (quad8, quad9)
    include the quadratic (b² terms)."""
    import reference
    from test_engine import _compare

    for kind in ("quad", "triangle", "quad8", "quad9"):
        shape, nodes, faces, _ = strip(kind, n=20)
        surface = DiffuseSurface(nodes, faces, basis=basis)
        pts, _ = near(shape, 200, seed=4)
        a = surface.project(pts, keep_patch=True)
        reduced = (a.terms < surface.nterms) & (a.status <= PENETRATION)
        assert reduced.any() or (basis, kind) in {("quadratic", "quad8"), ("quadratic", "quad9")}
        _compare(a, reference.project(surface, pts), float(np.median(surface.node_spacing)))


@pytest.mark.parametrize("kind", ["quad", "triangle"])
def test_every_preset_of_tune_has_an_error_estimate_on_a_strip(kind):
    """tune holds out nodes of a strip (all on its open edges: those of two facets or more)
    and every preset gets a finite leave-one-out error."""
    _, nodes, faces, _ = strip(kind)
    result = tune.tune(nodes, faces, dict(PRESETS), sample=20, seed=0,
                       timing_points=200, repeat=1, min_time=0.0)
    assert [e.name for e in result.estimates] == list(PRESETS)
    for e in result.estimates:
        assert np.isfinite(e.loo_rms) and e.loo_rms < 0.01 * RADIUS, (e.name, e.loo_rms)
    assert result.recommended in PRESETS


def calculix_deck(path, rings=3, n=40):
    """A plane-strain model extruded one element thick, as CalculiX decks such as hueeber1.inp
    are: a half annulus (radii 5 to 10, its lower half) of C3D8 cells graded towards the
    contact at its bottom, one cell thick in z; *NSET CONTACT the nodes of its outer arc.
    Written by meshio as an Abaqus/CalculiX .inp."""
    import meshio

    u = np.linspace(-1.0, 1.0, n + 1)
    theta = 1.5 * np.pi + 0.5 * np.pi * np.sign(u) * np.abs(u) ** 1.5
    radii = np.linspace(5.0, RADIUS, rings + 1)
    pts = np.array([[r * np.cos(t), r * np.sin(t), z] for z in (0.0, 1.0) for t in theta
                    for r in radii])

    def node(k, i, j):  # layer k, angle i, ring j
        return (k * (n + 1) + i) * (rings + 1) + j

    hexa = [[node(0, i, j), node(0, i, j + 1), node(0, i + 1, j + 1), node(0, i + 1, j),
             node(1, i, j), node(1, i, j + 1), node(1, i + 1, j + 1), node(1, i + 1, j)]
            for i in range(n) for j in range(rings)]
    contact = np.flatnonzero(np.isclose(np.hypot(pts[:, 0], pts[:, 1]), RADIUS))
    meshio.write(path, meshio.Mesh(pts, [("hexahedron", np.array(hexa))],
                                   point_sets={"CONTACT": contact}))
    return meshio.read(path)


def test_calculix_like_extruded_contact_surface(tmp_path):
    """`diffsurf project deck.inp points.csv --zone CONTACT`: the contact strip of an extruded
    plane-strain deck. Every point near the contact zone is answered (none outside), with a
    reduced basis (terms column below 6, logged), its gap error below the facets' (--method
    facet, same deck) and at least 10x below on RMS."""
    import polars as pl

    deck = tmp_path / "deck.inp"
    if "CONTACT" not in calculix_deck(deck).point_sets:
        pytest.skip("this meshio writes no *NSET")
    rng = np.random.default_rng(5)
    m = 300
    theta = 1.5 * np.pi + rng.uniform(-0.6, 0.6, m)
    r = RADIUS + rng.uniform(-1.0, 1.0, m)  # ±5% of the part (20 wide)
    pts = np.column_stack([r * np.cos(theta), r * np.sin(theta), rng.uniform(0.02, 0.98, m)])
    csv = tmp_path / "points.csv"
    np.savetxt(csv, pts, delimiter=",", header="x,y,z", comments="")
    out = {}
    for method in ("diffuse", "facet"):
        result = run("project", deck, csv, "--zone", "CONTACT", "--method", method,
                     "-o", tmp_path / f"{method}.csv")
        assert result.exit_code == 0, result.stderr
        out[method] = pl.read_csv(tmp_path / f"{method}.csv")
        if method == "diffuse":
            assert f"{m} contactors answered with a reduced basis" in result.stderr
    got = out["diffuse"]
    assert not got["status"].is_in(["outside", "failed"]).any()
    assert (got["terms"] < 6).all() and (got["terms"] >= 3).all()
    assert "terms" not in out["facet"].columns
    e = np.abs(got["gap"].to_numpy() - (r - RADIUS))
    e_f = np.abs(out["facet"]["gap"].to_numpy() - (r - RADIUS))
    assert np.sqrt(np.mean(e**2)) * 10 <= np.sqrt(np.mean(e_f**2)) and e.max() <= e_f.max(), \
        (np.sqrt(np.mean(e**2)), np.sqrt(np.mean(e_f**2)), e.max(), e_f.max())


@pytest.mark.parametrize("kind", ["quad", "triangle"])
def test_contact_element_on_a_strip(kind):
    """The contact element of a strip's contactor fits the projection's reduced basis at its
    direction (Patch.reduced, Patch.direction, held fixed as the frame is [§4.2]): its gap is
    the projection's, and a Taylor test of 𝒩 and ℳ (test_element's) passes: remainders fall
    as h² and h³."""
    import zlib

    from diffsurf_cli.element.element import contact
    from test_element import _check_symmetric, _sub_patch, _taylor

    shape, nodes, faces, _ = strip(kind, n=24)
    surface = DiffuseSurface(nodes, faces)
    on = shape.sample_near(4, 0.0, rng=11)
    points = on - 0.3 * shape.closest(on)[1]  # 0.3 inside
    result = contact(surface, points)
    assert len(result.elements) == len(points), result.projection.status
    patch = result.projection.patch
    assert np.all(patch.reduced >= 0) and np.all(np.isfinite(patch.direction))
    rng = np.random.default_rng(zlib.crc32(kind.encode()))
    for e in result.elements[:2]:
        i = e.contactor
        assert e.gap == pytest.approx(result.projection.gap[i], rel=1e-12, abs=1e-15)
        _check_symmetric(e.M)
        sub = _sub_patch(patch, i)
        sub.reduced, sub.direction = patch.reduced[i:i + 1], patch.direction[i:i + 1]
        u = np.concatenate([points[i], nodes[e.nodes].ravel()])

        def evaluate(v, e=e, sub=sub):
            moved = nodes.copy()
            moved[e.nodes] = v[3:].reshape(-1, 3)
            c2 = contact(DiffuseSurface(moved, faces, frame=surface.frame), v[None, :3],
                         second=False, pairing=sub)
            if len(c2.elements) != 1 or not np.array_equal(c2.elements[0].nodes, e.nodes):
                return None
            assert c2.elements[0].gap == pytest.approx(c2.projection.gap[0], rel=1e-10,
                                                       abs=1e-14)
            return c2.elements[0].gap, c2.elements[0].N

        _taylor(evaluate, u, e.gap, e.N, e.M, float(patch.spacing[i]), rng, f"{kind}/#{i}")


def test_pairs_file_keeps_a_strips_reduced_basis(tmp_path):
    """--save-pairs stores each contactor's reduced basis and direction with its frame, and
    --pairs holds them fixed (Patch.reduced, Patch.direction): the same answers again, and a
    stored direction turned by 0.3 rad turns them (it is used, not chosen again)."""
    import meshio
    import polars as pl

    _, nodes, faces, _ = strip("quad", n=24)
    target = tmp_path / "strip.vtu"
    meshio.write(target, meshio.Mesh(nodes, [("quad", faces[0])]))
    shape = Cylinder(radius=RADIUS, length=1.0, theta_range=(0.0, 0.9 * np.pi))
    pts, _ = near(shape, 100, seed=6)
    csv = tmp_path / "points.csv"
    np.savetxt(csv, pts, delimiter=",", header="x,y,z", comments="")
    pairs = tmp_path / "pairs.npz"
    first = run("project", target, csv, "--save-pairs", pairs, "-o", tmp_path / "a.csv")
    assert first.exit_code == 0, first.stderr
    stored = np.load(pairs)
    assert np.all(stored["reduced"] >= 0) and np.all(np.isfinite(stored["direction"]))
    again = run("project", target, csv, "--pairs", pairs, "-o", tmp_path / "b.csv")
    assert again.exit_code == 0, again.stderr
    a, b = pl.read_csv(tmp_path / "a.csv"), pl.read_csv(tmp_path / "b.csv")
    np.testing.assert_allclose(b["gap"].to_numpy(), a["gap"].to_numpy(), rtol=0, atol=1e-12)
    # the frozen direction is what --pairs uses: turning it turns the answers
    turned = dict(stored)
    turned["direction"] = stored["direction"] + 0.3
    np.savez(tmp_path / "turned.npz", **turned)
    other = run("project", target, csv, "--pairs", tmp_path / "turned.npz",
                "-o", tmp_path / "c.csv")
    assert other.exit_code == 0, other.stderr
    c = pl.read_csv(tmp_path / "c.csv")
    assert np.nanmax(np.abs(c["gap"].to_numpy() - a["gap"].to_numpy())) > 1e-6
