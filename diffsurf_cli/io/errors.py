"""The two exceptions of the I/O boundary, and the one-line reasons their messages quote."""
from __future__ import annotations

__all__ = ["ReadError", "WriteError"]

#: each reader's reason for refusing a file is cut to this length in the one-line error.
REASON_CHARS = 120


class ReadError(Exception):
    """An input file is missing, unreadable or not what diffsurf expects."""


class WriteError(Exception):
    """An output file cannot be (or must not be) written."""


def first_line(exc: BaseException) -> str:
    """The first line of ``exc``'s message (its type name if it has none)."""
    if isinstance(exc, UnicodeDecodeError):
        return f"binary bytes where text was expected (offset {exc.start})"
    text = str(exc).strip()
    line = text.splitlines()[0].strip() if text else ""
    return line or type(exc).__name__


def os_reason(exc: OSError) -> str:
    """The OS's words for ``exc`` without the (temporary) file name it quotes."""
    return exc.strerror or first_line(exc)
