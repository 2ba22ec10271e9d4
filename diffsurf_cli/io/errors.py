"""The two exceptions of the I/O boundary, and the one-line reasons their messages quote."""
from __future__ import annotations

import re

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


#: numpy's repr of a scalar (``np.int32(17)``, ``np.float64(nan)``): its value is the reader's.
_NUMPY_SCALAR = re.compile(r"\bnp\.\w+\(([^()]*)\)")


def reader_reason(exc: BaseException) -> str:
    """A readable reason for a file reader's (meshio's) failure ``exc``, on one line.

    A KeyError's message is only the missing key: an integer key is an id the file refers to
    and does not define (a node of an element, say); numpy scalars are shown as their values.
    """
    if isinstance(exc, KeyError) and len(exc.args) == 1:
        key = exc.args[0]
        if hasattr(key, "__index__") and not isinstance(key, bool):
            return f"it refers to id {int(key)}, which it does not define"
        return f"'{_plain(str(key))}' was expected and is missing"
    if isinstance(exc, IndexError):
        reason = first_line(exc)
        if reason == "IndexError":
            return "a reference to an entry that does not exist"
        return f"a reference to an entry that does not exist ({_plain(reason)})"
    return _plain(first_line(exc))


def _plain(text: str) -> str:
    """``text`` with numpy scalars shown as their values."""
    return _NUMPY_SCALAR.sub(r"\1", text)
