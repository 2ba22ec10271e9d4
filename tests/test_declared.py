"""Declared results (issue 31, item 4): every field of a `Projection` is a declared dataclass
field, none is attached after construction and no caller probes for one; the output columns
are declared once (`projection.COLUMNS`), and the faceted gap `facet_gap` is one of them."""
from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import numpy as np
import polars as pl
import pytest
import trimesh

from diffsurf_cli import DiffuseSurface, FacetSurface, build_surface, contact
from diffsurf_cli.io.contactors import RESULT_NAMES
from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.projection import COLUMNS, Projection
from diffsurf_cli.targets import read_surface
from samples import CYLINDER, PLATE_CSV, run

PACKAGE = Path(__file__).resolve().parent.parent / "diffsurf_cli"
FIELDS = {f.name for f in dataclasses.fields(Projection)}


def _sphere():
    mesh = trimesh.creation.icosphere(3)
    nodes, faces = np.asarray(mesh.vertices), [np.asarray(mesh.faces)]
    points = np.random.default_rng(5).uniform(-1.3, 1.3, (400, 3))
    return nodes, faces, points


def _undeclared(res) -> set:
    return set(vars(res)) - FIELDS


# -- declared fields ---------------------------------------------------------------------------
def test_every_surface_answers_with_declared_fields_only():
    """A result's attributes are its dataclass fields, on every surface and every path (with
    a pairing kept, with a frozen pairing, the contact element's); what a surface answers
    besides is there (not None), what it does not answer is None."""
    nodes, faces, points = _sphere()
    diffuse = DiffuseSurface(nodes, faces)
    facets = FacetSurface(nodes, faces)
    patched = PatchedSurface(nodes, faces)
    kept = diffuse.project(points, keep_patch=True)
    answers = {
        "diffuse": diffuse.project(points), "diffuse kept": kept,
        "diffuse frozen": diffuse.project_with(points, kept.patch),
        "facets": facets.project(points),
        "facets frozen": facets.project_with(points, facets.project(points).facet),
        "patched": patched.project(points), "patched moved": patched.moved(nodes).project(points),
    }
    for surface in (diffuse, facets, patched):
        answers[f"{type(surface).__name__} element"] = contact(surface, points).projection
    for name, res in answers.items():
        assert not _undeclared(res), (name, _undeclared(res))
    assert kept.alpha is not None and kept.alpha.shape == (len(points), diffuse.nterms)
    assert answers["diffuse"].alpha is None and answers["diffuse"].facet_gap is None
    for name in ("facets", "facets frozen"):
        res = answers[name]
        assert res.facet is not None and res.param is not None and res.source is None
        assert res.facet_gap is res.gap  # the facets' own gap is their gap
    res = answers["patched"]
    for field in ("source", "facet", "facet_gap", "facet_normal", "cell", "cell_param"):
        assert getattr(res, field) is not None, field
    assert res.alpha is None and res.param is None


def test_no_caller_probes_a_result_or_a_surface():
    """No getattr/hasattr in the package names a result's field, or a surface attribute
    that only some surfaces had (`facets`, `surfaces`, `node_spacing`): fields are declared,
    `facet_surface()` and `node_spacing` are every surface's."""
    probed = FIELDS | {"facets", "surfaces", "node_spacing", "facet_surface"}
    found = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                    and node.func.id in ("getattr", "hasattr") and len(node.args) >= 2
                    and isinstance(node.args[1], ast.Constant)
                    and node.args[1].value in probed):
                found.append(f"{path.relative_to(PACKAGE)}:{node.lineno}")
    assert not found, found


def test_one_name_for_the_facets_of_every_surface():
    """`facet_surface()` is a FacetSurface on every surface (a FacetSurface: itself), and
    `node_spacing` the same spacing as the facets'."""
    nodes, faces, _ = _sphere()
    facets = FacetSurface(nodes, faces)
    patched = PatchedSurface(nodes, faces)
    diffuse = DiffuseSurface(nodes, faces)
    assert facets.facet_surface() is facets
    for surface in (patched, patched.moved(nodes * 1.1), diffuse):
        own = surface.facet_surface()
        assert isinstance(own, FacetSurface)
        assert np.array_equal(own.node_spacing, surface.node_spacing)
    assert not hasattr(patched, "facets")  # the int table of corners is `corners` there
    assert np.array_equal(patched.corners, facets.facets)


# -- the declared columns ----------------------------------------------------------------------
def test_columns_follow_the_declaration():
    """`Projection.columns` is `COLUMNS` in order, less the fields a result does not hold,
    and the names refused as input columns are the declared ones (and the mesh vectors)."""
    nodes, faces, points = _sphere()
    names = [c.name for c in COLUMNS]
    patched = PatchedSurface(nodes, faces).project(points).columns()
    assert list(patched) == names
    assert list(FacetSurface(nodes, faces).project(points).columns()) == [
        n for n in names if n != "terms"]
    assert list(DiffuseSurface(nodes, faces).project(points).columns()) == [
        n for n in names if n != "facet_gap"]
    assert set(names) - {"x", "y", "z"} <= set(RESULT_NAMES)
    assert {"normal", "proximal_point"} <= set(RESULT_NAMES)


@pytest.mark.parametrize("method", ["diffuse", "facet"])
def test_cli_writes_the_facets_gap(tmp_path, method):
    """`diffsurf project` writes facet_gap, last, in every output (CSV, Parquet, a mesh): the
    gap of the target's facets, those of a FacetSurface on the same points (--method facet:
    the gap itself)."""
    _, nodes, faces = read_surface(CYLINDER)
    points = pl.read_csv(PLATE_CSV)
    xyz = points.select("x", "y", "z").to_numpy()
    want = FacetSurface(nodes, [f[:, :4] if f.shape[1] in (4, 8, 9) else f[:, :3]
                                for f in faces]).project(xyz).gap
    for name in ("out.parquet", "out.csv", "out.vtu"):
        out = tmp_path / f"{method}-{name}"
        r = run("project", CYLINDER, PLATE_CSV, "--method", method, "-o", out)
        assert r.exit_code == 0, r.output
        if name.endswith(".vtu"):
            import meshio

            got = np.asarray(meshio.read(out).point_data["facet_gap"])
        else:
            table = pl.read_parquet(out) if name.endswith(".parquet") else pl.read_csv(out)
            assert table.columns[-1] == "facet_gap"
            got = table["facet_gap"].to_numpy()
            if method == "facet":
                assert np.array_equal(got, table["gap"].to_numpy(), equal_nan=True)
        np.testing.assert_array_equal(got, want)


def test_facets_gap_of_the_default_surface_is_the_facets():
    """On the default surface (patches and guard), facet_gap is the facets' own answer
    whatever answered: a FacetSurface's gap on the same points, bit for bit."""
    nodes, faces, points = _sphere()
    res = build_surface(nodes, faces).project(points)
    np.testing.assert_array_equal(res.facet_gap, FacetSurface(nodes, faces).project(points).gap)
