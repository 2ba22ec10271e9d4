"""`diffsurf project`: contactors onto the diffuse (or faceted) surface of a target."""
from __future__ import annotations

import logging
import os

import click
import numpy as np

from .. import io
from ..projection import COLUMNS, LABELS, PENETRATION, REASONS, STATUS
from ..targets import PRECISION_DIGITS, coincident, precision_digits
from . import options
from .common import (
    STDOUT_NAMES,
    DiffsurfError,
    SetupStatus,
    count,
    guard,
    log,
    need_stdin,
    need_stdout,
    progress_bar,
    stderr_is_terminal,
    target_surface,
)

#: `diffsurf project --help`: its column list is the declared one (`projection.COLUMNS`)
HELP = """Project contactor POINTS onto the diffuse surface of TARGET.

TARGET is a surface mesh in any format meshio reads (.msh, .vtu, .vtk, .stl, .obj, .ply,
.inp, .med, ...); its nodes are those of its triangle and quad cells (mid-side nodes
included). POINTS is a table: CSV (x,y,z columns, header optional, other columns passed
through; separator ',', ';', tab or spaces, sniffed; fields may be "quoted"), '-' for CSV
on stdin, or Parquet (.parquet); or any mesh file (its nodes). -o takes .csv, .parquet or
a mesh format.

Output columns: the pass-through columns, then

\b
  {columns}

with (px,py,pz) the proximal point, (nx,ny,nz) the unit normal out of the target, gap > 0
open and < 0 penetration; status is open, contact, penetration, outside or failed, and
reason says why a point is outside or failed (few-nodes, ill-conditioned, off-target,
steep, no-convergence, recentre, bad-point; ok otherwise). rcond is the reciprocal
condition number of the point's scaled fit (1 is perfect): a lower bound of σmin/σmax
within a factor of the basis size, exact near the threshold; a support is rejected when
σmin/σmax is below 1e-3 (1e-4 for the linear basis). terms is the number of basis terms
fitted (diffuse method): the basis's size (6 quadratic), fewer where the support could not
determine it (a strip one element wide, a row of nodes) and the terms it could were fitted
(quadratic along the strip, linear or constant across), 0 where not even a line.
Every column, and when it is written: docs/outputs.md.

\b
Examples:
  diffsurf project target.msh points.csv -o gaps.csv
  diffsurf project target.msh points.csv -o gaps.csv --plot gaps.png
  diffsurf project target.msh cloud.parquet -o gaps.parquet
  cat points.csv | diffsurf project target.vtu - > gaps.csv
  diffsurf project plate_and_cylinder.msh plate.vtu --zone cylinder -o result.vtu
  diffsurf project cyl.msh plate.csv --penalty 1e4 --residual R.mtx --tangent K.mtx
  diffsurf project cyl.msh plate.csv --penalty 1e4 --rigid-target --tangent K.mtx
  diffsurf project cyl.msh plate.csv --penalty 1e4 --tangent K.mtx --gauss-newton
  diffsurf project cyl.msh plate.csv --elements E.npz -o gaps.csv
  diffsurf project target.msh 'cloud/*.parquet' -o out/ --workers 2

\b
Contact element (R = ε g N, K = ε (g M + N Nᵀ) over the contactors with status
penetration): the DOFs of R.mtx and K.mtx are dof = 3 node + component, contactors first
(in POINTS order), then TARGET's file points; with --rigid-target the contactors' only.
E.npz holds contactor (e,), nodes (e, K) (TARGET file point indices, -1 padded), gap (e,),
N (e, 3(K+1)), M (e, 3(K+1), 3(K+1)) for u = [x^c, x^nodes...], and status, reason (m,)
with their names in status_names, reason_names.
""".format(columns=",".join(c.name for c in COLUMNS))


@click.command("project", help=HELP)
@options.verbosity
@click.argument("target", metavar="TARGET")
@click.argument("points", metavar="POINTS")
@options.engine
@click.option("--method", type=click.Choice(["diffuse", "facet", "quadric"]), default="diffuse",
              show_default=True,
              help="Diffuse surface, the faceted target itself (node-to-facet, §2), or "
                   + options.QUADRIC_HELP)
@options.feature_angle(more=" The contact element (--penalty, --elements, --rigid-target) is "
                             "that of the patch (or the facets) answering each point; "
                             "pairings (--save-pairs, --pairs) use one surface.")
@options.output
@click.option("--penalty", type=options.FiniteFloatRange(min=0, min_open=True), default=None,
              metavar="EPS", help="Penalty ε of the contact element R = ε g N, K = ε(g M + N Nᵀ).")
@click.option("--residual", metavar="R.mtx", default=None,
              help="Write the assembled residual (Matrix Market); needs --penalty.")
@click.option("--tangent", metavar="K.mtx", default=None,
              help="Write the assembled sparse tangent (Matrix Market); needs --penalty.")
@click.option("--gauss-newton", is_flag=True, default=False,
              help="--tangent writes K = ε N Nᵀ only (no M): positive semi-definite whatever "
                   "the gap and the curvature; Newton then converges linearly.")
@click.option("--rigid-target", is_flag=True, default=False,
              help="The target does not move: elements of the contactors only (R and K then "
                   "have 3 m DOFs, the contactors'). Diffuse: the gap is the signed distance to "
                   "the diffuse surface, no pairing needed; the output's gap, normal and proximal "
                   "point are then that surface's (support 0, rcond NaN).")
@click.option("--elements", metavar="E.npz", default=None,
              help="Write the contact element arrays (contactor, nodes, gap, N, M, per-contactor "
                   "status and reason) as .npz; no --penalty needed.")
@click.option("--save-pairs", metavar="FILE.npz", default=None,
              help="Store each contactor's pairing (frame, support, radius / facet). Its file "
                   "holds one surface's: the diffuse surface is then one over the whole target "
                   "(--feature-angle ignored).")
@click.option("--pairs", metavar="FILE.npz", default=None,
              help="Reuse a stored pairing exactly instead of searching again (one diffuse "
                   "surface over the whole target, as --save-pairs).")
@click.option("--scheduler", metavar="ADDRESS", default=None,
              help="Run on the Dask cluster of this scheduler (tcp://host:8786): POINTS and -o "
                   "may then be partitions (a directory or a glob of .parquet / .csv files). "
                   "Needs diffsurf[dask].")
@click.option("--resume", is_flag=True, default=False,
              help="With --workers/--scheduler: skip the partitions whose output a stopped job "
                   "left whole (as many rows as the input, the result's columns); project "
                   "the others.")
@click.option("--workers", metavar="N", type=click.IntRange(min=1), default=None,
              help="Run as --scheduler does, on a local Dask cluster of N worker processes "
                   "(one core each).")
@click.option("--plot", metavar="FILE.png", default=None,
              help="Also draw the contactors coloured by gap over the target's edges to a "
                   ".png, .svg or .pdf (penetrations outlined, unanswered grey; beyond "
                   "200,000 contactors a sample); needs matplotlib (pip install "
                   "'diffsurf[plot]').")
@click.pass_context
def project(ctx, target, points, method, feature_angle, output, overwrite, penalty, residual,
            tangent, gauss_newton, rigid_target, elements, save_pairs, pairs, zone, flip_normals,
            scheduler, resume, workers, plot, **engine):
    """`diffsurf project` (its help: `HELP`): the options checked, the inputs read and the
    surface built, the contactors projected (or their contact elements built), the outputs
    written, all or none."""
    engine = _check_options(ctx, method, engine, penalty, residual, tangent, gauss_newton,
                            rigid_target, elements, save_pairs, pairs, resume, overwrite,
                            scheduler, workers)
    need_stdin(points)
    if scheduler is not None or workers is not None:
        return _on_cluster(ctx, target, points, output, overwrite, resume, scheduler, workers,
                           method, zone, flip_normals, dict(engine, feature_angle=feature_angle),
                           penalty=penalty, residual=residual, tangent=tangent,
                           rigid_target=rigid_target or None, elements=elements,
                           gauss_newton=gauss_newton or None,
                           save_pairs=save_pairs, pairs=pairs, plot=plot)
    _check_outputs(ctx, target, points, pairs, overwrite, penalty, output=output,
                   residual=residual, tangent=tangent, elements=elements,
                   save_pairs=save_pairs, plot=plot)
    # every output file is renamed into place at the end, or none is (a failure writing the
    # last one must not leave the others)
    batch = ctx.with_resource(io.output_batch())
    want_element = bool(residual or tangent or elements)
    tgt, surf, contactors, pairing, setup = _read_inputs(
        ctx, target, points, method, feature_angle, zone, flip_normals, output, save_pairs,
        pairs, engine)
    xc = contactors.points
    if len(xc):  # the engine the projection uses, as part of the setup, before its bar
        with setup:
            setup.engine(surf)
    setup.report()
    result = None
    if want_element:
        result = _contact(surf, xc, rigid_target, pairing,
                          second=bool((tangent and not gauss_newton) or elements))
        proj = result.projection
    elif pairing is not None or save_pairs:
        proj = (surf.project_with(xc, pairing) if pairing is not None
                else surf.project(xc, keep_patch=True))
    else:
        with progress_bar(ctx, len(xc), "projecting") as bar:
            proj = surf.project(xc, progress=bar)
    _log_projection(proj, surf, xc)
    if want_element:
        _write_element(ctx, result, tgt, method, len(xc), penalty, residual, tangent,
                       gauss_newton, elements, rigid_target, overwrite)
    if save_pairs:
        guard(ctx, io.save_pairs, save_pairs, io.pairing_from_core(proj, tgt, method), overwrite)
    if plot:  # before the results: a failure drawing leaves no output (one batch)
        fig = io.project_figure(tgt.points, tgt.cells, xc, proj.gap, proj.status_names,
                                target=target, points=points, tags=tgt.tags)
        guard(ctx, io.write_figure, plot, fig, overwrite)
    guard(ctx, io.write_result, output, contactors, proj.columns(), labels=LABELS,
          overwrite=overwrite)
    guard(ctx, batch.commit)


def _check_options(ctx, method, engine, penalty, residual, tangent, gauss_newton, rigid_target,
                   elements, save_pairs, pairs, resume, overwrite, scheduler, workers) -> dict:
    """The options that exclude or need each other refused (a UsageError) before any work;
    returns the engine options (`options.resolve`)."""
    if pairs:  # the pairing holds each contactor's frame, support and radius [§4.2]
        held = [flag for name, flag in (("support", "--support"), ("radius", "--radius"),
                                        ("k", "-k"), ("frame", "--frame"))
                if options.given(ctx, name)]
        if held:
            raise click.UsageError(f"--pairs fixes each contactor's frame, support and radius: "
                                   f"{', '.join(held)} would be ignored; leave "
                                   f"{'them' if len(held) > 1 else 'it'} out")
    if method == "facet":  # the facets themselves: no engine, no patches (build_surface)
        options.diffuse_only(ctx, "facet", "preset", "basis", "weight", "support", "radius",
                             "k", "frame", "feature_angle")
    if method == "quadric":  # its own fit: the radius is its one engine option
        quadric = options.quadric_engine(ctx, engine)
        if pairs or save_pairs:
            raise click.UsageError("--pairs and --save-pairs hold a diffuse or facet pairing: "
                                   "not with --method quadric")
        if scheduler is not None or workers is not None:
            raise click.UsageError("--workers and --scheduler run the diffuse and facet "
                                   "methods: not --method quadric")
    engine = quadric if method == "quadric" else options.resolve(ctx, engine)
    if (residual or tangent) and penalty is None:
        raise click.UsageError("--residual and --tangent need --penalty")
    if gauss_newton and not tangent:
        raise click.UsageError("--gauss-newton applies to the tangent: give --tangent")
    if rigid_target and not (residual or tangent or elements):
        raise click.UsageError("--rigid-target applies to the contact element: give "
                               "--residual, --tangent or --elements")
    if rigid_target and method == "diffuse" and (pairs or save_pairs):
        raise click.UsageError("--rigid-target: the diffuse gap of a rigid target is the signed "
                               "distance to its surface and has no pairing (--pairs, "
                               "--save-pairs)")
    if method == "facet" and engine.get("recentre"):
        raise click.UsageError("--recentre applies to the diffuse method only")
    if resume and scheduler is None and workers is None:
        raise click.UsageError("--resume applies to a job of partitions: give --workers N or "
                               "--scheduler ADDRESS")
    if resume and overwrite:  # --overwrite projected every partition again, --resume unheard
        raise click.UsageError("--resume and --overwrite exclude each other: skip the "
                               "partitions done, or project them all again")
    return engine


def _check_outputs(ctx, target, points, pairs, overwrite, penalty, **paths) -> None:
    """The output files (`paths`: option name -> path or None, -o as ``output``) refused
    before any work: two naming one file, '-' other than for -o, one of the inputs, one that
    exists without --overwrite, stdout closed, a plot without matplotlib."""
    output, plot = paths["output"], paths["plot"]
    named = {}
    for name, path in paths.items():
        opt = "-o" if name == "output" else "--" + name.replace("_", "-")
        if path == "-" and opt != "-o":
            raise click.BadParameter("'-' (stdout) is for -o only, expected a file name",
                                     param_hint=f"'{opt}'")
        if path and path != "-":
            if os.path.realpath(path) in named:
                raise click.UsageError(f"{named[os.path.realpath(path)]} and {opt} both name "
                                       f"{path}, expected a file per output")
            named[os.path.realpath(path)] = opt
    if penalty is not None and not (paths["residual"] or paths["tangent"] or paths["elements"]):
        raise click.UsageError("--penalty applies to the contact element: give --residual, "
                               "--tangent or --elements")
    if output in STDOUT_NAMES:
        need_stdout("use -o FILE")
    inputs = (("TARGET", target), ("POINTS", points), ("--pairs", pairs))
    for name, kind in (("output", "result"), ("residual", "matrix"), ("tangent", "matrix"),
                       ("elements", "pairs"), ("save_pairs", "pairs")):
        if paths[name]:  # never one of the inputs, --overwrite or not
            guard(ctx, io.check_output_path, paths[name], overwrite, kind, inputs)
    if plot:  # matplotlib there, the file new (or --overwrite), before the projection
        guard(ctx, io.paths.check_not_input, plot, inputs)
        guard(ctx, io.check_plot, plot, overwrite)


def _read_inputs(ctx, target, points, method, feature_angle, zone, flip_normals, output,
                 save_pairs, pairs, engine):
    """The target read and its surface built (the setup's stages on a terminal), the
    contactors read and checked, the stored pairing loaded: (target, surface, contactors,
    pairing or None, the setup's `SetupStatus`)."""
    if save_pairs or pairs:  # a pairing file holds one diffuse surface's frames and supports
        if method == "diffuse" and feature_angle is not None and feature_angle < 180:
            log.info("--save-pairs/--pairs: one diffuse surface over the whole target "
                     "(--feature-angle ignored; the facets neither answer nor guard)")
        feature_angle = None
    setup = SetupStatus(ctx)  # its stages on a terminal, its time logged, past a second
    with setup:
        tgt, surf = guard(ctx, target_surface, target, zone, method, flip_normals,
                          feature_angle=feature_angle, progress=setup, **engine)
    if save_pairs or pairs:  # a pairing is one diffuse surface's: no facets, no guard
        from ..patches.surface import PatchedSurface

        if isinstance(surf, PatchedSurface):
            surf = surf.surfaces[0]
    guard(ctx, _one_file, points)
    contactors = guard(ctx, io.read_contactors, points)
    clash = io.result_clashes(contactors)
    if clash:  # before any work: every format would hold them twice or drop one
        raise DiffsurfError(f"{points}: its column{'s' if len(clash) > 1 else ''} "
                            f"{', '.join(clash)} {'are' if len(clash) > 1 else 'is'} also "
                            f"result column{'s' if len(clash) > 1 else ''} (a result fed back "
                            f"as POINTS?): drop or rename {'them' if len(clash) > 1 else 'it'}")
    # a column -o cannot hold (text in a mesh, bytes in CSV) is refused before any work
    guard(ctx, io.contactors.check_passthrough, output, contactors)
    log.info("%s: %s", points, count(len(contactors.points), "contactor"))
    pairing = None
    if pairs:
        pairing = guard(ctx, io.load_pairs, pairs, method=method,
                        n_contactors=len(contactors.points), n_target=len(tgt.points))
        pairing = guard(ctx, io.pairing_to_core, pairing, tgt, method, surf, pairs)
    return tgt, surf, contactors, pairing, setup


def _contact(surf, xc, rigid_target, pairing, second):
    """The contact element of every contactor (`element.contact`), its ValueError a one-line
    domain error."""
    from ..element.element import contact

    try:
        return contact(surf, xc, rigid_target=rigid_target, second=second, pairing=pairing)
    except ValueError as exc:
        raise DiffsurfError(str(exc)) from exc


def _log_projection(proj, surf, xc) -> None:
    """What answered the contactors and their statuses (stderr), and the warnings of inputs
    whose answers cannot be trusted: too few significant digits, contactors on target
    nodes."""
    if proj.source is not None and (proj.source == -1).any():
        log.info("%s answered by the facets (at sharp edges and corners, or on patches too "
                 "small or narrow for the basis)", count(int((proj.source == -1).sum()),
                                                         "contactor"))
    if proj.source is not None and (proj.source == -3).any():
        log.info("%s answered by the target's curved cells (its second-order cells, or its "
                 "facets curved through their normals: where the facets would answer)",
                 count(int((proj.source == -3).sum()), "contactor"))
    counts = np.bincount(proj.status, minlength=len(STATUS))
    log.info("status: %s", ", ".join(f"{c} {s}" for s, c in zip(STATUS, counts) if c))
    if proj.terms is not None:
        reduced = int(np.count_nonzero((proj.terms > 0) & (proj.terms < surf.nterms)
                                       & (proj.status <= PENETRATION)))
        if reduced:
            log.info("%s answered with a reduced basis (their support cannot "
                     "determine the %s basis: a strip one element wide, a row of nodes; "
                     "column terms)", count(reduced, "contactor"), surf.basis)
    spacing = surf.node_spacing
    digits = precision_digits(xc, surf.nodes, spacing)
    if digits < PRECISION_DIGITS:
        log.warning("warning: for a node spacing of %.3g, the coordinates' magnitude leaves "
                    "about %.1f significant digits of it in the input: gaps and signs are not "
                    "reliable; translate the model near the origin", float(np.min(spacing)),
                    max(digits, 0.0))
    same = coincident(xc, surf.nodes)
    if same:
        log.warning("warning: %d of %d contactors coincide with target nodes (their gap is that "
                    "of the target to itself): is POINTS part of TARGET? --zone selects the "
                    "target's cells in a multi-body mesh", same, len(xc))


def _write_element(ctx, result, tgt, method, m, penalty, residual, tangent, gauss_newton,
                   elements, rigid_target, overwrite) -> None:
    """The contact element's outputs: its summary (stderr), Σ ε g²/2, the assembled residual
    and tangent (Matrix Market), the element arrays (.npz)."""
    _log_elements(result)
    cdofs = np.arange(3 * m).reshape(m, 3)  # contactors first, then the target's points
    if rigid_target:
        args = (cdofs, None, 3 * m)
        where = "dof = 3*contactor + component (rigid target: contactors only)"
    else:
        args = (cdofs, 3 * (m + tgt.nodes)[:, None] + np.arange(3), 3 * (m + len(tgt.points)))
        where = "dof = 3*node + component, contactors first, then target file points"
    if penalty is not None:
        log.info("Σ ε g²/2 = %r", result.energy(penalty))
    if residual:
        guard(ctx, io.write_matrix, residual, result.residual(penalty, *args)[:, None],
              overwrite, comment=f"diffsurf residual R = sum eps g N; {where}")
    if tangent:
        guard(ctx, io.write_matrix, tangent,
              result.tangent(penalty, *args, gauss_newton=gauss_newton), overwrite,
              comment=("diffsurf tangent K = sum eps N N^T (Gauss-Newton)" if gauss_newton
                       else "diffsurf tangent K = sum eps (g M + N N^T)")
              + "; same dofs as R")
    if elements:
        guard(ctx, io.save_elements, elements, io.elements_from_core(result, tgt, method),
              overwrite)



def _one_file(points: str) -> None:
    """A ReadError for POINTS that name partitions (a directory or a glob) without --workers
    or --scheduler, saying so."""
    if points != "-" and not os.path.isfile(points) and (
            os.path.isdir(points) or any(c in points for c in "*?[")):
        what = "is a directory, expected a file" if os.path.isdir(points) else "no such file"
        raise io.ReadError(f"{points}: {what} (partitions, a directory or a glob of them, are "
                           f"read with --workers N, a local Dask cluster, or --scheduler "
                           f"ADDRESS)")


def _log_elements(result) -> None:
    """How many contactors got an element, and why the others did not (stderr)."""
    from ..projection import OUTSIDE, PENETRATION

    status = result.status
    log.info("%s%s", count(len(result), "element"),
             " (rigid target)" if result.rigid_target else "")
    none = []
    for code, name in enumerate(STATUS):
        many = int(np.sum(status == code))
        if code == PENETRATION or not many:
            continue
        why = ""
        if code >= OUTSIDE:  # outside, failed: say why
            reasons = np.bincount(result.reason[status == code], minlength=len(REASONS))
            why = " (" + ", ".join(f"{c} {REASONS[r]}" for r, c in enumerate(reasons) if c) + ")"
        none.append(f"{many} {name}{why}")
    if none:
        log.info("no element: %s", ", ".join(none))
    if len(result.lost):
        log.warning("warning: %s got no element but may be penetrating (the facets find them "
                    "inside the target; status outside or failed): do not take them for open",
                    count(len(result.lost), "contactor"))


def _on_cluster(ctx, target, points, output, overwrite, resume, scheduler, workers, method,
                zone, flip_normals, engine, **one_machine):
    """`project --scheduler/--workers`: the partitions of POINTS projected on a Dask cluster
    (diffsurf_cli.cluster), each written under -o as it is done."""
    if scheduler is not None and workers is not None:
        raise click.UsageError("--scheduler and --workers exclude each other: a cluster of "
                               "one's own, or a local one of N workers")
    for name, value in one_machine.items():
        if value is not None:
            raise click.UsageError(f"--{name.replace('_', '-')} needs a one-machine run, not "
                                   f"--scheduler/--workers")
    if output == "-":
        raise click.UsageError("--scheduler/--workers write files: give -o DIR/ (each "
                               "partition under its own name), -o 'DIR/*.parquet' or -o FILE")
    from .. import cluster

    def run():
        try:
            cluster.require()
            sources = cluster.partitions(points)
            targets = cluster.output_paths(sources, output, overwrite or resume)
            if resume and not overwrite:
                total = len(sources)
                sources, targets, done = cluster.pending(sources, targets)
                if not sources:  # no cluster to start, no status to tell
                    log.info("all %s already done; nothing to project",
                             count(total, "partition"))
                    return None
                log.info("--resume: %s of %d done, %s to project", count(done, "partition"),
                         total, count(len(sources), "partition"))
            setup = SetupStatus(ctx)  # the engine is the workers' (it does not pickle)
            with setup:
                _, surf = target_surface(target, zone, method, flip_normals, progress=setup,
                                         **engine)
            setup.report()
            log.info("%s: %s", points, count(len(sources), "partition"))
            bar = not ctx.obj.get("quiet") and stderr_is_terminal()
            # dask's own logs (a failed task's traceback, a worker restarted) with -v only
            quiet = logging.WARNING if ctx.obj.get("verbose") else logging.CRITICAL
            with cluster.connect(scheduler, workers, log_level=quiet) as client:
                n = len(client.nthreads())
                if not n:
                    log.warning("dask: %s has no workers yet: the job waits for them",
                                scheduler)
                log.info("dask: %s, %s%s", scheduler or "local cluster", count(n, "worker"),
                         f"; dashboard {client.dashboard_link}"
                         if _has_dashboard(client) else "")
                return cluster.project_partitions(surf, sources, targets, client=client,
                                                  progress=bar, coincident=coincident)
        except cluster.ClusterError as exc:
            raise DiffsurfError(str(exc)) from exc

    summary = guard(ctx, run)
    if summary is None:  # --resume found every partition done
        return
    log.info("status: %s", ", ".join(f"{c} {s}" for s, c in zip(STATUS, summary.status) if c))
    if summary.coincident:
        log.warning("warning: %d of %d contactors coincide with target nodes (their gap is that "
                    "of the target to itself): is POINTS part of TARGET? --zone selects the "
                    "target's cells in a multi-body mesh", summary.coincident,
                    summary.contactors)
    rate = summary.contactors / summary.wall_seconds if summary.wall_seconds else 0.0
    log.info("%s in %s: %.0f per second, %.2f µs CPU each",
             count(summary.contactors, "contactor"), count(summary.partitions, "partition"),
             rate,
             1e6 * summary.cpu_seconds / max(summary.contactors, 1))
    if summary.peak_memory:
        log.info("peak memory per worker: %s MB", ", ".join(
            f"{b / 2**20:.0f}" for _, b in sorted(summary.peak_memory.items())))


def _has_dashboard(client) -> bool:
    """Whether the cluster's dashboard answers (it needs bokeh on the scheduler's side: we
    can only see ours)."""
    import importlib.util

    try:
        return ("dashboard" in client.scheduler_info().get("services", {})
                and importlib.util.find_spec("bokeh") is not None)
    except Exception:  # noqa: BLE001 - the link is a courtesy
        return False
