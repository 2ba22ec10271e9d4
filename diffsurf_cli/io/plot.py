"""Pictures of a command's result (``project --plot``, ``smooth --plot``): matplotlib Figures
built without pyplot (no display, no global state), written by :func:`.figure.write_figure`.

matplotlib is an optional extra (``pip install 'diffsurf[plot]'``): it is imported inside the
functions, and :func:`check_plot` says how to install it before any work is done.
"""
from __future__ import annotations

import os

import numpy as np

from .errors import WriteError
from .paths import check_output_path

__all__ = ["MAX_POINTS", "check_plot", "require_matplotlib", "project_figure", "smooth_figure",
           "target_edges"]

#: the most contactors drawn: beyond it a sample is (the figure stays quick to draw and small).
MAX_POINTS = 200_000

#: the most edges of a target drawn all; beyond it only its outline and feature edges are.
MAX_EDGES = 30_000

#: the most facets of a surface drawn (smooth --plot); beyond it a sample is.
MAX_FACETS = 150_000

#: a feature edge of the drawn outline: its facets' normals differ by more than this (degrees).
FEATURE_ANGLE = 30.0

#: the gap's colours: red for a penetration (g < 0), blue for open (g > 0), grey for contact.
CMAP = "coolwarm_r"

#: unanswered contactors (outside, failed: NaN gap).
UNANSWERED_COLOUR = "0.55"


def require_matplotlib() -> None:
    """WriteError with the one line saying how to install matplotlib, if it is missing."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise WriteError("--plot needs matplotlib: pip install 'diffsurf[plot]'") from None


def check_plot(path: str, overwrite: bool) -> None:
    """Before any work: matplotlib is there (:func:`require_matplotlib`) and ``path`` may be
    written as a figure (.png, .svg or .pdf; an existing file only with ``overwrite``)."""
    require_matplotlib()
    if str(path) == "-":  # check_output_path takes '-' for stdout, the results' only
        raise WriteError("-: a figure is not written to stdout, expected a .png, .svg or .pdf "
                         "file name")
    check_output_path(path, overwrite, kind="figure")


def _facets(points: np.ndarray, cells) -> list[np.ndarray]:
    """The corner connectivity of surface ``cells`` (meshio type, connectivity): triangles
    (f, 3) and quads (f, 4); higher-order cells list their corners first."""
    out = []
    for kind, conn in cells:
        conn = np.asarray(conn, dtype=np.int64)
        corners = 3 if kind.startswith("triangle") else 4 if kind.startswith("quad") else 0
        if corners and conn.ndim == 2 and conn.shape[1] >= corners and len(conn):
            out.append(conn[:, :corners])
    return out


def target_edges(points: np.ndarray, cells, tags=None,
                 max_edges: int = MAX_EDGES) -> tuple[np.ndarray, bool]:
    """The edges of a target to draw, as (e, 2, 3) segments, and whether they are all of them.

    Every edge of the facets when there are at most ``max_edges``; else the outline: the
    boundary edges (one facet), the edges where facets meet at more than
    :data:`FEATURE_ANGLE` and those between two tags (``tags``: per block of ``cells``, one
    per cell, or None).
    """
    points = np.asarray(points, dtype=np.float64)
    facets = _facets(points, cells)
    if not facets:
        return np.zeros((0, 2, 3)), True
    edges, owner = [], []
    start = 0
    for f in facets:
        k = f.shape[1]
        edges.append(np.stack([f, np.roll(f, -1, axis=1)], -1).reshape(-1, 2))
        owner.append(np.repeat(np.arange(start, start + len(f)), k))
        start += len(f)
    edges, owner = np.concatenate(edges), np.concatenate(owner)
    key = np.sort(edges, axis=1)
    unique, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    if len(unique) <= max_edges:
        return points[unique], True
    # facet normals (Newell's: corners' cross products summed, a quad's too)
    normals = np.concatenate([
        np.cross(points[f], points[np.roll(f, -1, axis=1)]).sum(axis=1) for f in facets])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    # each edge's first two facets (a non-manifold edge: its first two)
    order = np.argsort(inverse, kind="stable")
    first = np.searchsorted(inverse[order], np.arange(len(unique)))
    a = owner[order[first]]
    b = owner[order[np.minimum(first + 1, len(order) - 1)]]
    keep = counts == 1
    cos = np.einsum("ij,ij->i", normals[a], normals[b])
    keep |= (counts >= 2) & (cos < np.cos(np.radians(FEATURE_ANGLE)))
    if tags is not None:
        tag = np.concatenate([np.asarray(t) for t, f in zip(tags, cells) if len(f)])
        if len(tag) == len(normals):
            keep |= (counts >= 2) & (tag[a] != tag[b])
    return points[unique[keep]], False


def _limits(ax, *clouds: np.ndarray) -> None:
    """Equal aspect: the limits of all ``clouds`` together, and a box shaped as they are (a
    flat scene stays flat, no axis is thinner than 4% of the longest), seen from where its
    longer horizontal side runs across the picture."""
    pts = np.concatenate([c.reshape(-1, 3) for c in clouds if len(c)])
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not len(pts):
        ax.view_init(elev=28, azim=-58)
        return
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    span = hi - lo
    longest = max(float(span.max()), 1e-12)
    span = np.maximum(span, 0.04 * longest)
    mid = (lo + hi) / 2
    pad = 0.02 * longest
    ax.set_xlim(mid[0] - span[0] / 2 - pad, mid[0] + span[0] / 2 + pad)
    ax.set_ylim(mid[1] - span[1] / 2 - pad, mid[1] + span[1] / 2 + pad)
    ax.set_zlim(mid[2] - span[2] / 2 - pad, mid[2] + span[2] / 2 + pad)
    ax.set_box_aspect(span + 2 * pad, zoom=1.08)
    # azimuth -90 looks along +y (x across the picture), 0 along -x (y across)
    ratio = span[1] / span[0]
    ax.view_init(elev=28, azim=-25 if ratio > 1.5 else -65 if ratio < 1 / 1.5 else -58)


def _order(*clouds: np.ndarray) -> list[int]:
    """The coordinates drawn as matplotlib's x, y, z: the last (drawn upwards) is the thinnest
    of the scene (stray points aside) when it is clearly thinner than the others (a plate's
    normal, a layer of contactors: seen from above), else z; a cyclic order, so the axes stay
    right-handed.

    (matplotlib's own ``vertical_axis`` misplaces the equal aspect: the coordinates are
    permuted here instead, and the axes labelled with their names.)"""
    pts = np.concatenate([c.reshape(-1, 3) for c in clouds if len(c)])
    pts = pts[np.isfinite(pts).all(axis=1)]
    up = 2
    if len(pts) >= 2:
        lo, hi = np.percentile(pts, [2, 98], axis=0)  # a few strays do not turn the view
        span = hi - lo
        thin = int(np.argmin(span))
        if span[thin] < 0.5 * np.sort(span)[1]:
            up = thin
    return [(up + 1) % 3, (up + 2) % 3, up]


def _view(ax, order: list[int]) -> None:
    """The axes' names (``order``: the coordinate drawn on each), no panes."""
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.pane.set_alpha(0.0)  # no grey panes: the picture is the surface and the points
        axis.label.set_size("small")
    ax.tick_params(labelsize="x-small")
    ax.set_xlabel("xyz"[order[0]])
    ax.set_ylabel("xyz"[order[1]])
    ax.set_zlabel("xyz"[order[2]])


def _name(path: str | None) -> str:
    return "stdin" if path in (None, "-") else os.path.basename(str(path))


def project_figure(target_points: np.ndarray, cells, contactors: np.ndarray, gap: np.ndarray,
                   status, target: str | None = None, points: str | None = None, tags=None,
                   max_points: int = MAX_POINTS, seed: int = 0):
    """The contactors coloured by gap over the edges of the target, in 3-D; a Figure.

    Parameters
    ----------
    target_points : (n, 3) float
        The target file's points; ``cells`` its surface cells (meshio type, connectivity
        into them) and ``tags`` their tags per block (or None), for :func:`target_edges`.
    contactors : (m, 3) float
    gap : (m,) float
        NaN where the contactor is unanswered (outside, failed): drawn grey.
    status : (m,) str
        Each contactor's status name (open, contact, penetration, outside, failed).
    target, points : str
        The file names, for the title ('-' or None: stdin).
    max_points : int
        The most contactors drawn: beyond it the penetrating and unanswered ones are kept
        first and the others sampled (said in the title).

    Notes
    -----
    The colours are centred on gap 0 (red penetration, blue open; each side scaled to its own
    extreme when both are present, so a small penetration beside large open gaps still
    shows red); penetrations are outlined in black.
    """
    from matplotlib import colors
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    contactors = np.asarray(contactors, dtype=np.float64).reshape(-1, 3)
    gap = np.asarray(gap, dtype=np.float64).ravel()
    status = np.asarray(status).astype(str).ravel()
    m = len(contactors)
    answered = np.isfinite(gap)
    penetrating = answered & (status == "penetration")
    counts = {s: int(np.sum(status == s)) for s in ("contact", "penetration", "open")}
    counts["unanswered"] = int(np.sum(~answered))

    drawn = np.arange(m)
    if m > max_points:  # the penetrating and unanswered first, then a sample of the others
        rng = np.random.default_rng(seed)
        first = np.flatnonzero(penetrating | ~answered)
        rest = np.flatnonzero(~(penetrating | ~answered))
        if len(first) > max_points:
            first = rng.choice(first, max_points, replace=False)
        more = rng.choice(rest, max(max_points - len(first), 0), replace=False)
        drawn = np.sort(np.concatenate([first, more]))

    edges, every_edge = target_edges(target_points, cells, tags)
    order = _order(contactors[drawn])
    edges, contactors = edges[..., order], contactors[:, order]
    fig = Figure(figsize=(10, 6.5), layout="constrained")
    ax = fig.add_subplot(projection="3d")
    if len(edges):
        ax.add_collection3d(Line3DCollection(edges, colors="0.35", linewidths=0.6,
                                             alpha=0.7, zorder=1))

    g = gap[drawn]
    fin = np.isfinite(g)
    lo = float(np.min(g[fin])) if fin.any() else 0.0
    hi = float(np.max(g[fin])) if fin.any() else 0.0
    if lo < 0 < hi:  # both sides: each scaled to its own extreme
        norm = colors.TwoSlopeNorm(vcenter=0.0, vmin=lo, vmax=hi)
    else:
        norm = colors.CenteredNorm(vcenter=0.0, halfrange=max(abs(lo), abs(hi)) or 1.0)
    size = float(np.clip(3000.0 / np.sqrt(max(len(drawn), 1)), 0.5, 30.0))
    pts, pen, unk = contactors[drawn], penetrating[drawn], ~fin
    # open and contact first, the penetrating on top of them, each as one collection
    rest = fin & ~pen
    mappable = ax.scatter(*pts[rest].T, c=g[rest], cmap=CMAP, norm=norm, s=size,
                          depthshade=False, linewidths=0, zorder=2)
    outlined = size > 2  # a dense cloud's outlines would hide its colours: colour only
    if pen.any():
        mappable = ax.scatter(*pts[pen].T, c=g[pen], cmap=CMAP, norm=norm,
                              s=size * (1.6 if outlined else 1.0), depthshade=False,
                              edgecolors="k" if outlined else "none",
                              linewidths=0.6 if outlined else 0, zorder=3)
    if unk.any():
        ax.scatter(*pts[unk].T, color=UNANSWERED_COLOUR, marker="x", s=size,
                   depthshade=False, linewidths=0.8, zorder=2)
    bar = fig.colorbar(mappable, ax=ax, shrink=0.6, pad=0.07)
    bar.set_label("gap")
    if lo < 0 < hi:  # each half its own ticks: the smaller side would have none
        bar.set_ticks(np.concatenate([np.linspace(lo, 0, 3), np.linspace(0, hi, 5)[1:]]))
        bar.ax.yaxis.set_major_formatter("{x:.3g}")

    handles = [
        Line2D([], [], ls="", marker="o", mfc=_colour(CMAP, norm, lo if lo < 0 else -1),
               mec="k" if outlined else "none", mew=0.8, ms=7,
               label=f"penetration: {counts['penetration']:,}"
                     + (" (outlined)" if outlined else "")),
        Line2D([], [], ls="", marker="o", mfc=_colour(CMAP, norm, 0.0), mec="none", ms=7,
               label=f"contact: {counts['contact']:,}"),
        Line2D([], [], ls="", marker="o", mfc=_colour(CMAP, norm, hi if hi > 0 else 1),
               mec="none", ms=7, label=f"open: {counts['open']:,}"),
        Line2D([], [], ls="", marker="x", color=UNANSWERED_COLOUR, mew=1.2, ms=7,
               label=f"unanswered (outside, failed): {counts['unanswered']:,}"),
        Line2D([], [], color="0.45", lw=0.8,
               label="target: its edges" if every_edge
               else f"target: outline and edges > {FEATURE_ANGLE:g}°"),
    ]
    ax.legend(handles=handles, loc="upper left", fontsize="small", framealpha=0.85)

    _limits(ax, edges, contactors[drawn])
    _view(ax, order)
    title = f"{_name(points)} projected onto {_name(target)}: {m:,} contactor" \
            f"{'' if m == 1 else 's'}\n" + ", ".join(f"{counts[k]:,} {k}" for k in (
                "contact", "penetration", "open", "unanswered"))
    if len(drawn) < m:
        title += (f"\n(drawn: {len(drawn):,} of {m:,}: every penetrating and unanswered one "
                  f"first, a random sample of the others)")
    ax.set_title(title, fontsize="medium")
    return fig


def _colour(cmap: str, norm, value: float):
    """The colour of ``value`` in ``cmap`` under ``norm`` (for a legend's marker)."""
    from matplotlib import colormaps

    return colormaps[cmap](float(norm(value)))


def _shaded(vertices: np.ndarray, faces: list[np.ndarray], base, light) -> tuple:
    """Polygons of ``faces`` and their colours: ``base`` lit by ``light`` (two-sided
    Lambert, with an ambient part so no facet is black)."""
    from matplotlib import colors

    polys, shades = [], []
    for f in faces:
        if not len(f):
            continue
        p = vertices[f]
        n = np.cross(p, np.roll(p, -1, axis=1)).sum(axis=1)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        polys += list(p)
        shades.append(np.abs(n @ light))
    shade = np.concatenate(shades) if shades else np.zeros(0)
    rgb = np.asarray(colors.to_rgb(base))
    face = np.clip(rgb[None, :] * (0.45 + 0.6 * shade[:, None]), 0, 1)
    return polys, face


def smooth_figure(nodes: np.ndarray, facets: list[np.ndarray], vertices: np.ndarray,
                  faces: list[np.ndarray], target: str | None = None,
                  output: str | None = None, levels: int | None = None,
                  max_facets: int = MAX_FACETS, seed: int = 0):
    """The faceted target and its smoothed surface side by side (same view and limits); a
    Figure of two 3-D axes.

    ``facets`` index ``nodes`` and ``faces`` index ``vertices``: lists of (f, 3) triangles
    and (f, 4) quads. A surface of more than ``max_facets`` facets is drawn as a sample of
    them (said in its title).
    """
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    nodes = np.asarray(nodes, dtype=np.float64)
    vertices = np.asarray(vertices, dtype=np.float64)
    fig = Figure(figsize=(12, 5.2), layout="constrained")
    order = _order(nodes)
    nodes, vertices = nodes[:, order], vertices[:, order]
    light = np.array([0.4, -0.6, 1.0])  # from above, in front: as the view (drawn z is up)
    light /= np.linalg.norm(light)
    rng = np.random.default_rng(seed)
    panels = ((f"faceted: {_name(target)}", nodes, facets, "#9db4d0", "0.25"),
              (f"smooth: {_name(output)}" + (f" ({levels} level{'s' * (levels != 1)})"
                                              if levels is not None else ""),
               vertices, faces, "#e0b07a", "none"))
    for i, (title, pts, cells, colour, edge) in enumerate(panels):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        total = sum(len(f) for f in cells)
        kept = cells
        if total > max_facets:
            kept = [f[np.sort(rng.choice(len(f), int(round(len(f) * max_facets / total)),
                                         replace=False))] for f in cells]
            title += f"\n(drawn: {sum(len(f) for f in kept):,} of {total:,} facets)"
        polys, face = _shaded(pts, kept, colour, light)
        thin = total > 5000  # a dense mesh's edges would paint it black
        # no edge: each facet's own colour (an edgeless facet shows the seams between them)
        plain = thin or edge == "none"
        ax.add_collection3d(Poly3DCollection(
            polys, facecolors=face, edgecolors=face if plain else edge,
            linewidths=0.3 if plain else 0.25))
        _limits(ax, nodes, vertices)
        _view(ax, order)
        used = len(np.unique(np.concatenate([f.ravel() for f in cells]))) if total else 0
        ax.set_title(f"{title}\n{total:,} facets, {used:,} nodes", fontsize="medium")
    return fig
