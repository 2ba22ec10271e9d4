"""CSV reading and writing throughput: diffsurf_cli.fastcsv (through io._parse_csv and
io._write_csv) against the pure Python/numpy path it replaced and against numpy's
loadtxt/savetxt, in the same run, as ratios (issue 5).

Read: ``ROWS`` rows of ``id,x,y,z`` with 17 significant digits. Write: the ``project`` result,
``ROWS`` rows x 15 columns (an id pass-through, x,y,z,gap,nx,ny,nz,px,py,pz, the status
label, support and iterations, rcond, the reason label), to a file. Each figure is the best of
``REPEAT`` runs (wall clock; the CPU time of the process is printed too, since a loaded
machine slows the wall clock of the parallel kernels most).

``--memory`` reads 2,000,000 rows with an id column and reports the peak of traced
allocations (tracemalloc) and the growth of the peak RSS of a fresh process (with
``--old-memory`` also for the old reader, which needs several GB). ``--startup`` times, in
fresh processes, what every command pays before its first row: importing fastcsv (loading the
compiled _ccsv and computing its tables) and io, and the first read and write of a tiny file.

    python3 benchmarks/csv_io.py [--rows 200000] [--memory [--old-memory]] [--startup]
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import io as _io
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
from types import SimpleNamespace

import numpy as np

from diffsurf_cli import io as dio
from diffsurf_cli.mls.surface import REASONS, STATUS

REPEAT = 5


# --------------------------------------------------------------------------------------------
# the peer: io.py's CSV functions before fastcsv, verbatim but for the exception class
# --------------------------------------------------------------------------------------------


class OldReadError(Exception):
    pass


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


@contextlib.contextmanager
def _gc_paused():
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def _data_lines(lines):
    for lineno, line in enumerate(lines, 1):
        s = line.strip()
        if s and s[0] != "#":
            yield lineno, s


def old_parse_csv(text: str, name: str):
    if "\x00" in text:
        raise OldReadError(f"{name}: not a text CSV file (contains NUL bytes)")
    with _gc_paused():
        lines = text.split("\n")
        stripped = [s.strip() for s in lines]
        kept = [s for s in stripped if s and s[0] != "#"]
        if not kept:
            raise OldReadError(f"{name}: no data rows, expected CSV lines x,y,z")
        first_lineno = next(_data_lines(lines))[0]
        first_fields = kept[0].split(",")
        ncols = len(first_fields)
        if any(not _is_number(f) for f in first_fields):
            names = [f.strip().strip('"').strip() for f in first_fields]
            lower = [n.lower() for n in names]
            idx = []
            for axis in ("x", "y", "z"):
                n = lower.count(axis)
                if n != 1:
                    what = "no" if n == 0 else "more than one"
                    raise OldReadError(
                        f"{name}, line {first_lineno}: header has {what} '{axis}' column, "
                        f"expected columns named x,y,z (got {','.join(names)!r})"
                    )
                idx.append(lower.index(axis))
            pidx = [j for j in range(ncols) if j not in idx]
            pnames = [names[j] for j in pidx]
            body = kept[1:]
            skip = 1
        else:
            if ncols < 3:
                raise OldReadError(
                    f"{name}, line {first_lineno}: expected 3 numeric columns x,y,z, got {ncols}"
                )
            idx = [ncols - 3, ncols - 2, ncols - 1]
            pidx = list(range(ncols - 3))
            pnames = [f"col{j + 1}" for j in pidx]
            body = kept
            skip = 0
        if not body:
            raise OldReadError(f"{name}: no data rows after the header, expected CSV lines x,y,z")
        rows = [s.split(",") for s in body]
        if any(len(r) != ncols for r in rows):
            for k, (lineno, _) in enumerate(_data_lines(lines)):
                if k >= skip and len(rows[k - skip]) != ncols:
                    raise OldReadError(
                        f"{name}, line {lineno}: expected {ncols} comma separated columns "
                        f"(as on line {first_lineno}), got {len(rows[k - skip])}"
                    )
        cols = list(zip(*rows))
        del rows
        try:
            points = np.column_stack([np.array(cols[j], dtype=np.float64) for j in idx])
        except ValueError:
            for k, (lineno, _) in enumerate(_data_lines(lines)):
                if k < skip:
                    continue
                for j, axis in zip(idx, "xyz"):
                    text_ = cols[j][k - skip]
                    if not _is_number(text_):
                        raise OldReadError(
                            f"{name}, line {lineno}: expected a number for {axis}, "
                            f"got {text_.strip()!r}"
                        ) from None
            points = np.array([[float(v) for v in cols[j]] for j in idx], dtype=np.float64).T
            points = np.ascontiguousarray(points)
        if pidx:
            passthrough = list(map(list, zip(*([f.strip() for f in cols[j]] for j in pidx))))
        else:
            passthrough = [[] for _ in range(len(body))]
    return points, pnames, passthrough


def _old_column_text(values, words):
    arr = np.asarray(values)
    if words is not None:
        return [words[c] for c in arr.tolist()]
    if arr.dtype.kind == "f":
        return list(map(repr, arr.astype(np.float64, copy=False).tolist()))
    return list(map(str, arr.astype(np.int64, copy=False).tolist()))


def old_write_csv(fh, contactors, columns: dict, labels: dict) -> None:
    header = list(contactors.passthrough_names) + list(columns)
    fh.write(",".join(header) + "\n")
    columns = {k: np.asarray(v) for k, v in columns.items()}
    p = len(contactors.points)
    chunk = 50000
    has_pass = bool(contactors.passthrough_names)
    with _gc_paused():
        for start in range(0, p, chunk):
            stop = min(start + chunk, p)
            parts = [_old_column_text(v[start:stop], labels.get(k)) for k, v in columns.items()]
            if has_pass:
                parts.insert(0, list(map(",".join, contactors.passthrough[start:stop])))
            fh.write("\n".join(map(",".join, zip(*parts))))
            fh.write("\n")


# --------------------------------------------------------------------------------------------
# data
# --------------------------------------------------------------------------------------------


def contactor_csv(rows: int, seed: int = 0) -> bytes:
    """``id,x,y,z`` with 17 significant digits, as a mesher or a script writes them."""
    rng = np.random.default_rng(seed)
    xyz = rng.normal(scale=40.0, size=(rows, 3))
    body = np.char.add(np.arange(1, rows + 1).astype(str), ",")
    text = "\n".join(f"{i}{x:.17g},{y:.17g},{z:.17g}"
                     for i, (x, y, z) in zip(body.tolist(), xyz.tolist()))
    return ("id,x,y,z\n" + text + "\n").encode("ascii")


def result_columns(rows: int, seed: int = 1):
    """The 15 output columns of ``diffsurf project`` with plausible values."""
    rng = np.random.default_rng(seed)
    x = rng.normal(scale=40.0, size=(rows, 3))
    n = rng.normal(size=(rows, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    gap = rng.normal(scale=1e-2, size=rows)
    return {
        "x": x[:, 0], "y": x[:, 1], "z": x[:, 2], "gap": gap,
        "nx": n[:, 0], "ny": n[:, 1], "nz": n[:, 2],
        "px": x[:, 0] - gap * n[:, 0], "py": x[:, 1] - gap * n[:, 1],
        "pz": x[:, 2] - gap * n[:, 2],
        "status": rng.integers(0, len(STATUS), rows),
        "support": rng.integers(6, 40, rows), "iterations": rng.integers(0, 6, rows),
        "rcond": 10.0 ** rng.uniform(-4, 0, rows),
        "reason": rng.integers(0, len(REASONS), rows),
    }


def best(fn, repeat=REPEAT, setup=None):
    """(best wall seconds, CPU seconds of that run) over ``repeat`` calls."""
    out = []
    for _ in range(repeat):
        if setup is not None:
            setup()
        gc.collect()
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        out.append((time.perf_counter() - t0, time.process_time() - c0))
    return min(out)


def report(title, rows, results):
    ref = results[0][1][0]
    print(f"\n{title} ({rows} rows)")
    for name, (wall, cpu) in results:
        ratio = wall / ref
        print(f"  {name:34s} {wall * 1e3:9.1f} ms wall {cpu * 1e3:9.1f} ms CPU "
              f"{rows / wall / 1e6:7.2f} M rows/s   {ratio:6.1f}x the time of fastcsv")


# --------------------------------------------------------------------------------------------
# runs
# --------------------------------------------------------------------------------------------


def bench_read(rows: int):
    data = contactor_csv(rows)
    text = data.decode("utf-8")
    new = lambda: dio._parse_csv(dio._csv_bytes(data, "bench.csv"), "bench.csv")  # noqa: E731
    new()  # warm-up
    p_new, _, t_new = new()
    p_old, _, t_old = old_parse_csv(text, "bench.csv")
    assert p_new.tobytes() == p_old.tobytes() and t_new == t_old, "fastcsv and the peer differ"
    loadtxt = lambda: np.loadtxt(_io.StringIO(text), delimiter=",", skiprows=1)  # noqa: E731
    assert loadtxt()[:, 1:].tobytes() == p_new.tobytes()
    report("read id,x,y,z", rows, [
        ("fastcsv (io._parse_csv)", best(new)),
        ("old io._parse_csv (str, numpy)", best(lambda: old_parse_csv(text, "bench.csv"))),
        ("np.loadtxt (no pass-through)", best(loadtxt, repeat=2)),
    ])


def bench_write(rows: int, directory: str):
    cols = result_columns(rows)
    labels = {"status": STATUS, "reason": REASONS}
    ids = [[str(i)] for i in range(1, rows + 1)]
    c_new = dio.Contactors("bench.csv", np.zeros((rows, 3)), ["id"], ids, None)
    c_old = SimpleNamespace(points=c_new.points, passthrough_names=["id"], passthrough=ids)
    path = os.path.join(directory, "out.csv")

    def write(fn, contactors):
        with open(path, "w", encoding="utf-8", newline="\n") as fh:
            fn(fh, contactors, cols, labels)

    new = lambda: write(dio._write_csv, c_new)  # noqa: E731
    new()  # warm-up
    with open(path, "rb") as fh:
        got = fh.read()
    write(old_write_csv, c_old)
    with open(path, "rb") as fh:
        assert fh.read() == got, "fastcsv and the peer wrote different bytes"
    numeric = np.column_stack([np.arange(1, rows + 1)] + list(cols.values())).astype(np.float64)

    def savetxt():
        np.savetxt(path, numeric, fmt="%.17g", delimiter=",", header=",".join(["id", *cols]),
                   comments="")

    def fresh():  # the CLI writes a new temporary file; truncating an old one costs time
        if os.path.exists(path):
            os.unlink(path)

    report("write 15 columns + id", rows, [
        ("fastcsv (io._write_csv)", best(new, setup=fresh)),
        ("old io._write_csv (repr, joins)", best(lambda: write(old_write_csv, c_old),
                                                 setup=fresh)),
        ("np.savetxt %.17g (numbers only)", best(savetxt, repeat=2, setup=fresh)),
    ])
    print(f"  output {len(got) / 1e6:.1f} MB, identical bytes from fastcsv and the old writer")


_RSS_CHILD = """
import sys
sys.path.insert(0, sys.argv[3])
import numpy as np
from diffsurf_cli import io
import csv_io


def peak_kb():  # VmHWM: peak RSS of this process image (ru_maxrss would include the parent's)
    with open("/proc/self/status") as fh:
        return int(next(line for line in fh if line.startswith("VmHWM")).split()[1])


path, which = sys.argv[1], sys.argv[2]
io._parse_csv(io._csv_bytes(b"x,y,z\\n1,2,3\\n", "w"), "w")  # compiled code loaded
before = peak_kb()
if which == "new":
    c = io.read_contactors(path)
else:
    with open(path, "rb") as fh:
        csv_io.old_parse_csv(io._decode(fh.read(), path), path)
print(before, peak_kb())
"""


def bench_memory(rows: int, directory: str, old: bool):
    path = os.path.join(directory, "big.csv")
    with open(path, "wb") as fh:
        for start in range(0, rows, 200000):
            block = contactor_csv(min(200000, rows - start), seed=start)
            fh.write(block if start == 0 else block.split(b"\n", 1)[1])
    size = os.path.getsize(path)
    dio.read_contactors(path)  # warm-up, and the file into the page cache
    gc.collect()
    tracemalloc.start()
    c = dio.read_contactors(path)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    kept = c.points.nbytes + c.passthrough.data.nbytes + c.passthrough.offsets.nbytes
    print(f"\nmemory: read_contactors of {rows} rows with an id column ({size / 1e6:.0f} MB file)")
    print(f"  fastcsv: peak traced allocations {peak / 1e6:.0f} MB = the file's bytes "
          f"{size / 1e6:.0f} MB + {(peak - size) / 1e6:.0f} MB; the result keeps "
          f"{kept / 1e6:.0f} MB (points {c.points.nbytes / 1e6:.0f} MB, ids "
          f"{c.passthrough.data.nbytes / 1e6:.0f} MB + offsets "
          f"{c.passthrough.offsets.nbytes / 1e6:.0f} MB)")
    del c
    here = os.path.dirname(os.path.abspath(__file__))
    if not os.path.exists("/proc/self/status"):
        return
    for which in ("new", "old") if old else ("new",):
        t = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", _RSS_CHILD, path, which, here], check=True,
                             capture_output=True, text=True).stdout.split()
        before, after = (int(v) * 1024 for v in out)
        print(f"  {'fastcsv' if which == 'new' else 'old reader':10s} peak RSS of a fresh "
              f"process grows by {(after - before) / 1e6:5.0f} MB while reading "
              f"({time.perf_counter() - t:.1f} s for the process)")


_CHILD = """
import sys, time
t0 = time.perf_counter()
import numpy as np
t1 = time.perf_counter()
from diffsurf_cli import fastcsv
t2 = time.perf_counter()
from diffsurf_cli import io
t3 = time.perf_counter()
data = b"id,x,y,z\\n1,0.5,2,3\\n2,1e-3,nan,4\\n"
io._parse_csv(io._csv_bytes(data, "x.csv"), "x.csv")
t4 = time.perf_counter()
import io as pyio
c = io.Contactors("x", np.zeros((2, 3)), ["id"], [["1"], ["2"]])
io._write_csv(pyio.StringIO(), c, {"x": np.array([0.5, 1.0]), "n": np.array([1, 2]),
                                   "s": np.array([0, 1])}, {"s": ("a", "b")})
t5 = time.perf_counter()
print(t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4, "numba" in sys.modules)
"""


def bench_startup(runs: int = 5):
    """Median over ``runs`` fresh processes of the import and first-call times."""
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", _CHILD], check=True, capture_output=True,
                             text=True).stdout.split()
        times.append([float(v) for v in out[:5]] + [time.perf_counter() - t])
        numba = out[5] == "True"
    imp_np, imp_csv, imp_io, read, write, proc = np.median(np.array(times), axis=0)
    print(f"\nstart-up (median of {runs} fresh processes):")
    print(f"  import numpy {imp_np * 1e3:5.0f} ms   import fastcsv (C library + tables) "
          f"{imp_csv * 1e3:4.1f} ms   import io {imp_io * 1e3:5.0f} ms")
    print(f"  first read {read * 1e3:5.1f} ms   first write {write * 1e3:5.1f} ms   whole process "
          f"{proc * 1e3:5.0f} ms   numba imported: {'yes' if numba else 'no'}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=200000)
    ap.add_argument("--memory", action="store_true", help="read 2M rows under tracemalloc")
    ap.add_argument("--old-memory", action="store_true",
                    help="with --memory, also the peak RSS of the old reader (GBs)")
    ap.add_argument("--startup", action="store_true",
                    help="time the imports and first calls in fresh processes")
    args = ap.parse_args(argv)
    print(f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as d:
        bench_read(args.rows)
        bench_write(args.rows, d)
        if args.memory:
            bench_memory(2000000, d, args.old_memory)
    if args.startup:
        bench_startup()


if __name__ == "__main__":
    main()
