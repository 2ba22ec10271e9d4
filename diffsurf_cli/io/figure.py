"""Figures (``diffsurf tune --plot``), written by matplotlib in the format of their extension."""
from __future__ import annotations

from .atomic import write_atomically
from .paths import check_output_path, extension

__all__ = ["write_figure"]


def write_figure(path: str, fig, overwrite: bool = False) -> None:
    """Write a matplotlib figure (.png, .svg or .pdf, from the extension), atomically.

    An existing file is kept unless ``overwrite``; see :func:`check_output_path` (kind
    'figure').
    """
    path = str(path)
    check_output_path(path, overwrite, kind="figure")
    ext = extension(path)
    write_atomically(path, overwrite, ext,
                     lambda tmp: fig.savefig(tmp, format=ext[1:], dpi=150))
