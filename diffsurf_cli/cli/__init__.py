"""diffsurf command line: a thin layer (parse → read → core → write) over the package.

Results go to stdout or -o FILE; logs and progress go to stderr only. Domain errors exit 1
with a one-line message, bad options exit 2 (click), no traceback unless -v.
"""
from __future__ import annotations

import contextlib
import logging
import os
import sys

import click
import numpy as np

from .. import __version__, io
from . import options
from ..mls.frame import corner_faces
from ..mls.surface import CHUNK, REASONS, STATUS, DiffuseSurface

# The facet method and the contact element (scipy.sparse) are imported where they are used,
# so a plain `project` starts without them.

log = logging.getLogger("diffsurf")


class DiffsurfError(click.ClickException):
    """A domain error: one line on stderr, exit 1."""

    def show(self, file=None):
        click.echo(f"diffsurf: error: {self.format_message()}", err=True)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="diffsurf")
@click.option("-v", "--verbose", count=True, help="More logging; -v also shows tracebacks.")
@click.option("-q", "--quiet", is_flag=True, help="Only errors on stderr.")
@click.pass_context
def main(ctx, verbose, quiet):
    """Smooth faceted contact surfaces by diffuse approximation (moving least squares) and
    compute gaps, normals and proximal points on the smooth surface.

    \b
    Examples:
      diffsurf project target.msh points.csv -o gaps.csv
      cat points.csv | diffsurf project target.vtu - > gaps.csv
      diffsurf project plate_and_cylinder.msh plate.vtu --zone cylinder -o result.vtu
    """
    level = logging.ERROR if quiet else (logging.DEBUG if verbose > 1 else logging.INFO)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("diffsurf: %(message)s"))
    log.handlers[:] = [handler]
    log.setLevel(level)
    log.propagate = False
    ctx.obj = {"verbose": verbose, "quiet": quiet}


def build_target(path, zone, method, flip, **engine):
    """Read a target mesh and build the diffuse (or faceted) surface of its surface nodes."""
    target = io.read_target(path, zone=zone)
    for kind, count in sorted(target.ignored.items()):
        log.info("%s: ignored %d %s cells (not surface cells)", path, count, kind)
    nodes = target.points[target.nodes]
    faces = [np.searchsorted(target.nodes, f) for f in corner_faces(target.cells)]
    nfaces = sum(len(f) for f in faces)
    log.info("%s: target of %d nodes, %d facets%s", path, len(nodes), nfaces,
             f" (zone {zone!r})" if zone else "")
    try:
        if method == "facet":
            from ..facet.surface import FacetSurface

            surf = FacetSurface(nodes, faces, flip=flip)
        else:
            surf = DiffuseSurface(nodes, faces, flip=flip, **engine)
            log.info("frame: %s; basis %s, weight %s, support %s", surf.frame, surf.basis,
                     surf.weight, surf.support)
    except ValueError as exc:
        raise DiffsurfError(f"{path}: {exc}") from exc
    return target, surf


@contextlib.contextmanager
def progress_bar(ctx, total: int, label: str):
    """A progress callback drawing a bar on stderr when it is a terminal (and not -q) and the
    job has more than one chunk; None (silent) otherwise."""
    if total <= CHUNK or ctx.obj.get("quiet") or not sys.stderr.isatty():
        yield None
        return
    with click.progressbar(length=total, label=f"diffsurf: {label}", file=sys.stderr,
                           show_pos=True, show_eta=True) as bar:
        done = [0]

        def update(n):
            bar.update(n - done[0])
            done[0] = n

        yield update


def guard(ctx, fn, *args, **kwargs):
    """Run `fn`, turning expected errors into one-line messages (tracebacks only with -v)."""
    try:
        return fn(*args, **kwargs)
    except BrokenPipeError:
        # the reader of stdout went away (`| head`): stop quietly, as pipeline tools do
        sys.stdout = open(os.devnull, "w")
        ctx.exit(1)
    except (io.ReadError, io.WriteError, DiffsurfError) as exc:
        if ctx.obj.get("verbose"):
            raise (exc.__cause__ or exc)  # the original error, with its traceback
        raise DiffsurfError(exc.format_message() if isinstance(exc, DiffsurfError)
                            else str(exc)) from exc


@main.command()
@click.argument("target", metavar="TARGET")
@click.argument("points", metavar="POINTS")
@options.engine
@click.option("--method", type=click.Choice(["diffuse", "facet"]), default="diffuse",
              show_default=True,
              help="Diffuse surface, or the faceted target itself (node-to-facet, §2).")
@options.output
@click.option("--penalty", type=click.FloatRange(min=0, min_open=True), default=None,
              metavar="EPS", help="Penalty ε of the contact element R = ε g N, K = ε(g M + N Nᵀ).")
@click.option("--residual", metavar="R.mtx", default=None,
              help="Write the assembled residual (Matrix Market); needs --penalty.")
@click.option("--tangent", metavar="K.mtx", default=None,
              help="Write the assembled sparse tangent (Matrix Market); needs --penalty.")
@click.option("--save-pairs", metavar="FILE.npz", default=None,
              help="Store each contactor's pairing (frame, support, radius / facet).")
@click.option("--pairs", metavar="FILE.npz", default=None,
              help="Reuse a stored pairing exactly instead of searching again.")
@click.pass_context
def project(ctx, target, points, method, output, overwrite, penalty, residual, tangent,
            save_pairs, pairs, zone, flip_normals, **engine):
    """Project contactor POINTS onto the diffuse surface of TARGET.

    TARGET is a surface mesh in any format meshio reads (.msh, .vtu, .vtk, .stl, .obj, .ply,
    .inp, .med, ...); its nodes are those of its triangle and quad cells (mid-side nodes
    included). POINTS is a CSV file (x,y,z columns, header optional, other columns passed
    through), '-' for CSV on stdin, or any mesh file (its nodes).

    Output columns: the pass-through columns, then
    x,y,z,gap,nx,ny,nz,px,py,pz,status,support,iterations,rcond,reason
    with (px,py,pz) the proximal point, (nx,ny,nz) the unit normal out of the target, gap > 0
    open and < 0 penetration; status is open, contact, penetration, outside or failed, and
    reason says why a point is outside or failed (few-nodes, ill-conditioned, off-target,
    steep, no-convergence, recentre, bad-point; ok otherwise). rcond is the reciprocal
    condition number of the point's scaled fit (1 is perfect; below 1e-3, 1e-4 for the
    linear basis, the support is rejected).

    \b
    Examples:
      diffsurf project target.msh points.csv -o gaps.csv
      cat points.csv | diffsurf project target.vtu - > gaps.csv
      diffsurf project plate_and_cylinder.msh plate.vtu --zone cylinder -o result.vtu
      diffsurf project cyl.msh plate.csv --penalty 1e4 --residual R.mtx --tangent K.mtx
    """
    engine = options.resolve(ctx, engine)
    if (residual or tangent) and penalty is None:
        raise click.UsageError("--residual and --tangent need --penalty")
    if method == "facet" and engine.get("recentre"):
        raise click.UsageError("--recentre applies to the diffuse method only")
    named = {}
    for opt, path in (("-o", output), ("--residual", residual), ("--tangent", tangent),
                      ("--save-pairs", save_pairs)):
        if path == "-" and opt != "-o":
            raise click.BadParameter("'-' (stdout) is for -o only, expected a file name",
                                     param_hint=f"'{opt}'")
        if path and path != "-":
            if os.path.realpath(path) in named:
                raise click.UsageError(f"{named[os.path.realpath(path)]} and {opt} both name "
                                       f"{path}, expected a file per output")
            named[os.path.realpath(path)] = opt
    for path, kind in ((output, "result"), (residual, "matrix"), (tangent, "matrix"),
                       (save_pairs, "pairs")):
        if path:
            guard(ctx, io.check_output_path, path, overwrite, kind)
    # every output file is renamed into place at the end, or none is (a failure writing the
    # last one must not leave the others)
    batch = ctx.with_resource(io.output_batch())
    tgt, surf = guard(ctx, build_target, target, zone, method, flip_normals, **engine)
    contactors = guard(ctx, io.read_contactors, points)
    xc = contactors.points
    log.info("%s: %d contactors", points, len(xc))
    pairing = None
    if pairs:
        pairing = guard(ctx, io.load_pairs, pairs, method=method, n_contactors=len(xc),
                        n_target=len(tgt.points))
        pairing = guard(ctx, _pairing_to_core, pairing, tgt, method, surf, pairs)
    want_element = penalty is not None and (residual or tangent)
    if want_element:
        from ..element.element import contact

        try:
            result = contact(surf, xc, second=bool(tangent), pairing=pairing)
        except ValueError as exc:
            raise DiffsurfError(str(exc)) from exc
        proj = result.projection
    elif pairing is not None or save_pairs:
        proj = (surf.project_with(xc, pairing) if pairing is not None
                else surf.project(xc, keep_patch=True))
    else:
        with progress_bar(ctx, len(xc), "projecting") as bar:
            proj = surf.project(xc, progress=bar)
    counts = np.bincount(proj.status, minlength=len(STATUS))
    log.info("status: %s", ", ".join(f"{c} {s}" for s, c in zip(STATUS, counts) if c))
    if want_element:
        args = (penalty, len(xc), tgt.nodes, len(tgt.points))
        log.info("%d closed contacts; Σ ε g²/2 = %r", len(result.elements), result.energy(penalty))
        if residual:
            guard(ctx, io.write_matrix, residual, result.residual(*args)[:, None], overwrite,
                  comment="diffsurf residual R = sum eps g N; dof = 3*node + component, "
                          "contactors first, then target file points")
        if tangent:
            guard(ctx, io.write_matrix, tangent, result.tangent(*args), overwrite,
                  comment="diffsurf tangent K = sum eps (g M + N N^T); same dofs as R")
    if save_pairs:
        guard(ctx, io.save_pairs, save_pairs, _pairing_from_core(proj, tgt, surf, method),
              overwrite)
    guard(ctx, io.write_result, output, contactors, proj.columns(),
          labels={"status": STATUS, "reason": REASONS}, overwrite=overwrite)
    guard(ctx, batch.commit)


@main.command()
@click.argument("target", metavar="TARGET")
@options.engine
@click.option("-o", "--output", "output", metavar="FILE", required=True,
              help="Output mesh; the format follows the extension (.vtu, .vtk, .msh, .stl, ...).")
@click.option("--overwrite", is_flag=True, help="Replace the output file if it exists.")
@click.option("--levels", type=click.IntRange(0, 8), default=None,
              help="Uniform subdivisions of every facet (each splits a facet in 4) [default: 1].")
@click.option("--edge-length", type=click.FloatRange(min=0, min_open=True), default=None,
              metavar="L", help="Subdivide until no facet edge is longer than L.")
@click.option("--keep-nodes", is_flag=True,
              help="Pin the original nodes (approximant weights would move them).")
@click.pass_context
def smooth(ctx, target, output, overwrite, levels, edge_length, keep_nodes, zone, flip_normals,
           **engine):
    """Resample the faceted TARGET onto its diffuse surface.

    Each facet is refined (triangles into 4 triangles, quads into 4 quads), then every vertex
    is placed on the diffuse surface of the ORIGINAL nodes, with the same engine options as
    `project`. Higher-order cells are refined from their corners (their mid-side nodes still
    feed the fit). Point data: normal, principal curvatures k1 >= k2 (> 0 convex), moved (how
    far each vertex moved) and status. With approximant weights the original nodes move off
    the facets; the largest such move is reported on stderr (--keep-nodes pins them).

    \b
    Examples:
      diffsurf smooth cylinder.msh -o cylinder_smooth.vtu --levels 2
      diffsurf smooth part.stl -o part_smooth.stl --edge-length 0.5
      diffsurf smooth cylinder.msh -o nodes_fixed.vtu --weight singular
    """
    from ..smooth import levels_for
    from ..smooth import smooth as smooth_surface

    engine = options.resolve(ctx, engine)
    if levels is not None and edge_length is not None:
        raise click.UsageError("give --levels or --edge-length, not both")
    if output == "-":
        raise click.BadParameter("'-' (stdout) cannot hold a mesh, expected a file name",
                                 param_hint="'-o'")
    guard(ctx, io.check_output_path, output, overwrite, "mesh")
    tgt, surf = guard(ctx, build_target, target, zone, "diffuse", flip_normals, **engine)
    faces = [np.searchsorted(tgt.nodes, f) for f in corner_faces(tgt.cells)]
    if edge_length is not None:
        levels = levels_for(surf.nodes, faces, edge_length)
    levels = 1 if levels is None else levels
    result = smooth_surface(surf, faces, levels, keep_nodes)
    nfaces = sum(len(f) for f in result.faces)
    log.info("%d levels: %d vertices, %d facets", levels, len(result.vertices), nfaces)
    log.info("largest move of an original node off the facets: %r%s", result.node_deviation,
             " (pinned by --keep-nodes)" if keep_nodes else "")
    if result.unplaced:
        log.warning("%d vertices had no usable support and stay on the facets (status outside)",
                    result.unplaced)
    guard(ctx, io.write_mesh, output, result.vertices, result.faces, result.point_data, overwrite)


@main.command("tune")
@click.argument("target", metavar="TARGET")
@click.argument("points", metavar="[POINTS]", required=False)
@click.option("--sample", type=click.IntRange(min=1), default=200, show_default=True,
              help="Target nodes to hold out in all (leave-one-out).")
@click.option("--seed", type=int, default=0, show_default=True,
              help="Seed of the held-out nodes and of the sampled timing points.")
@click.option("--plot", metavar="FILE.png", default=None,
              help="Draw the trade curve (error against points/s) to a .png, .svg or .pdf; "
                   "needs matplotlib (pip install 'diffsurf[plot]').")
@click.option("--overwrite", is_flag=True, help="Replace the --plot file if it exists.")
@click.option("--flip-normals", is_flag=True,
              help="Reverse the target's orientation (+normal into the target).")
@click.option("--zone", metavar="NAME", default=None,
              help="Use only the surface cells of this Gmsh physical group or cell set.")
@click.pass_context
def tune_command(ctx, target, points, sample, seed, plot, overwrite, flip_normals, zone):
    """Measure each preset's accuracy and speed on TARGET, and recommend one.

    Accuracy needs no exact answer: target nodes are held out (leave-one-out), the diffuse
    surface is built without them, and their distance |gap| to it is the error. Removing a
    node coarsens the mesh there, so the estimate is pessimistic in absolute terms; it ranks
    the presets. Speed: points/s projecting POINTS (CSV, '-' for stdin, or a mesh file's
    nodes), or, without POINTS, 10000 points sampled within one node spacing of the facets
    (fewer than 10000 POINTS are repeated up to 10000 for the timing).

    Prints one header line and one row per preset (whitespace-separated columns): preset,
    settings (basis/weight/support), loo_rms and loo_max (held-out |gap|, target units),
    rms/h and max/h (the same in local node spacings h), loo_outside (held-out nodes left
    outside or failed, not in the errors), outside+failed (timed points left outside or
    failed), points/s. The last line is `recommended: NAME`: the fastest preset whose
    loo_rms is within 1.25x the best, among those leaving the fewest points outside or
    failed (speeds within 10% are a tie, won by the smaller loo_rms). Progress goes to stderr.

    \b
    Examples:
      diffsurf tune target.msh
      diffsurf tune target.msh contactors.csv --plot trade.png
      diffsurf tune plate_and_cylinder.msh --zone cylinder --sample 500 --seed 1
    """
    from .. import tune as tuning

    if plot:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise DiffsurfError("--plot needs matplotlib: pip install 'diffsurf[plot]'") from None
        guard(ctx, io.check_output_path, plot, overwrite, "figure")
    tgt = guard(ctx, io.read_target, target, zone=zone)
    for kind, count in sorted(tgt.ignored.items()):
        log.info("%s: ignored %d %s cells (not surface cells)", target, count, kind)
    nodes = tgt.points[tgt.nodes]
    faces = [np.searchsorted(tgt.nodes, f) for f in corner_faces(tgt.cells)]
    log.info("%s: target of %d nodes, %d facets%s", target, len(nodes),
             sum(len(f) for f in faces), f" (zone {zone!r})" if zone else "")
    xc = None
    if points:
        xc = guard(ctx, io.read_contactors, points).points
        log.info("%s: %d points to time", points, len(xc))
    settings = {name: options.resolve(ctx, {"preset": name}) for name in options.PRESETS}
    try:
        result = tuning.tune(nodes, faces, settings, xc, sample=sample, seed=seed,
                             flip=flip_normals, progress=log.info)
    except ValueError as exc:
        raise DiffsurfError(f"{target}: {exc}") from exc
    header = ["preset", "settings", "loo_rms", "loo_max", "rms/h", "max/h", "loo_outside",
              "outside+failed", "points/s"]
    rows = [[e.name, options.summary(e.options), f"{e.loo_rms:.3g}", f"{e.loo_max:.3g}",
             f"{e.loo_rms_h:.3g}", f"{e.loo_max_h:.3g}", str(e.loo_bad), str(e.bad),
             f"{e.rate:.0f}"] for e in result.estimates]
    widths = [max(len(r[i]) for r in [header] + rows) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) if i < 2 else c.rjust(w)
                       for i, (c, w) in enumerate(zip(r, widths))).rstrip()
             for r in [header] + rows]
    log.info("recommended: the fastest preset within %gx the best loo_rms, among those "
             "leaving the fewest points outside or failed (speeds within %gx: the smaller "
             "loo_rms)", tuning.TOLERANCE, tuning.SPEED_TIE)
    if plot:
        fig = tuning.plot(result, title=f"{os.path.basename(target)}: speed/accuracy trade "
                                        f"(recommended: {result.recommended})")
        guard(ctx, io.write_figure, plot, fig, overwrite)
        log.info("%s: trade curve written", plot)
    guard(ctx, click.echo, "\n".join(lines + [f"recommended: {result.recommended}"]))


def _pairing_from_core(proj, tgt, surf, method) -> dict:
    """A pairing in file terms: target node indices are the target file's point indices."""
    meta = {"method": method, "n_contactors": len(proj.points), "n_target": len(tgt.points)}
    if method == "facet":
        return {**meta, "facet": proj.facet}
    p = proj.patch
    index = np.where(p.index >= 0, tgt.nodes[np.maximum(p.index, 0)], -1)
    return {**meta, "origin": p.origin, "axes": p.axes, "radius": p.radius,
            "spacing": p.spacing, "index": index}


def _pairing_to_core(pairing: dict, tgt, method, surf, path):
    from ..mls.surface import Patch

    if method == "facet":
        if pairing["facet"].max(initial=-1) >= len(surf.facets):
            raise io.ReadError(f"{path}: the pairing's facets are not facets of the target "
                                f"(other mesh or zone?)")
        return pairing["facet"]
    idx = pairing["index"]
    local = np.searchsorted(tgt.nodes, np.maximum(idx, 0))
    local = np.minimum(local, len(tgt.nodes) - 1)
    ok = (idx < 0) | (tgt.nodes[local] == idx)
    if not ok.all():
        raise io.ReadError(f"{path}: the pairing's support nodes are not surface nodes of the "
                            f"target (other mesh or zone?)")
    return Patch(pairing["origin"], pairing["axes"], pairing["radius"], pairing["spacing"],
                 np.where(idx >= 0, local, -1))


if __name__ == "__main__":  # pragma: no cover
    main()
