"""Atomic writes: every output goes to a temporary file beside it and is renamed into place,
alone or with the other outputs of the same command (an output batch)."""
from __future__ import annotations

import contextlib
import os
import tempfile

from .errors import WriteError, first_line, os_reason

__all__ = ["OutputBatch", "output_batch", "write_atomically", "check_new", "check_directory"]


class OutputBatch:
    """Outputs of one command written to temporary files, renamed into place together.

    See :func:`output_batch`. ``pending`` holds (temporary file, path, overwrite).
    """

    def __init__(self):
        self.pending: list[tuple[str, str, bool]] = []

    def commit(self) -> None:
        """Rename every pending output into place; WriteError (and nothing renamed) if one
        of them appeared meanwhile without ``overwrite``."""
        try:
            for _tmp, path, overwrite in self.pending:
                if not overwrite and os.path.lexists(path):
                    raise WriteError(f"{path}: already exists (use --overwrite)")
            while self.pending:
                tmp, path, _ = self.pending[0]
                try:
                    os.replace(tmp, path)
                except OSError as exc:
                    raise WriteError(f"{path}: cannot write ({os_reason(exc)})") from None
                self.pending.pop(0)
        finally:
            self.discard()

    def discard(self) -> None:
        """Remove the temporary files of the outputs not renamed yet."""
        for tmp, _, _ in self.pending:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        self.pending.clear()


#: the batch of the command running now, if any (see output_batch).
_batch: OutputBatch | None = None


@contextlib.contextmanager
def output_batch():
    """Defer the final rename of every file written inside the block until ``commit()``.

    A command with several outputs (``-o``, ``--residual``, ``--tangent``, ``--save-pairs``)
    then leaves all of them or none: a failure while writing the last one leaves neither new
    files nor replaced old ones. Leaving the block without ``commit()`` removes the temporary
    files.

    Yields
    ------
    batch : OutputBatch
    """
    global _batch
    previous, _batch = _batch, OutputBatch()
    try:
        yield _batch
    finally:
        _batch.discard()
        _batch = previous


def write_atomically(path: str, overwrite: bool, ext: str, write) -> None:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it to ``path``.

    Nothing half-written is ever left: on any failure the temporary file is removed and a
    WriteError naming ``path`` is raised; an existing ``path`` is kept unless ``overwrite``.
    Inside :func:`output_batch` the rename waits for the batch's ``commit()``. ``ext`` ends
    the temporary file's name, for writers that choose a format by extension.
    """
    directory, base = os.path.split(os.path.abspath(path))
    if _batch is not None and any(os.path.abspath(p) == os.path.abspath(path)
                                  for _, p, _ in _batch.pending):
        raise WriteError(f"{path}: named for two outputs, expected a file name per output")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{base}.tmp", suffix=ext, dir=directory)
    except OSError as exc:
        raise WriteError(
            f"{path}: cannot create a file in '{directory}' ({os_reason(exc)})") from None
    try:
        os.close(fd)
        write(tmp)
        # mkstemp makes the file private; give it the permissions a plain open() would
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        if not overwrite and os.path.lexists(path):
            raise WriteError(f"{path}: already exists (use --overwrite)")
        if _batch is not None:
            _batch.pending.append((tmp, path, overwrite))
            return
        os.replace(tmp, path)
    except BaseException as exc:
        reason = None
        if isinstance(exc, Exception) and not isinstance(exc, WriteError):
            reason = write_reason(exc, tmp)
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if reason is not None:
            raise WriteError(f"{path}: cannot write ({reason})") from None
        raise


#: bytes appended to a file whose writer failed without saying why (`write_reason`).
PROBE_BYTES = 1 << 16


def write_reason(exc: Exception, tmp: str | None = None) -> str:
    """Why writing failed, in the OS's words where the OS refused: an OSError with an errno
    in the chain of ``exc`` (meshio wraps it in its own error), else, if ``tmp`` (the file
    being written) is given, the error of a probe write to it: numpy's ``tofile``, which
    writes most mesh formats, says '60000 requested and 8178 written' or 'problem writing
    element 1024' and drops the errno (ENOSPC, EDQUOT, EFBIG, EIO); polars words it in its
    own. Failing both, the first line of ``exc``."""
    seen, cause = set(), exc
    while cause is not None and id(cause) not in seen:
        seen.add(id(cause))
        if isinstance(cause, OSError) and cause.errno is not None:
            return os_reason(cause)
        cause = cause.__cause__ or cause.__context__
    if tmp is not None:
        try:  # the device said no to the writer: ask it again, with an errno this time
            with open(tmp, "ab") as fh:
                # no fsync: it would first write back all the failed output; local file
                # systems refuse at write(), and a network one at the close
                fh.write(bytes(PROBE_BYTES))
        except OSError as probe:
            if probe.errno is not None:
                return os_reason(probe)
    return os_reason(exc) if isinstance(exc, OSError) else first_line(exc)


def check_new(path: str, overwrite: bool) -> None:
    """WriteError if ``path`` is a directory, or exists and ``overwrite`` is False."""
    if os.path.isdir(path):
        raise WriteError(f"{path}: is a directory, expected an output file name")
    if os.path.lexists(path) and not overwrite:
        raise WriteError(f"{path}: already exists (use --overwrite)")


def check_directory(path: str) -> None:
    """WriteError unless the directory of ``path`` exists and takes new files."""
    parent, base = os.path.split(os.path.abspath(path))
    if not os.path.isdir(parent):
        if os.path.exists(parent):
            raise WriteError(f"{path}: '{parent}' is not a directory, expected a directory")
        raise WriteError(f"{path}: directory '{parent}' does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise WriteError(f"{path}: directory '{parent}' is not writable")
    # access() says yes to root and knows nothing of read-only file systems: try it for real
    try:
        fd, probe = tempfile.mkstemp(prefix=f".{base}.probe", dir=parent)
    except OSError as exc:
        raise WriteError(
            f"{path}: cannot create a file in '{parent}' ({os_reason(exc)})") from None
    try:
        os.close(fd)
    finally:  # even when a signal ends the run here
        os.unlink(probe)
