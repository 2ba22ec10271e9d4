"""The contact element through the command line: R and K written by `diffsurf project` are the
gradient and Hessian of Σ ε g²/2 with respect to every DOF of the INPUT FILES.

Run once with --penalty/--residual/--tangent/--save-pairs, then move every coordinate of the
contactor CSV and of the target mesh (written back with meshio, gmsh22) by ±h d and re-run with
--pairs (the frozen pairing); compare central differences of Σ ε g²/2 (from the output CSV's
gaps of the rows with status penetration) with R·d, and of R with K d. DOFs: contactors first
in input order, then the target file's points in file order, dof = 3*node + component.
"""
from __future__ import annotations

import os

import meshio
import numpy as np
import pytest
import scipy.io
from click.testing import CliRunner

from diffsurf_cli.cli import main

from conftest import CYLINDER
from conftest import PLATE_CSV as PLATE
EPS_PENALTY = 1000.0
H = 1e-5  # mm: the node spacing is 2.5 mm along z and ~2 mm around the cylinder


def _plate_subset():
    """Plate nodes x in [28, 37] on the rows z = 1.25 and 3.75: 10 penetrate, 4 do not.

    (Not the rows z = 0, 2.5, 5: they lie exactly in the planes of the cylinder's facet edges,
    where a contactor's closest point on its frozen facet is on the facet's boundary with an
    inactive constraint: the node-to-facet gap is C¹ but not C² there, so K is one-sided.)
    """
    data = np.genfromtxt(PLATE, delimiter=",", names=True)
    keep = (data["x"] >= 28) & (data["x"] <= 37) & np.isin(data["z"], [1.25, 3.75])
    ids = data["id"][keep].astype(int)
    xyz = np.column_stack([data["x"][keep], data["y"][keep], data["z"][keep]])
    return ids, xyz


def _write_csv(path, ids, xyz):
    with open(path, "w") as fh:
        fh.write("id,x,y,z\n")
        for i, p in zip(ids, xyz):
            fh.write(f"{int(i)},{float(p[0])!r},{float(p[1])!r},{float(p[2])!r}\n")


def _write_target(path, mesh, points):
    moved = meshio.Mesh(points, mesh.cells, cell_data=mesh.cell_data, field_data=mesh.field_data)
    meshio.write(path, moved, file_format="gmsh22", binary=False)


def _read_out(path):
    """Gaps and status words of the output CSV, in row order."""
    with open(path) as fh:
        header = fh.readline().strip().split(",")
        rows = [line.strip().split(",") for line in fh if line.strip()]
    gi, si = header.index("gap"), header.index("status")
    gap = np.array([float(r[gi]) for r in rows])
    status = np.array([r[si] for r in rows])
    return gap, status


def _energy(path, penalty):
    gap, status = _read_out(path)
    closed = status == "penetration"
    return 0.5 * penalty * float(np.sum(gap[closed] ** 2)), status


def _run(args):
    runner = CliRunner()
    result = runner.invoke(main, ["-q", "project", *args], catch_exceptions=False)
    return result


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cli_element")
    mesh = meshio.read(CYLINDER)
    ids, xyz = _plate_subset()
    return tmp, mesh, ids, xyz


@pytest.mark.parametrize("method", ["diffuse", "facet"])
def test_cli_residual_tangent_are_derivatives(scene, method):
    tmp, mesh, ids, xyz = scene
    d_ = tmp / method
    d_.mkdir()
    nc, nt = len(xyz), len(mesh.points)
    target = str(d_ / "target.msh")
    points = str(d_ / "points.csv")
    _write_target(target, mesh, mesh.points)
    _write_csv(points, ids, xyz)
    R_path, K_path, P_path, out = (str(d_ / n) for n in ("R.mtx", "K.mtx", "P.npz", "out.csv"))
    res = _run([target, points, "--method", method, "--penalty", str(EPS_PENALTY),
                "--residual", R_path, "--tangent", K_path, "--save-pairs", P_path, "-o", out])
    assert res.exit_code == 0, res.output
    E0, status0 = _energy(out, EPS_PENALTY)
    assert (status0 == "penetration").sum() >= 8 and (status0 == "open").sum() >= 2, status0
    R = np.asarray(scipy.io.mmread(R_path)).ravel()
    K = scipy.io.mmread(K_path).tocsr()
    size = 3 * (nc + nt)
    assert R.shape == (size,) and K.shape == (size, size)
    assert abs(K - K.T).max() <= 1e-12 * abs(K).max()
    # open contactors carry nothing
    for i in np.flatnonzero(status0 != "penetration"):
        assert not R[3 * i:3 * i + 3].any()

    rng = np.random.default_rng(7 if method == "diffuse" else 8)
    d = rng.standard_normal(size)
    dc, dt = d[:3 * nc].reshape(nc, 3), d[3 * nc:].reshape(nt, 3)
    E, Rs = {}, {}
    for sign in (+1, -1):
        tag = "p" if sign > 0 else "m"
        tgt = str(d_ / f"target_{tag}.msh")
        pts = str(d_ / f"points_{tag}.csv")
        _write_target(tgt, mesh, mesh.points + sign * H * dt)
        _write_csv(pts, ids, xyz + sign * H * dc)
        r_out, o_out = str(d_ / f"R_{tag}.mtx"), str(d_ / f"out_{tag}.csv")
        res = _run([tgt, pts, "--method", method, "--penalty", str(EPS_PENALTY),
                    "--residual", r_out, "--pairs", P_path, "-o", o_out])
        assert res.exit_code == 0, res.output
        E[sign], status = _energy(o_out, EPS_PENALTY)
        assert np.array_equal(status, status0)
        Rs[sign] = np.asarray(scipy.io.mmread(r_out)).ravel()
    dE = (E[1] - E[-1]) / (2 * H)
    Rd = R @ d
    assert abs(dE - Rd) <= 1e-5 * abs(Rd), (method, dE, Rd)
    dR = (Rs[1] - Rs[-1]) / (2 * H)
    Kd = K @ d
    assert np.linalg.norm(dR - Kd) <= 1e-5 * np.linalg.norm(Kd), (
        method, np.linalg.norm(dR - Kd) / np.linalg.norm(Kd))
    # the target's DOFs matter: the contact force on the target balances the contactors'
    fc = R[:3 * nc].reshape(-1, 3).sum(0)
    ft = R[3 * nc:].reshape(-1, 3).sum(0)
    assert np.allclose(fc, -ft, atol=1e-9 * np.abs(fc).max())


@pytest.mark.parametrize("method", ["diffuse", "facet"])
def test_cli_pairs_for_other_counts_is_an_error(scene, method):
    tmp, mesh, ids, xyz = scene
    d_ = tmp / f"bad_{method}"
    d_.mkdir()
    target = str(d_ / "target.msh")
    _write_target(target, mesh, mesh.points)
    points = str(d_ / "points.csv")
    fewer = str(d_ / "fewer.csv")
    _write_csv(points, ids, xyz)
    _write_csv(fewer, ids[:5], xyz[:5])
    pairs = str(d_ / "P.npz")
    res = _run([target, points, "--method", method, "--save-pairs", pairs,
                "-o", str(d_ / "o.csv")])
    assert res.exit_code == 0, res.output
    res = _run([target, fewer, "--method", method, "--pairs", pairs, "--penalty", "10",
                "--residual", str(d_ / "R.mtx"), "-o", str(d_ / "o2.csv")])
    assert res.exit_code == 1
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert "error" in lines[0] and pairs in lines[0], lines[0]
    assert "Traceback" not in res.output
    assert not os.path.exists(d_ / "o2.csv") and not os.path.exists(d_ / "R.mtx")


def test_cli_residual_needs_penalty(scene):
    tmp, mesh, ids, xyz = scene
    d_ = tmp / "nopenalty"
    d_.mkdir()
    points = str(d_ / "points.csv")
    _write_csv(points, ids, xyz)
    for opt in ("--residual", "--tangent"):
        res = _run([CYLINDER, points, opt, str(d_ / "R.mtx"), "-o", str(d_ / "o.csv")])
        assert res.exit_code == 2, res.output
        assert "--penalty" in res.stderr
        assert not os.path.exists(d_ / "R.mtx")
