"""The projection on a Dask cluster: contactors held in partitions (Parquet or CSV files, or a
dask DataFrame) are projected where they lie, onto a target surface built once and shared.

dask.distributed schedules the partitions, recomputes those of a worker that dies and draws
the progress bar; this module only says what one partition's task is. dask is an optional
dependency (``pip install diffsurf[dask]``), imported by this module alone, which nothing
imports unless asked (``diffsurf project --scheduler/--workers``, or a user's import).

Two ways in:

- :func:`project_partitions`: files to files, as the command line does. Each task reads one
  input partition with :func:`diffsurf_cli.io.read_contactors`, projects it and writes it with
  :func:`diffsurf_cli.io.write_result`: the same reader, engine and writer as a one-machine
  run, so the same columns and the same bits. Outputs keep their input's file name.
- :func:`project_dataframe`: a dask DataFrame (or files) in, a lazy dask DataFrame of results
  out, partition for partition.

Memory: a worker holds one partition at a time per thread (its rows, the result columns and
the writer's buffers, a few hundred bytes per contactor) plus the target surface; it does not
grow with the number of partitions.
"""
from __future__ import annotations

import contextlib
import glob
import logging
import os
import re
import shutil
import sys
import tempfile
import time
import uuid
import warnings
from dataclasses import dataclass, field

import numpy as np

from . import io
from .io.errors import first_line
from .io.paths import TABLE_EXTENSIONS, extension
from .projection import LABELS, STATUS

__all__ = ["ClusterError", "Summary", "require", "connect", "partitions", "output_paths",
           "project_partitions", "project_dataframe", "project_frame"]

#: the prefix of the hidden directory beside the outputs where each task writes its partition
#: before renaming it into place (removed at the end of the job, with whatever a killed
#: worker left half-written there).
STAGING_PREFIX = ".diffsurf-staging-"


class ClusterError(Exception):
    """The job cannot run or did not finish: the scheduler is unreachable, or a partition
    failed (the message names its file)."""


@dataclass
class Summary:
    """What a job did, summed over its partitions.

    Attributes
    ----------
    partitions : int
    contactors : int
        Rows projected.
    status : (len(STATUS),) int
        Contactors per status, in the order of `STATUS`.
    coincident : int
        Contactors found at a target node (by the ``coincident`` check given to the job).
    cpu_seconds : float
        CPU time of the tasks (read, project, write), summed over workers.
    wall_seconds : float
        From the first task submitted to the last partition written.
    peak_memory : dict of str to int
        Worker (host:pid) -> its peak resident memory in bytes over its life, as its tasks saw
        it (``getrusage``); empty where the platform does not say.
    """

    partitions: int = 0
    contactors: int = 0
    status: np.ndarray = field(default_factory=lambda: np.zeros(len(STATUS), np.int64))
    coincident: int = 0
    cpu_seconds: float = 0.0
    wall_seconds: float = 0.0
    peak_memory: dict = field(default_factory=dict)

    def add(self, part: dict) -> None:
        self.partitions += 1
        self.contactors += part["contactors"]
        self.status += part["status"]
        self.coincident += part["coincident"]
        self.cpu_seconds += part["cpu_seconds"]
        if part["peak_memory"] is not None:
            worker = part["worker"]
            self.peak_memory[worker] = max(self.peak_memory.get(worker, 0), part["peak_memory"])


# --------------------------------------------------------------------------------------------
# partitions and their outputs
# --------------------------------------------------------------------------------------------

def _natural_key(path: str):
    """Sort key that orders 'part-2' before 'part-10' (as dask orders the files of a glob)."""
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path)]


def partitions(points: str) -> list[str]:
    """The partition files named by ``points``, in input order.

    Parameters
    ----------
    points : str
        A glob (``points/*.parquet``), a directory (its .parquet, .csv and .txt files, hidden
        ones excepted) or one file. Files are in natural order (``part-2`` before
        ``part-10``).

    Returns
    -------
    list of str

    Raises
    ------
    ReadError
        Nothing matches, or a match is not a table (.parquet, .csv, .txt).
    """
    points = str(points)
    if points == "-":
        raise io.ReadError("-: partitions cannot be read from stdin, expected files, a "
                           "directory or a glob")
    if glob.has_magic(points):
        found = [p for p in glob.glob(points) if os.path.isfile(p)]
        if not found:
            raise io.ReadError(f"{points}: no file matches")
    elif os.path.isdir(points):
        found = [os.path.join(points, n) for n in os.listdir(points)
                 if not n.startswith(".") and extension(n) in TABLE_EXTENSIONS
                 and os.path.isfile(os.path.join(points, n))]
        if not found:
            raise io.ReadError(f"{points}: no .parquet, .csv or .txt file in this directory")
    elif os.path.exists(points):
        found = [points]
    else:
        raise io.ReadError(f"{points}: no such file or directory")
    for p in found:
        if extension(p) not in TABLE_EXTENSIONS:
            raise io.ReadError(f"{p}: not a table partition, expected .parquet, .csv or .txt")
    return sorted(found, key=_natural_key)


def output_paths(sources: list[str], out: str, overwrite: bool = False) -> list[str]:
    """The output file of each partition, checked before any work is done.

    Parameters
    ----------
    sources : list of str
        The input partitions (:func:`partitions`).
    out : str
        A directory (``out/``, created if missing): each output keeps its input's file name;
        a pattern ``out/*.parquet``: the input's name with that extension (``*`` stands for
        the name without its extension); or one file, for one partition.
    overwrite : bool
        Whether existing outputs may be replaced.

    Returns
    -------
    list of str

    Raises
    ------
    WriteError
        An output exists (without ``overwrite``), is an input, is named twice (two inputs of
        the same name in different directories), is not a table, or its directory cannot be
        written.
    """
    out = str(out)
    if out == "-":
        raise io.WriteError("-: partitions are written to files, expected a directory "
                            "(-o out/), a pattern (-o 'out/*.parquet') or a file")
    directory, pattern = None, None
    if glob.has_magic(out):
        directory, pattern = os.path.split(out)
        if pattern.count("*") != 1 or glob.has_magic(directory) or "?" in pattern \
                or "[" in pattern:
            raise io.WriteError(f"{out}: expected one '*' in the file name "
                                f"(-o 'out/*.parquet'), standing for each input's name")
    elif out.endswith(("/", os.sep)) or os.path.isdir(out):
        directory = out
    elif len(sources) > 1:
        raise io.WriteError(f"{out}: {len(sources)} partitions need a directory (-o "
                            f"{out.rstrip('/')}/) or a pattern, not one file")
    if directory is None:
        targets = [out]
    else:
        directory = directory or "."
        if os.path.exists(directory) and not os.path.isdir(directory):
            raise io.WriteError(f"{directory}: is not a directory, expected one for the "
                                f"output partitions")
        try:
            os.makedirs(directory, exist_ok=True)
        except OSError as exc:
            raise io.WriteError(f"{directory}: cannot create the directory "
                                f"({exc.strerror or first_line(exc)})") from None
        names = [os.path.basename(s) for s in sources]
        if pattern is not None:
            names = [pattern.replace("*", os.path.splitext(n)[0]) for n in names]
        targets = [os.path.join(directory, n) for n in names]
    inputs = {os.path.realpath(s): s for s in sources}
    seen = {}
    for source, target in zip(sources, targets):
        real = os.path.realpath(target)
        if real in inputs:
            raise io.WriteError(f"{target}: is the input partition {inputs[real]}, expected "
                                f"another directory for the outputs")
        if real in seen:
            raise io.WriteError(f"{target}: the output of both {seen[real]} and {source}, "
                                f"expected input partitions with distinct names")
        seen[real] = source
        if extension(target) not in TABLE_EXTENSIONS:
            raise io.WriteError(f"{target}: an output partition is a table, expected .parquet, "
                                f".csv or .txt")
    # the full check (directory writable, with a probe file) once per directory; then only
    # whether each file exists
    probed = set()
    for target in targets:
        parent = os.path.dirname(os.path.abspath(target))
        if parent not in probed:
            io.check_output_path(target, True)  # the directory, with a probe file
            probed.add(parent)
        if not overwrite and os.path.lexists(target):
            raise io.WriteError(f"{target}: already exists (use --overwrite, or --resume to "
                                f"skip the partitions a job left done)")
    return targets


def pending(sources: list[str], targets: list[str]):
    """The partitions still to project when a job is run again (`project --resume`): an
    output that exists is skipped where it holds a whole result of its input (written whole,
    by its atomic rename: as many rows as the input, and the result's columns); any other
    existing output is refused. Empty staging directories an interrupted job left in the
    output directories are removed.

    Returns (sources, targets, done): the partitions to project and how many are done.

    Raises
    ------
    WriteError
        An output exists that is not a whole result of its input.
    """
    import polars as pl

    for directory in {os.path.dirname(os.path.abspath(t)) for t in targets}:
        for stale in glob.glob(os.path.join(glob.escape(directory), STAGING_PREFIX + "*")):
            try:
                os.rmdir(stale)  # only when empty: another job's files are never touched
            except OSError:
                pass
    todo_sources, todo_targets, done = [], [], 0
    for source, target in zip(sources, targets):
        if not os.path.lexists(target):
            todo_sources.append(source)
            todo_targets.append(target)
            continue
        try:
            frame = (pl.scan_parquet(target) if extension(target) == ".parquet"
                     else pl.scan_csv(target, infer_schema=False,
                                      separator="\t" if extension(target) == ".txt" else ","))
            columns = frame.collect_schema().names()
            rows = frame.select(pl.len()).collect().item()
        except Exception:  # noqa: BLE001 - unreadable: not a result
            columns, rows = [], -1
        whole = {"gap", "status", "reason"} <= set(columns) and rows == len(
            io.read_contactors(source).points)
        if not whole:
            raise io.WriteError(f"{target}: already exists and is not a whole result of "
                                f"{source} (use --overwrite to project it again)")
        done += 1
    return todo_sources, todo_targets, done


# --------------------------------------------------------------------------------------------
# the cluster
# --------------------------------------------------------------------------------------------

def require() -> None:
    """ClusterError unless dask.distributed can be imported (it is an optional extra)."""
    try:
        import dask.distributed  # noqa: F401
    except ImportError as exc:
        raise ClusterError(f"running on a Dask cluster needs dask.distributed "
                           f"(pip install 'diffsurf[dask]'): {first_line(exc)}") from None


@contextlib.contextmanager
def connect(scheduler: str | None = None, workers: int | None = None, threads: int = 1,
            log_level: int = logging.WARNING):
    """A dask.distributed Client: of the scheduler at ``scheduler``, or of a new local
    cluster of ``workers`` processes with ``threads`` threads each.

    A local worker runs the engine on one core per thread (dask sets OMP_NUM_THREADS=1 in
    its workers), so ``workers`` x ``threads`` should not exceed the cores. ``log_level`` is
    the level below which the local cluster's own logs (a failed task's traceback, a worker
    restarted) are silenced: a failed job is reported by the error it raises.

    Raises
    ------
    ClusterError
        dask.distributed is missing, or the scheduler cannot be reached.
    """
    require()
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise ClusterError(f"{scheduler}: cannot reach the Dask scheduler "
                               f"({first_line(exc)})") from None
        with client:
            yield client
        return
    # the dashboard (if bokeh is installed) on a free port: 8787 may be another cluster's
    with _interrupt_here_only():
        cluster = LocalCluster(n_workers=int(workers or 1), threads_per_worker=int(threads),
                               processes=True, dashboard_address=":0", silence_logs=log_level)
    with cluster, Client(cluster) as client:
        client.register_plugin(_interrupts_ignored(), name="diffsurf-interrupts-ignored")
        yield client


def _interrupts_ignored():
    """A worker plugin that leaves SIGINT ignored in the local cluster's workers once polars
    is imported there: polars installs a Ctrl-C handler when it is imported (to cancel a
    query), over the ignored signal the worker started with (`_interrupt_here_only`), and a
    Ctrl-C then broke the partition a worker was reading with a KeyboardInterrupt and its
    traceback. Also set up on a worker started again."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class InterruptsIgnored(WorkerPlugin):
        def setup(self, worker):
            import signal
            import threading

            import polars  # noqa: F401 - its handler first, then ignored over it

            if threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGINT, signal.SIG_IGN)

    return InterruptsIgnored()


@contextlib.contextmanager
def _interrupt_here_only():
    """SIGINT ignored while the local cluster's worker processes start, so that they ignore
    it too (a spawned process keeps an ignored signal, and then Python and asyncio leave it
    ignored): Ctrl-C in a terminal signals the whole process group, and a worker interrupted
    mid-task prints its KeyboardInterrupt traceback, twice, and leaks its semaphores. This
    process alone takes the interrupt and closes the cluster, which stops the workers. A
    Ctrl-C while they start (a second or two) is ignored. From a thread other than the main
    one (where signals cannot be set), nothing changes."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _shareable(surface):
    """``surface`` as it may travel to the workers: without the compiled engine's state,
    which each worker rebuilds on first use (it is a cache of the node grid, not picklable)."""
    if getattr(surface, "_engine", None) is None:
        return surface
    import copy

    shared = copy.copy(surface)
    shared._engine = None
    return shared


def _share(client, surface):
    """The surface as a task result held on the cluster (a Future). A task, not
    ``scatter``: if every worker holding it dies, the scheduler computes it again from the
    graph instead of failing the job."""
    with warnings.catch_warnings():
        # the surface is the one large argument of the graph, sent once on purpose
        warnings.filterwarnings("ignore", message=".*[Ll]arge graph.*")
        return client.submit(_identity, _shareable(surface), pure=False,
                             key=f"diffsurf-surface-{uuid.uuid4().hex}")


def _identity(x):
    return x


#: per worker process: the shared surface last seen and this process's working copy of it.
_WORKING = {}


def _working_copy(surface):
    """This process's copy of the shared ``surface``, to project with. The engine state the
    copy builds on first use stays out of the shared object, which dask may still have to
    send to another worker (that state does not pickle); the copy is shallow (the arrays are
    shared) and kept until another surface comes, so the engine is built once per worker and
    job."""
    entry = _WORKING.get(id(surface))
    if entry is None or entry[0] is not surface:
        import copy

        _WORKING.clear()  # the previous job's target
        entry = (surface, copy.copy(surface))
        _WORKING[id(surface)] = entry
    return entry[1]


def _peak_memory() -> int | None:
    """This process's peak resident memory in bytes, None where getrusage is missing."""
    try:
        import resource
    except ImportError:  # Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak) if sys.platform == "darwin" else int(peak) * 1024  # Linux says KiB


def _project_file(surface, source: str, target: str, staging: str, coincident=None) -> dict:
    """One partition's task: read ``source``, project it, write ``target``.

    The result goes to a file of its own in ``staging`` (io writes it to a temporary name and
    renames it), then is renamed onto ``target``: a task run twice (its worker died after
    writing) replaces the file with the same bytes, and a task killed mid-write leaves its
    remains in ``staging`` only. Any failure is raised naming ``source``.
    """
    start = time.process_time()
    try:
        contactors = io.read_contactors(source)
        proj = _working_copy(surface).project(contactors.points)
        staged = os.path.join(staging, f"{uuid.uuid4().hex}-{os.path.basename(target)}")
        io.write_result(staged, contactors, proj.columns(), labels=LABELS, overwrite=True)
        os.replace(staged, target)
    except io.ReadError:
        raise  # names the file already
    except io.WriteError as exc:
        raise io.WriteError(f"{target}: {str(exc).split(': ', 1)[-1]}") from None
    except Exception as exc:  # noqa: BLE001 - any failure fails the job naming the partition
        raise ClusterError(f"{source}: {type(exc).__name__}: {first_line(exc)}") from None
    status = np.bincount(proj.status, minlength=len(STATUS))
    same = int(coincident(contactors.points, surface.nodes)) if coincident else 0
    import socket

    return {"contactors": len(contactors.points), "status": status, "coincident": same,
            "cpu_seconds": time.process_time() - start, "peak_memory": _peak_memory(),
            "worker": f"{socket.gethostname()}:{os.getpid()}"}


def project_partitions(surface, sources: list[str], targets: list[str], *, client,
                       progress: bool = False, coincident=None) -> Summary:
    """Project every partition file onto ``surface`` on the cluster of ``client``.

    Parameters
    ----------
    surface : DiffuseSurface or FacetSurface
        The target's surface, built once here and sent to the workers.
    sources, targets : list of str
        Input and output partition files (:func:`partitions`, :func:`output_paths`; outputs
        already checked). Inputs and outputs must be paths the workers see (one file system).
    client : distributed.Client
    progress : bool
        Draw dask's progress bar on stderr.
    coincident : callable, optional
        ``coincident(points, nodes) -> int``, run on each partition and summed (the command
        line's check for contactors that are target nodes).

    Returns
    -------
    Summary

    Raises
    ------
    ReadError, WriteError, ClusterError
        The first partition that failed (the message names its file); the other tasks are
        cancelled, outputs already written are kept (each one whole).
    """
    from concurrent.futures import CancelledError  # dask's FutureCancelledError is one

    from dask.distributed import as_completed
    from distributed.scheduler import KilledWorker

    summary = Summary()
    if not sources:
        return summary
    directories = sorted({os.path.dirname(os.path.abspath(t)) for t in targets})
    staging = {d: tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=d) for d in directories}
    job = uuid.uuid4().hex[:12]
    futures = []
    start = time.perf_counter()
    try:
        shared = _share(client, surface)
        for i, (source, target) in enumerate(zip(sources, targets)):
            futures.append(client.submit(
                _project_file, shared, source, target,
                staging[os.path.dirname(os.path.abspath(target))], coincident,
                key=f"diffsurf-project-{job}-{i}", pure=False, retries=0))
        if progress:
            from dask.distributed import progress as _progress

            # dask's text bar writes to stdout; logs and progress belong on stderr (it
            # clears its line when done)
            with contextlib.redirect_stdout(sys.stderr):
                _progress(futures)
        index = {f.key: i for i, f in enumerate(futures)}
        for future in as_completed(futures):
            i = index[future.key]
            try:
                summary.add(future.result())
            except KilledWorker:
                raise ClusterError(f"{sources[i]}: the workers projecting it died (out of "
                                   f"memory? a smaller partition needs less)") from None
            except CancelledError:
                raise ClusterError(f"{sources[i]}: cancelled (the cluster shut down?)") \
                    from None
    except BaseException:
        client.cancel(futures)
        raise
    finally:
        summary.wall_seconds = time.perf_counter() - start
        for d in staging.values():
            _remove_staging(d)
    return summary


def _remove_staging(path: str, attempts: int = 50) -> None:
    """Remove a staging directory. After a failure, cancelled tasks that were already running
    on a worker go on until they end (dask cannot stop them) and may create a file in it
    between rmtree's listing and its rmdir, which then fails: try again until it is gone (a
    task that finds it gone fails to write, harmlessly)."""
    for _ in range(attempts):
        shutil.rmtree(path, ignore_errors=True)
        if not os.path.exists(path):
            return
        time.sleep(0.1)


# --------------------------------------------------------------------------------------------
# dask DataFrames
# --------------------------------------------------------------------------------------------

def _coordinates(columns) -> list:
    """The x, y and z columns of ``columns`` (any case, one each), as io reads tables."""
    from .io.table import coordinate_columns

    columns = list(columns)
    try:
        return [columns[j] for j in coordinate_columns(columns)]
    except ValueError as exc:
        raise ValueError(f"{exc}, expected columns x, y, z (got "
                         f"{', '.join(map(str, columns)) or 'no columns'})") from None


def project_frame(surface, frame):
    """Project the contactors of one pandas DataFrame: one partition's task.

    Parameters
    ----------
    surface : DiffuseSurface or FacetSurface
    frame : pandas.DataFrame
        Columns x, y, z (any case; numbers, missing values read as NaN) and others, passed
        through.

    Returns
    -------
    pandas.DataFrame
        The pass-through columns, then the result columns of a one-machine run
        (`Projection.columns`: those of `projection.COLUMNS` the surface answers); status and
        reason categorical (the words of `STATUS`, `REASONS`). Same index as ``frame``. A
        row with a missing, NaN or inf coordinate is a 'failed' row.
    """
    import pandas as pd

    xyz = _coordinates(list(frame.columns))
    for c in xyz:
        if not pd.api.types.is_numeric_dtype(frame[c].dtype):
            raise ValueError(f"column '{c}' holds {frame[c].dtype}, expected numbers")
    points = np.empty((len(frame), 3), np.float64)
    for axis, c in enumerate(xyz):
        points[:, axis] = frame[c].to_numpy(dtype=np.float64, na_value=np.nan)
    proj = surface.project(points)
    out = frame.drop(columns=xyz)
    names = set(out.columns)
    columns = {}
    for name, values in proj.columns().items():
        if name in names:
            raise ValueError(f"two columns named '{name}' (an input column passed through and "
                             f"a result): rename the input column")
        columns[name] = (pd.Categorical.from_codes(values.astype(np.int64), LABELS[name])
                         if name in LABELS else values)
    result = pd.DataFrame(columns, index=frame.index)
    return pd.concat([out, result], axis=1) if len(out.columns) else result


def _read_frame(source: str):
    """One partition file as a pandas DataFrame, read as a one-machine run reads it: the
    pass-through columns, then x, y, z."""
    import pandas as pd

    try:
        contactors = io.read_contactors(source)
    except io.ReadError:
        raise
    except Exception as exc:  # noqa: BLE001
        raise ClusterError(f"{source}: {type(exc).__name__}: {first_line(exc)}") from None
    frame = pd.DataFrame({n: s.to_pandas() for n, s in
                          zip(contactors.passthrough_names, contactors.passthrough)})
    for axis in range(3):
        frame["xyz"[axis]] = contactors.points[:, axis]
    return frame


def project_dataframe(surface, points):
    """Project a partitioned cloud of contactors, lazily: a dask DataFrame of results.

    Parameters
    ----------
    surface : DiffuseSurface or FacetSurface
        The target's surface; it enters the graph once and every partition's task uses it.
    points : dask.dataframe.DataFrame or str
        Contactors with columns x, y, z (any case, numbers) and others passed through; or
        partition files (a glob, a directory or a file, see :func:`partitions`), read as a
        one-machine run reads them, one partition per file in natural order.

    Returns
    -------
    dask.dataframe.DataFrame
        One partition per input partition, in order, with the index of ``points``: the
        pass-through columns, then the result columns (see :func:`project_frame`). Nothing
        is computed until asked (``.compute()``, ``.to_parquet(...)``).

    Raises
    ------
    ValueError
        ``points`` lacks x, y or z, or a result name is taken by an input column.

    Examples
    --------
    >>> import dask.dataframe as dd
    >>> from diffsurf_cli import DiffuseSurface
    >>> from diffsurf_cli.cluster import project_dataframe
    >>> surface = DiffuseSurface(nodes, faces)
    >>> result = project_dataframe(surface, dd.read_parquet("points/*.parquet"))
    >>> result.to_parquet("out/")
    """
    import dask
    import dask.dataframe as dd

    if isinstance(points, (str, os.PathLike)):
        sources = partitions(os.fspath(points))
        meta = _read_frame(sources[0]).iloc[:0]
        points = dd.from_map(_read_frame, sources, meta=meta, enforce_metadata=False)
    elif not isinstance(points, dd.DataFrame):
        raise TypeError(f"points: expected a dask DataFrame or a path, got "
                        f"{type(points).__name__}")
    shared = _shareable(surface)
    meta = project_frame(shared, points._meta)  # an empty frame: checks the columns too
    return points.map_partitions(_project_partition, dask.delayed(shared, pure=False),
                                 meta=meta)


def _project_partition(frame, surface):
    # map_partitions passes the partition first
    return project_frame(_working_copy(surface), frame)
