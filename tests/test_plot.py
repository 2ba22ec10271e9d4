"""`project --plot` and `smooth --plot` (issue 32, item 18): a picture of the result, drawn
headless by matplotlib, refused before any work when it cannot be written."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from diffsurf_cli import io
from samples import CYLINDER, N_PLATE, PLATE_CSV, run

PNG = b"\x89PNG\r\n\x1a\n"


def _pixels(path):
    """The image at ``path`` as (h, w, 3) floats in [0, 1] (read back by matplotlib)."""
    from matplotlib import image

    return image.imread(str(path))[..., :3]


def _reddish(rgb):
    return (rgb[..., 0] > 0.6) & (rgb[..., 1] < 0.45) & (rgb[..., 2] < 0.45)


def _bluish(rgb):
    return (rgb[..., 2] > 0.6) & (rgb[..., 0] < 0.45) & (rgb[..., 1] < 0.6)


def test_project_plot_draws_penetrating_red_and_open_blue_beside_results_on_stdout(tmp_path):
    pytest.importorskip("matplotlib")
    png = tmp_path / "gaps.png"
    result = run("project", CYLINDER, PLATE_CSV, "-o", "-", "--plot", png)
    assert result.exit_code == 0, result.stderr
    # the results still go to stdout, the picture to its own file
    assert result.stdout.splitlines()[0].startswith("id,x,y,z,gap")
    assert len(result.stdout.splitlines()) == N_PLATE + 1
    data = png.read_bytes()
    assert data[:8] == PNG and 20_000 < len(data) < 5_000_000
    assert [p.name for p in tmp_path.iterdir()] == ["gaps.png"]  # no temporary left
    rgb = _pixels(png)
    assert rgb.shape[0] >= 600 and rgb.shape[1] >= 600
    # the plate's 25 penetrating contactors (red) and its 240 open ones (blue) both show; the
    # colorbar alone holds a few thousand of each, the points add to them
    red, blue = int(_reddish(rgb).sum()), int(_bluish(rgb).sum())
    assert red > 3000 and blue > 3000, (red, blue)


def test_project_figure_colours_both_sides_and_draws_unanswered_grey():
    pytest.importorskip("matplotlib")
    from matplotlib import colors

    nodes = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    cells = [("quad", np.array([[0, 1, 2, 3]]))]
    xc = np.array([[0.2, 0.2, -0.05], [0.5, 0.5, 0.3], [0.8, 0.2, 0.0], [3.0, 3.0, 1.0]])
    gap = np.array([-0.05, 0.3, 0.0, np.nan])
    status = ["penetration", "open", "contact", "outside"]
    fig = io.project_figure(nodes, cells, xc, gap, status, target="t.msh", points="p.csv")
    ax = fig.axes[0]
    title = ax.get_title()
    assert "p.csv" in title and "t.msh" in title
    assert "1 contact, 1 penetration, 1 open, 1 unanswered" in title
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(t.startswith("unanswered") and t.endswith(": 1") for t in legend), legend
    scatters = [c for c in ax.collections if hasattr(c, "_offsets3d")]
    # the colour of gap 0 is the colormap's middle; -0.05 and 0.3 lie on its two sides
    coloured = [c for c in scatters if c.get_array() is not None]
    values = np.concatenate([np.asarray(c.get_array()) for c in coloured])
    assert sorted(values) == [-0.05, 0.0, 0.3]
    norm = coloured[0].norm
    assert norm(-0.05) < 0.5 == norm(0.0) < norm(0.3)
    grey = [c for c in scatters if c.get_array() is None]
    assert len(grey) == 1 and np.allclose(grey[0].get_edgecolor()[0][:3],
                                          colors.to_rgb(io.plot.UNANSWERED_COLOUR))
    assert fig.axes[1].get_ylabel() == "gap"  # the colorbar


def test_project_figure_samples_a_large_cloud_keeping_the_penetrating():
    pytest.importorskip("matplotlib")
    nodes = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    cells = [("quad", np.array([[0, 1, 2, 3]]))]
    rng = np.random.default_rng(0)
    xc = rng.uniform(0, 1, (1000, 3))
    gap = xc[:, 2] - 0.02  # 2% penetrating
    status = np.where(gap < 0, "penetration", "open")
    fig = io.project_figure(nodes, cells, xc, gap, status, max_points=100)
    ax = fig.axes[0]
    scatters = [c for c in ax.collections if hasattr(c, "_offsets3d")]
    drawn = np.concatenate([np.asarray(c.get_array()) for c in scatters])
    assert len(drawn) == 100
    assert np.sum(drawn < 0) == np.sum(gap < 0)  # every penetrating one is drawn
    assert "drawn: 100 of 1,000" in ax.get_title()


def test_project_plot_without_matplotlib_says_how_to_install_before_any_work(
        tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    out = tmp_path / "gaps.csv"
    result = run("project", CYLINDER, PLATE_CSV, "-o", out, "--plot", tmp_path / "g.png")
    assert result.exit_code == 1
    assert result.stderr.strip() == ("diffsurf: error: --plot needs matplotlib: "
                                     "pip install 'diffsurf[plot]'")
    assert list(tmp_path.iterdir()) == []  # no result either: refused before the projection
    result = run("smooth", CYLINDER, "-o", tmp_path / "s.vtu", "--plot", tmp_path / "s.png")
    assert result.exit_code == 1 and "pip install 'diffsurf[plot]'" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_project_plot_existing_file_is_refused_before_the_projection(tmp_path):
    pytest.importorskip("matplotlib")
    png, out = tmp_path / "gaps.png", tmp_path / "gaps.csv"
    png.write_bytes(b"an earlier picture")
    result = run("project", CYLINDER, PLATE_CSV, "-o", out, "--plot", png)
    assert result.exit_code == 1
    assert "gaps.png" in result.stderr and "--overwrite" in result.stderr
    assert "status:" not in result.stderr  # nothing projected
    assert result.stdout == "" and not out.exists()
    assert png.read_bytes() == b"an earlier picture"
    result = run("project", CYLINDER, PLATE_CSV, "-o", out, "--plot", png, "--overwrite")
    assert result.exit_code == 0, result.stderr
    assert png.read_bytes()[:8] == PNG and out.exists()


@pytest.mark.parametrize("name", ["gaps.jpg", "gaps"])
def test_project_plot_refuses_other_formats_in_one_line(tmp_path, name):
    pytest.importorskip("matplotlib")
    result = run("project", CYLINDER, PLATE_CSV, "-o", tmp_path / "g.csv",
                 "--plot", tmp_path / name)
    assert result.exit_code == 1
    assert result.stderr.strip().splitlines() == [
        f"diffsurf: error: {tmp_path / name}: expected a .png or .svg or .pdf file name"]
    assert list(tmp_path.iterdir()) == []


def test_project_plot_and_output_cannot_be_one_file(tmp_path):
    result = run("project", CYLINDER, PLATE_CSV, "-o", tmp_path / "a.png",
                 "--plot", tmp_path / "a.png")
    assert result.exit_code == 2 and "both name" in result.stderr


def test_project_plot_needs_a_one_machine_run(tmp_path):
    result = run("project", CYLINDER, PLATE_CSV, "-o", tmp_path / "out/", "--workers", "1",
                 "--plot", tmp_path / "g.png")
    assert result.exit_code == 2 and "--plot needs a one-machine run" in result.stderr


def test_smooth_figure_has_two_axes_with_the_same_view_and_limits():
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    from diffsurf_cli.smooth import refine

    nodes = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0.2], [0, 1, 0.1]], float)
    facets = [np.array([[0, 1, 2], [0, 2, 3]])]
    vertices, faces = refine(nodes, facets, 2)
    vertices = vertices + [0, 0, 0.05]  # a smooth surface off the facets
    fig = io.smooth_figure(nodes, facets, vertices, faces, target="t.stl", output="s.vtu",
                           levels=2)
    assert isinstance(fig, Figure) and len(fig.axes) == 2
    left, right = fig.axes
    for get in ("get_xlim", "get_ylim", "get_zlim"):
        assert getattr(left, get)() == getattr(right, get)()
    assert (left.elev, left.azim) == (right.elev, right.azim)
    assert "2 facets" in left.get_title() and "32 facets" in right.get_title()
    assert "t.stl" in left.get_title() and "s.vtu" in right.get_title()


def test_smooth_plot_writes_the_picture_and_the_mesh(tmp_path):
    pytest.importorskip("matplotlib")
    png, out = tmp_path / "compare.png", tmp_path / "smooth.vtu"
    result = run("smooth", CYLINDER, "-o", out, "--plot", png)
    assert result.exit_code == 0, result.stderr
    assert png.read_bytes()[:8] == PNG and out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["compare.png", "smooth.vtu"]
    again = run("smooth", CYLINDER, "-o", tmp_path / "other.vtu", "--plot", png)
    assert again.exit_code == 1 and "--overwrite" in again.stderr
    assert not (tmp_path / "other.vtu").exists()


def test_help_shows_a_plot_example():
    for command, example in (("project", "--plot gaps.png"), ("smooth", "--plot compare.png")):
        result = run(command, "--help")
        assert result.exit_code == 0 and example in result.output


def test_smooth_plot_refuses_stdout(tmp_path):
    result = run("smooth", CYLINDER, "-o", tmp_path / "s.vtu", "--plot", "-")
    assert result.exit_code == 1
    assert result.stderr.strip() == ("diffsurf: error: -: a figure is not written to stdout, "
                                     "expected a .png, .svg or .pdf file name")
    assert list(tmp_path.iterdir()) == []


def test_a_large_target_draws_its_outline_features_and_tag_borders_only():
    # a 4 x 4 grid of quads folded by 90 degrees along x = 2, two tags split along y = 2
    x, y = np.meshgrid(np.arange(5.0), np.arange(5.0), indexing="ij")
    x, y = x.ravel(), y.ravel()
    points = np.c_[np.minimum(x, 2), y, np.maximum(x - 2, 0)]
    quads = np.array([[5 * i + j, 5 * (i + 1) + j, 5 * (i + 1) + j + 1, 5 * i + j + 1]
                      for i in range(4) for j in range(4)])
    tags = [np.where(quads[:, 0] % 5 < 2, 1, 2)]
    every, all_of_them = io.plot.target_edges(points, [("quad", quads)])
    assert all_of_them and len(every) == 40
    outline, all_of_them = io.plot.target_edges(points, [("quad", quads)], tags, max_edges=39)
    assert not all_of_them
    # 16 boundary edges, 4 along the fold (x = 2), 4 between the tags (y = 2)
    assert len(outline) == 24
    mid = outline.mean(axis=1)  # each edge's midpoint
    fold = np.isclose(mid[:, 0], 2) & np.isclose(mid[:, 2], 0)
    border = np.isclose(mid[:, 1], 2) & ~fold
    assert fold.sum() == 4 and border.sum() == 4
