"""Click options shared by the diffsurf commands, declared once (as rasterio's rio does)."""
from __future__ import annotations

import click

from . import basis, frame, surface, weight

#: The engine options and their defaults (chosen by measurement: see README, "Defaults").
DEFAULTS = dict(basis="quadratic", weight="wendland", support="radius", radius=None, k=None,
                frame="auto", recentre=False)


def engine(f):
    """Options that build the diffuse surface (basis, weight, support, frame, projection)."""
    decorators = [
        click.option("--basis", type=click.Choice(basis.BASES), default=DEFAULTS["basis"],
                     show_default=True, help="Polynomial basis of the local fit [14]."),
        click.option("--weight", type=click.Choice(weight.WEIGHTS), default=DEFAULTS["weight"],
                     show_default=True,
                     help="Weight function [15]; 'singular' interpolates the nodes."),
        click.option("--support", type=click.Choice(surface.SUPPORTS),
                     default=DEFAULTS["support"], show_default=True,
                     help="Support: nodes within --radius spacings, or the -k nearest."),
        click.option("--radius", type=click.FloatRange(min=1.0, min_open=True),
                     default=DEFAULTS["radius"],
                     help="Domain of influence R, in local node spacings "
                          "[default: 2.0; 3.0 for the cubic basis]."),
        click.option("-k", "k", type=click.IntRange(min=3), default=None,
                     help="Nearest nodes per fit with --support knn [default: 3x basis size]."),
        click.option("--frame", type=click.Choice(frame.FRAMES), default=DEFAULTS["frame"],
                     show_default=True,
                     help="Diffuse frame: one mean plane, a PCA frame per point, or auto."),
        click.option("--recentre/--no-recentre", default=DEFAULTS["recentre"], show_default=True,
                     help="Re-centre the fit on the proximal point until it stops moving "
                          "(projection on the diffuse surface itself)."),
        click.option("--flip-normals", is_flag=True,
                     help="Reverse the target's orientation (+normal into the target)."),
        click.option("--zone", metavar="NAME", default=None,
                     help="Use only the surface cells of this Gmsh physical group or cell set."),
    ]
    for d in reversed(decorators):
        f = d(f)
    return f


def output(f):
    f = click.option("--overwrite", is_flag=True, help="Replace output files that exist.")(f)
    f = click.option("-o", "--output", "output", metavar="FILE", default="-", show_default=True,
                     help="Output: .csv, or any mesh format meshio writes (.vtu, ...); "
                          "'-' for CSV on stdout.")(f)
    return f
