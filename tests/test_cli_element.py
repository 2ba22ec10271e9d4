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
from samples import CYLINDER
from samples import PLATE_CSV as PLATE

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


def test_cli_gauss_newton_tangent(scene):
    """--gauss-newton: K.mtx is Σ ε N Nᵀ of the elements written by --elements in the same
    run (the full K minus Σ ε g M); refused without --tangent."""
    tmp, mesh, ids, xyz = scene
    d_ = tmp / "gauss_newton"
    d_.mkdir()
    points = str(d_ / "points.csv")
    _write_csv(points, ids, xyz)
    K_path, E_path, out = (str(d_ / n) for n in ("K.mtx", "E.npz", "o.csv"))
    res = _run([CYLINDER, points, "--rigid-target", "--penalty", str(EPS_PENALTY), "--tangent",
                K_path, "--gauss-newton", "--elements", E_path, "-o", out])
    assert res.exit_code == 0, res.output
    K = scipy.io.mmread(K_path).toarray()
    with np.load(E_path) as z:
        contactor, N = z["contactor"], z["N"]
    assert len(contactor) >= 8
    ref = np.zeros_like(K)
    for c, n in zip(contactor, N):
        ref[3 * c:3 * c + 3, 3 * c:3 * c + 3] += EPS_PENALTY * np.outer(n, n)
    np.testing.assert_allclose(K, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    res = _run([CYLINDER, points, "--penalty", "1", "--gauss-newton", "-o", out])
    assert res.exit_code == 2 and "--tangent" in res.stderr, res.output


@pytest.mark.parametrize("method", ["diffuse", "facet"])
def test_cli_rigid_target_residual_tangent_are_derivatives(scene, method):
    """--rigid-target: R and K have the contactors' 3 m DOFs only and are the gradient and
    Hessian of Σ ε g²/2 with respect to the contactor coordinates (the target stays put)."""
    tmp, mesh, ids, xyz = scene
    d_ = tmp / f"rigid_{method}"
    d_.mkdir()
    nc = len(xyz)
    points = str(d_ / "points.csv")
    _write_csv(points, ids, xyz)
    R_path, K_path, out = (str(d_ / n) for n in ("R.mtx", "K.mtx", "out.csv"))
    # facet: the closest facet is frozen (as a node-to-facet element does); diffuse: no pairing
    keep = ["--save-pairs", str(d_ / "P.npz")] if method == "facet" else []
    again = ["--pairs", str(d_ / "P.npz")] if method == "facet" else []
    res = _run([CYLINDER, points, "--method", method, "--rigid-target", "--penalty",
                str(EPS_PENALTY), "--residual", R_path, "--tangent", K_path, "-o", out, *keep])
    assert res.exit_code == 0, res.output
    E0, status0 = _energy(out, EPS_PENALTY)
    assert (status0 == "penetration").sum() >= 8 and (status0 == "open").sum() >= 2, status0
    R = np.asarray(scipy.io.mmread(R_path)).ravel()
    K = scipy.io.mmread(K_path).tocsr()
    assert R.shape == (3 * nc,) and K.shape == (3 * nc, 3 * nc)
    assert abs(K - K.T).max() <= 1e-12 * abs(K).max()
    # each contactor's 3x3 block only: no coupling between contactors
    blocks = np.arange(3 * nc) // 3
    Kc = K.tocoo()
    assert np.array_equal(blocks[Kc.row], blocks[Kc.col])
    for i in np.flatnonzero(status0 != "penetration"):
        assert not R[3 * i:3 * i + 3].any()
    rng = np.random.default_rng(17 if method == "diffuse" else 18)
    d = rng.standard_normal(3 * nc)
    E, Rs = {}, {}
    for sign in (+1, -1):
        tag = "p" if sign > 0 else "m"
        pts = str(d_ / f"points_{tag}.csv")
        _write_csv(pts, ids, xyz + sign * H * d.reshape(nc, 3))
        r_out, o_out = str(d_ / f"R_{tag}.mtx"), str(d_ / f"out_{tag}.csv")
        res = _run([CYLINDER, pts, "--method", method, "--rigid-target", "--penalty",
                    str(EPS_PENALTY), "--residual", r_out, "-o", o_out, *again])
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


@pytest.mark.parametrize("rigid", [False, True], ids=["full", "rigid"])
@pytest.mark.parametrize("method", ["diffuse", "facet"])
def test_cli_elements_npz(scene, method, rigid):
    """--elements E.npz: the element arrays, consistent with the CSV written in the same run
    (gaps, statuses) and with R.mtx / K.mtx assembled from them by the documented numbering."""
    tmp, mesh, ids, xyz = scene
    d_ = tmp / f"npz_{method}_{rigid}"
    d_.mkdir()
    nc, nt = len(xyz), len(mesh.points)
    points = str(d_ / "points.csv")
    # two rows that get no element for other reasons than being open: a NaN (failed) and a
    # point far beyond the cylinder's end (outside for the diffuse surface, open for facets)
    bad = np.vstack([xyz, [np.nan, 30.0, 2.5], [32.5, 30.0, 60.0]])
    _write_csv(points, np.arange(len(bad)), bad)
    nc = len(bad)
    R_path, K_path, E_path, out = (str(d_ / n) for n in ("R.mtx", "K.mtx", "E.npz", "o.csv"))
    flags = ["--rigid-target"] if rigid else []
    res = CliRunner().invoke(main, ["project", CYLINDER, points, "--method", method, *flags,
                                    "--penalty", str(EPS_PENALTY), "--residual", R_path,
                                    "--tangent", K_path, "--elements", E_path, "-o", out],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    with np.load(E_path) as z:
        E = {k: z[k] for k in z.files}  # no pickled objects: loads with allow_pickle=False
    assert str(E["method"]) == method and bool(E["rigid_target"]) == rigid
    assert list(E["status_names"]) == ["open", "contact", "penetration", "outside", "failed"]
    gap_csv, status_csv = _read_out(out)
    names = E["status_names"][E["status"]]
    assert list(names) == list(status_csv)
    assert names[-2] == "failed" and E["reason_names"][E["reason"][-2]] == "bad-point"
    if method == "diffuse":
        assert names[-1] == "outside", names[-1]
    assert "no element:" in res.stderr and "failed (1 bad-point)" in res.stderr, res.stderr
    # one element per penetrating contactor, in order, with the CSV's gap
    np.testing.assert_array_equal(E["contactor"], np.flatnonzero(names == "penetration"))
    np.testing.assert_allclose(E["gap"], gap_csv[E["contactor"]], rtol=1e-12, atol=0)
    e, K_ = E["nodes"].shape
    if rigid:
        assert K_ == 0
    else:
        assert K_ >= (4 if method == "facet" else 6)
        valid = E["nodes"][E["nodes"] >= 0]
        assert valid.max() < nt and (E["nodes"] >= 0).any(axis=1).all()
    assert E["N"].shape == (e, 3 * (K_ + 1)) and E["M"].shape == (e, 3 * (K_ + 1), 3 * (K_ + 1))
    # padding carries exactly nothing
    pad = np.repeat(np.concatenate([np.zeros((e, 1), bool), E["nodes"] < 0], axis=1), 3, axis=1)
    assert not E["N"][pad].any() and not E["M"][pad[:, :, None] & pad[:, None, :]].any()
    # R and K from the arrays, by the numbering --help documents (an obvious loop)
    size = 3 * nc if rigid else 3 * (nc + nt)
    R_ref = np.zeros(size)
    K_ref = np.zeros((size, size))
    for c, nodes, g, N, M in zip(E["contactor"], E["nodes"], E["gap"], E["N"], E["M"]):
        dof = [3 * c + k for k in range(3)]
        for node in nodes:
            dof += [3 * (nc + node) + k if node >= 0 else -1 for k in range(3)]
        for a, da in enumerate(dof):
            if da < 0:
                continue
            R_ref[da] += EPS_PENALTY * g * N[a]
            for b, db in enumerate(dof):
                if db >= 0:
                    K_ref[da, db] += EPS_PENALTY * (g * M[a, b] + N[a] * N[b])
    R = np.asarray(scipy.io.mmread(R_path)).ravel()
    K = scipy.io.mmread(K_path).toarray()
    np.testing.assert_allclose(R, R_ref, rtol=0, atol=1e-12 * np.abs(R_ref).max())
    np.testing.assert_allclose(K, K_ref, rtol=0, atol=1e-12 * np.abs(K_ref).max())


def test_cli_rigid_target_usage(scene):
    tmp, mesh, ids, xyz = scene
    d_ = tmp / "rigid_usage"
    d_.mkdir()
    points = str(d_ / "points.csv")
    _write_csv(points, ids, xyz)
    # without an element output there is nothing for --rigid-target to change
    res = _run([CYLINDER, points, "--rigid-target", "-o", str(d_ / "o.csv")])
    assert res.exit_code == 2 and "--rigid-target" in res.stderr, res.stderr
    # the diffuse rigid gap has no pairing to store or reuse
    res = _run([CYLINDER, points, "--rigid-target", "--elements", str(d_ / "E.npz"),
                "--save-pairs", str(d_ / "P.npz"), "-o", str(d_ / "o.csv")])
    assert res.exit_code == 2 and "pairing" in res.stderr, res.stderr
    assert not os.path.exists(d_ / "o.csv") and not os.path.exists(d_ / "E.npz")
