"""The engine options of a diffuse surface, their defaults and the named presets (`--preset`).

A preset is a full set of `DiffuseSurface` options; `engine_options` expands one and lets
options given explicitly override it, as ``diffsurf project --preset fast --basis cubic`` does.
"""
from __future__ import annotations

from .mls import basis as _basis
from .tol import DEFAULT_RADIUS

#: The engine options and their defaults (chosen by measurement: see docs/presets.md,
#: "Defaults, and why").
DEFAULTS = dict(basis="quadratic", weight="wendland", support="radius", radius=None, k=None,
                frame="auto", recentre=False)

#: Named engine settings (`--preset`), each a full set of engine options, chosen by measurement:
#: `python benchmarks/compare.py --candidates` measures the candidates on spheres, cylinders,
#: saddles and tori (benchmarks/results/candidates.md, 20000 points per mesh; figures below
#: from it) and `python benchmarks/compare.py` the presets against the peers (compare.md).
#: No preset leaves a point outside or failed on the closed shapes (spheres, tori).
PRESETS = {
    # The 12 nearest nodes (2x the quadratic basis; the default's radius holds 13-15, and a
    # frame ball 1.5x wider): gap RMS error within 1.45x of default on every mesh (worst:
    # structured torus n=128, 5.1e-6 against 3.5e-6), no point outside. Smaller supports fail
    # silently on the structured torus, whose inner equator is 1.7x anisotropic: knn k=8 or
    # 10, radius 1.6 or 1.75 give normals off by 75-89 degrees and gaps off by up to 0.15 (37%
    # of the tube radius) at n=32, and k=8 leaves points outside.
    "fast": dict(DEFAULTS, support="knn", k=12),
    # The defaults (docs/presets.md, "Defaults, and why"): the smallest gap error of every
    # candidate measured.
    "default": dict(DEFAULTS),
    # Cubic over 3 spacings: the normal error converges one order faster (O(h^3)); on the finest
    # meshes it is 0.51x default on the cylinder, 0.16x on the structured torus, the same on
    # the sphere and on the Gmsh torus. Its gap error is 1.4-5x default's everywhere (both
    # O(h^4); the wider support has a larger constant). No candidate had a smaller gap error
    # than default: --recentre matched it but left points unsettled (16 of 20000 on the torus
    # n=32, 1 on the sphere n=4), a Gaussian weight over 2.5 spacings was 6x better on the fine
    # cylinder's normals but 2x worse on the tori's, with 2-3.5x the gap error.
    # Named for what it is better at (issue 22: "accurate" had the larger gap errors).
    "normals": dict(DEFAULTS, basis="cubic", radius=3.0),
}

#: The other fit `tune` measures beside the presets: `diffsurf project --method quadric`
#: (`mls.quadric.QuadricSurface`, moving algebraic quadrics fitted to positions and normals;
#: its radius and normal weight chosen by benchmarks/coarse_fits.py). Not a preset: no
#: DiffuseSurface option applies to it.
QUADRIC = dict(method="quadric", radius=2.0, beta=0.03)

#: Former preset names, still taken (with a warning by the command line): name -> preset.
RENAMED = {"accurate": "normals"}
#: What each preset is for, in --help.
PRESET_NOTES = {
    "fast": "the fewest support nodes that stayed reliable",
    "default": "the smallest gap errors",
    "normals": "the smallest normal errors on fine curved meshes; larger gap errors",
}


def engine_options(preset: str = "default", **overrides) -> dict:
    """The engine options of a preset, with the options given explicitly overriding it.

    Parameters
    ----------
    preset : {'fast', 'default', 'normals'}
        A name of `PRESETS` (or a former name, `RENAMED`); None means 'default'.
    **overrides
        `DiffuseSurface` options that win over the preset's (an explicit value equal to the
        built-in default wins too: ``engine_options('normals', basis='quadratic')`` is the
        quadratic basis over 3 spacings).

    Returns
    -------
    dict
        basis, weight, support, radius, k, frame, recentre (and any other override):
        keyword arguments of `DiffuseSurface`.

    Raises
    ------
    ValueError
        For an unknown preset.
    """
    name = RENAMED.get(preset, preset) or "default"
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}: expected one of {', '.join(PRESETS)}")
    return {**PRESETS[name], **overrides}


def summary(options: dict) -> str:
    """One token describing engine options: 'quadratic/wendland/radius2' or '.../knn12'
    ('quadric/radius2/beta0.03' for `QUADRIC`)."""
    if options.get("method") == "quadric":
        return f"quadric/radius{options['radius']:g}/beta{options['beta']:g}"
    if options["support"] == "knn":
        k = options["k"] if options["k"] is not None else 3 * _basis.size(options["basis"])
        support = f"knn{k}"
    else:
        radius = options["radius"]
        support = f"radius{DEFAULT_RADIUS[options['basis']] if radius is None else radius:g}"
    parts = [options["basis"], options["weight"], support]
    if options["frame"] != "auto":
        parts.append(f"frame-{options['frame']}")
    if options["recentre"]:
        parts.append("recentre")
    return "/".join(parts)


def describe_presets() -> str:
    """The presets and what they expand to, in words (for --help and reports)."""
    words = {"knn": "knn k=", "radius": "radius "}

    def spell(token):
        for short, long in words.items():
            if token.startswith(short):
                return long + token[len(short):]
        return token

    return "; ".join(f"{name} = {', '.join(spell(t) for t in summary(o).split('/'))}"
                     + (f" ({PRESET_NOTES[name]})" if name in PRESET_NOTES else "")
                     for name, o in PRESETS.items()) + "."
