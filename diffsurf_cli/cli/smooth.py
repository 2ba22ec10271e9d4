"""`diffsurf smooth`: resample a faceted target onto its diffuse surface."""
from __future__ import annotations

import os

import click
import numpy as np

from .. import io
from ..mls.frame import corner_faces
from . import options
from .common import DiffsurfError, SetupStatus, guard, log, progress_bar, target_surface


@click.command("smooth")
@options.verbosity
@click.argument("target", metavar="TARGET")
@options.engine
@click.option("-o", "--output", "output", metavar="FILE", required=True,
              help="Output mesh; the format follows the extension (.vtu, .vtk, .msh, .stl, ...).")
@click.option("--overwrite", is_flag=True, help="Replace the output file if it exists.")
@click.option("--levels", type=click.IntRange(0, 8), default=None,
              help="Uniform subdivisions of every facet (each splits a facet in 4) [default: 1].")
@click.option("--edge-length", type=options.FiniteFloatRange(min=0, min_open=True), default=None,
              metavar="L", help="Subdivide until no facet edge is longer than L.")
@click.option("--keep-nodes", is_flag=True,
              help="Pin the original nodes (approximant weights would move them).")
@click.option("--plot", metavar="FILE.png", default=None,
              help="Also draw the faceted and the smooth surfaces side by side to a .png, .svg "
                   "or .pdf; needs matplotlib (pip install 'diffsurf[plot]').")
@click.option("--method", type=click.Choice(["diffuse", "quadric"]), default="diffuse",
              show_default=True, help="The diffuse surface, or " + options.QUADRIC_HELP)
@options.feature_angle
@click.pass_context
def smooth(ctx, target, output, overwrite, levels, edge_length, keep_nodes, plot, method,
           feature_angle, zone, flip_normals, **engine):
    """Resample the faceted TARGET onto its diffuse surface.

    Each facet is refined (triangles into 4 triangles, quads into 4 quads), then every vertex
    is placed on the diffuse surface of the ORIGINAL nodes, with the same engine options as
    `project`. Higher-order cells are refined from their corners (their mid-side nodes still
    feed the fit). Point data: normal, principal curvatures k1 >= k2 (> 0 convex), moved (how
    far each vertex moved) and placed (1 on the diffuse surface, 0 left on the facets where
    no support could carry the fit). A refinement that would not fit in memory is refused
    before it starts, with the size it would need. With approximant weights the original nodes
    move off the facets; the largest such move is reported on stderr (--keep-nodes pins them).

    \b
    Examples:
      diffsurf smooth cylinder.msh -o cylinder_smooth.vtu --levels 2
      diffsurf smooth part.stl -o part_smooth.stl --edge-length 0.5
      diffsurf smooth cylinder.msh -o nodes_fixed.vtu --weight singular
      diffsurf smooth torus.msh -o torus_smooth.vtu --plot compare.png
      diffsurf smooth torus.msh -o torus_quadric.vtu --method quadric --levels 2
    """
    from ..smooth import levels_for, refined_size
    from ..smooth import smooth as smooth_surface

    engine = (options.quadric_engine(ctx, engine) if method == "quadric"
              else options.resolve(ctx, engine))
    if levels is not None and edge_length is not None:
        raise click.UsageError("give --levels or --edge-length, not both")
    if output == "-":
        raise click.BadParameter("'-' (stdout) cannot hold a mesh, expected a file name",
                                 param_hint="'-o'")
    # never the input, --overwrite or not
    guard(ctx, io.check_output_path, output, overwrite, "mesh", (("TARGET", target),))
    if plot:  # matplotlib there, the file new (or --overwrite), before the smoothing
        if os.path.realpath(plot) == os.path.realpath(output):
            raise click.UsageError(f"-o and --plot both name {plot}, expected a file per "
                                   f"output")
        guard(ctx, io.paths.check_not_input, plot, (("TARGET", target),))
        guard(ctx, io.check_plot, plot, overwrite)
    # the mesh and the figure are renamed into place together, or neither is
    batch = ctx.with_resource(io.output_batch())
    setup = SetupStatus(ctx)  # its stages on a terminal, its time logged, past a second
    with setup:
        tgt, surf = guard(ctx, target_surface, target, zone, method, flip_normals,
                          feature_angle=feature_angle, progress=setup, **engine)
        setup.engine(surf)  # the smoothing's, built before its bar
    setup.report()
    faces = [np.searchsorted(tgt.nodes, f) for f in corner_faces(tgt.cells)]
    if edge_length is not None:
        levels = levels_for(surf.nodes, faces, edge_length)
    levels = 1 if levels is None else levels
    total = int(refined_size(faces, levels)[0])
    log.info("%d levels: placing %d vertices on the smooth surface", levels, total)
    try:
        with progress_bar(ctx, total, "smoothing") as bar:
            result = smooth_surface(surf, faces, levels, keep_nodes, progress=bar)
    except MemoryError as exc:
        raise DiffsurfError(f"{target}: {exc}") from None
    nfaces = sum(len(f) for f in result.faces)
    log.info("%d levels: %d vertices, %d facets", levels, len(result.vertices), nfaces)
    log.info("largest move of an original node off the facets: %r%s", result.node_deviation,
             " (pinned by --keep-nodes)" if keep_nodes else "")
    if result.unplaced:
        log.warning("%d vertices had no usable support and stay on the facets (placed 0)",
                    result.unplaced)
    guard(ctx, io.write_mesh, output, result.vertices, result.faces, result.point_data, overwrite)
    if plot:
        fig = io.smooth_figure(surf.nodes, faces, result.vertices, result.faces, target=target,
                               output=output, levels=levels)
        guard(ctx, io.write_figure, plot, fig, overwrite)
    guard(ctx, batch.commit)
