"""Issue 32 ("A newcomer's third hour"): hostile mesh files for the target reader.

A PLY whose header stops before ``end_header`` (meshio's header reader loops forever), an OBJ
face index beyond int64 (an OverflowError), an ASCII STL cut before ``endsolid`` (read as the
facets before the cut, exit 0) and a binary Gmsh file with bytes inserted in its element
section (its elements shifted: most of them dropped as degenerate facets behind a note).
Each must be one io.ReadError naming the file, quickly.
"""
from __future__ import annotations

import contextlib
import re
import signal
from pathlib import Path

import meshio
import numpy as np
import pytest

from diffsurf_cli import io
from samples import CYLINDER, PLATE_CSV, run

#: seconds a read may take before it counts as a hang.
HANG_SECONDS = 10


class Hang(BaseException):
    """Raised by the alarm: a BaseException, so that no reader's `except Exception` takes it
    for a failure of the file."""


@contextlib.contextmanager
def no_hang(seconds: int = HANG_SECONDS):
    def alarm(*_):
        raise Hang(f"the read did not end within {seconds} s")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def read_error(path) -> str:
    """The one-line ReadError message that reading the target ``path`` gives."""
    with no_hang(), pytest.raises(io.ReadError) as info:
        io.read_target(str(path))
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path)), message
    return message


def cylinder(kind: str = "quad") -> meshio.Mesh:
    mesh = meshio.read(CYLINDER)
    quads = mesh.cells_dict["quad"]
    if kind == "quad":
        return meshio.Mesh(mesh.points, [("quad", quads)])
    tri = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    return meshio.Mesh(mesh.points, [("triangle", tri)])


def written(tmp_path, name: str, mesh: meshio.Mesh, fmt: str, **kwargs) -> bytes:
    path = tmp_path / name
    meshio.write(str(path), mesh, file_format=fmt, **kwargs)
    return path.read_bytes()


def line_ends(data: bytes) -> list[int]:
    """The offset just after each line of ``data`` (the cuts at every line)."""
    return [i + 1 for i, b in enumerate(data) if b == ord("\n")]


# -------------------------------------------------------------------------------------------
# item 1: a PLY header that stops before end_header hung in meshio's header reader
# -------------------------------------------------------------------------------------------


def test_ply_header_without_end_header_is_an_error(tmp_path):
    path = tmp_path / "bad.ply"
    path.write_bytes(b"ply\nformat ascii 1.0\n")
    message = read_error(path)
    assert "end_header" in message


def test_ply_header_without_end_header_on_the_command_line(tmp_path):
    """The tester's command line: a one-line error and exit 1, not a hang."""
    path = tmp_path / "bad.ply"
    path.write_bytes(b"ply\nformat ascii 1.0\n")
    with no_hang():
        res = run("project", path, PLATE_CSV, "-o", tmp_path / "out.csv")
    assert res.exit_code == 1, (res.exit_code, res.stderr)
    lines = res.stderr.strip().splitlines()
    assert lines == [lines[0]] and lines[0].startswith("diffsurf: error: "), res.stderr
    assert str(path) in lines[0] and "end_header" in lines[0]


@pytest.mark.parametrize("binary", [False, True])
def test_ply_cut_at_every_header_line(tmp_path, binary):
    data = written(tmp_path, "seed.ply", cylinder(), "ply", binary=binary)
    header_end = data.index(b"end_header")
    path = tmp_path / "cut.ply"
    for cut in [c for c in line_ends(data) if c <= header_end] + [header_end + 5]:
        path.write_bytes(data[:cut])
        read_error(path)


def test_binary_ply_cut_in_its_data(tmp_path):
    """Cut at the end of a face, a binary PLY was read as the faces before the cut."""
    data = written(tmp_path, "seed.ply", cylinder(), "ply", binary=True)
    body = data.index(b"end_header\n") + len(b"end_header\n")
    path = tmp_path / "cut.ply"
    for cut in range(len(data) - 1, body - 1, -3):
        path.write_bytes(data[:cut])
        read_error(path)


def test_binary_ply_declaring_more_faces_than_bytes(tmp_path):
    """meshio walks the declared faces one by one in Python (and allocates them at once):
    10**8 of them in a file of a few kilobytes took minutes."""
    data = written(tmp_path, "seed.ply", cylinder(), "ply", binary=True)
    path = tmp_path / "many.ply"
    path.write_bytes(data.replace(b"element face 64", b"element face 100000000"))
    assert "100000000 face" in read_error(path)


def test_a_reader_looping_at_the_end_of_a_file_is_stopped(tmp_path):
    """Not only the PLY header: any meshio reader that keeps reading at the end of a file
    (here the ANSYS reader, tried on a .msh that is no Gmsh file, waiting for a ')' that never
    comes) ends with a ReadError instead of a hang."""
    path = tmp_path / "bad.msh"
    path.write_bytes(b"(10 (0 1 5 0 3)")
    message = read_error(path)
    assert "end of the file" in message


# -------------------------------------------------------------------------------------------
# item 2: an OBJ face index beyond int64 raised OverflowError
# -------------------------------------------------------------------------------------------


def test_obj_face_index_beyond_int64(tmp_path):
    path = tmp_path / "big.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n")
    message = read_error(path)
    assert "line 4" in message and "99999999999999999999" in message


@pytest.mark.parametrize("face", ["f 1 2 4", "f 1 2 0", "f 1 2 x", "f 1/1 2//3 -9"])
def test_obj_face_index_of_no_vertex(tmp_path, face):
    path = tmp_path / "bad.obj"
    path.write_text(f"# three vertices\nv 0 0 0\nv 1 0 0\nv 0 1 0\n{face}\n")
    assert "line 5" in read_error(path)


def test_obj_valid_faces_still_read(tmp_path):
    path = tmp_path / "ok.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1/1/1 2//2 3\nf 2 4 3\n")
    target = io.read_target(str(path))
    assert sum(len(c) for _, c in target.cells) == 2


# -------------------------------------------------------------------------------------------
# item 10: an ASCII STL cut before endsolid was read as the facets before the cut
# -------------------------------------------------------------------------------------------


def icosphere_stl(tmp_path) -> bytes:
    """The tester's file: an ASCII STL of 320 facets (an icosphere)."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=2)
    assert len(sphere.faces) == 320
    mesh = meshio.Mesh(np.asarray(sphere.vertices), [("triangle", np.asarray(sphere.faces))])
    return written(tmp_path, "sphere.stl", mesh, "stl", binary=False)


def test_ascii_stl_cut_in_the_middle(tmp_path):
    data = icosphere_stl(tmp_path)
    path = tmp_path / "cut.stl"
    path.write_bytes(data[:len(data) // 2])
    message = read_error(path)
    assert "endsolid" in message and "truncated" in message


def test_ascii_stl_cut_at_every_line(tmp_path):
    data = icosphere_stl(tmp_path)
    whole = io.read_target(str(tmp_path / "sphere.stl"))
    assert sum(len(c) for _, c in whole.cells) == 320
    path = tmp_path / "cut.stl"
    end = data.rindex(b"endsolid")
    for cut in [c for c in line_ends(data) if c <= end][::3] + [end + 3]:
        path.write_bytes(data[:cut])
        read_error(path)


@pytest.mark.parametrize("edit", ["drop-vertex", "extra-vertex", "drop-endloop", "garbage"])
def test_ascii_stl_facets_of_the_wrong_shape(tmp_path, edit):
    """A facet with two or four vertices, or a line that is no STL keyword: meshio took the
    last three numbers of every line that is not a keyword it skips."""
    lines = icosphere_stl(tmp_path).split(b"\n")
    at = lines.index(next(ln for ln in lines if ln.strip().startswith(b"vertex")))
    if edit == "drop-vertex":
        del lines[at]
    elif edit == "extra-vertex":
        lines.insert(at, lines[at])
    elif edit == "drop-endloop":
        del lines[at + 3]
    else:
        lines.insert(at, b"  1 2 3")
    path = tmp_path / "bad.stl"
    path.write_bytes(b"\n".join(lines))
    read_error(path)


# -------------------------------------------------------------------------------------------
# item 10: bytes inserted in a Gmsh element section shifted the elements after them
# -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("fmt", ["gmsh22", "gmsh"])
def test_binary_msh_with_nul_bytes_in_the_element_section(tmp_path, fmt):
    data = written(tmp_path, "seed.msh", cylinder("triangle"), fmt, binary=True)
    whole = io.read_target(str(tmp_path / "seed.msh"))
    assert sum(len(c) for _, c in whole.cells) == 128
    start = data.index(b"$Elements\n") + len(b"$Elements\n")
    if fmt == "gmsh22":  # after the line of the element count (its text read as a number)
        start = data.index(b"\n", start) + 1
    end = data.index(b"$EndElements")
    path = tmp_path / "nul.msh"
    for at in range(start, end + 1, 5):
        path.write_bytes(data[:at] + b"\0" * 8 + data[at:])
        message = read_error(path)
        # the shifted entries: an element type or node that is none, or more data than
        # declared
        assert re.search("corrupt|truncated|does not define|does not exist", message), message


@pytest.mark.parametrize("fmt", ["gmsh22", "gmsh"])
def test_ascii_msh_element_lines_that_disagree_with_the_count(tmp_path, fmt):
    """An element line more or less than the section declares: the extra one was skipped, the
    next section's first line read as an element."""
    lines = written(tmp_path, "seed.msh", cylinder("triangle"), fmt, binary=False).split(b"\n")
    last = lines.index(b"$EndElements") - 1
    path = tmp_path / "bad.msh"
    path.write_bytes(b"\n".join(lines[:last] + [lines[last]] * 2 + lines[last + 1:]))
    assert "corrupt" in read_error(path)


@pytest.mark.parametrize("tag", [b"0", b"-3"])
def test_msh_element_of_node_tag_zero_or_negative(tmp_path, tag):
    """Gmsh node tags start at 1: meshio made tag 0 (and negative ones) the last node."""
    lines = written(tmp_path, "seed.msh", cylinder("triangle"), "gmsh22",
                    binary=False).split(b"\n")
    first = lines.index(b"$Elements") + 2
    fields = lines[first].split()
    fields[-1] = tag
    lines[first] = b" ".join(fields)
    path = tmp_path / "bad.msh"
    path.write_bytes(b"\n".join(lines))
    message = read_error(path)
    assert "node" in message and tag.decode() in message


@pytest.mark.parametrize("fmt", ["gmsh22", "gmsh"])
def test_msh_node_tag_far_beyond_the_nodes(tmp_path, fmt):
    """meshio maps node tags to points through a table as long as the largest tag, filled at
    once: a corrupt tag of 2**31 made it gigabytes (the process killed for its memory)."""
    lines = written(tmp_path, "seed.msh", cylinder("triangle"), fmt, binary=False).split(b"\n")
    if fmt == "gmsh22":  # the first node line: tag x y z
        at = lines.index(b"$Nodes") + 2
        lines[at] = b" ".join([b"1099511627776"] + lines[at].split()[1:])
    else:  # the tags of the first entity block follow its header line
        at = lines.index(b"$Nodes") + 3
        assert lines[at] == b"1", lines[at]
        lines[at] = b"1099511627776"
    path = tmp_path / "tag.msh"
    path.write_bytes(b"\n".join(lines))
    assert "node tag 1099511627776" in read_error(path)


def test_valid_binary_and_ascii_msh_still_read(tmp_path):
    for fmt in ("gmsh22", "gmsh"):
        for binary in (False, True):
            written(tmp_path, "ok.msh", cylinder(), fmt, binary=binary)
            target = io.read_target(str(tmp_path / "ok.msh"))
            assert sum(len(c) for _, c in target.cells) == 64
    assert sum(len(c) for _, c in io.read_target(CYLINDER).cells) == 64


def test_sample_meshes_still_read():
    for path in sorted(Path(CYLINDER).parent.glob("*.*")):
        if path.suffix in (".msh", ".stl", ".vtu"):
            assert io.read_target(str(path)).cells
