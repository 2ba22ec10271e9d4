"""Table reading and writing: diffsurf's polars path against polars alone, numpy's
loadtxt/savetxt and the hand-written C it replaced (fastcsv at commit 201ecf9), in one run, as
ratios of CPU time (issue 10, item 3).

Data: ``--rows`` (200,000) rows of 16 float64 columns (13 plain columns, then x, y, z), 17
significant digits. Write: the 16 columns to a file, as ``write_result`` writes them (header,
shortest round-trip floats). Read: that file as contactors (x, y, z and 13 pass-through
columns kept as text) with ``read_contactors``; then the common shape, ``id,x,y,z``, by the
fast path and by the full reader alone. Each figure is the best of ``REPEAT`` runs;
CPU time is the process's (all threads), wall clock is printed too. fastcsv runs in a child
process from a worktree of 201ecf9 built in place; without one (``--old`` not a built
checkout) its rows are left out:

    git worktree add /tmp/oldcsv 201ecf9 && (cd /tmp/oldcsv && python setup.py build_ext -i)
    python benchmarks/csv_io.py [--rows 200000] [--old /tmp/oldcsv] [--memory] [--startup]

``--memory`` reads 2,000,000 rows of ``id,x,y,z`` in fresh processes and prints the growth of
their peak RSS (polars allocates outside tracemalloc's view). ``--startup`` times, in fresh
processes, ``import diffsurf_cli.io`` and the first read and write of a tiny CSV.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from unittest import mock

import numpy as np

REPEAT = 5

_CHILD = r"""
import json, sys, time
import numpy as np
mode, path, out, repeat = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
from diffsurf_cli import io
assert io.__file__.startswith(sys.argv[5]), io.__file__


def best(fn):
    cpu, wall = [], []
    for _ in range(repeat):
        c, w = time.process_time(), time.perf_counter()
        fn()
        cpu.append(time.process_time() - c)
        wall.append(time.perf_counter() - w)
    return min(cpu), min(wall)


if mode == "read":
    result = best(lambda: io.read_contactors(path))
    c = io.read_contactors(path)
    np.save(out, c.points)
else:
    data = np.load(path)
    cols = {f"c{k + 1}": data[:, k] for k in range(data.shape[1])}
    c = io.Contactors("x", data[:, :3], [], None, None)

    def write():
        if hasattr(io, "_write_csv"):  # fastcsv's io
            with open(out, "w", encoding="utf-8", newline="\n") as fh:
                io._write_csv(fh, c, cols, {})
        else:
            io.write_result(out, c, cols, overwrite=True)

    result = best(write)
print(json.dumps(result))
"""


def best(fn, repeat=REPEAT):
    cpu, wall = [], []
    for _ in range(repeat):
        c, w = time.process_time(), time.perf_counter()
        fn()
        cpu.append(time.process_time() - c)
        wall.append(time.perf_counter() - w)
    return min(cpu), min(wall)


def child(root: str, mode: str, path: str, out: str):
    """Run the read or write of the package at ``root`` in a fresh process: (cpu, wall)."""
    env = dict(os.environ, PYTHONPATH=root)
    res = subprocess.run([sys.executable, "-c", _CHILD, mode, path, out, str(REPEAT),
                          os.path.join(root, "diffsurf_cli")],
                         check=True, capture_output=True, text=True, env=env, cwd=root)
    return tuple(json.loads(res.stdout.strip().splitlines()[-1]))


def table_data(rows: int, seed: int = 0) -> np.ndarray:
    """(rows, 16) doubles over many magnitudes, as a result table holds them."""
    rng = np.random.default_rng(seed)
    return rng.normal(size=(rows, 16)) * 10.0 ** rng.integers(-8, 8, size=(rows, 16))


def report(title: str, results: list, unit_rows: int) -> None:
    print(f"\n{title}")
    base = results[0][1][0]
    for name, (cpu, wall) in results:
        print(f"  {name:34s} CPU {cpu:6.3f} s  wall {wall:6.3f} s  "
              f"{unit_rows / cpu / 1e6:5.2f} M rows/CPU-s  {cpu / base:5.2f}x the CPU time of "
              f"diffsurf")


def bench(rows: int, directory: str, old: str | None) -> None:
    import polars as pl

    from diffsurf_cli import io as dio
    from diffsurf_cli.io import table

    data = table_data(rows)
    npy = os.path.join(directory, "data.npy")
    np.save(npy, data)
    names = [f"c{k + 1}" for k in range(13)] + ["x", "y", "z"]
    cols = dict(zip(names, data.T))
    c = dio.Contactors("x", data[:, 13:], [], None, None)
    path = os.path.join(directory, "table.csv")

    # write
    results = [("diffsurf write_result (polars)",
                best(lambda: dio.write_result(path, c, cols, overwrite=True)))]
    frame = pl.DataFrame(cols)
    other = os.path.join(directory, "other.csv")
    results.append(("polars DataFrame.write_csv alone", best(lambda: frame.write_csv(other))))
    results.append(("numpy.savetxt %.17g", best(lambda: np.savetxt(
        other, data, fmt="%.17g", delimiter=",", header=",".join(names), comments=""),
        repeat=2)))
    if old:
        results.append(("fastcsv @201ecf9 (C, child process)",
                        child(old, "write", npy, other)))
    report(f"write {rows} rows x 16 float64 columns ({os.path.getsize(path) / 1e6:.0f} MB)",
           results, rows)
    back = pl.read_csv(path).to_numpy()
    assert back.tobytes() == data.tobytes(), "the CSV did not read back bit for bit"
    print("  every float read back bit for bit by polars (and by diffsurf below)")

    # read
    got = dio.read_contactors(path)
    assert got.points.tobytes() == data[:, 13:].tobytes()
    assert got.passthrough_names == names[:13]
    results = [("diffsurf read_contactors (polars)", best(lambda: dio.read_contactors(path)))]
    results.append(("polars read_csv alone, all Float64",
                    best(lambda: pl.read_csv(path, schema={n: pl.Float64 for n in names}))))
    results.append(("numpy.loadtxt", best(lambda: np.loadtxt(path, delimiter=",", skiprows=1),
                                          repeat=1)))
    if old:
        out = os.path.join(directory, "old_points.npy")
        results.append(("fastcsv @201ecf9 (C, child process)", child(old, "read", path, out)))
        assert np.load(out).tobytes() == got.points.tobytes(), "fastcsv read other numbers"
    report(f"read {rows} rows x 16 columns as contactors (x, y, z + 13 pass-through)",
           results, rows)

    # the common shape: an id and the coordinates, as a plain file (the fast path reads it)
    shape = os.path.join(directory, "points.csv")
    with open(shape, "w") as fh:
        fh.write("id,x,y,z\n")
        fh.writelines(f"{i},{x!r},{y!r},{z!r}\n" for i, (x, y, z) in enumerate(
            data[:, 13:].tolist()))
    got = dio.read_contactors(shape)

    def full_reader():  # the fast path cannot tell: the full reader runs
        with mock.patch.object(table, "_read_plain", return_value=None):
            return dio.read_contactors(shape)

    assert full_reader().points.tobytes() == got.points.tobytes()
    results = [("diffsurf read_contactors (polars)", best(lambda: dio.read_contactors(shape))),
               ("  the same, full reader only", best(full_reader)),
               ("polars read_csv alone (Int64, Float64)",
                best(lambda: pl.read_csv(shape, schema={"id": pl.Int64, "x": pl.Float64,
                                                        "y": pl.Float64, "z": pl.Float64})))]
    if old:
        out = os.path.join(directory, "old_points.npy")
        results.append(("fastcsv @201ecf9 (C, child process)", child(old, "read", shape, out)))
        assert np.load(out).tobytes() == got.points.tobytes(), "fastcsv read other numbers"
    report(f"read {rows} rows id,x,y,z as contactors ({os.path.getsize(shape) / 1e6:.0f} MB)",
           results, rows)


_RSS_CHILD = r"""
import sys
from diffsurf_cli import io


def peak_kb():  # VmHWM: the peak RSS of this process image
    with open("/proc/self/status") as fh:
        return int(next(line for line in fh if line.startswith("VmHWM")).split()[1])


import numpy, polars  # loaded before the baseline, as a command has them
io.read_contactors(sys.argv[2])  # compiled code and tables loaded
before = peak_kb()
c = io.read_contactors(sys.argv[1])
print(before, peak_kb(), c.points.nbytes)
"""


def bench_memory(directory: str, old: str | None, rows: int = 2_000_000) -> None:
    path = os.path.join(directory, "big.csv")
    rng = np.random.default_rng(1)
    with open(path, "w") as fh:
        fh.write("id,x,y,z\n")
        for start in range(0, rows, 200_000):
            pts = rng.normal(size=(200_000, 3))
            fh.writelines(f"{start + i},{x!r},{y!r},{z!r}\n"
                          for i, (x, y, z) in enumerate(pts.tolist()))
    tiny = os.path.join(directory, "tiny.csv")
    with open(tiny, "w") as fh:
        fh.write("id,x,y,z\n1,2,3,4\n")
    size = os.path.getsize(path)
    print(f"\nmemory: read_contactors of {rows} rows id,x,y,z ({size / 1e6:.0f} MB file), "
          f"growth of the peak RSS of a fresh process")
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for name, root in (("diffsurf (polars)", here), ("fastcsv @201ecf9", old)):
        if root is None:
            continue
        env = dict(os.environ, PYTHONPATH=root)
        out = subprocess.run([sys.executable, "-c", _RSS_CHILD, path, tiny], check=True,
                             capture_output=True, text=True, env=env, cwd=root).stdout.split()
        before, after, kept = (int(v) for v in out)
        grown = after - before
        print(f"  {name:20s} +{grown / 1e3:5.0f} MB  ({grown * 1e3 / size:.1f}"
              f"x the file; the points alone are {kept / 1e6:.0f} MB)")


_STARTUP = r"""
import sys, time
t0 = time.perf_counter()
import diffsurf_cli.io as io
t1 = time.perf_counter()
import io as pyio
import numpy as np
c = io.read_contactors("-", stdin=pyio.StringIO("id,x,y,z\n1,0.5,2,3\n2,1e-3,nan,4\n"))
t2 = time.perf_counter()
io.write_result("-", c, {"x": np.array([0.5, 1.0]), "s": np.array([0, 1])},
                labels={"s": ("a", "b")}, stdout=pyio.StringIO())
t3 = time.perf_counter()
print(t1 - t0, t2 - t1, t3 - t2, "polars" in sys.modules)
"""


def bench_startup(old: str | None, runs: int = 5) -> None:
    print(f"\nstart-up (median of {runs} fresh processes): import io, first read, first write")
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for name, root in (("diffsurf (polars)", here), ("fastcsv @201ecf9", old)):
        if root is None:
            continue
        env = dict(os.environ, PYTHONPATH=root)
        times, lazy = [], None
        for _ in range(runs):
            out = subprocess.run([sys.executable, "-c", _STARTUP], check=True, env=env,
                                 cwd=root, capture_output=True, text=True).stdout.split()
            times.append([float(v) for v in out[:3]])
        imp, read, write = np.median(np.array(times), axis=0)
        res = subprocess.run([sys.executable, "-c", "import sys, diffsurf_cli.io; "
                              "print('polars' in sys.modules)"], env=env, cwd=root,
                             capture_output=True, text=True, check=True)
        lazy = res.stdout.strip() == "False"
        print(f"  {name:20s} import io {imp * 1e3:5.0f} ms (polars not imported: {lazy})  "
              f"first read {read * 1e3:5.0f} ms  first write {write * 1e3:5.0f} ms")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=200_000)
    ap.add_argument("--old", default="/tmp/oldcsv",
                    help="a checkout of 201ecf9 built in place (fastcsv), or ''")
    ap.add_argument("--memory", action="store_true")
    ap.add_argument("--startup", action="store_true")
    args = ap.parse_args(argv)
    old = args.old if args.old and os.path.exists(
        os.path.join(args.old, "diffsurf_cli", "fastcsv.py")) else None
    if args.old and old is None:
        print(f"(no built fastcsv checkout at {args.old}: its rows are left out)")
    print(f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as d:
        bench(args.rows, d, old)
        if args.memory:
            bench_memory(d, old)
    if args.startup:
        bench_startup(old)


if __name__ == "__main__":
    main()
