"""Click options shared by the diffsurf commands, declared once (as rasterio's rio does)."""
from __future__ import annotations

import logging
import math
import sys

import click

from ..mls import basis, frame, surface, weight
from ..patches.segment import FEATURE_ANGLE_DEG
from ..presets import DEFAULTS, PRESETS, RENAMED, describe_presets, engine_options


def engine(f):
    """Options that build the diffuse surface (basis, weight, support, frame, projection)."""
    decorators = [
        click.option("--preset", type=_PresetChoice(list(PRESETS)), default="default",
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
        click.option("--radius", type=FiniteFloatRange(min=1.0, min_open=True),
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
                     help="Use only the surface cells of this Gmsh physical group, cell set or "
                          "node set, or the faces of this Abaqus/CalculiX *SURFACE."),
    ]
    for d in reversed(decorators):
        f = d(f)
    return f


class FiniteFloatRange(click.FloatRange):
    """A `click.FloatRange` that refuses NaN and infinities: click's range lets NaN through
    (every comparison with it is false) and inf through an open-ended range, and the engine
    then ran on them (`--penalty nan` wrote a tangent full of NaN, `--edge-length nan` ended
    in a traceback)."""

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{number} is not a finite number, expected one in the range "
                      f"{self._describe_range()}.", param, ctx)
        return number


class _PresetChoice(click.Choice):
    """The presets, listed by their names; a former name (`presets.RENAMED`) still taken."""

    def convert(self, value, param, ctx):
        if value in RENAMED:
            return value
        return super().convert(value, param, ctx)


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
        `DiffuseSurface` (`presets.engine_options`).
    """
    from click.core import ParameterSource

    kwargs = dict(engine_kwargs)
    name = kwargs.pop("preset", None) or "default"
    if name in RENAMED:
        from .common import log

        log.warning("warning: --preset %s is now called %s (it has the smallest normal "
                    "errors, not the smallest gap errors)", name, RENAMED[name])
        name = RENAMED[name]
    explicit = {}
    for key in PRESETS.get(name, ()):
        source = ctx.get_parameter_source(key) if key in kwargs else None
        if source is not None and source is not ParameterSource.DEFAULT:
            explicit[key] = kwargs[key]
    try:
        resolved = engine_options(name, **explicit)
    except ValueError as exc:  # an unknown preset
        raise click.BadParameter(str(exc), param_hint="'--preset'") from None
    _check_support(ctx, resolved, "support" in explicit, name)
    return resolved


def _check_support(ctx: click.Context, resolved: dict, support_given: bool, preset: str):
    """A UsageError for -k without a knn support, or --radius with one: the support ignores
    the other's size, and the run was byte-identical to one without the option."""
    support = resolved["support"]
    size = {"knn": "radius", "radius": "k"}.get(support)  # the other support's size
    if size is None or not given(ctx, size):
        return
    flag, needs = ("-k", "knn") if size == "k" else ("--radius", "radius")
    where = "" if support_given or preset == "default" else f", from --preset {preset}"
    raise click.UsageError(f"{flag} applies to --support {needs} (the support here is "
                           f"{support}{where}): give --support {needs} or leave {flag} out")


#: `--method quadric` (`mls.quadric.QuadricSurface`): its help, and the one engine option it takes
QUADRIC_HELP = ("quadric: moving algebraic quadrics fitted to the nodes' positions and "
                "normals, for smooth coarse curved targets (a few elements per quarter circle; "
                "no creases, no guard; takes --radius only).")


def diffuse_only(ctx: click.Context, method: str, *names: str) -> None:
    """Refuse (a UsageError naming them) the diffuse method's options `names` given with
    another --method."""
    unused = given(ctx, *names)
    if unused:
        raise click.UsageError(f"{flags(ctx, unused)} appl{'y' if len(unused) > 1 else 'ies'} "
                               f"to the diffuse method only: leave "
                               f"{'them' if len(unused) > 1 else 'it'} out with --method "
                               f"{method}")


def quadric_engine(ctx: click.Context, engine: dict) -> dict:
    """The quadric method's options from a command's engine options: --radius when given;
    a diffuse-only option given is refused."""
    diffuse_only(ctx, "quadric", "preset", "basis", "weight", "support", "k", "frame",
                 "recentre", "feature_angle")
    return {"radius": engine["radius"]} if given(ctx, "radius") else {}


def given(ctx: click.Context, *names: str) -> list[str]:
    """Those of the parameters `names` given explicitly (not from their default: the command
    line, an environment variable or a default map, as `resolve` counts them), in order."""
    from click.core import ParameterSource

    return [n for n in names
            if ctx.get_parameter_source(n) not in (None, ParameterSource.DEFAULT)]


def flags(ctx: click.Context, names) -> str:
    """The command line spelling of parameters: '--basis, -k'."""
    spelt = {p.name: p.opts[0] for p in ctx.command.params}
    return ", ".join(spelt.get(n, n) for n in names)


def output(f):
    f = click.option("--overwrite", is_flag=True, help="Replace output files that exist.")(f)
    f = click.option("-o", "--output", "output", metavar="FILE", default="-", show_default=True,
                     help="Output: .csv (comma separated), .tsv or .txt (tab separated), "
                          ".parquet, or a mesh format that holds point data (.vtu, .vtk, .msh, "
                          ".avs; others would lose columns and are refused); '-' for CSV on "
                          "stdout; /dev/null, /dev/stdout or a FIFO get CSV (TSV if named "
                          ".tsv/.txt).")(f)
    return f


def _verbosity(ctx: click.Context, param: click.Parameter, value):
    """-v/-q callback: accumulate over the group and the command (either side of the command
    name), then set the level of the 'diffsurf' logger (stderr only)."""
    obj = ctx.ensure_object(dict)  # a command's context shares its group's object
    if param.name == "verbose":
        obj["verbose"] = obj.get("verbose", 0) + value
    else:
        obj["quiet"] = obj.get("quiet", False) or value
    log = logging.getLogger("diffsurf")
    if not log.handlers or getattr(log.handlers[0], "stream", None) is not sys.stderr:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("diffsurf: %(message)s"))
        log.handlers[:] = [handler]
    log.setLevel(logging.ERROR if obj.get("quiet")
                 else logging.DEBUG if obj.get("verbose", 0) > 1 else logging.INFO)
    log.propagate = False
    return value


def verbosity(f):
    """-v/--verbose and -q/--quiet, declared on the group and on every command, so they work
    before or after the command name (`diffsurf -q project ...` and `diffsurf project ... -q`)."""
    f = click.option("-q", "--quiet", is_flag=True, expose_value=False, callback=_verbosity,
                     help="Only errors on stderr.")(f)
    f = click.option("-v", "--verbose", count=True, expose_value=False, callback=_verbosity,
                     help="More logging; -v also shows tracebacks.")(f)
    return f


def feature_angle(f=None, *, more: str = ""):
    """--feature-angle DEG: the diffuse surface per smooth patch (`patches.surface`).

    `more` ends its help with what it means for the command's own options (each command's
    help names only the options it has): ``@feature_angle`` or
    ``@feature_angle(more=" ...")``."""
    def decorate(f):
        return click.option(
            "--feature-angle", type=FiniteFloatRange(min=0, max=180), metavar="DEG",
            default=FEATURE_ANGLE_DEG, show_default=True,
            help="Build the diffuse surface per smooth patch, bounded by edges whose facets "
                 "differ by more than DEG degrees, by the file's face or region tags, by flat "
                 "faces and by open boundaries; answer each point with the closest patch "
                 "(sharp edges stay sharp, the two sides of a thin wall never mix). 180: one "
                 "diffuse surface over the whole target." + more)(f)

    return decorate if f is None else decorate(f)
