"""The projection on a Dask cluster (diffsurf_cli.cluster, `project --workers/--scheduler`),
against one process: the same bits, in the same order, whatever happens to the workers."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")  # the 'test' extra installs it
pl = pytest.importorskip("polars")
pd = pytest.importorskip("pandas")

import dask.dataframe as dd  # noqa: E402

from diffsurf_cli import cluster, io  # noqa: E402
from diffsurf_cli.mls.surface import DiffuseSurface  # noqa: E402
from diffsurf_cli.projection import REASONS, STATUS  # noqa: E402
from diffsurf_cli.testing.shapes import Sphere  # noqa: E402
from samples import CYLINDER, PLATE_CSV, run  # noqa: E402

SHAPE = Sphere()


@pytest.fixture(scope="module")
def surface():
    nodes, faces = SHAPE.mesh(12)
    return DiffuseSurface(nodes, [faces])


@pytest.fixture(scope="module")
def client():
    """Two worker processes of one thread, as `--workers 2` starts them."""
    with cluster.connect(workers=2) as c:
        yield c


def cloud(m, seed, bad=False):
    """Contactors near the sphere; with ``bad``, rows of NaN and inf (failed rows)."""
    points = SHAPE.sample_near(m, 0.05, rng=seed)
    if bad:
        points[m // 3] = [np.nan, 0.0, 0.0]
        points[m // 2, 2] = np.inf
    return points


def write_partitions(directory, sizes, seed=0, bad=True, fmt="parquet"):
    """Partitions part-0, part-1, ... (natural order differs from lexicographic beyond 10),
    each with an id column passed through; returns (paths, all points in order)."""
    os.makedirs(directory, exist_ok=True)
    paths, blocks, start = [], [], 0
    for i, m in enumerate(sizes):
        points = cloud(m, seed + i, bad=bad and i == 2)
        frame = pl.DataFrame({"id": np.arange(start, start + m), "x": points[:, 0],
                              "y": points[:, 1], "z": points[:, 2]})
        path = os.path.join(directory, f"part-{i}.{fmt}")
        frame.write_parquet(path) if fmt == "parquet" else frame.write_csv(path)
        paths.append(path)
        blocks.append(points)
        start += m
    return paths, np.concatenate(blocks)


def assert_same_bits(got: dict, want: dict):
    """Every result column of ``want`` (a Projection's columns) bit for bit in ``got``
    (floats compared as their 64 bits, so NaN, inf and -0.0 count; labels as words)."""
    for name, w in want.items():
        g = np.asarray(got[name])
        if name in ("status", "reason"):
            words = np.asarray(STATUS if name == "status" else REASONS, dtype=object)[w]
            assert np.array_equal(g.astype(object), words), name
        elif w.dtype.kind == "f":
            assert g.dtype == np.float64, name
            assert np.array_equal(g.view(np.uint64), w.view(np.uint64)), name
        else:
            assert np.array_equal(g, w) and g.dtype.kind in "iu", name


def read_outputs(paths) -> pl.DataFrame:
    return pl.concat([pl.read_parquet(p) for p in paths])


def columns_of(frame) -> dict:
    out = {}
    for name in frame.columns:
        col = frame[name]
        out[name] = (col.cast(pl.String).to_numpy() if name in ("status", "reason")
                     else col.to_numpy())
    return out


# --------------------------------------------------------------------------------------------
# partitions and outputs (no cluster)
# --------------------------------------------------------------------------------------------

def test_partitions_in_natural_order(tmp_path):
    for name in ("part-10.parquet", "part-2.csv", "part-1.parquet", ".hidden.parquet",
                 "notes.md"):
        (tmp_path / name).write_text("x")
    want = [str(tmp_path / n) for n in ("part-1.parquet", "part-2.csv", "part-10.parquet")]
    assert cluster.partitions(str(tmp_path)) == want
    assert cluster.partitions(str(tmp_path / "part-*")) == want
    assert cluster.partitions(want[2]) == want[2:]
    with pytest.raises(io.ReadError, match=r"notes\.md: not a table partition"):
        cluster.partitions(str(tmp_path / "*"))
    with pytest.raises(io.ReadError, match=r"nothing\*\.parquet: no file matches"):
        cluster.partitions(str(tmp_path / "nothing*.parquet"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(io.ReadError, match="no .parquet, .csv or .txt file"):
        cluster.partitions(str(tmp_path / "empty"))


def test_output_paths(tmp_path):
    sources = [str(tmp_path / "in" / n) for n in ("a.parquet", "b.csv")]
    out = tmp_path / "out"
    assert cluster.output_paths(sources, f"{out}/") == [str(out / "a.parquet"),
                                                       str(out / "b.csv")]
    assert out.is_dir()  # created
    assert cluster.output_paths(sources, str(out / "r-*.parquet")) == [
        str(out / "r-a.parquet"), str(out / "r-b.parquet")]
    with pytest.raises(io.WriteError, match="2 partitions need a directory"):
        cluster.output_paths(sources, str(tmp_path / "one.parquet"))
    assert cluster.output_paths(sources[:1], str(tmp_path / "one.parquet")) == [
        str(tmp_path / "one.parquet")]
    (out / "b.csv").write_text("old")
    with pytest.raises(io.WriteError, match=r"b\.csv: already exists \(use --overwrite, or "
                                           r"--resume"):
        cluster.output_paths(sources, str(out))
    assert cluster.output_paths(sources, str(out), overwrite=True)[1] == str(out / "b.csv")
    with pytest.raises(io.WriteError, match="is the input partition"):
        cluster.output_paths([str(out / "b.csv")], str(out))
    twins = [str(tmp_path / d / "a.parquet") for d in ("d1", "d2")]
    with pytest.raises(io.WriteError, match="the output of both"):
        cluster.output_paths(twins, str(out))
    with pytest.raises(io.WriteError, match="an output partition is a table"):
        cluster.output_paths(sources, str(out / "*.vtu"))


def test_frame_columns_checked_before_any_work(surface):
    frame = pd.DataFrame({"x": [0.0], "y": [0.0]})
    with pytest.raises(ValueError, match="no 'z' column"):
        cluster.project_dataframe(surface, dd.from_pandas(frame, npartitions=1))
    frame = pd.DataFrame({"x": [0.0], "y": [0.0], "z": [1.0], "gap": [1.0]})
    with pytest.raises(ValueError, match="two columns named 'gap'"):
        cluster.project_dataframe(surface, dd.from_pandas(frame, npartitions=1))
    frame = pd.DataFrame({"x": ["a"], "y": [0.0], "z": [1.0]})
    with pytest.raises(ValueError, match="column 'x' holds"):
        cluster.project_dataframe(surface, dd.from_pandas(frame, npartitions=1))


# --------------------------------------------------------------------------------------------
# on a cluster of 2 worker processes
# --------------------------------------------------------------------------------------------

def test_partitions_equal_one_process_bit_for_bit(surface, client, tmp_path):
    sizes = [700, 1, 1500, 300, 900, 50, 400, 600, 200, 100, 800, 250]  # 12: part-10 > part-2
    sources, points = write_partitions(str(tmp_path / "in"), sizes)
    targets = cluster.output_paths(cluster.partitions(str(tmp_path / "in")),
                                   str(tmp_path / "out") + "/")
    summary = cluster.project_partitions(surface, cluster.partitions(str(tmp_path / "in")),
                                         targets, client=client)
    want = surface.project(points)
    got = read_outputs(targets)
    assert got["id"].to_list() == list(range(len(points)))  # every row once, in input order
    assert_same_bits(columns_of(got), want.columns())
    assert (want.status == STATUS.index("failed")).sum() == 2  # the NaN and inf rows
    assert summary.partitions == len(sizes) and summary.contactors == len(points)
    assert np.array_equal(summary.status, np.bincount(want.status, minlength=len(STATUS)))
    assert len(summary.peak_memory) >= 1 and min(summary.peak_memory.values()) > 0
    # each partition exactly as a one-machine run writes it (same columns, types, values)
    for source, target in zip(sources, [os.path.join(tmp_path / "out", os.path.basename(s))
                                        for s in sources]):
        alone = str(tmp_path / "alone.parquet")
        contactors = io.read_contactors(source)
        io.write_result(alone, contactors, surface.project(contactors.points).columns(),
                        labels=cluster.LABELS, overwrite=True)
        assert pl.read_parquet(target).equals(pl.read_parquet(alone))
    assert sorted(os.listdir(tmp_path / "out")) == sorted(os.path.basename(s) for s in sources)


def test_dataframe_equals_one_process_bit_for_bit(surface, client, tmp_path):
    points = cloud(3000, 7, bad=True)
    frame = pd.DataFrame({"label": [f"c{i}" for i in range(len(points))],
                          "X": points[:, 0], "Y": points[:, 1], "Z": points[:, 2],
                          "id": np.arange(len(points))},
                         index=pd.RangeIndex(1000, 1000 + len(points)))
    lazy = cluster.project_dataframe(surface, dd.from_pandas(frame, npartitions=5))
    assert isinstance(lazy, dd.DataFrame) and lazy.npartitions == 5
    got = client.compute(lazy).result()
    assert list(got.columns) == ["label", "id"] + list(surface.project(points[:1]).columns())
    assert got.index.equals(frame.index)  # order and index kept
    assert got["label"].tolist() == frame["label"].tolist()
    assert str(got["status"].dtype) == "category"
    assert_same_bits({k: got[k].to_numpy() for k in got.columns}, surface.project(points).columns())

    # from partition files: read as one machine reads them, one partition per file
    sources, cloud_points = write_partitions(str(tmp_path / "in"), [500, 20, 800])
    lazy = cluster.project_dataframe(surface, str(tmp_path / "in"))
    assert lazy.npartitions == 3
    got = client.compute(lazy).result()
    assert got["id"].tolist() == list(range(len(cloud_points)))
    assert_same_bits({k: got[k].to_numpy() for k in got.columns},
                     surface.project(cloud_points).columns())

    # dask's own reader, with pyarrow-backed columns
    lazy = cluster.project_dataframe(
        surface, dd.read_parquet(str(tmp_path / "in" / "*.parquet"), dtype_backend="pyarrow"))
    again = client.compute(lazy).result()
    assert again["id"].tolist() == got["id"].tolist()
    assert_same_bits({k: again[k].to_numpy() for k in again.columns},
                     surface.project(cloud_points).columns())


def test_bad_partition_fails_the_job_naming_its_file(surface, client, tmp_path):
    sources, _ = write_partitions(str(tmp_path / "in"), [300, 300, 300, 300], bad=False)
    with open(sources[2], "r+b") as fh:  # a damaged partition: its footer overwritten
        fh.seek(-12, os.SEEK_END)
        fh.write(b"\0" * 12)
    targets = cluster.output_paths(sources, str(tmp_path / "out") + "/")
    with pytest.raises(io.ReadError) as err:
        cluster.project_partitions(surface, sources, targets, client=client)
    message = str(err.value)
    assert message.startswith(f"{sources[2]}: ") and "\n" not in message
    # no half-written file nor staging directory left; whatever was written is whole
    for name in os.listdir(tmp_path / "out"):
        assert not name.startswith("."), name
        assert pl.read_parquet(tmp_path / "out" / name).height == 300

    text = tmp_path / "text"
    text.mkdir()
    (text / "a.csv").write_text("x,y,z\n0,0,1.1\n")
    (text / "b.csv").write_text("x,y,z\n0,0,1.1\n0,zero,1\n")
    targets = cluster.output_paths(cluster.partitions(str(text)), str(tmp_path / "out2") + "/")
    with pytest.raises(io.ReadError, match=r"b\.csv.*line 3"):
        cluster.project_partitions(surface, cluster.partitions(str(text)), targets,
                                   client=client)


def test_progress_bar_on_stderr(surface, client, tmp_path, capsys):
    sources, _ = write_partitions(str(tmp_path / "in"), [200, 200], bad=False)
    targets = cluster.output_paths(sources, str(tmp_path / "out") + "/")
    cluster.project_partitions(surface, sources, targets, client=client, progress=True)
    out, err = capsys.readouterr()
    assert out == ""
    assert "100% Completed" in err


def test_killed_worker_loses_nothing(surface, client, tmp_path):
    """A worker killed (SIGKILL) mid-job: its partitions are computed again, every output is
    there once, whole, with the one-process bits; no leftover of the killed task."""
    n = 16
    sources, points = write_partitions(str(tmp_path / "in"), [40000] * n, bad=False)
    targets = cluster.output_paths(sources, str(tmp_path / "out") + "/")
    pids = client.run(os.getpid)
    victim = sorted(pids.values())[0]
    seen = {}

    def kill_after_first_output():
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            done = [t for t in targets if os.path.exists(t)]
            if done:
                seen["outputs at kill"] = len(done)
                os.kill(victim, signal.SIGKILL)
                return
            time.sleep(0.01)

    killer = threading.Thread(target=kill_after_first_output)
    killer.start()
    summary = cluster.project_partitions(surface, sources, targets, client=client)
    killer.join()
    assert 0 < seen["outputs at kill"] < n  # killed mid-job
    with pytest.raises(ProcessLookupError):
        os.kill(victim, 0)  # it is dead
    assert summary.partitions == n and summary.contactors == len(points)
    assert sorted(os.listdir(tmp_path / "out")) == sorted(os.path.basename(t) for t in targets)
    got = read_outputs(targets)
    assert got["id"].to_list() == list(range(len(points)))
    assert_same_bits(columns_of(got), surface.project(points).columns())
    client.wait_for_workers(2, timeout=60)  # the nanny started a new one


# --------------------------------------------------------------------------------------------
# the command line
# --------------------------------------------------------------------------------------------

def test_cli_workers_2_equals_one_machine_runs(tmp_path):
    """`project TARGET 'DIR/*' -o OUT/ --workers 2`: each output is the file a one-machine run
    writes for that partition, byte for byte (CSV) or table for table (Parquet)."""
    plate = pl.read_csv(PLATE_CSV)
    parts = tmp_path / "plate"
    parts.mkdir()
    for i, lo in enumerate(range(0, plate.height, 100)):
        chunk = plate.slice(lo, 100)
        chunk.write_parquet(parts / f"p{i}.parquet") if i % 2 else \
            chunk.write_csv(parts / f"p{i}.csv")
    result = run("project", CYLINDER, str(parts / "p*"), "-o", f"{tmp_path / 'out'}/",
                 "--workers", "2")
    assert result.exit_code == 0, result.stderr
    assert result.stdout == ""
    assert "3 partitions" in result.stderr and "peak memory per worker" in result.stderr
    for source in sorted(parts.iterdir()):
        alone = tmp_path / f"alone{source.suffix}"
        single = run("project", CYLINDER, str(source), "-o", str(alone), "--overwrite", "-q")
        assert single.exit_code == 0, single.stderr
        mine = tmp_path / "out" / source.name
        if source.suffix == ".csv":
            assert mine.read_bytes() == alone.read_bytes()
        else:
            assert pl.read_parquet(mine).equals(pl.read_parquet(alone))
    again = run("project", CYLINDER, str(parts), "-o", str(tmp_path / "out"), "--workers", "2")
    assert again.exit_code == 1
    assert "already exists (use --overwrite, or --resume" in again.stderr


def test_cli_scheduler_and_facet(client, tmp_path):
    """--scheduler ADDRESS: the job runs on that cluster (here the module's), --method facet
    too, each output as a one-machine run writes it."""
    result = run("project", CYLINDER, PLATE_CSV, "-o", str(tmp_path / "c.csv"), "--method",
                 "facet", "--scheduler", client.scheduler.address)
    assert result.exit_code == 0, result.stderr
    assert f"dask: {client.scheduler.address}, 2 workers" in result.stderr
    alone = run("project", CYLINDER, PLATE_CSV, "-o", str(tmp_path / "a.csv"), "--method",
                "facet")
    assert alone.exit_code == 0, alone.stderr
    assert (tmp_path / "c.csv").read_bytes() == (tmp_path / "a.csv").read_bytes()


def test_cli_bad_partition_and_usage(tmp_path):
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "a.csv").write_text("x,y,z\n30,30,5\n")
    (tmp_path / "in" / "b.parquet").write_bytes(b"PAR1 not really")
    result = run("project", CYLINDER, str(tmp_path / "in"), "-o", f"{tmp_path / 'o'}/",
                 "--workers", "1")
    assert result.exit_code == 1
    lines = result.stderr.strip().splitlines()
    assert lines[-1].startswith(f"diffsurf: error: {tmp_path / 'in' / 'b.parquet'}: ")
    for args, words in ((["-o", "-"], "write files"),
                        (["-o", "x/", "--penalty", "1"], "--penalty needs a one-machine run"),
                        (["-o", "x/", "--scheduler", "tcp://h:1"], "exclude each other")):
        result = run("project", CYLINDER, str(tmp_path / "in"), *args, "--workers", "2")
        assert result.exit_code == 2 and words in result.stderr, result.stderr


def test_no_dask_without_cluster_options(tmp_path):
    """A one-machine run imports neither dask nor distributed (they are an optional extra)."""
    code = ("import sys\nfrom diffsurf_cli.cli import main\n"
            f"main(['project', {CYLINDER!r}, {PLATE_CSV!r}, '-q', '-o', "
            f"{str(tmp_path / 'r.csv')!r}], standalone_mode=False)\n"
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed'))\n"
            "assert not bad, bad\n")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
    assert (tmp_path / "r.csv").exists()


def test_cli_resume_skips_the_partitions_a_stopped_job_left_whole(tmp_path):
    """Issue 22, item 12: an interrupted `--workers` job left some finished partitions and an
    empty staging directory, and the rerun stopped at 'p03.parquet: already exists'.
    `--resume` projects only the partitions not done (a finished one is whole: its rename is
    atomic; checked by its rows and columns), removes the empty staging directories, and
    refuses an output that is not a whole result; the outputs are those of a full run."""
    plate = pl.read_csv(PLATE_CSV)
    parts = tmp_path / "plate"
    parts.mkdir()
    for i, lo in enumerate(range(0, plate.height, 70)):
        plate.slice(lo, 70).write_parquet(parts / f"p{i}.parquet")
    out = tmp_path / "out"
    full = run("project", CYLINDER, str(parts), "-o", f"{out}/", "--workers", "2", "-q")
    assert full.exit_code == 0, full.stderr
    reference = {p.name: pl.read_parquet(p) for p in out.iterdir()}
    assert len(reference) == 4
    # as a stopped job leaves it: two outputs missing, an empty staging directory
    (out / "p1.parquet").unlink()
    (out / "p3.parquet").unlink()
    (out / f"{cluster.STAGING_PREFIX}x1y2z3").mkdir()
    again = run("project", CYLINDER, str(parts), "-o", f"{out}/", "--workers", "2")
    assert again.exit_code == 1 and "--resume" in again.stderr, again.stderr
    resumed = run("project", CYLINDER, str(parts), "-o", f"{out}/", "--workers", "2",
                  "--resume")
    assert resumed.exit_code == 0, resumed.stderr
    assert "2 partitions of 4 done, 2 partitions to project" in resumed.stderr
    assert sorted(p.name for p in out.iterdir()) == sorted(reference)
    for name, frame in reference.items():
        assert pl.read_parquet(out / name).equals(frame), name
    # an output that is not a whole result of its input is refused, not taken as done
    reference["p0.parquet"].head(5).write_parquet(out / "p0.parquet")
    bad = run("project", CYLINDER, str(parts), "-o", f"{out}/", "--workers", "2", "--resume")
    assert bad.exit_code == 1 and "p0.parquet: already exists and is not a whole result" \
        in bad.stderr, bad.stderr
    assert run("project", CYLINDER, PLATE_CSV, "--resume").exit_code == 2


@pytest.mark.slow
def test_cli_ctrl_c_stops_a_workers_run_quietly(tmp_path):
    """Issue 22, item 12: Ctrl-C in a terminal signals the whole process group, workers too;
    they printed their KeyboardInterrupt tracebacks and leaked semaphores. Only diffsurf
    takes the interrupt (its workers ignore it) and closes the cluster: one 'diffsurf:
    interrupted' (exit 130), no worker's traceback, no staging directory; `--resume` then
    finishes the job."""
    import meshio

    nodes = meshio.read(CYLINDER).points
    rng = np.random.default_rng(3)
    parts = tmp_path / "cloud"
    parts.mkdir()
    for i in range(40):
        pick = nodes[rng.integers(0, len(nodes), 40_000)]
        pts = pick + rng.normal(0.0, 0.5, pick.shape)
        pl.DataFrame({"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2]}).write_parquet(
            parts / f"p{i:02d}.parquet")
    out = tmp_path / "out"
    args = [sys.executable, "-m", "diffsurf_cli", "project", CYLINDER, str(parts), "-o",
            f"{out}/", "--workers", "2"]
    # a session of its own: the test's process group is not the one signalled
    job = subprocess.Popen(args, stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 120
    while job.poll() is None and time.monotonic() < deadline:
        if out.is_dir() and any(p.suffix == ".parquet" for p in out.iterdir()):
            break  # the workers are at work
        time.sleep(0.05)
    assert job.poll() is None, "the job ended before it could be interrupted"
    os.killpg(job.pid, signal.SIGINT)  # as a terminal's Ctrl-C does
    _, err = job.communicate(timeout=120)
    assert job.returncode == 128 + signal.SIGINT, err  # issue 32, item 9: as other signals
    assert err.count("diffsurf: interrupted") == 1 and "Aborted!" not in err, err
    for word in ("Traceback", "KeyboardInterrupt", "leaked"):
        assert word not in err, err
    done = sorted(p.name for p in out.iterdir())
    assert 0 < len(done) < 40 and all(n.endswith(".parquet") for n in done), done
    resumed = subprocess.run([*args, "--resume", "-q"], capture_output=True, text=True,
                             timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert len(list(out.iterdir())) == 40
    assert pl.read_parquet(out / "p39.parquet").height == 40_000
