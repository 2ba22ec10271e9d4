"""diffsurf command line: a thin layer (parse → read → core → write) over the package, one
module per command (project.py, smooth.py, tune.py), options declared once (options.py).

Results go to stdout or -o FILE; logs and progress go to stderr only. Domain errors exit 1
with a one-line message, bad options exit 2 (click), no traceback unless -v.
"""
from __future__ import annotations

import click

from .. import __version__
from . import options
from .common import DiffsurfError, log  # noqa: F401  (re-exported)
from .project import project
from .smooth import smooth
from .tune import tune_command


class _Diffsurf(click.Group):
    """The command group. Ctrl-C ends a run as SIGTERM and SIGHUP do (`_exit_on_signals`):
    the command unwinds (its temporary files removed, nothing half-written), and the exit
    status is 128 + SIGINT = 130, as a shell reports it; 'diffsurf: interrupted' on stderr,
    nothing under -q (click itself said 'Aborted!' and exited 1, even under -q)."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:  # the command's context is closed: its resources released
            if not (ctx.obj or {}).get("quiet"):
                click.echo("diffsurf: interrupted", err=True)
            ctx.exit(128 + 2)  # SIGINT is 2 on every platform Python signals on


@click.group(cls=_Diffsurf, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="diffsurf")
@options.verbosity
@click.pass_context
def main(ctx):
    """Smooth faceted contact surfaces by diffuse approximation (moving least squares) and
    compute gaps, normals and proximal points on the smooth surface.

    -v/-q may be given before or after the command.

    \b
    Examples:
      diffsurf project target.msh points.csv -o gaps.csv
      cat points.csv | diffsurf project target.vtu - > gaps.csv
      diffsurf project plate_and_cylinder.msh plate.vtu --zone cylinder -o result.vtu
    """
    ctx.ensure_object(dict)
    _exit_on_signals(ctx)


def _exit_on_signals(ctx) -> None:
    """SIGTERM and SIGHUP end the run as Ctrl-C does, unwinding: temporary files are removed,
    nothing half-written is left (the default action kills the process where it stands).
    The exit status is 128 + the signal's number, as a shell reports a killed command; the
    previous handlers come back when the command ends."""
    import signal

    def terminate(signum, frame):
        raise SystemExit(128 + signum)

    for name in ("SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is None:  # Windows has no SIGHUP
            continue
        try:
            previous = signal.signal(sig, terminate)
        except ValueError:  # not the main thread (an embedding application): leave it be
            continue
        ctx.call_on_close(lambda sig=sig, previous=previous: signal.signal(sig, previous))


for _command in (project, smooth, tune_command):
    main.add_command(_command)
