"""API inputs a hostile tester tried (issue 32): each is refused with a one-line ValueError that
says what is wrong, or answered as documented, never silently wrong.

- 6b: a penalty that is not finite and > 0 (0, negative, NaN, inf) wherever a penalty enters;
- 8: facets with corners outside [0, n) or not integers; `assemble`'s chunk; a pairing made on
  another type of surface, or for another number of contactors;
- 11: a closed target wound inside out is said (API: a warning naming flip=True; command
  line: a log warning naming --flip-normals);
- 12: a contactor far from every node is 'outside', 'off-target', NaN in every float column;
- 15: targets 1e9 to 1e30 in size (and 1e-30) build and project without a RuntimeWarning.
"""
from __future__ import annotations

import subprocess
import sys
import warnings

import meshio
import numpy as np
import pytest

from diffsurf_cli.element.element import assemble, contact
from diffsurf_cli.element.friction import Coulomb
from diffsurf_cli.element.rigid import RigidTarget
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.mls.frame import facet_corners
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.projection import OFF_TARGET, OUTSIDE, REASONS, InsideOutWarning, inside_out
from diffsurf_cli.targets import build_surface, read_surface, surface_from_file
from diffsurf_cli.testing.shapes import Sphere, Torus
from samples import CYLINDER, CYLINDER_STL, N_PLATE, PLATE_CSV, run


@pytest.fixture(scope="module")
def cylinder():
    """The sample half cylinder (nodes, faces) and the plate's contactors."""
    _, nodes, faces = read_surface(CYLINDER)
    plate = np.loadtxt(PLATE_CSV, delimiter=",", skiprows=1)[:, 1:4]
    assert len(plate) == N_PLATE
    return nodes, faces, plate


# ------------------------------------------------------------------ 6b. the penalty


BAD_PENALTIES = [-1.0, 0.0, np.nan, np.inf, -np.inf]


@pytest.mark.parametrize("penalty", BAD_PENALTIES)
def test_a_penalty_not_finite_and_positive_is_refused_everywhere(cylinder, penalty):
    nodes, faces, plate = cylinder
    surf = DiffuseSurface(nodes, faces)
    c = contact(surf, plate)
    assert len(c)  # the plate penetrates the cylinder: elements to assemble
    dofs = np.arange(3 * len(plate)).reshape(-1, 3)
    calls = {
        "residual": lambda: c.residual(penalty, dofs),
        "tangent": lambda: c.tangent(penalty, dofs),
        "gauss-newton tangent": lambda: c.tangent(penalty, dofs, gauss_newton=True),
        "energy": lambda: c.energy(penalty),
        "tractions": lambda: c.tractions(penalty),
        "element residual": lambda: c[0].residual(penalty),
        "element tangent": lambda: c[0].tangent(penalty),
        "assemble": lambda: assemble(surf, plate, penalty, dofs),
        "per contactor": lambda: c.residual(np.r_[np.ones(len(plate) - 1), penalty], dofs),
    }
    for name, call in calls.items():
        with pytest.raises(ValueError, match="penalty must be finite and > 0"):
            call()
            pytest.fail(name)
    # friction and the rigid target's own result
    rigid = contact(surf, plate, rigid_target=True, friction=Coulomb(0.3))
    with pytest.raises(ValueError, match="penalty must be finite and > 0"):
        rigid.residual(penalty, dofs)
    with pytest.raises(ValueError, match="penalty must be finite and > 0"):
        rigid.tangent(penalty, dofs)
    res = RigidTarget.for_surface(surf).evaluate(plate[:5])
    for call in (res.residual, res.tangent):
        with pytest.raises(ValueError, match="penalty must be finite and > 0"):
            call(penalty)
    # a good penalty still assembles
    assert np.abs(c.residual(1.0, dofs)).sum() > 0


def test_the_command_line_refuses_a_non_finite_penalty(tmp_path):
    for value in ("inf", "nan"):
        result = run("project", "-q", CYLINDER, PLATE_CSV, "-o", str(tmp_path / "o.csv"),
                     "--penalty", value, "--residual", str(tmp_path / "R.mtx"))
        assert result.exit_code == 2, result.stderr
        assert "--penalty" in result.stderr and "Traceback" not in result.stderr
        assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------ 8. facets, chunk, pairing


def test_facet_corners_outside_the_nodes_are_refused(cylinder):
    """A corner -1 wrapped to the last node and changed 30 of the plate's 265 gaps."""
    nodes, faces, _ = cylinder
    n = len(nodes)
    for value, shown in ((-1, "got -1"), (n, f"got {n}")):
        bad = [f.copy() for f in faces]
        bad[0][3, 1] = value
        for build in (lambda b: DiffuseSurface(nodes, b), lambda b: PatchedSurface(nodes, b),
                      lambda b: FacetSurface(nodes, [facet_corners(f) for f in b]),
                      lambda b: build_surface(nodes, b)):
            with pytest.raises(ValueError, match=rf"must index the {n} nodes .*{shown}"):
                build(bad)
    with pytest.raises(ValueError, match="must be integers"):
        DiffuseSurface(nodes, [f + 0.5 for f in faces])
    with pytest.raises(ValueError, match="shape"):
        DiffuseSurface(nodes, [faces[0][:, :2]])
    # integral floats and one block as a list of rows are facets as they are
    a = DiffuseSurface(nodes, faces).project(nodes + 0.1)
    b = DiffuseSurface(nodes, [f.astype(float) for f in faces]).project(nodes + 0.1)
    c = DiffuseSurface(nodes, faces[0].tolist()).project(nodes + 0.1)
    np.testing.assert_array_equal(a.gap, b.gap)
    np.testing.assert_array_equal(a.gap, c.gap)


@pytest.mark.parametrize("chunk", [-1, 0, 2.5, True, "8"])
def test_assemble_refuses_a_chunk_that_is_not_a_positive_integer(cylinder, chunk):
    """chunk=-1 returned R = 0, an empty K and uninitialised statuses."""
    nodes, faces, plate = cylinder
    surf = DiffuseSurface(nodes, faces)
    dofs = np.arange(3 * len(plate)).reshape(-1, 3)
    with pytest.raises(ValueError, match="chunk must be a positive integer"):
        assemble(surf, plate, 1.0, dofs, chunk=chunk)
    R, K, status = assemble(surf, plate, 1.0, dofs, chunk=100)
    np.testing.assert_array_equal(status, contact(surf, plate).status)


def test_a_pairing_of_another_type_of_surface_is_refused(cylinder):
    """A FacetSurface's pairing given to a DiffuseSurface was silently ignored (searched
    again)."""
    nodes, faces, plate = cylinder
    surfaces = {"DiffuseSurface": DiffuseSurface(nodes, faces),
                "FacetSurface": FacetSurface(nodes, [facet_corners(f) for f in faces]),
                "PatchedSurface": PatchedSurface(nodes, faces, feature_angle=None)}
    pairings = {name: contact(s, plate).pairing for name, s in surfaces.items()}
    for made, pairing in pairings.items():
        assert pairing.made_on == made
        for name, surf in surfaces.items():
            if name == made:
                again = contact(surf, plate, pairing=pairing)
                np.testing.assert_array_equal(again.status, contact(surf, plate).status)
                continue
            with pytest.raises(ValueError, match=f"made on a {made}, not on this {name}"):
                contact(surf, plate, pairing=pairing)
    # the raw pairings: a Patch is no facet's, facet indices no diffuse surface's
    patch = contact(surfaces["DiffuseSurface"], plate).projection.patch
    facet = contact(surfaces["FacetSurface"], plate).projection.facet
    with pytest.raises(ValueError, match="Patch .* no pairing for a FacetSurface"):
        contact(surfaces["FacetSurface"], plate, pairing=patch)
    with pytest.raises(ValueError, match="facet indices .* no pairing for a DiffuseSurface"):
        contact(surfaces["DiffuseSurface"], plate, pairing=facet)


def test_a_pairing_for_other_contactors_is_refused(cylinder):
    """A pairing made for 265 contactors used with 10 gave a reshape error (or, in
    `assemble`, silently its first 10 rows)."""
    nodes, faces, plate = cylinder
    dofs = np.arange(30).reshape(-1, 3)
    for surf in (DiffuseSurface(nodes, faces),
                 FacetSurface(nodes, [facet_corners(f) for f in faces]),
                 PatchedSurface(nodes, faces, feature_angle=None), build_surface(nodes, faces)):
        c = contact(surf, plate)
        raw = (c.projection.patch if isinstance(surf, DiffuseSurface)
               else c.projection.facet if isinstance(surf, FacetSurface) else None)
        for pairing in (c.pairing, raw) if raw is not None else (c.pairing,):
            with pytest.raises(ValueError, match="pairing is for 265 contactors, got 10"):
                contact(surf, plate[:10], pairing=pairing)
            with pytest.raises(ValueError, match="pairing is for 265 contactors, got 10"):
                assemble(surf, plate[:10], 1.0, dofs, pairing=pairing)
        if raw is not None:
            with pytest.raises(ValueError, match="pairing is for 265 contactors, got 10"):
                surf.project_with(plate[:10], raw)


# ------------------------------------------------------------------ 11. inside out


def test_a_closed_target_wound_inside_out_is_said():
    """All facets of a sphere reversed: 1996 of 2000 signs reversed, and no word."""
    nodes, faces = Sphere().mesh(10)
    tnodes, quads = Torus().mesh_quads(16)
    assert inside_out(nodes, [faces]) == (0, 0.0)
    for build in (DiffuseSurface, FacetSurface, PatchedSurface, build_surface):
        with pytest.warns(InsideOutWarning, match="flip=True") as caught:
            build(nodes, [faces[:, ::-1]])
        assert len(caught) == 1  # once, not once per part
        assert caught[0].message.facets == len(faces) and caught[0].message.volume < 0
        with pytest.warns(InsideOutWarning, match="flip=True"):
            build(tnodes, [quads[:, ::-1]])
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            build(nodes, [faces])                        # outward: nothing to say
            build(nodes, [faces[:, ::-1]], flip=True)    # said so
            build(nodes, [faces[:-4, ::-1]])             # open: no inside
    # two spheres, one reversed: that one's facets only
    both = np.vstack([nodes, nodes + 5.0])
    facets, volume = inside_out(both, [np.vstack([faces, faces[:, ::-1] + len(nodes)])])
    assert facets == len(faces) and volume < 0
    # a hollow sphere (a thin shell): its inner wall rightly faces the void, nothing to say
    shell = np.vstack([nodes, 0.9 * nodes])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        PatchedSurface(shell, [np.vstack([faces, faces[:, ::-1] + len(nodes)])])


def test_the_command_line_names_flip_normals_for_an_inside_out_target(tmp_path):
    nodes, faces = Sphere().mesh(10)
    path = str(tmp_path / "inside_out.stl")
    meshio.write(path, meshio.Mesh(nodes, [("triangle", faces[:, ::-1])]))
    points = str(tmp_path / "points.csv")
    np.savetxt(points, nodes * 1.2, delimiter=",", header="x,y,z", comments="")
    result = run("project", path, points, "-o", str(tmp_path / "o.csv"))
    assert result.exit_code == 0, result.stderr
    said = [line for line in result.stderr.splitlines() if "inside out" in line]
    assert len(said) == 1 and "--flip-normals" in said[0] and path in said[0], result.stderr
    assert "InsideOutWarning" not in result.stderr  # the log's line, not Python's warning
    result = run("project", path, points, "-o", str(tmp_path / "o2.csv"), "--flip-normals")
    assert result.exit_code == 0 and "inside out" not in result.stderr
    _, surf = surface_from_file(CYLINDER)  # open: nothing said (checked in the test above)


# ------------------------------------------------------------------ 12. far from every node


def test_a_contactor_far_from_every_node_is_off_target_with_nan(cylinder):
    """Past an open edge and far away a contactor got few-nodes or steep, with rcond 0.0 at
    (1000, 0, 0) where other unanswered rows had NaN."""
    nodes, faces, plate = cylinder
    points = np.array([[1000.0, 0, 0], [32.5, 500.0, 2.0], [32.5, 20.3, 12.5],
                       [32.5, 20.3, 27.5], [22.5, 50.0, 2.0]])
    diffuse = DiffuseSurface(nodes, faces)
    for surf in (diffuse, build_surface(nodes, faces), surface_from_file(CYLINDER)[1]):
        r = surf.project(np.vstack([points, plate]))
        far = slice(0, len(points))
        assert np.all(r.status[far] == OUTSIDE) and np.all(r.reason[far] == OFF_TARGET), \
            r.reason_names[far]
        for column in (r.gap, r.normal, r.proximal_point, r.rcond, r.curvature):
            assert np.isnan(column[far]).all()
        # the plate is answered as it was
        alone = surf.project(plate)
        np.testing.assert_array_equal(r.status[len(points):], alone.status)
        np.testing.assert_array_equal(r.gap[len(points):], alone.gap)
    # the command line: every numeric column NaN
    result = run("project", "-q", CYLINDER, "-", "-o", "-",
                 input="x,y,z\n1000,0,0\n32.5,500,2\n")
    assert result.exit_code == 0, result.stderr
    header, *rows = result.stdout.strip().splitlines()
    names = header.split(",")
    for row in rows:
        cells = dict(zip(names, row.split(",")))
        assert cells["status"] == "outside" and cells["reason"] == "off-target", row
        for name in ("gap", "nx", "ny", "nz", "px", "py", "pz", "rcond"):
            assert cells[name].lower() in ("nan", ""), (name, row)
    assert "off-target" in REASONS


def test_near_an_open_edge_the_answers_are_unchanged(cylinder):
    """Within the support radius of a node nothing changes: just past the edge the diffuse
    surface still answers, a little farther it is off the target with its fit's rcond."""
    nodes, faces, _ = cylinder
    surf = DiffuseSurface(nodes, faces)
    r = surf.project([[32.5, 20.3, 7.51], [32.5, 20.3, 8.5]])
    assert r.status[0] <= 2 and np.isfinite(r.gap[0])
    assert r.reason[1] == OFF_TARGET and np.isfinite(r.rcond[1])


# ------------------------------------------------------------------ 15. scale


@pytest.mark.parametrize("scale", [1e-30, 1e9, 1e10, 1e30])
def test_targets_of_any_size_build_and_project_without_warnings(scale):
    """A triangulated target 1e9 in size: 'overflow encountered in divide' (patches/surface.py,
    a floor of 1e-300 under an edge length), on stderr despite -q."""
    t, nodes, faces = read_surface(CYLINDER_STL)
    plate = np.loadtxt(PLATE_CSV, delimiter=",", skiprows=1)[:, 1:4]
    ref = build_surface(nodes, faces).project(plate)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for angle in (40, None):
            surf = build_surface(nodes * scale, faces, feature_angle=angle)
            r = surf.project(plate * scale)
            if angle == 40:
                np.testing.assert_array_equal(r.status, ref.status)
                np.testing.assert_allclose(r.gap / scale, ref.gap, rtol=1e-9, atol=1e-9)
        tnodes, quads = Torus().mesh_quads(12)
        build_surface(tnodes * scale, [quads]).project(tnodes * 1.1 * scale)


def test_the_command_line_is_quiet_for_a_huge_target(tmp_path):
    mesh = meshio.read(CYLINDER_STL)
    path = str(tmp_path / "huge.stl")
    meshio.write(path, meshio.Mesh(mesh.points * 1e10, mesh.cells))
    plate = np.loadtxt(PLATE_CSV, delimiter=",", skiprows=1)[:, 1:4] * 1e10
    points = str(tmp_path / "plate.csv")
    np.savetxt(points, plate, delimiter=",", header="x,y,z", comments="")
    # a process of its own: Python shows a warning once per place in a process
    result = subprocess.run([sys.executable, "-m", "diffsurf_cli", "project", "-q", path, points,
                             "-o", str(tmp_path / "o.csv")], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0 and result.stderr == "", result.stderr
