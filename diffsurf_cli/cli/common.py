"""What the diffsurf commands share: logging, one-line domain errors, the progress bar."""
from __future__ import annotations

import contextlib
import logging
import os
import sys
import time

import click

from .. import io
from ..mls.surface import CHUNK
from ..targets import surface_from_file

# The contact element (scipy.sparse) is imported where it is used, so a plain `project`
# starts without it.

log = logging.getLogger("diffsurf")


class DiffsurfError(click.ClickException):
    """A domain error: one line on stderr, exit 1."""

    def show(self, file=None):
        click.echo(f"diffsurf: error: {self.format_message()}", err=True)


def count(n: int, noun: str) -> str:
    """'1 contactor', '2 contactors': a count and its noun, singular for one."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def target_surface(path, zone, method, flip, feature_angle=None, **engine):
    """`targets.surface_from_file`: (Target, surface); its ValueError a one-line domain error
    (with -v, the original error's traceback)."""
    try:
        return surface_from_file(path, zone=zone, method=method, flip=flip,
                                 feature_angle=feature_angle, **engine)
    except ValueError as exc:
        raise DiffsurfError(str(exc)) from (exc.__cause__ or exc)


def stderr_is_terminal() -> bool:
    """Whether stderr is a terminal (False when it is closed: `2>&-` leaves sys.stderr None)."""
    return sys.stderr is not None and sys.stderr.isatty()


#: the names of the standard output as an output path (-o): it is closed when sys.stdout is None
STDOUT_NAMES = ("-", "/dev/stdout", "/dev/fd/1", "/proc/self/fd/1")


def need_stdin(points) -> None:
    """A one-line error when POINTS is '-' and stdin is closed (`<&-`: sys.stdin is None)."""
    if points == "-" and sys.stdin is None:
        raise DiffsurfError("-: stdin is closed, expected CSV on it (or a file name for POINTS)")


def need_stdout(why: str) -> None:
    """A one-line error, before any work, when stdout is closed (`>&-`: sys.stdout is None)
    and the command would print there."""
    if sys.stdout is None:
        raise DiffsurfError(f"stdout is closed: {why}")


@contextlib.contextmanager
def progress_bar(ctx, total: int, label: str):
    """A progress callback drawing a bar on stderr when it is a terminal (and not -q) and the
    job has more than one chunk; None (silent) otherwise."""
    if total <= CHUNK or ctx.obj.get("quiet") or not stderr_is_terminal():
        yield None
        return
    with click.progressbar(length=total, label=f"diffsurf: {label}", file=sys.stderr,
                           show_pos=True, show_eta=True) as bar:
        done, started = [0], [False]

        def update(n):
            if not started[0]:
                # the ETA counts from the work's start (progress(0), or the first report),
                # not from the setup before it: click's ETA is the elapsed time since the
                # bar's start over the work done, and reading a 2M-point table and building
                # the engine made an 18-second job's first ETA 8:54
                started[0] = True
                bar.start = bar.last_eta = time.time()
                bar.avg = []
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
            # the original error itself, with its traceback and its own chain
            raise (exc.__cause__ or exc)  # noqa: B904
        raise DiffsurfError(exc.format_message() if isinstance(exc, DiffsurfError)
                            else str(exc)) from exc
