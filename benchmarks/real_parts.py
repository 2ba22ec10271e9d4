"""Real parts (issue 19): diffsurf and the facets side by side on a battery of public meshes,
run through the command line as a user runs them.

The battery (`parts.py`, built on the first run or by ``--build-only``): the contact surfaces
of CalculiX's test decks, each one ``--zone``; gmsh's STEP/BREP benchmark parts meshed at about
diag/25, first order with face tags, second order with tags, as STL (no tags) and as a tetra
volume mesh; trimesh's CAD STL models. The parts are extracted from local mirrors of those
repositories into ``benchmarks/out/parts/`` (git-ignored), never committed.

Contactors, per row: ``--points`` (20,000) points uniform by area on the target's facets
(corners), offset along the facet normal by uniform(-0.02, 0.02) x the diagonal of the
target's own nodes (of the zone, for a deck). Seeded by the row's name.

References:

- gmsh parts: the signed distance to the same CAD meshed 8x finer (nodes on the CAD), and
  finer where it bends (`parts.FINE_PER_TURN`: a one-cell-wide fillet of the coarse mesh is
  narrower than 8 of the uniform reference's cells), by `FacetSurface` (pseudonormal
  signs). Its sign is checked against the coarse facets' where |reference| > 0.5% of the
  diagonal: a row whose signs agree on less than 95% of those points
  is dropped (the surface faces inward or is not consistently oriented). Error = |g - g_ref|.
  On curved faces the fine mesh's own chordal sag is 1/64 of the coarse one's, so ratios of
  facets / diffsurf of about 64 and more mean diffsurf is at the reference's accuracy.
- STLs and decks: the facets themselves, with their vertices welded within 1e-9 of the
  diagonal (binary STLs hold the same vertex as 0 and 1e-17: left apart, they cut the surface
  into open pieces), allowing the tessellation's sag: the largest w·θ/8 over manifold edges
  whose dihedral angle θ is below 40°, w the width of either facet across the edge
  (2 area/|edge| for triangles, area/|edge| for quads). Error = max(0, |g - g_ref| - sag).

Per row, diffsurf (``diffsurf project TARGET POINTS.parquet [--zone Z] [EXTRA]``, defaults) and
the facets (the same with ``--method facet``), on the points they answer (status open, contact
or penetration):

- wrong signs: sign(g) != sign(g_ref) where |g_ref| > 1e-3 of the diagonal (and, where the
  reference is the facets, also > the sag: closer than the sag the facets' sign is not the
  surface's);
- gross: error > 1% of the diagonal;
- lost: % of points `outside` or `failed` (a target the command line refuses loses them all);
- RMS error near sharp edges and elsewhere, and the largest error, / diagonal. "Near" = the
  reference's closest point lies within one local node spacing of the target (at the nearest
  target node, mid-side nodes counting) of a sharp edge of the reference mesh (dihedral angle
  above 40°, an open boundary or a non-manifold edge);
- guard: % of points diffsurf answered with reason `guard`; facets: % it answered by the facets
  (terms 0).

Written: the markdown table on stdout and in ``benchmarks/results/real_parts.md`` (with the
command line, the date and the sources' commits), and per row the worst 20 diffsurf points
(every wrong sign up to 20, then the largest errors) in ``benchmarks/out/parts/ROW.worst.csv``.
Points and references are cached in ``benchmarks/out/parts/cache/``: a re-run costs the
diffsurf calls. On 2 cores with ``--jobs 2``, a first run takes about 7 minutes (2 building the
battery with gmsh), a re-run about 4.

A resolution study: ``--coarse N`` meshes the gmsh parts at diag/N instead of diag/25, as a
battery of its own (``benchmarks/out/parts-cN/``, its table in ``results/real_parts.cN.md``),
to tell a row that the method leaves short from one whose features are narrower than its
cells: ``--coarse 50 --parts 'gmsh.*'`` and ``--coarse 100 --parts 'gmsh.[BS]*'`` are in
``results/``.

    python benchmarks/real_parts.py [--parts GLOB] [--points N] [--jobs N] [--extra "ARGS"]
                                    [--coarse N] [--build-only] [--no-write]
"""
from __future__ import annotations

import argparse
import datetime
import fnmatch
import hashlib
import os
import shlex
import subprocess
import sys
import tempfile
import time
import zlib
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import polars as pl
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

import parts
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.io import ReadError, read_target

RESULTS = Path(__file__).resolve().parent / "results" / (
    "real_parts.md" if parts.COARSE == 25 else f"real_parts.c{parts.COARSE}.md")
CACHE = parts.OUT / "cache"
#: dihedral angle of a sharp edge (degrees), as diffsurf's default feature angle
SHARP_DEG = 40.0
#: contactors within this fraction of the diagonal of the target
BAND = 0.02
#: wrong signs count where |g_ref| exceeds this fraction of the diagonal
SIGN_FLOOR = 1e-3
#: gross errors exceed this fraction of the diagonal
GROSS = 1e-2
#: nodes closer than this fraction of the diagonal are one node of a facet reference
WELD = 1e-9
#: For the rows whose reference is the facets (STLs, decks): errors count only beyond this
#: many times the largest chordal sag anywhere on the part (`sag_allowance`), as the issue
#: measures them ("more than twice the largest chordal sag anywhere on the part").
ALLOWANCE_SAGS = 2.0
#: the dumps' count of worst points
WORST = 20
#: statuses of an answered point
ANSWERED = ("open", "contact", "penetration")
#: a gmsh row is dropped when the coarse facets' signs agree with the reference's on less than
#: this share of the points where |g_ref| > ORIENT_FLOOR of the diagonal
ORIENT_AGREE, ORIENT_FLOOR = 0.95, 5e-3
#: the criteria of issue 19
MAX_LOST_PCT, MIN_RATIO = 1.0, 5.0


class Refused(Exception):
    """The command line refused the target or the points (its last stderr line)."""


# --- the one call of diffsurf ---------------------------------------------------------------
def run_diffsurf(target, points, zone=None, *extra, threads=None) -> pl.DataFrame:
    """``diffsurf project TARGET POINTS -o OUT.parquet -q [--zone ZONE] [EXTRA...]``, as a user
    runs it; its result table (status and reason as words).

    Raises
    ------
    Refused
        The command failed; its message is the last line of its stderr.
    """
    env = dict(os.environ)
    if threads:
        env["OMP_NUM_THREADS"] = str(threads)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.parquet"
        cmd = [sys.executable, "-m", "diffsurf_cli", "project", str(target), str(points),
               "-o", str(out), "-q"]
        if zone is not None:
            cmd += ["--zone", zone]
        done = subprocess.run(cmd + list(extra), capture_output=True, text=True, env=env)
        if done.returncode != 0:
            lines = done.stderr.strip().splitlines() or [f"exit status {done.returncode}"]
            raise Refused(lines[-1])
        return pl.read_parquet(out)


# --- geometry of a faceted mesh -------------------------------------------------------------
def load_target(path: Path, zone: str | None):
    """(nodes (n, 3), facets (f, 4) corners into nodes, -1 in a triangle's 4th) of a target
    as diffsurf reads it."""
    target = read_target(str(path), zone)
    nodes = target.points[target.nodes]
    blocks = []
    for _, conn in target.cells:
        corners = 3 if conn.shape[1] in (3, 6, 7) else 4
        f = np.searchsorted(target.nodes, conn[:, :corners])
        blocks.append(np.pad(f, ((0, 0), (0, 4 - corners)), constant_values=-1))
    return nodes, np.concatenate(blocks)


def facet_list(facets: np.ndarray) -> list[np.ndarray]:
    """The (f, 4) padded facets as FacetSurface's blocks: (t, 3) triangles and (q, 4) quads."""
    tri = facets[:, 3] < 0
    return [b for b in (facets[tri, :3], facets[~tri]) if len(b)]


def diagonal(nodes: np.ndarray) -> float:
    return float(np.linalg.norm(nodes.max(axis=0) - nodes.min(axis=0)))


def area_vectors(nodes: np.ndarray, facets: np.ndarray) -> np.ndarray:
    """Area-weighted normals (right-hand rule); a quad's from its diagonals."""
    a, b, c = (nodes[facets[:, i]] for i in range(3))
    d = nodes[np.where(facets[:, 3] < 0, facets[:, 2], facets[:, 3])]
    tri = (facets[:, 3] < 0)[:, None]
    return np.where(tri, 0.5 * np.cross(b - a, c - a), 0.5 * np.cross(c - a, d - b))


def weld(nodes: np.ndarray, facets: np.ndarray, tol: float):
    """Nodes closer than `tol` made one; (nodes, facets) without the duplicates."""
    pairs = cKDTree(nodes).query_pairs(tol, output_type="ndarray")
    if not len(pairs):
        return nodes, facets
    n = len(nodes)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    first = np.zeros(label.max() + 1, dtype=np.int64)
    first[label[::-1]] = np.arange(n)[::-1]
    welded = np.where(facets >= 0, label[np.maximum(facets, 0)], -1)
    return nodes[first], welded


@dataclass
class Edges:
    """The edges of a faceted mesh: ``ends`` (e, 2) nodes; ``count`` facets per edge;
    ``angle`` the dihedral angle (radians) of edges with two facets (nan otherwise);
    ``width`` (e, 2) the width of both facets across the edge."""

    ends: np.ndarray
    count: np.ndarray
    angle: np.ndarray
    width: np.ndarray

    @property
    def sharp(self) -> np.ndarray:
        """Edges of dihedral angle above SHARP_DEG, open boundaries, non-manifold edges."""
        return (self.count != 2) | (np.nan_to_num(self.angle, nan=np.pi) > np.radians(SHARP_DEG))


def edges(nodes: np.ndarray, facets: np.ndarray) -> Edges:
    """The `Edges` of facets (f, 4) padded with -1."""
    n = len(nodes)
    kind = np.where(facets[:, 3] < 0, 3, 4)
    nxt = np.where(kind[:, None] == 3, facets[:, [1, 2, 0, 0]], facets[:, [1, 2, 3, 0]])
    real = np.arange(4)[None, :] < kind[:, None]
    a, b = facets[real], nxt[real]
    owner = np.repeat(np.arange(len(facets)), kind)
    key = np.minimum(a, b) * n + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    key, owner, a, b = key[order], owner[order], a[order], b[order]
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    count = np.diff(np.r_[start, len(key)])
    area = area_vectors(nodes, facets)
    size = np.linalg.norm(area, axis=1)
    unit = area / np.maximum(size, 1e-300)[:, None]
    length = np.linalg.norm(nodes[a] - nodes[b], axis=1)
    width = np.where(kind[owner] == 3, 2.0, 1.0) * size[owner] / np.maximum(length, 1e-300)
    two = count == 2
    f0, f1 = owner[start], owner[np.minimum(start + 1, len(key) - 1)]
    cos = np.clip(np.einsum("ij,ij->i", unit[f0], unit[f1]), -1.0, 1.0)
    angle = np.where(two, np.arccos(cos), np.nan)
    w = np.column_stack([width[start], width[np.minimum(start + 1, len(key) - 1)]])
    return Edges(np.column_stack([a[start], b[start]]), count, angle, w)


def exact_sphere(nodes: np.ndarray):
    """(centre, radius) when every node lies on one sphere to 1e-6 of its radius (an STL of
    a sphere: trimesh's unit_sphere), else None."""
    centre = 0.5 * (nodes.min(axis=0) + nodes.max(axis=0))
    r = np.linalg.norm(nodes - centre, axis=1)
    radius = float(np.median(r))
    if radius > 0 and np.max(np.abs(r - radius)) <= 1e-6 * radius and len(nodes) > 20:
        return centre, radius
    return None


def sag_allowance(e: Edges) -> float:
    """The largest chordal sag w·θ/8 over manifold edges below the sharp angle, both facets."""
    smooth = (e.count == 2) & (np.nan_to_num(e.angle, nan=np.pi) < np.radians(SHARP_DEG))
    if not smooth.any():
        return 0.0
    return float((e.width[smooth].max(axis=1) * e.angle[smooth] / 8).max())


def node_spacing(nodes: np.ndarray) -> np.ndarray:
    """Mean distance of each node to its 4 nearest (diffsurf's node spacing)."""
    k = min(5, len(nodes))
    dist, _ = cKDTree(nodes).query(nodes, k=k)
    return dist[:, 1:].mean(axis=1)


def edge_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray, reach: np.ndarray):
    """Distance of each point to the nearest segment (a, b) when within `reach` (per point),
    inf otherwise. Long segments are cut into pieces so a k-d tree of their midpoints finds the
    candidates."""
    if not len(a):
        return np.full(len(points), np.inf)
    length = np.linalg.norm(b - a, axis=1)
    piece = max(float(np.median(length)), 1e-300)
    cuts = np.maximum(1, np.ceil(length / piece).astype(np.int64))
    seg = np.repeat(np.arange(len(a)), cuts)
    k = np.arange(len(seg)) - np.repeat(np.cumsum(cuts) - cuts, cuts)
    t0, t1 = k / cuts[seg], (k + 1) / cuts[seg]
    pa = a[seg] + t0[:, None] * (b - a)[seg]
    pb = a[seg] + t1[:, None] * (b - a)[seg]
    half = 0.5 * np.linalg.norm(pb - pa, axis=1).max()
    near = cKDTree(0.5 * (pa + pb)).query_ball_point(points, reach + half)
    counts = np.array([len(c) for c in near])
    dist = np.full(len(points), np.inf)
    if not counts.sum():
        return dist
    who = np.repeat(np.arange(len(points)), counts)
    cand = np.concatenate([np.asarray(c, dtype=np.int64) for c in near if len(c)])
    d = pb[cand] - pa[cand]
    t = np.clip(np.einsum("ij,ij->i", points[who] - pa[cand], d)
                / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0.0, 1.0)
    r = np.linalg.norm(points[who] - (pa[cand] + t[:, None] * d), axis=1)
    np.minimum.at(dist, who, r)
    return np.where(dist <= reach, dist, np.inf)


# --- points and references ------------------------------------------------------------------
def seed_points(nodes, facets, count, diag, seed) -> np.ndarray:
    """`count` points uniform by area on the facets (quads as two triangles), offset along
    the facet normal by uniform(-BAND, BAND) x diag."""
    quads = facets[facets[:, 3] >= 0]
    tris = np.concatenate([facets[facets[:, 3] < 0, :3], quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    a, b, c = (nodes[tris[:, i]] for i in range(3))
    normal = 0.5 * np.cross(b - a, c - a)
    area = np.linalg.norm(normal, axis=1)
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(tris), size=count, p=area / area.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
    on = a[pick] + u[:, None] * (b - a)[pick] + v[:, None] * (c - a)[pick]
    unit = normal[pick] / area[pick, None]
    return on + rng.uniform(-BAND, BAND, count)[:, None] * diag * unit


@dataclass
class Reference:
    """What a row's points are measured against (cached in CACHE)."""

    points: np.ndarray       # (m, 3) the contactors
    gap: np.ndarray          # (m,) reference signed distance
    foot: np.ndarray         # (m, 3) its closest point
    edge: np.ndarray         # (m,) distance of the foot to a sharp edge / local spacing (inf > 2)
    diag: float
    allowance: float         # the facets' sag (0 for a fine reference)
    agree: float             # share of coarse-facet signs agreeing with the reference's
    nodes: int               # target nodes

    @property
    def near(self) -> np.ndarray:
        return self.edge <= 1.0


def study_rows(description: str, default) -> tuple[list[parts.Row], int]:
    """The command line of a study of the battery's cached rows (shortfall.py,
    rigid_parts.py): ``ROW ...`` (default: the rows `default` keeps) and ``--points N``;
    returns the rows, not dropped, and N."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("rows", nargs="*")
    ap.add_argument("--points", type=int, default=20000)
    args = ap.parse_args()
    man = parts.Manifest.load(parts.OUT / "manifest.json")
    return [r for r in man.rows if not r.dropped and (
        r.name in args.rows if args.rows else default(r))], args.points


def _file_key(row: parts.Row, count: int) -> str:
    digest = hashlib.sha1()
    for rel in (row.target, row.reference):
        if rel:
            digest.update((parts.OUT / rel).read_bytes())
    digest.update(f"{row.zone}|{count}|{BAND}|{SHARP_DEG}|{WELD}|{ALLOWANCE_SAGS}|v3".encode())
    return digest.hexdigest()[:16]


def reference(row: parts.Row, count: int) -> tuple[Reference, Path, bool]:
    """The row's contactors, their Parquet file and reference, and whether they came from
    the cache (else computed and cached)."""
    CACHE.mkdir(parents=True, exist_ok=True)
    key = _file_key(row, count)
    npz, table = CACHE / f"{row.name}.{count}.npz", CACHE / f"{row.name}.{count}.parquet"
    if npz.exists() and table.exists():
        data = np.load(npz)
        if str(data["key"]) == key:
            return (Reference(**{k: data[k] for k in Reference.__dataclass_fields__}), table,
                    True)
    nodes, facets = load_target(parts.OUT / row.target, row.zone)
    diag = diagonal(nodes)
    pts = seed_points(nodes, facets, count, diag, zlib.crc32(row.name.encode()))
    coarse = FacetSurface(nodes, facet_list(facets))
    if row.reference:
        fine = np.load(parts.OUT / row.reference)
        ref_nodes, ref_facets = fine["nodes"], np.pad(fine["faces"], ((0, 0), (0, 1)),
                                                      constant_values=-1)
        allowance = 0.0
    else:
        ref_nodes, ref_facets = weld(nodes, facets, WELD * diag)
        allowance = None
    proj = FacetSurface(ref_nodes, facet_list(ref_facets)).project(pts)
    e = edges(ref_nodes, ref_facets)
    if allowance is None:
        allowance = ALLOWANCE_SAGS * sag_allowance(e)
    sphere = exact_sphere(nodes)
    if sphere is not None:  # an STL of a sphere: the sphere itself is the reference
        centre, radius = sphere
        offset = pts - centre
        dist = np.linalg.norm(offset, axis=1)
        proj.gap = dist - radius
        proj.proximal_point = centre + offset * (radius / dist)[:, None]
        allowance = 0.0
    sharp = e.ends[e.sharp]
    spacing = node_spacing(nodes)[cKDTree(nodes).query(proj.proximal_point)[1]]
    dist = edge_distance(proj.proximal_point, ref_nodes[sharp[:, 0]], ref_nodes[sharp[:, 1]],
                         2.0 * spacing)
    g = coarse.project(pts).gap
    firm = np.abs(proj.gap) > ORIENT_FLOOR * diag
    agree = float(np.mean(np.sign(g[firm]) == np.sign(proj.gap[firm]))) if firm.any() else 1.0
    ref = Reference(pts, proj.gap, proj.proximal_point, dist / spacing, diag, allowance, agree,
                    len(nodes))
    pl.DataFrame({"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2]}).write_parquet(table)
    np.savez(npz, key=key, **{k: getattr(ref, k) for k in Reference.__dataclass_fields__})
    return ref, table, False


# --- metrics --------------------------------------------------------------------------------
@dataclass
class Scores:
    """One method's figures on one row (errors / diagonal)."""

    wrong: int = 0
    gross: int = 0
    lost: float = 0.0          # % of points
    rms_edge: float = np.nan
    rms_else: float = np.nan
    max: float = np.nan
    guard: float = 0.0         # % of points
    by_facets: float = 0.0     # % of points answered with terms 0
    refused: str = ""


def errors(gap: np.ndarray, ref: Reference, pick=slice(None)) -> np.ndarray:
    """|g - g_ref| less the allowance (not below 0), at the points `pick`."""
    return np.maximum(np.abs(gap - ref.gap[pick]) - ref.allowance, 0.0)


def wrong_signs(gap: np.ndarray, answered: np.ndarray, ref: Reference) -> np.ndarray:
    firm = np.abs(ref.gap) > max(SIGN_FLOOR * ref.diag, ref.allowance)
    return answered & firm & (np.sign(gap) != np.sign(ref.gap))


def score(table: pl.DataFrame | None, ref: Reference, refused: str = "") -> Scores:
    """The `Scores` of one method's result table (None: refused, every point lost)."""
    if table is None:
        return Scores(lost=100.0, refused=refused)
    gap = table["gap"].to_numpy()
    status = table["status"].cast(pl.Utf8).to_numpy()
    reason = table["reason"].cast(pl.Utf8).to_numpy()
    answered = np.isin(status, ANSWERED)
    err = np.where(answered, errors(gap, ref), np.nan) / ref.diag

    def rms(mask):
        e = err[mask & answered]
        return float(np.sqrt(np.mean(e ** 2))) if len(e) else np.nan

    terms = table["terms"].to_numpy() if "terms" in table.columns else None
    return Scores(
        wrong=int(wrong_signs(gap, answered, ref).sum()),
        gross=int((err[answered] > GROSS).sum()),
        lost=100.0 * float((~answered).mean()),
        rms_edge=rms(ref.near), rms_else=rms(~ref.near),
        max=float(np.nanmax(err)) if answered.any() else np.nan,
        guard=100.0 * float((reason == "guard").mean()),
        by_facets=100.0 * float((answered & (terms == 0)).mean()) if terms is not None else 0.0)


def dump_worst(path: Path, ref: Reference, diff: pl.DataFrame | None,
               facets: pl.DataFrame | None) -> None:
    """diffsurf's wrong signs (up to WORST) and the WORST points where it is farthest from
    the reference (|g - g_ref|, before the allowance), with the reference and the facets'
    answers, to CSV."""
    if diff is None:
        return
    gap = diff["gap"].to_numpy()
    status = diff["status"].cast(pl.Utf8).to_numpy()
    answered = np.isin(status, ANSWERED)
    err = np.where(answered, errors(gap, ref), np.nan)
    # ranked by |g - g_ref| itself: a large allowance (sag) must not hide the failures
    off = np.where(answered, np.abs(gap - ref.gap), -1.0)
    wrong = np.flatnonzero(wrong_signs(gap, answered, ref))
    wrong = wrong[np.argsort(-off[wrong], kind="stable")][:WORST]
    largest = np.argsort(-off, kind="stable")[:WORST]
    pick = np.unique(np.concatenate([wrong, largest[off[largest] > 0]]))
    pick = pick[np.argsort(-off[pick], kind="stable")]
    fgap = facets["gap"].to_numpy()[pick] if facets is not None else np.full(len(pick), np.nan)
    out = pl.DataFrame({
        "point": pick, "x": ref.points[pick, 0], "y": ref.points[pick, 1],
        "z": ref.points[pick, 2],
        "region": np.where(ref.near[pick], "edge", "else"),
        "edge_spacings": ref.edge[pick],
        "g_ref": ref.gap[pick], "g_diffsurf": gap[pick], "g_facets": fgap,
        "off_diffsurf_diag": off[pick] / ref.diag,
        "err_diffsurf_diag": err[pick] / ref.diag,
        "err_facets_diag": errors(fgap, ref, pick) / ref.diag,
        "wrong_sign": np.isin(pick, wrong),
        "status": status[pick].astype(str),
        "reason": diff["reason"].cast(pl.Utf8).to_numpy()[pick].astype(str),
        **{c: diff[c].to_numpy()[pick] for c in ("terms", "support", "iterations", "rcond",
                                                   "nx", "ny", "nz", "px", "py", "pz")
           if c in diff.columns},
        "foot_x": ref.foot[pick, 0], "foot_y": ref.foot[pick, 1], "foot_z": ref.foot[pick, 2],
    })
    out.write_csv(path)


@dataclass
class Result:
    row: parts.Row
    ref: Reference | None = None
    diff: Scores = field(default_factory=Scores)
    facets: Scores = field(default_factory=Scores)
    unreadable: str = ""
    seconds: float = 0.0
    cached: bool = True


def _short(message: str) -> str:
    """`message` with the battery's folder left out of its paths."""
    return message.replace(f"{parts.OUT}/", "")


def measure(row: parts.Row, count: int, extra: tuple, threads: int | None) -> Result:
    """Seed, reference, run diffsurf and the facets, score and dump one row."""
    t0 = time.perf_counter()
    if row.dropped:
        return Result(row)
    try:
        ref, table, cached = reference(row, count)
    except ReadError as exc:
        return Result(row, unreadable=_short(str(exc).splitlines()[0]))
    if row.reference and ref.agree < ORIENT_AGREE:
        row.dropped = (f"coarse facets and reference agree in sign on {100 * ref.agree:.1f}% "
                       f"of the points: not consistently oriented")
        return Result(row, ref)
    target = parts.OUT / row.target
    results = []
    for args in (extra, ("--method", "facet")):
        try:
            results.append((run_diffsurf(target, table, row.zone, *args, threads=threads), ""))
        except Refused as exc:
            results.append((None, _short(str(exc))))
    (diff, why_d), (facets, why_f) = results
    dump_worst(parts.OUT / f"{row.name}.worst.csv", ref, diff, facets)
    return Result(row, ref, score(diff, ref, why_d), score(facets, ref, why_f),
                  seconds=time.perf_counter() - t0, cached=cached)


# --- the table ------------------------------------------------------------------------------
HEAD = ("| part | variant | nodes | points edge/else | wrong signs d/f | gross d/f | lost % d/f "
        "| RMS edge d/f | RMS else d/f | else f/d | max d/f | guard % | by facets % | sag |")


def _e(x: float) -> str:
    return "-" if not np.isfinite(x) else ("0" if x == 0 else f"{x:.1e}")


def _pct(x: float) -> str:
    return "0" if x == 0 else (f"{x:.2f}" if x < 1 else f"{x:.1f}")


def ratio(r: Result) -> float:
    """Facets' RMS elsewhere / diffsurf's, on rows with a fine reference (nan otherwise)."""
    if not r.row.reference or r.ref is None:
        return np.nan
    f, d = r.facets.rms_else, r.diff.rms_else
    return f / d if d > 0 else (np.inf if f > 0 else np.nan)


def line(r: Result) -> str:
    row = r.row
    part = row.part if row.family != "gmsh" else f"{row.part} (gmsh)"
    if r.unreadable or row.dropped or r.ref is None:
        why = f"unreadable: {r.unreadable}" if r.unreadable else f"dropped: {row.dropped}"
        return f"| {part} | {row.variant} | {why.replace('|', '/')} |" + " |" * 11
    d, f, ref = r.diff, r.facets, r.ref
    near = int(ref.near.sum())
    variant = row.variant + (" (diffsurf refused)" if d.refused else "")
    q = ratio(r)
    return (f"| {part} | {variant} | {ref.nodes} | {near}/{len(ref.gap) - near} "
            f"| {d.wrong}/{f.wrong} | {d.gross}/{f.gross} | {_pct(d.lost)}/{_pct(f.lost)} "
            f"| {_e(d.rms_edge)}/{_e(f.rms_edge)} | {_e(d.rms_else)}/{_e(f.rms_else)} "
            f"| {'-' if not np.isfinite(q) else f'{q:.1f}'} | {_e(d.max)}/{_e(f.max)} "
            f"| {_pct(d.guard)} | {_pct(d.by_facets)} "
            f"| {'-' if row.reference else _e(ref.allowance / ref.diag)} |")


def verdicts(results: list[Result]) -> list[str]:
    """The summary lines: rows violating each criterion of issue 19, unreadable, dropped."""
    measured = [r for r in results if r.ref is not None and not r.row.dropped]
    first, second = [], []
    for r in measured:
        why = []
        if r.diff.wrong > r.facets.wrong:
            why.append(f"wrong signs {r.diff.wrong}>{r.facets.wrong}")
        if r.diff.gross > r.facets.gross:
            why.append(f"gross {r.diff.gross}>{r.facets.gross}")
        if r.diff.lost > MAX_LOST_PCT:
            why.append(f"lost {r.diff.lost:.1f}%" + (" (refused)" if r.diff.refused else ""))
        if why:
            first.append(f"{r.row.name} ({', '.join(why)})")
        if r.row.variant in ("o1-tags", "o2-tags"):
            q = ratio(r)
            if not q >= MIN_RATIO:
                second.append(f"{r.row.name} ({q:.1f}x)")
    tagged = sum(r.row.variant in ("o1-tags", "o2-tags") for r in measured)
    out = [f"**No more wrong signs, no more gross errors than the facets, <= {MAX_LOST_PCT:g}% "
           f"lost**: {len(first)} of {len(measured)} measured rows violate it"
           + (": " + "; ".join(first) if first else "."),
           f"**RMS elsewhere >= {MIN_RATIO:g}x smaller than the facets' on tagged and "
           f"second-order meshes**: {len(second)} of {tagged} rows violate it"
           + (": " + "; ".join(second) if second else ".")]
    bad = {}
    for r in results:
        if r.unreadable:
            bad.setdefault(r.unreadable, []).append(r.row.name)
    if bad:
        out.append("**Unreadable** (not measured): " + "; ".join(
            f"{', '.join(names)} ({why})" for why, names in bad.items()))
    gone = [f"{r.row.name} ({r.row.dropped})" for r in results if r.row.dropped]
    if gone:
        out.append(f"**Dropped**: {'; '.join(gone)}")
    refused = [f"{r.row.name} ({r.diff.refused})" for r in results if r.diff.refused]
    if refused:
        out.append(f"**Refused by diffsurf** (every point counted lost): {'; '.join(refused)}")
    return out


def _commit() -> str:
    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--",
                                "diffsurf_cli"], capture_output=True, text=True).stdout.strip()
        return head + (" (diffsurf_cli modified)" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def report(results, args, manifest, seconds, built) -> str:
    ran = "python benchmarks/real_parts.py " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    sources = ", ".join(f"{k} {v[:10]}" for k, v in manifest.commits.items())
    head = [
        "# Real parts (issue 19): diffsurf (d) and the facets (f) side by side", "",
        f"`{ran.strip()}` on {datetime.date.today().isoformat()}, diffsurf {_commit()}, "
        f"sources {sources}; gmsh parts meshed at diag/{parts.COARSE}; {args.points} points "
        f"per row within ±{100 * BAND:g}% of the diagonal; diffsurf run as "
        f"`diffsurf project TARGET POINTS.parquet [--zone Z]"
        f"{' ' + args.extra if args.extra else ''}`, the facets with `--method facet`; "
        f"{seconds / 60:.1f} min with --jobs {args.jobs} (building the battery "
        f"{built / 60:.1f} min; points and references computed for "
        f"{sum(not r.cached for r in results)} rows, cached for the others).", "",
        "Errors and RMS / diagonal; wrong signs where |reference| > 1e-3 diagonal (and > the "
        "sag, for facet references); gross: error > 1% diagonal; lost: outside or failed; "
        "edge: the reference's foot within one local node spacing of a sharp edge (> 40°); "
        "else f/d: facets' RMS elsewhere / diffsurf's (gmsh rows); sag: the allowance of rows "
        "whose reference is the facets themselves (STLs, decks), / diagonal. See the docstring "
        "of benchmarks/real_parts.py.", "",
        HEAD, "|" + "---|" * (HEAD.count("|") - 1)]
    return "\n".join(head + [line(r) for r in results] + [""] + verdicts(results)) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", default="*", help="glob of row names: family.part.variant "
                    "(ccx.hueeber1.Smast, gmsh.part.o2-tags, stl.plate_holes.stl)")
    ap.add_argument("--points", type=int, default=20000, help="contactors per row")
    ap.add_argument("--jobs", type=int, default=1, help="rows measured at the same time")
    ap.add_argument("--extra", default="", help="more options of `diffsurf project` (quoted)")
    ap.add_argument("--coarse", type=int, default=parts.COARSE,
                    help="mesh the gmsh parts at diag/N (default %(default)s; another N is a "
                    "battery of its own, in benchmarks/out/parts-cN, and its table goes to "
                    "results/real_parts.cN.md): a resolution study")
    ap.add_argument("--build-only", action="store_true", help="build the battery and stop")
    ap.add_argument("--no-write", action="store_true",
                    help=f"print the table only (do not write {RESULTS.name})")
    args = ap.parse_args(argv)
    if args.coarse != parts.COARSE:  # parts.py reads it on import, in every process
        os.environ["DIFFSURF_BATTERY_COARSE"] = str(args.coarse)
        os.execv(sys.executable, [sys.executable, __file__,
                                  *(sys.argv[1:] if argv is None else argv)])
    t0 = time.perf_counter()
    manifest = parts.build(args.parts, args.jobs)
    built = time.perf_counter() - t0
    if args.build_only:
        print(f"{len(manifest.rows)} rows built in {parts.OUT}", file=sys.stderr)
        return
    rows = [r for r in manifest.rows if fnmatch.fnmatch(r.name, args.parts)]
    if not rows:
        raise SystemExit(f"no row matches --parts {args.parts!r}")
    extra = tuple(shlex.split(args.extra))
    threads = max(1, (os.cpu_count() or 1) // args.jobs) if args.jobs > 1 else None
    jobs = [(r, args.points, extra, threads) for r in rows]
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            results = list(pool.map(measure, *zip(*jobs)))
    else:
        results = [measure(*j) for j in jobs]
    for r in results:
        print(f"  {r.row.name}: {r.seconds:.1f} s", file=sys.stderr)
    text = report(results, args, manifest, time.perf_counter() - t0, built)
    print(text)
    if not args.no_write:
        RESULTS.write_text(text)


if __name__ == "__main__":
    main()
