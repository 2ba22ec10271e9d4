"""diffsurf's presets against the faceted closest point and MeshLab's APSS, in one run.

For spheres, cylinders and saddles at three resolutions each, and tori (the structured
`shapes.Torus` at three resolutions, and the unstructured Gmsh mesh `sample_meshes/torus.msh`),
every method projects the same points and is measured against the exact surface:

- diffsurf, each preset of the CLI (`presets.PRESETS`);
- the faceted closest point: trimesh (`proximity.closest_point`, normal = the closest
  facet's normal, gap = (x - closest)·normal) and libigl (`igl.signed_distance`,
  pseudonormal sign; normal = the closest facet's normal), if importable;
- MeshLab's APSS (pymeshlab, if importable): the target's vertices as the point set, a
  per-vertex radius from its 16 nearest neighbours (APSS crashes without one), and the query
  points as a vertex-only proxy mesh; APSS moves each proxy vertex to its projection p, so its
  gap is |x - p| signed by (x - p)·n_exact, and its normal the vertex normal it computes.

Columns: gap RMS and max error, normal-angle RMS and max (degrees), points/s, and the points
left outside or failed (not in the errors). Throughput is the projection only, best of
`--repeat` after a warm-up: diffsurf's surface, trimesh's r-tree and APSS's radius attribute
are built beforehand; `igl.signed_distance` builds its AABB tree inside every call.

Then the speed targets of issue 5, on 200k points within ±0.05 of a unit sphere meshed with
1692 nodes (`Sphere().mesh(13)`): (a) `diffsurf project` end to end as a subprocess (CSV in,
CSV out, default preset) against APSS in-process, (b) the core `DiffuseSurface.project` at
the default preset against `igl.signed_distance`, (c) the accuracy of each. Ratios are
printed, never asserted.

    python benchmarks/compare.py [--quick] [--points N] [--repeat R]
    python benchmarks/compare.py --candidates      # the settings the presets were chosen from

Writes benchmarks/results/compare.md and compare.png (`--quick`: compare_quick.*;
`--candidates`: candidates.md).
"""
from __future__ import annotations

import argparse
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from diffsurf_cli import io as dio
from diffsurf_cli import presets
from diffsurf_cli.mls.frame import corner_faces
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.projection import OUTSIDE
from diffsurf_cli.testing.shapes import Cylinder, Saddle, Sphere, Torus

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
#: normal offsets of the query points, as a fraction of the shape's size
OFFSET = 0.05

try:
    import igl
except ImportError:  # optional (bench extra)
    igl = None
try:
    import pymeshlab
except ImportError:  # optional (bench extra)
    pymeshlab = None


@dataclass
class Case:
    family: str
    label: str        # e.g. "sphere n=8"
    shape: object     # exact surface: closest(points) -> closest, normal, signed distance
    size: float       # offsets are OFFSET * size; errors are reported in target units
    nodes: np.ndarray
    faces: np.ndarray


def gmsh_torus() -> Case | None:
    path = ROOT / "sample_meshes" / "torus.msh"
    if not path.exists():
        return None
    target = dio.read_target(str(path))
    nodes = target.points[target.nodes]
    faces = np.concatenate([np.searchsorted(target.nodes, f) for f in corner_faces(target.cells)])
    return Case("torus.msh (Gmsh)", "torus.msh (Gmsh, R=10 r=3)", Torus(10.0, 3.0), 3.0, nodes,
                faces)


def cases(quick: bool) -> list[Case]:
    table = [("sphere", Sphere(), (4, 8, 16), 1.0, "R=1"),
             ("cylinder", Cylinder(), (24, 48, 96), 1.0, "R=1"),
             ("saddle", Saddle(), (8, 16, 32), 1.0, "z=(x²-y²)/2"),
             ("torus", Torus(), (32, 64, 128), Torus().minor, "R=1 r=0.4")]
    out = []
    for family, shape, resolutions, size, what in table:
        for n in (resolutions[1:2] if quick else resolutions):
            nodes, faces = shape.mesh(n)
            out.append(Case(family, f"{family} n={n} ({what})", shape, size, nodes, faces))
    extra = gmsh_torus()
    if extra is not None:
        out.append(extra)
    return out


# -- metrics ------------------------------------------------------------------------------------
def angle_deg(a, b):
    """Angle (degrees) between rows of a and b, accurate near 0 (atan2, not arccos)."""
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=1),
                                 np.einsum("ij,ij->i", a, b)))


def rms(x):
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def metrics(gap, normal, exact, bad, rate, build=float("nan")):
    """Row of errors: gap and normal against the exact closest point; `bad` rows excluded."""
    _, n_exact, d_exact = exact
    ok = ~bad & np.isfinite(gap)
    e = np.abs(gap[ok] - d_exact[ok])
    row = dict(gap_rms=rms(e), gap_max=float(e.max()) if len(e) else np.nan, rate=rate,
               bad=int((~ok).sum()), build=build)
    if normal is None:
        row.update(normal_rms=np.nan, normal_max=np.nan)
    else:
        a = angle_deg(normal[ok], n_exact[ok])
        row.update(normal_rms=rms(a), normal_max=float(a.max()) if len(a) else np.nan)
    return row


def best_time(fn, repeat, warmup=None):
    if warmup is not None:
        warmup()
    best, out = np.inf, None
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - start)
    return best, out


# -- methods --------------------------------------------------------------------------------
def run_diffsurf(case, points, exact, engine_options, repeat):
    start = time.perf_counter()
    surface = DiffuseSurface(case.nodes, [case.faces], **engine_options)
    build = time.perf_counter() - start
    t, result = best_time(lambda: surface.project(points), repeat,
                          warmup=lambda: surface.project(points[:64]))
    return metrics(result.gap, result.normal, exact, result.status >= OUTSIDE, len(points) / t,
                   build)


def run_trimesh(case, points, exact, repeat):
    start = time.perf_counter()
    mesh = trimesh.Trimesh(case.nodes, case.faces, process=False)
    _ = mesh.triangles_tree  # the r-tree closest_point uses; built once, cached
    build = time.perf_counter() - start
    t, (cp, _, tri) = best_time(lambda: trimesh.proximity.closest_point(mesh, points), repeat)
    fn = mesh.face_normals[tri]
    gap = np.einsum("ij,ij->i", points - cp, fn)
    return metrics(gap, fn, exact, np.zeros(len(points), bool), len(points) / t, build)


def run_igl(case, points, exact, repeat):
    v, f = np.ascontiguousarray(case.nodes), np.ascontiguousarray(case.faces, dtype=np.int64)
    kind = igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_PSEUDONORMAL
    t, (s, tri, _, _) = best_time(lambda: igl.signed_distance(points, v, f, sign_type=kind),
                                  repeat)
    a, b, c = (v[f[tri, i]] for i in range(3))
    fn = np.cross(b - a, c - a)
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    return metrics(np.asarray(s), fn, exact, np.zeros(len(points), bool), len(points) / t)


def apss_project(nodes, faces, points):
    """APSS projection of `points` onto the MLS surface of `nodes`.

    Returns (projected (m, 3), normals (m, 3) or None, seconds of the APSS call alone,
    seconds of everything: mesh set, radius attribute, APSS, read-back).
    """
    start = time.perf_counter()
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=nodes, face_matrix=faces))
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=points))
    ms.set_current_mesh(0)
    # APSS needs a per-vertex radius on the point set first, or it crashes
    ms.compute_custom_radius_scalar_attribute_per_vertex(nbneighbors=16)
    call = time.perf_counter()
    ms.compute_mls_projection_apss(controlmesh=0, proxymesh=1)
    call = time.perf_counter() - call
    ms.set_current_mesh(1)
    mesh = ms.current_mesh()
    projected = mesh.vertex_matrix()
    normals = mesh.vertex_normal_matrix()
    total = time.perf_counter() - start
    length = np.linalg.norm(normals, axis=1) if normals.shape == projected.shape else None
    if length is None or not np.all(np.abs(length - 1) < 1e-6):
        normals = None  # APSS did not give unit normals: no normal metrics
    return projected, normals, call, total


def apss_gap(points, projected, exact_normal):
    d = points - projected
    return np.linalg.norm(d, axis=1) * np.sign(np.einsum("ij,ij->i", d, exact_normal))


def run_apss(case, points, exact, repeat):
    best, out = np.inf, None
    apss_project(case.nodes, case.faces, points[:64])  # warm-up
    for _ in range(repeat):  # each call moves its proxy vertices: a fresh mesh set per repeat
        out = apss_project(case.nodes, case.faces, points)
        best = min(best, out[2])
    projected, normals, _, _ = out
    gap = apss_gap(points, projected, exact[1])
    bad = ~np.all(np.isfinite(projected), axis=1)
    return metrics(gap, normals, exact, bad, len(points) / best)


def methods():
    out = [(f"diffsurf {name}", lambda c, p, e, r, o=o: run_diffsurf(c, p, e, o, r))
           for name, o in presets.PRESETS.items()]
    out.append(("facets (trimesh)", run_trimesh))
    if igl is not None:
        out.append(("facets (libigl)", run_igl))
    if pymeshlab is not None:
        out.append(("MeshLab APSS", run_apss))
    return out


# -- report ---------------------------------------------------------------------------------
def fmt(v, kind="e"):
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "n/a"
    if kind == "rate":
        return f"{v:,.0f}"
    return f"{v:.2e}"


def table(rows, with_settings=False) -> list[str]:
    head = ["shape", "nodes", "method"] + (["settings"] if with_settings else []) + [
        "gap RMS", "gap max", "normal RMS (°)", "normal max (°)", "points/s",
        "outside+failed"]
    lines = ["| " + " | ".join(head) + " |",
             "|" + "|".join("---" if i < 3 + with_settings else "---:"
                            for i in range(len(head))) + "|"]
    for r in rows:
        cells = [r["case"], str(r["nodes"]), r["method"]]
        if with_settings:
            cells.append(r["settings"])
        cells += [fmt(r["gap_rms"]), fmt(r["gap_max"]), fmt(r["normal_rms"]),
                  fmt(r["normal_max"]), fmt(r["rate"], "rate"), str(r["bad"])]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def environment() -> str:
    import numpy

    from diffsurf_cli.threads import max_threads

    parts = [f"python {platform.python_version()}", f"numpy {numpy.__version__}",
             f"diffsurf's compiled engine on {max_threads()} OpenMP threads",
             f"{os.cpu_count()} CPUs ({platform.machine()})"]
    if igl is not None:
        parts.append("libigl " + _version("libigl"))
    if pymeshlab is not None:
        parts.append("pymeshlab " + _version("pymeshlab"))
    parts.append("trimesh " + trimesh.__version__)
    return ", ".join(parts)


def _version(dist):
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return "?"


def plot(rows, path):
    try:
        from matplotlib.figure import Figure
    except ImportError:
        print("matplotlib not installed: no PNG (pip install 'diffsurf[plot]')", file=sys.stderr)
        return False
    families = list(dict.fromkeys(r["family"] for r in rows))
    names = list(dict.fromkeys(r["method"] for r in rows))
    markers = dict(zip(names, "os^DvP*X"))
    ncols = min(3, len(families) + 1)
    nrows = -(-(len(families) + 1) // ncols)  # one more panel for the legend
    fig = Figure(figsize=(5.0 * ncols, 4.2 * nrows), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for ax, family in zip(axes, families):
        for name in names:
            sel = [r for r in rows if r["family"] == family and r["method"] == name
                   and np.isfinite(r["gap_rms"]) and r["gap_rms"] > 0]
            if sel:
                ax.plot([r["rate"] for r in sel], [r["gap_rms"] for r in sel],
                        marker=markers[name], linestyle=":", label=name)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(family)
        ax.set_xlabel("points/s")
        ax.grid(True, which="both", alpha=0.3)
        ax.set_ylabel("gap RMS error (target units)")
    handles, labels = axes[0].get_legend_handles_labels()
    for ax in axes[len(families):]:
        ax.axis("off")
    axes[len(families)].legend(handles, labels, loc="center")
    fig.suptitle("gap error against throughput (one marker per mesh; finer meshes lower)")
    dio.write_figure(str(path), fig, overwrite=True)
    return True


# -- speed targets ------------------------------------------------------------------------------
#: MeshLab APSS as a user's script run end to end, as `diffsurf project` is: interpreter start,
#: imports, target and CSV read (np.loadtxt), APSS, CSV write (np.savetxt, 6 columns).
APSS_SCRIPT = """
import sys
import numpy as np
import pymeshlab
target, points_csv, out_csv = sys.argv[1:4]
ms = pymeshlab.MeshSet()
ms.load_new_mesh(target)
ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.loadtxt(points_csv, delimiter=",", skiprows=1)))
ms.set_current_mesh(0)
ms.compute_custom_radius_scalar_attribute_per_vertex(nbneighbors=16)
ms.compute_mls_projection_apss(controlmesh=0, proxymesh=1)
ms.set_current_mesh(1)
m = ms.current_mesh()
np.savetxt(out_csv, np.hstack([m.vertex_matrix(), m.vertex_normal_matrix()]), delimiter=",",
           fmt="%.17g", header="px,py,pz,nx,ny,nz", comments="")
"""


def speed_targets(n_points, repeat) -> list[str]:
    """Issue 5's targets (a)-(c), on `n_points` points within ±0.05 of a 1692-node sphere."""
    sphere = Sphere(radius=1.0)
    nodes, faces = sphere.mesh(13)
    rng = np.random.default_rng(5)
    u = rng.standard_normal((n_points, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    points = u * rng.uniform(0.95, 1.05, n_points)[:, None]
    exact = sphere.closest(points)
    out = ["## Speed targets\n", f"{n_points:,} points at radius 1 ± 0.05 around a unit sphere "
           f"meshed with {len(nodes)} nodes (`Sphere().mesh(13)`). Ratios above 1 favour "
           f"diffsurf.\n"]
    acc = []

    # APSS in-process. Its call is bimodal here: 0.19 s in a fresh process that does nothing
    # else (benchmarks/apss_alone.py, every run), but 0.58-0.60 s in some runs of this
    # benchmark, whether measured before or after the CLI; the cause is not found. The README
    # quotes the fast figure.
    apss = None
    if pymeshlab is not None:
        calls, totals, res = [], [], None
        for _ in range(max(repeat, 1)):
            res = apss_project(nodes, faces, points)
            calls.append(res[2])
            totals.append(res[3])
        apss = (min(calls), min(totals), res)

    # (a) the CLI end to end, as a user runs it
    with tempfile.TemporaryDirectory() as tmp:
        target = os.path.join(tmp, "sphere.vtu")
        dio.write_mesh(target, nodes, [faces], {})
        csv_in = os.path.join(tmp, "points.csv")
        np.savetxt(csv_in, points, delimiter=",", header="x,y,z", comments="", fmt="%.17g")
        csv_out = os.path.join(tmp, "out.csv")
        # the installed entry point, as a user runs it (else the module, same code)
        exe = shutil.which("diffsurf")
        cmd = ([exe] if exe else [sys.executable, "-m", "diffsurf_cli.cli"]) + [
            "-q", "project", target, csv_in, "-o", csv_out, "--overwrite"]
        times = []
        for _ in range(max(repeat, 2)):
            start = time.perf_counter()
            subprocess.run(cmd, check=True)
            times.append(time.perf_counter() - start)
        cli = min(times[1:])
        data = np.genfromtxt(csv_out, delimiter=",", names=True, dtype=None, encoding="utf-8")
        gap = np.asarray(data["gap"], float)
        normal = np.column_stack([data["nx"], data["ny"], data["nz"]]).astype(float)
        bad = np.isin(data["status"], ["outside", "failed"])
        acc.append(("diffsurf project (CLI, default)", metrics(gap, normal, exact, bad,
                                                               n_points / cli)))
    lines = [f"(a) `diffsurf project` end to end (subprocess: start-up, CSV read, projection, "
             f"CSV write): best {cli:.3f} s of runs 2-{len(times)} ({n_points / cli:,.0f} "
             f"points/s); run 1 {times[0]:.3f} s."]
    if pymeshlab is not None:
        call, total, res = apss
        acc.append(("MeshLab APSS (in-process)", metrics(apss_gap(points, res[0], exact[1]),
                                                         res[1], exact,
                                                         ~np.all(np.isfinite(res[0]), axis=1),
                                                         n_points / call)))
        lines += [f"    MeshLab APSS in-process: the projection call {call:.3f} s; with its "
                  f"set-up (mesh set, radius attribute, read-back) {total:.3f} s.",
                  f"    ratio APSS call / diffsurf CLI = **{call / cli:.2f}**; "
                  f"APSS with set-up / diffsurf CLI = **{total / cli:.2f}** (target ≥ 1)."]
        with tempfile.TemporaryDirectory() as tmp:  # APSS as a script, end to end
            target = os.path.join(tmp, "sphere.obj")
            trimesh.Trimesh(nodes, faces, process=False).export(target)
            csv_in = os.path.join(tmp, "points.csv")
            np.savetxt(csv_in, points, delimiter=",", header="x,y,z", comments="", fmt="%.17g")
            cmd = [sys.executable, "-c", APSS_SCRIPT, target, csv_in, os.path.join(tmp, "o.csv")]
            script = []
            for _ in range(max(repeat, 2)):
                start = time.perf_counter()
                subprocess.run(cmd, check=True)
                script.append(time.perf_counter() - start)
            start = time.perf_counter()
            subprocess.run([sys.executable, "-c", "import numpy, click, meshio"], check=True)
            imports = time.perf_counter() - start
        lines += [f"    MeshLab APSS as a Python script end to end (start-up, np.loadtxt, APSS, "
                  f"np.savetxt): best {min(script[1:]):.3f} s; ratio APSS script / diffsurf CLI "
                  f"= **{min(script[1:]) / cli:.2f}**.",
                  f"    for scale: a Python process that only imports numpy, click and meshio "
                  f"takes {imports:.3f} s."]
    else:
        lines.append("    pymeshlab not installed: no APSS comparison.")

    # (b) the core against libigl's faceted signed distance
    surface = DiffuseSurface(nodes, [faces], **presets.PRESETS["default"])
    t_core, result = best_time(lambda: surface.project(points), max(repeat, 1),
                               warmup=lambda: surface.project(points[:64]))
    acc.append(("DiffuseSurface.project (core, default)",
                metrics(result.gap, result.normal, exact, result.status >= OUTSIDE,
                        n_points / t_core)))
    lines.append(f"(b) core `DiffuseSurface.project`, default preset: {t_core:.3f} s "
                 f"({n_points / t_core:,.0f} points/s).")
    if igl is not None:
        kind = igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_PSEUDONORMAL
        f64 = np.ascontiguousarray(faces, dtype=np.int64)
        t_igl, (s, tri, _, _) = best_time(
            lambda: igl.signed_distance(points, nodes, f64, sign_type=kind), max(repeat, 1))
        a, b, c = (nodes[f64[tri, i]] for i in range(3))
        fn = np.cross(b - a, c - a)
        fn /= np.linalg.norm(fn, axis=1, keepdims=True)
        acc.append(("igl.signed_distance (facets)",
                    metrics(np.asarray(s), fn, exact, np.zeros(n_points, bool), n_points / t_igl)))
        # libigl's default sign (the generalised winding number) is the call as written;
        # the pseudonormal sign is its fastest: both are reported, the target is judged on each
        t_default, _ = best_time(lambda: igl.signed_distance(points, nodes, f64),
                                 max(repeat, 1))
        lines += [f"    `igl.signed_distance` (pseudonormal sign, its fastest; AABB built in the "
                  f"call): {t_igl:.3f} s ({n_points / t_igl:,.0f} points/s).",
                  f"    throughput ratio diffsurf core / libigl pseudonormal = "
                  f"**{t_igl / t_core:.2f}** (target ≥ 0.5).",
                  f"    `igl.signed_distance` with its default arguments (winding-number "
                  f"sign): {t_default:.3f} s ({n_points / t_default:,.0f} points/s); ratio "
                  f"**{t_default / t_core:.2f}**."]
    else:
        lines.append("    libigl not installed: no comparison.")
    lines += ["", "(c) accuracy against the exact sphere:", "",
              "| method | gap RMS | gap max | normal RMS (°) | normal max (°) | points/s | "
              "outside+failed |", "|---|---:|---:|---:|---:|---:|---:|"]
    for name, m in acc:
        lines.append(f"| {name} | {fmt(m['gap_rms'])} | {fmt(m['gap_max'])} | "
                     f"{fmt(m['normal_rms'])} | {fmt(m['normal_max'])} | "
                     f"{fmt(m['rate'], 'rate')} | {m['bad']} |")
    return out + lines


# -- candidates the presets were chosen from --------------------------------------------------
CANDIDATES = {
    "default": {},
    "knn k=8": dict(support="knn", k=8),
    "knn k=10": dict(support="knn", k=10),
    "knn k=12": dict(support="knn", k=12),
    "radius 1.6": dict(radius=1.6),
    "radius 1.75": dict(radius=1.75),
    "cubic radius 3": dict(basis="cubic", radius=3.0),
    "recentre": dict(recentre=True),
    "gauss radius 2.5": dict(weight="gauss", radius=2.5),
    "gauss radius 3": dict(weight="gauss", radius=3.0),
}


def run_candidates(args):
    rows = []
    for case in cases(args.quick):
        points = case.shape.sample_near(args.points, OFFSET * case.size,
                                        np.random.default_rng(0))
        exact = case.shape.closest(points)
        for name, o in CANDIDATES.items():
            engine = dict(presets.DEFAULTS, **o)
            r = run_diffsurf(case, points, exact, engine, args.repeat)
            rows.append(dict(r, family=case.family, case=case.label, nodes=len(case.nodes),
                             method=name, settings=presets.summary(engine)))
        print(f"  {case.label}: done", file=sys.stderr)
    lines = ["# Preset candidates", "", f"{environment()}", "",
             f"{args.points} points per mesh within ±{OFFSET:.0%} of the shape's size "
             f"(sphere, cylinder, saddle: 1; tori: the tube radius); errors in target units; "
             f"throughput: best of {args.repeat}.", ""] + table(rows, with_settings=True)
    text = "\n".join(lines) + "\n"
    print(text)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / ("candidates_quick.md" if args.quick else "candidates.md")).write_text(text)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="one resolution per shape, fewer points (a smoke run)")
    parser.add_argument("--points", type=int, default=None,
                        help="query points per mesh [default 20000; --quick 2000]")
    parser.add_argument("--repeat", type=int, default=3, help="timing repeats (best kept)")
    parser.add_argument("--target-points", type=int, default=None,
                        help="points of the speed targets [default 200000; --quick 20000]")
    parser.add_argument("--candidates", action="store_true",
                        help="measure the candidate settings the presets were chosen from")
    args = parser.parse_args(argv)
    args.points = args.points or (2000 if args.quick else 20000)
    if args.candidates:
        return run_candidates(args)
    target_points = args.target_points or (20_000 if args.quick else 200_000)

    rows = []
    for case in cases(args.quick):
        points = case.shape.sample_near(args.points, OFFSET * case.size,
                                        np.random.default_rng(0))
        exact = case.shape.closest(points)
        for name, run in methods():
            r = run(case, points, exact, args.repeat)
            rows.append(dict(r, family=case.family, case=case.label, nodes=len(case.nodes),
                             method=name))
        print(f"  {case.label}: done", file=sys.stderr)
    missing = [name for name, mod in (("libigl", igl), ("pymeshlab", pymeshlab)) if mod is None]
    lines = ["# diffsurf presets against faceted projection and MeshLab APSS", "",
             f"`python benchmarks/compare.py{' --quick' if args.quick else ''}`; "
             f"{environment()}.", "",
             f"{args.points} points per mesh, offset along the exact normal by up to "
             f"±{OFFSET:.0%} of the shape's size (sphere, cylinder, saddle: 1; tori: the tube "
             f"radius); errors in target units against the exact surface, over the points "
             f"each method projected (`outside+failed` are left out). Throughput: projection "
             f"only, best of {args.repeat} after a warm-up (surface, r-tree and APSS radii "
             f"built beforehand; `igl.signed_distance` builds its tree in the call). The "
             f"saddle is quadratic: the quadratic basis reproduces it to round-off. The "
             f"presets: {presets.describe_presets()}", ""]
    if missing:
        lines += [f"Not installed, rows skipped: {', '.join(missing)} "
                  f"(`pip install -e '.[bench]'`).", ""]
    lines += table(rows) + [""] + speed_targets(target_points, args.repeat)
    text = "\n".join(lines) + "\n"
    print(text)
    RESULTS.mkdir(parents=True, exist_ok=True)
    stem = "compare_quick" if args.quick else "compare"
    (RESULTS / f"{stem}.md").write_text(text)
    if plot(rows, RESULTS / f"{stem}.png"):
        print(f"wrote {RESULTS / (stem + '.md')} and {RESULTS / (stem + '.png')}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
