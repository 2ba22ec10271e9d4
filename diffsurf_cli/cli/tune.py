"""`diffsurf tune`: measure each preset's accuracy and speed on a target, recommend one."""
from __future__ import annotations

import os

import click
import numpy as np

from .. import io
from ..presets import PRESETS, QUADRIC, engine_options, summary
from ..targets import read_surface
from . import options
from .common import DiffsurfError, command_line_message, guard, log, need_stdin, need_stdout


@click.command("tune")
@options.verbosity
@click.argument("target", metavar="TARGET")
@click.argument("points", metavar="[POINTS]", required=False)
@click.option("--sample", type=click.IntRange(min=1), default=200, show_default=True,
              help="Target nodes to hold out in all (leave-one-out).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the held-out nodes and of the sampled timing points.")
@click.option("--plot", metavar="FILE.png", default=None,
              help="Draw the trade curve (error against points/s) to a .png, .svg or .pdf; "
                   "needs matplotlib (pip install 'diffsurf[plot]').")
@click.option("--overwrite", is_flag=True, help="Replace the --plot file if it exists.")
@click.option("--flip-normals", is_flag=True,
              help="Reverse the target's orientation (+normal into the target).")
@click.option("--zone", metavar="NAME", default=None,
              help="Use only the surface cells of this Gmsh physical group or cell set.")
@options.feature_angle
@click.pass_context
def tune_command(ctx, target, points, sample, seed, plot, overwrite, flip_normals, zone,
                 feature_angle):
    """Measure each preset's accuracy and speed on TARGET, and recommend one.

    Each preset is measured on the surface `diffsurf project` answers with: the diffuse
    surface per smooth patch (--feature-angle, the file's face tags), the facets at sharp
    edges and where a patch cannot answer, every answer guarded by the facets. The last row,
    quadric, is `diffsurf project`'s quadric method (quadrics fitted to positions and normals,
    one surface, no guard): the accurate one on smooth coarse curved targets, a few elements
    per quarter circle; `recommended: quadric` means that method.

    Accuracy needs no exact answer: target nodes are held out (leave-one-out), the diffuse
    surface is built without them, and their distance |gap| to it is the error. Removing a
    node coarsens the mesh there, so the estimate is pessimistic in absolute terms; it ranks
    the presets. Speed: points/s projecting POINTS (CSV, Parquet, '-' for CSV on stdin, or a
    mesh file's nodes), or, without POINTS, 10000 points sampled within one node spacing of
    the facets (fewer than 10000 POINTS are repeated up to 10000 for the timing).

    Prints one header line and one row per preset (whitespace-separated columns): preset,
    settings (basis/weight/support), loo_rms and loo_max (held-out |gap|, target units),
    rms/h and max/h (the same in local node spacings h), loo_outside (held-out nodes left
    outside or failed, not in the errors), outside+failed (timed points left outside or
    failed), points/s. The last line is `recommended: NAME`: the fastest preset whose
    loo_rms is within 1.25x the best, among those leaving the fewest points outside or failed
    (held-out plus timed; a preset with more failures than another is never recommended).
    Speeds are points per CPU second, best of 5 runs; within 10% they are a tie, won by the
    smaller loo_rms. `recommended: none` when no such preset has an error estimate. Progress
    goes to stderr.

    \b
    Examples:
      diffsurf tune target.msh
      diffsurf tune target.msh contactors.csv --plot trade.png
      diffsurf tune plate_and_cylinder.msh --zone cylinder --sample 500 --seed 1
    """
    from .. import tune as tuning

    if overwrite and not plot:  # the only file tune writes
        raise click.UsageError("--overwrite applies to the --plot file: give --plot FILE.png "
                               "or leave --overwrite out")
    need_stdout("tune prints its table there")  # before the minutes of measuring
    need_stdin(points)
    if plot:  # matplotlib there, the file new (or --overwrite), before any work
        guard(ctx, io.paths.check_not_input, plot, (("TARGET", target), ("POINTS", points)))
        guard(ctx, io.check_plot, plot, overwrite)
    tgt, nodes, faces = guard(ctx, read_surface, target, zone)
    angle = 180.0 if feature_angle is None else feature_angle
    tags = np.concatenate(tgt.tags) if tgt.tags is not None else None
    xc = None
    if points:
        xc = guard(ctx, io.read_contactors, points).points
        log.info("%s: %d points to time", points, len(xc))
    settings = {name: engine_options(name) for name in PRESETS}
    settings["quadric"] = dict(QUADRIC)  # the other fit: --method quadric
    try:
        result = tuning.tune(nodes, faces, settings, xc, sample=sample, seed=seed,
                             flip=flip_normals, progress=log.info,
                             patches={"feature_angle": angle, "tags": tags,
                                      "smooth_tags": tgt.faces_tagged})
    except ValueError as exc:
        raise DiffsurfError(f"{target}: {command_line_message(exc)}") from exc
    header = ["preset", "settings", "loo_rms", "loo_max", "rms/h", "max/h", "loo_outside",
              "outside+failed", "points/s"]
    rows = [[e.name, summary(e.options), f"{e.loo_rms:.3g}", f"{e.loo_max:.3g}",
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
    if result.recommended is None:
        log.warning("no preset could estimate its error among those with the fewest failures "
                    "(every held-out node outside or failed): no recommendation")
    guard(ctx, click.echo, "\n".join(lines + [f"recommended: {result.recommended or 'none'}"]))
