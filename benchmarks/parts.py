"""The "real parts" battery of `real_parts.py` (issue 19): public parts extracted from local
mirrors of their repositories and meshed here, never committed.

Sources (bare git mirrors, brought by the search tool's ``fetch``; their root is
``/work/.mirror`` or ``$DIFFSURF_MIRRORS``):

- CalculiX's test decks (``fetch github:Dhondtguido/CalculiX``, ``test/*.inp``): every surface
  named on a ``*CONTACT PAIR`` data line of the decks in `DECKS` is one row, used through
  ``--zone NAME``; files a deck ``*INCLUDE``s are extracted beside it;
- gmsh's STEP/BREP benchmark parts (``fetch github:live-clones/gmsh``, `CAD`), meshed by gmsh's
  OpenCASCADE kernel at about diag/25 (`COARSE`) in four variants, each one row: ``o1-tags``
  (first-order triangles, .msh with each CAD face's entity tag), ``o2-tags`` (triangle6, mid-side
  nodes on the CAD), ``stl`` (the first-order triangles as binary STL: no tags) and ``tet`` (a
  first-order tetra volume mesh, whose boundary is the target); and a reference mesh 8x finer
  (`FINE`; 4x when 8x would pass `MAX_FINE_TRIANGLES`), its nodes on the CAD, and finer where
  the CAD bends (`FINE_PER_TURN` elements per turn of its curvature, down to 1/`FINE` of its
  own size): a coarse mesh is finer than diag/25 across a fillet narrower than that (its
  edges are a fillet's width), and a reference of uniform size coarse / 8 was no finer
  there (Solid_56's one-cell-wide fillet strips: the reference's own chords were 0.1 off the
  CAD, about what diffsurf and the facets were measured off it);
- trimesh's CAD STL models (``fetch github:mikedh/trimesh``, ``models/``, `STLS`).

Everything goes to ``benchmarks/out/parts/`` (git-ignored): ``src/`` the extracted files,
``targets/`` the gmsh meshes, ``fine/`` the references (nodes and triangles, .npz), and
``manifest.json``, the rows with their sources, commits and build notes. A build skips what is
already there. With ``$DIFFSURF_BATTERY_COARSE=N`` the gmsh parts are meshed at diag/N instead,
into ``benchmarks/out/parts-cN/``.

    python benchmarks/parts.py [--parts GLOB] [--jobs N] [--force]
"""
from __future__ import annotations

import argparse
import fnmatch
import json
import os
import re
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

#: coarse element size of the gmsh parts: the CAD's bounding-box diagonal / COARSE; another
#: value (``$DIFFSURF_BATTERY_COARSE``, set by ``real_parts.py --coarse N`` for a resolution
#: study) builds a battery of its own in ``out/parts-cN``
COARSE = int(os.environ.get("DIFFSURF_BATTERY_COARSE", "25"))
#: where the parts are built (git-ignored)
OUT = Path(__file__).resolve().parent / "out" / ("parts" if COARSE == 25 else f"parts-c{COARSE}")

#: source -> (mirror folder, the fetch that brings it)
MIRRORS = {
    "ccx": ("Dhondtguido+CalculiX", "github:Dhondtguido/CalculiX"),
    "gmsh": ("live-clones+gmsh", "github:live-clones/gmsh"),
    "trimesh": ("mikedh+trimesh", "github:mikedh/trimesh"),
}

#: CalculiX decks (test/NAME.inp) whose contact surfaces are rows: curved faces of hexa
#: (cycliccontact), thin zones one element wide (scheibe2n2f, hueeber1), a one-facet master
#: (beamcontact), quad8 and triangle6 faces (contact2, cubef2f1, ringfcontact1, punch1,
#: contactdeleteelement), shells (ball: S8) and a deck whose *NODE lines end with a comma
#: (metalforming).
DECKS = ("cycliccontact", "hueeber1", "scheibe2n2f", "beamcontact", "contact2", "cubef2f1",
         "ringfcontact1", "punch1", "contactdeleteelement", "ball", "metalforming")

#: gmsh parts: name -> path in the gmsh repository. Chosen among benchmarks/step and
#: benchmarks/statreport for meshing in seconds at diag/25 and being one closed solid (or a few).
CAD = {
    "part": "benchmarks/step/part.step",
    "Block": "benchmarks/step/Block.stp",
    "Solid_56": "benchmarks/step/Solid_56.step",
    "U_Joint_2": "benchmarks/step/U_Joint_2.stp",
    "linkrods": "benchmarks/statreport/linkrods.step",
    "Angled": "benchmarks/statreport/Angled.step",
    "Zylkopf": "benchmarks/statreport/Zylkopf.stp",
    "Kurbelwelle": "benchmarks/statreport/Kurbelwelle.stp",
    "Cylinder_1": "benchmarks/statreport/Cylinder_1.brep",
    "Cone_1": "benchmarks/statreport/Cone_1.brep",
    "Torus_1": "benchmarks/statreport/Torus_1.brep",
}
#: the gmsh variants, each one row
VARIANTS = ("o1-tags", "o2-tags", "stl", "tet")
#: the reference's element size: coarse / FINE (coarse / 4 above MAX_FINE_TRIANGLES), and
#: FINE_PER_TURN elements per turn of the CAD's curvature, down to (coarse / FINE) / FINE.
#: Measured on Solid_56 o2-tags: diffsurf's RMS away from sharp edges is 6.06x below the
#: facets' against 16 per turn (0.7M triangles), 6.08x against 40 (3.6M), 4.83x against the
#: uniform coarse / 8 (0.11M)
FINE = 8
FINE_PER_TURN = 16
MAX_FINE_TRIANGLES = 2_000_000
#: seconds one part may take to mesh
MESH_TIMEOUT = 600

#: trimesh's CAD STL models (models/NAME), each one row. Left out: empty.stl, soup.stl (a
#: triangle soup), multibody.stl (inconsistent winding), shared.STL (not watertight), teapot.stl
#: (not CAD), the one-box samples (unit_cube, large_block_obb, origin_inside) and box.STL.
STLS = ("plate_holes.STL", "angle_block.STL", "featuretype.STL", "octagonal_pocket.stl",
        "1002_tray_bottom.STL", "idler_riser.STL", "ADIS16480.STL", "counter.unitsmm.STL",
        "large_block.STL", "7_8ths_cube.stl", "round.stl", "cylinder.stl", "torus.STL",
        "unit_sphere.STL", "20mm-xyz-cube.stl", "busted.STL")


@dataclass
class Row:
    """One target of the battery.

    Attributes
    ----------
    name : str
        ``family.part.variant``, what ``--parts`` globs match.
    family : str
        'ccx', 'gmsh' or 'stl'.
    part, variant : str
        The part (deck, CAD or STL name) and the variant (a deck's zone, a gmsh variant, 'stl').
    target : str
        The target file, relative to `OUT`.
    zone : str or None
        ``--zone`` of the target (a deck's surface).
    reference : str or None
        The fine reference mesh (.npz, relative to `OUT`) of a gmsh part; None: the facets of
        the target themselves, allowing their chordal sag.
    note : str
        Build notes (the reference's refinement, the surface's orientation check).
    dropped : str
        Why the row cannot be measured ('' when it can).
    """

    name: str
    family: str
    part: str
    variant: str
    target: str
    zone: str | None = None
    reference: str | None = None
    note: str = ""
    dropped: str = ""


@dataclass
class Manifest:
    rows: list = field(default_factory=list)
    commits: dict = field(default_factory=dict)

    def save(self, path: Path) -> None:
        path.write_text(json.dumps({"commits": self.commits,
                                    "rows": [asdict(r) for r in self.rows]}, indent=1))

    @classmethod
    def load(cls, path: Path) -> Manifest:
        if not path.exists():
            raise SystemExit(f"{path}: no battery built yet; run python benchmarks/parts.py")
        data = json.loads(path.read_text())
        return cls([Row(**r) for r in data["rows"]], data.get("commits", {}))


class MissingMirror(SystemExit):
    pass


def mirror(source: str) -> Path:
    """The bare git directory of `source` ('ccx', 'gmsh', 'trimesh'); SystemExit naming the
    fetch to run when it is missing."""
    folder, fetch = MIRRORS[source]
    root = Path(os.environ.get("DIFFSURF_MIRRORS", "/work/.mirror"))
    git_dir = root / folder / "repo"
    if not (git_dir / "HEAD").exists():
        raise MissingMirror(f"{git_dir}: mirror not found; bring it with the search tool's "
                            f"`fetch {fetch}` (or set DIFFSURF_MIRRORS)")
    return git_dir


def git(git_dir: Path, *args: str) -> bytes:
    return subprocess.run(["git", f"--git-dir={git_dir}", *args], check=True,
                          capture_output=True).stdout


def extract(git_dir: Path, path: str, dest: Path) -> Path:
    """`path` of the mirror's HEAD written to `dest` (kept when already there)."""
    if not dest.exists():
        dest.parent.mkdir(parents=True, exist_ok=True)
        tmp = dest.with_name(dest.name + ".part")
        tmp.write_bytes(git(git_dir, "show", f"HEAD:{path}"))
        tmp.rename(dest)
    return dest


# --- CalculiX decks -----------------------------------------------------------------------
def contact_surfaces(text: str) -> list[str]:
    """The surface names on the data lines of a deck's ``*CONTACT PAIR`` keywords, in order,
    each once (the slave and master of each pair)."""
    names = []
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if not re.match(r"\s*\*contact\s*pair", line, re.I):
            continue
        for data in lines[i + 1:]:
            if data.startswith("**"):
                continue
            if data.lstrip().startswith("*"):
                break
            for name in data.split(","):
                name = name.strip()
                if name and name not in names:
                    names.append(name)
    return names


def includes(text: str) -> list[str]:
    """The files a deck ``*INCLUDE``s (INPUT=...)."""
    return re.findall(r"^\s*\*include\s*,\s*input\s*=\s*\"?([^\"\n,]+)", text, re.I | re.M)


def deck_rows(parts_glob: str) -> list[Row]:
    git_dir = mirror("ccx")
    rows = []
    for deck in DECKS:
        dest = extract(git_dir, f"test/{deck}.inp", OUT / "src" / "ccx" / f"{deck}.inp")
        text = dest.read_text(errors="replace")
        for inc in includes(text):
            extract(git_dir, f"test/{inc.strip()}", dest.parent / inc.strip())
        for zone in contact_surfaces(text):
            rows.append(Row(f"ccx.{deck}.{zone}", "ccx", f"{deck}.inp", zone,
                            str(dest.relative_to(OUT)), zone=zone))
    return [r for r in rows if fnmatch.fnmatch(r.name, parts_glob)]


# --- trimesh STLs ---------------------------------------------------------------------------
def stl_rows(parts_glob: str) -> list[Row]:
    rows = [Row(f"stl.{n.rsplit('.', 1)[0].replace('.', '_')}.stl", "stl", n, "stl",
                f"src/trimesh/{n}") for n in STLS]
    rows = [r for r in rows if fnmatch.fnmatch(r.name, parts_glob)]
    if rows:
        git_dir = mirror("trimesh")
        for r in rows:
            extract(git_dir, f"models/{r.part}", OUT / r.target)
    return rows


# --- gmsh parts -----------------------------------------------------------------------------
def gmsh_files(name: str) -> dict:
    """The files of gmsh part `name`, relative to `OUT`."""
    return {"o1-tags": f"targets/{name}.o1.msh", "o2-tags": f"targets/{name}.o2.msh",
            "stl": f"targets/{name}.o1.stl", "tet": f"targets/{name}.tet.msh",
            "fine": f"fine/{name}.fine.npz", "log": f"targets/{name}.build.json"}


def gmsh_rows(parts_glob: str, jobs: int, force: bool) -> list[Row]:
    wanted = [n for n in CAD if any(fnmatch.fnmatch(f"gmsh.{n}.{v}", parts_glob)
                                    for v in VARIANTS)]
    if not wanted:
        return []
    git_dir = mirror("gmsh")
    for name in wanted:
        extract(git_dir, CAD[name], OUT / "src" / "gmsh" / Path(CAD[name]).name)
    todo = [n for n in wanted if force or not (OUT / gmsh_files(n)["log"]).exists()]
    with ThreadPoolExecutor(max(1, jobs)) as pool:
        for name, error in zip(todo, pool.map(mesh_part, todo)):
            print(f"  gmsh {name}: {error or 'meshed'}", file=sys.stderr)
    rows = []
    for name in wanted:
        files = gmsh_files(name)
        log = json.loads((OUT / files["log"]).read_text())
        for v in VARIANTS:
            row = Row(f"gmsh.{name}.{v}", "gmsh", Path(CAD[name]).name, v, files[v],
                      reference=files["fine"], note=log.get("note", ""),
                      dropped=log.get("dropped", {}).get(v, log.get("error", "")))
            if fnmatch.fnmatch(row.name, parts_glob):
                rows.append(row)
    return rows


def mesh_part(name: str) -> str:
    """Mesh gmsh part `name` in a child process (gmsh is one global state, and may crash or
    hang on a CAD file); the error's one line, '' when it went well. The child writes the
    part's build log (notes, dropped variants) itself."""
    src = OUT / "src" / "gmsh" / Path(CAD[name]).name
    log = OUT / gmsh_files(name)["log"]
    log.parent.mkdir(parents=True, exist_ok=True)
    (OUT / "fine").mkdir(parents=True, exist_ok=True)
    try:
        done = subprocess.run([sys.executable, __file__, "_mesh", name, str(src)],
                              capture_output=True, text=True, timeout=MESH_TIMEOUT)
    except subprocess.TimeoutExpired:
        error = f"gmsh took over {MESH_TIMEOUT} s"
    else:
        lines = (done.stderr.strip() or "no message").splitlines()
        error = "" if done.returncode == 0 else lines[-1][:200]
    if error:
        log.write_text(json.dumps({"error": error}))
    return error


def _gmsh_session(src: Path):
    """gmsh initialised quietly on one thread with `src` imported: (gmsh, CAD bbox diagonal,
    volume tags)."""
    import gmsh

    gmsh.initialize(["-noenv"], readConfigFiles=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.NumThreads", 1)
    gmsh.model.add("part")
    gmsh.model.occ.importShapes(str(src))
    gmsh.model.occ.synchronize()
    box = gmsh.model.getBoundingBox(-1, -1)
    diag = float(np.linalg.norm(np.subtract(box[3:], box[:3])))
    volumes = [t for _, t in gmsh.model.getEntities(3)]
    gmsh.option.setNumber("Mesh.MshFileVersion", 2.2)
    gmsh.option.setNumber("Mesh.Binary", 1)
    return gmsh, diag, volumes


def _sizes(gmsh, h: float) -> None:
    gmsh.option.setNumber("Mesh.MeshSizeMin", h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)


def _fine_sizes(gmsh, h: float) -> None:
    """The reference's sizes: h, and finer where the CAD bends (`FINE_PER_TURN`)."""
    gmsh.option.setNumber("Mesh.MeshSizeMin", h / FINE)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", FINE_PER_TURN)


def _surface_triangles(gmsh):
    """(nodes (n, 3), triangles (t, 3) into nodes) of the current 2D mesh."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    index = np.full(int(tags.max()) + 1, -1, np.int64)
    index[tags.astype(np.int64)] = np.arange(len(tags))
    tris = []
    for kind, _, conn in zip(*gmsh.model.mesh.getElements(2)):
        if kind == 2:  # 3-node triangle
            tris.append(index[conn.astype(np.int64)].reshape(-1, 3))
    return coords.reshape(-1, 3), np.concatenate(tris)


def orientation(nodes: np.ndarray, tris: np.ndarray) -> tuple[float, int]:
    """(signed volume enclosed by the triangles, number of directed edges used twice or
    without their reverse: open or inconsistently oriented)."""
    a, b, c = nodes[tris[:, 0]], nodes[tris[:, 1]], nodes[tris[:, 2]]
    volume = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)
    n = len(nodes)
    directed = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    key, count = np.unique(directed[:, 0] * n + directed[:, 1], return_counts=True)
    reverse = directed[:, 1] * n + directed[:, 0]
    has_reverse = np.isin(directed[:, 0] * n + directed[:, 1], reverse)
    bad = int((count > 1).sum()) + int((~has_reverse).sum())
    return volume, bad


def mesh_one(name: str, src: Path) -> None:
    """Mesh CAD file `src` as gmsh part `name` (`gmsh_files`): the coarse surface (first and
    second order, .msh with tags and STL), a tetra volume mesh, and the fine reference; write
    the build log. Run in a child process by `mesh_part`."""
    files = {k: OUT / v for k, v in gmsh_files(name).items()}
    log = {"dropped": {}}
    t0 = time.perf_counter()
    gmsh, diag, volumes = _gmsh_session(src)
    try:
        if not volumes:
            raise SystemExit(f"{src.name}: no solid in the CAD file (faces only)")
        h = diag / COARSE
        _sizes(gmsh, h)
        gmsh.model.mesh.generate(2)
        nodes, tris = _surface_triangles(gmsh)
        volume, bad = orientation(nodes, tris)
        log.update(diag=diag, h=h, coarse_triangles=len(tris), volume=volume, bad_edges=bad)
        if volume <= 0:
            raise SystemExit(f"{src.name}: the surface mesh faces inward (volume {volume:.3g})")
        gmsh.write(str(files["o1-tags"]))
        gmsh.write(str(files["stl"]))
        gmsh.model.mesh.setOrder(2)
        gmsh.write(str(files["o2-tags"]))
        gmsh.model.mesh.setOrder(1)
        factor = FINE if len(tris) * FINE ** 2 <= MAX_FINE_TRIANGLES else FINE // 2
        gmsh.model.mesh.clear()
        _fine_sizes(gmsh, h / factor)
        gmsh.model.mesh.generate(2)
        fine_nodes, fine_tris = _surface_triangles(gmsh)
        np.savez(files["fine"], nodes=fine_nodes, faces=fine_tris)
        log.update(fine_factor=factor, fine_triangles=len(fine_tris))
        gmsh.model.mesh.clear()
        _sizes(gmsh, h)
        try:
            gmsh.model.mesh.generate(3)
            gmsh.model.addPhysicalGroup(3, volumes, name="part")  # only the tetra are written
            gmsh.write(str(files["tet"]))
        except Exception as exc:  # noqa: BLE001 - gmsh raises Exception with its last error
            log["dropped"]["tet"] = f"gmsh cannot mesh the volume: {str(exc)[:120]}"
    finally:
        gmsh.finalize()
    notes = [f"{log['coarse_triangles']} triangles, reference {log['fine_factor']}x finer "
             f"({log['fine_triangles']} triangles)"]
    if log["bad_edges"]:
        notes.append(f"{log['bad_edges']} open or inconsistently oriented edges")
    log["note"] = "; ".join(notes)
    log["seconds"] = round(time.perf_counter() - t0, 1)
    files["log"].write_text(json.dumps(log, indent=1))


# --- the whole battery ---------------------------------------------------------------------
def build(parts_glob: str = "*", jobs: int = 1, force: bool = False) -> Manifest:
    """Extract and mesh the rows matching `parts_glob`, update and return the manifest."""
    OUT.mkdir(parents=True, exist_ok=True)
    manifest = Manifest()
    for source in MIRRORS:
        try:
            manifest.commits[source] = git(mirror(source), "rev-parse", "HEAD").decode().strip()
        except MissingMirror as exc:
            print(exc, file=sys.stderr)
    manifest.rows = (deck_rows(parts_glob) + gmsh_rows(parts_glob, jobs, force)
                     + stl_rows(parts_glob))
    old = OUT / "manifest.json"
    if old.exists() and parts_glob != "*":  # keep the rows of the other parts
        kept = [r for r in Manifest.load(old).rows
                if r.name not in {n.name for n in manifest.rows}]
        manifest.rows = kept + manifest.rows
        manifest.rows.sort(key=_order)
    manifest.save(old)
    return manifest


def _order(row: Row):
    """Sort key of a row: decks, gmsh parts, STLs, each in the order of its list."""
    parts = {"ccx": [f"{d}.inp" for d in DECKS], "gmsh": [Path(p).name for p in CAD.values()],
             "stl": list(STLS)}[row.family]
    return (("ccx", "gmsh", "stl").index(row.family),
            parts.index(row.part) if row.part in parts else len(parts),
            VARIANTS.index(row.variant) if row.variant in VARIANTS else 0)


def main(argv=None):
    if argv is None and len(sys.argv) > 1 and sys.argv[1] == "_mesh":
        mesh_one(sys.argv[2], Path(sys.argv[3]))
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", default="*", help="glob of row names (family.part.variant)")
    ap.add_argument("--jobs", type=int, default=1, help="parts meshed at the same time")
    ap.add_argument("--force", action="store_true", help="mesh the gmsh parts again")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    manifest = build(args.parts, args.jobs, args.force)
    dropped = [r for r in manifest.rows if r.dropped]
    print(f"{len(manifest.rows)} rows in {OUT / 'manifest.json'} ({len(dropped)} dropped) in "
          f"{time.perf_counter() - t0:.0f} s", file=sys.stderr)
    for r in dropped:
        print(f"  dropped {r.name}: {r.dropped}", file=sys.stderr)


if __name__ == "__main__":
    main()
