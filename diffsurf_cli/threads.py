"""How many OpenMP threads a compiled loop over contactors gets: the one rule every compiled
entry point with a parallel loop follows (`threads_for`).

Below a measured crossover (`tol.PARALLEL_MIN`, per entry point: the batch where two threads
start to win in wall time), a batch runs on the calling thread in a plain loop, without an
OpenMP parallel region: waking the other threads and the barrier at the end would cost more
than they save, and a solver's calls for a few contactors would each pay it. Above it, one
thread per half a crossover of contactors, up to OpenMP's count (OMP_NUM_THREADS, else the
CPUs).
"""
from __future__ import annotations

from . import tol
from ._codes import max_threads

__all__ = ["chunk_size", "max_threads", "threads_for"]


def threads_for(m: int, kernel: str) -> int:
    """Threads for a batch of m contactors of the compiled `kernel` (a key of
    `tol.PARALLEL_MIN`): 1 below its crossover (a serial loop), else one per half a crossover
    of contactors, at most `max_threads()`."""
    crossover = tol.PARALLEL_MIN[kernel]
    if m < crossover:
        return 1
    return max(1, min(max_threads(), (2 * m) // crossover))


def chunk_size(m: int, threads: int, largest: int) -> int:
    """Contactors a thread takes at a time from a dynamic schedule over m: `largest` (nearby
    contactors together share the cache), less for a small batch, so that each thread gets
    about 4 chunks or more (a batch of two chunks would leave a thread idle at its end)."""
    return max(1, min(largest, m // (4 * max(threads, 1))))
