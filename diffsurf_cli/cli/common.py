"""What the diffsurf commands share: logging, one-line domain errors, reading the target,
the progress bar."""
from __future__ import annotations

import contextlib
import logging
import os
import sys

import click
import numpy as np

from .. import io
from ..mls.frame import cell_faces, facet_corners
from ..mls.surface import CHUNK, DiffuseSurface

# The facet method and the contact element (scipy.sparse) are imported where they are used,
# so a plain `project` starts without them.

log = logging.getLogger("diffsurf")


class DiffsurfError(click.ClickException):
    """A domain error: one line on stderr, exit 1."""

    def show(self, file=None):
        click.echo(f"diffsurf: error: {self.format_message()}", err=True)


def read_surface(path, zone):
    """Read a target mesh: (Target, its surface nodes (n, 3), its facet blocks indexing them),
    saying on stderr what was read; ``target.tags`` (face or region tags, per block) go with
    the blocks. Blocks keep the mid-side nodes of higher-order cells, which
    the diffuse surface gives their cells' normals (the facet method uses the corners)."""
    target = io.read_target(path, zone=zone)
    for kind, count in sorted(target.ignored.items()):
        log.info("%s: ignored %d %s cells (not surface cells)", path, count, kind)
    for kind, count in sorted(target.boundary.items()):
        log.info("%s: the target is the boundary of %d %s cells", path, count, kind)
    nodes = target.points[target.nodes]
    faces = [np.searchsorted(target.nodes, f) for f in cell_faces(target.cells)]
    log.info("%s: target of %d nodes, %d facets%s", path, len(nodes),
             sum(len(f) for f in faces), f" (zone {zone!r})" if zone else "")
    return target, nodes, faces


def build_target(path, zone, method, flip, feature_angle=None, **engine):
    """Read a target mesh and build the diffuse (or faceted) surface of its surface nodes;
    with `feature_angle` (degrees) below 180, the diffuse surface per smooth patch
    (`PatchedSurface`: bounded by edges sharper than it, the file's face or region tags, open
    boundaries); 180 or None: one diffuse surface over the whole target."""
    target, nodes, faces = read_surface(path, zone)
    try:
        if method == "facet":
            from ..facet.surface import FacetSurface

            surf = FacetSurface(nodes, [facet_corners(f) for f in faces], flip=flip)
        elif feature_angle is not None and feature_angle < 180:
            from ..patches.surface import PatchedSurface

            tags = np.concatenate(target.tags) if target.tags is not None else None
            surf = PatchedSurface(nodes, faces, feature_angle=feature_angle, tags=tags,
                                  flip=flip, **engine)
            log.info("%d smooth patch%s (feature angle %g°%s)", surf.npatches,
                     "es" if surf.npatches > 1 else "", feature_angle,
                     ", face tags" if tags is not None else "")
            log.info("frame: %s; basis %s, weight %s, support %s", surf.frame, surf.basis,
                     surf.weight, surf.support)
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
