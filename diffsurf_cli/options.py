"""Click options shared by the diffsurf commands, declared once (as rasterio's rio does)."""
from __future__ import annotations

import click

from . import basis, frame, surface, weight

#: The engine options and their defaults (chosen by measurement: see README, "Defaults").
DEFAULTS = dict(basis="quadratic", weight="wendland", support="radius", radius=None, k=None,
                frame="auto", recentre=False)

#: Named engine settings (`--preset`), each a full set of engine options. Chosen by measurement
#: (`python benchmarks/compare.py --candidates` prints the table of the candidates; the README's
#: "Presets" gives the figures). Every preset leaves no more points outside or failed than
#: `default` on the closed test shapes (spheres, tori).
PRESETS = {
    # Support of the 12 nearest nodes (2x the quadratic basis): 1.3-1.7x the default's
    # throughput before the compiled kernel, gap RMS error within 1.7x of default on every
    # test shape. Fewer nodes (k = 8-10, or radius 1.6) fail silently on the structured torus,
    # whose inner equator is 1.7x anisotropic: gap errors up to 0.4 tube radii and normals off
    # by 86 degrees at k = 10, n = 32.
    "fast": dict(DEFAULTS, support="knn", k=12),
    # Today's defaults (README, "Defaults"): the most accurate gap of every candidate measured.
    "default": dict(DEFAULTS),
    # Cubic basis over 3 spacings: normals converge one order faster (O(h^3)), 2-6x smaller
    # normal error than default on the finer cylinders and structured tori; the gap error is
    # 1.4-5x larger and it is 3-4x slower. Quadratic with --recentre left points unsettled on
    # the coarse torus (4 of 3000); a Gaussian weight over 2.5-3 spacings was less accurate.
    "accurate": dict(DEFAULTS, basis="cubic", radius=3.0),
}


def engine(f):
    """Options that build the diffuse surface (basis, weight, support, frame, projection)."""
    decorators = [
        click.option("--preset", type=click.Choice(list(PRESETS)), default="default",
                     show_default=True,
                     help="Named engine settings; an option given explicitly overrides its "
                          "preset value. " + describe_presets()),
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


def summary(options: dict) -> str:
    """One token describing engine options: 'quadratic/wendland/radius2' or '.../knn12'."""
    from .surface import DEFAULT_RADIUS

    if options["support"] == "knn":
        support = f"knn{options['k'] if options['k'] is not None else 3 * basis.size(options['basis'])}"
    else:
        radius = options["radius"] if options["radius"] is not None else DEFAULT_RADIUS[options["basis"]]
        support = f"radius{radius:g}"
    parts = [options["basis"], options["weight"], support]
    if options["frame"] != "auto":
        parts.append(f"frame-{options['frame']}")
    if options["recentre"]:
        parts.append("recentre")
    return "/".join(parts)


def describe_presets() -> str:
    """The presets and what they expand to, for --help."""
    words = {"knn": "knn k=", "radius": "radius "}

    def spell(token):
        for short, long in words.items():
            if token.startswith(short):
                return long + token[len(short):]
        return token

    return "; ".join(f"{name} = {', '.join(spell(t) for t in summary(o).split('/'))}"
                     for name, o in PRESETS.items()) + "."


def resolve(ctx: click.Context, engine_kwargs: dict) -> dict:
    """The engine options of a command: its --preset, overridden by options given explicitly.

    An option counts as explicit when it did not come from its default (command line,
    environment variable or a default map); any other engine option takes the preset's value.

    Parameters
    ----------
    ctx : click.Context
        The command's context (``click.get_current_context()``).
    engine_kwargs : dict
        The command's engine keyword arguments, ``preset`` included ('default' if absent).

    Returns
    -------
    dict
        basis, weight, support, radius, k, frame, recentre: keyword arguments of
        `DiffuseSurface`.
    """
    from click.core import ParameterSource

    kwargs = dict(engine_kwargs)
    name = kwargs.pop("preset", None) or "default"
    if name not in PRESETS:
        raise click.BadParameter(f"unknown preset {name!r}: expected one of {', '.join(PRESETS)}",
                                 param_hint="'--preset'")
    resolved = dict(PRESETS[name])
    for key in resolved:
        source = ctx.get_parameter_source(key) if key in kwargs else None
        if source is not None and source is not ParameterSource.DEFAULT:
            resolved[key] = kwargs[key]
    return resolved


def output(f):
    f = click.option("--overwrite", is_flag=True, help="Replace output files that exist.")(f)
    f = click.option("-o", "--output", "output", metavar="FILE", default="-", show_default=True,
                     help="Output: .csv, or any mesh format meshio writes (.vtu, ...); "
                          "'-' for CSV on stdout.")(f)
    return f
