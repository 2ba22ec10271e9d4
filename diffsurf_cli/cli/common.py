"""What the diffsurf commands share: logging, one-line domain errors, the progress bar."""
from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
import time

import click

from .. import io
from ..mls.surface import CHUNK, TooFewNodes
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


def target_surface(path, zone, method, flip, feature_angle=None, progress=None, **engine):
    """`targets.surface_from_file`: (Target, surface); its ValueError a one-line domain error
    (with -v, the original error's traceback). `progress`: called with each stage's name
    (a `SetupStatus`)."""
    try:
        return surface_from_file(path, zone=zone, method=method, flip=flip,
                                 feature_angle=feature_angle, progress=progress, **engine)
    except ValueError as exc:
        raise DiffsurfError(command_line_message(exc)) from (exc.__cause__ or exc)


def command_line_message(exc: BaseException) -> str:
    """An API error's message as the command line says it: where it (or what caused it, a
    file's error prefixed with its name) names the API's keyword for a fix, the flag instead
    (`TooFewNodes`: basis="linear" is --basis linear)."""
    message = str(exc)
    cause = exc if isinstance(exc, TooFewNodes) else exc.__cause__
    if isinstance(cause, TooFewNodes) and cause.fits and message.endswith(str(cause)):
        message = message[:len(message) - len(str(cause))] + cause.text(f"--basis {cause.fits}")
    return message


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


#: Seconds of a target's setup (reading it, building its surface and engine) after which a
#: terminal shows its stage, and its time is logged: a small target's setup says nothing
SETUP_REPORT_SECONDS = 1.0


class SetupStatus:
    """The target's setup on stderr: a progress callback for `targets.surface_from_file`
    (``status(stage)``, each stage's name) drawing one self-overwriting line, 'diffsurf:
    setting up the target: STAGE (N s)', once the setup has taken `SETUP_REPORT_SECONDS`,
    when stderr is a terminal and not -q (nothing otherwise, as `progress_bar`).

    ``with status:`` times a part of the setup (reading the target and building its surface;
    then its engine, `engine`): the line is drawn only within one, and cleared at its end, so
    the lines logged between the parts (the contactors read) and the projection's own bar
    start on a clean line. `report` logs the parts' time when it reached the threshold. A
    thread redraws the line every `TICK` seconds (the elapsed time moves within a long stage);
    log records clear it first (the thread draws it again)."""

    TICK = 0.25

    def __init__(self, ctx):
        self.show = not ctx.obj.get("quiet") and stderr_is_terminal()
        self.stage = ""
        self.seconds = 0.0  # of the parts done
        self._start = None  # of the part under way
        self._drawn = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = None
        self._handlers = []

    def __call__(self, stage: str) -> None:
        self.stage = stage
        self._draw()

    def elapsed(self) -> float:
        """Seconds of setup so far: the parts done and the one under way."""
        under_way = time.monotonic() - self._start if self._start is not None else 0.0
        return self.seconds + under_way

    def engine(self, surf) -> None:
        """Build the surface's compiled engine now (it is built on first use): its time is the
        setup's, not the projection's first chunk's."""
        self("engine")
        surf.engine  # noqa: B018 - the property builds it

    def report(self) -> None:
        """Log the setup's time when it took `SETUP_REPORT_SECONDS` or more."""
        if self.seconds >= SETUP_REPORT_SECONDS:
            log.info("target set up in %.1f s", self.seconds)

    def __enter__(self):
        self._start = time.monotonic()
        if self.show:
            self._stop.clear()
            for handler in log.handlers:  # a log record first clears the line
                self._handlers.append((handler, vars(handler).get("emit")))
                handler.emit = self._clearing(handler.emit)
            self._thread = threading.Thread(target=self._tick, daemon=True,
                                            name="diffsurf-setup-status")
            self._thread.start()
        return self

    def __exit__(self, *exc):
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None
        for handler, own in self._handlers:  # the emit it had
            if own is None:
                del handler.emit
            else:
                handler.emit = own
        self._handlers = []
        with self._lock:
            self._clear()
            self.seconds += time.monotonic() - self._start
            self._start = None
        return False

    def _tick(self) -> None:
        while not self._stop.wait(self.TICK):
            self._draw()

    def _draw(self) -> None:
        if not self.show:
            return
        with self._lock:
            if self._start is None or self._stop.is_set():
                return
            seconds = self.elapsed()
            if seconds < SETUP_REPORT_SECONDS:
                return
            sys.stderr.write(f"\r\x1b[Kdiffsurf: setting up the target: {self.stage} "
                             f"({int(seconds)} s)")
            sys.stderr.flush()
            self._drawn = True

    def _clear(self) -> None:  # under the lock
        if self._drawn:
            sys.stderr.write("\r\x1b[K")
            sys.stderr.flush()
            self._drawn = False

    def _clearing(self, emit):
        def clear_then_emit(record):
            with self._lock:  # the thread draws it again after the record, not within it
                self._clear()
                emit(record)
        return clear_then_emit


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
