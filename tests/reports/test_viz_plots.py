"""Issue 16 (viz): error histograms and the trajectory coloured by the error, as evo users
expect them (evo_ape --plot_mode xy with a colour map), in ``compare --plot`` and the report.

Real data: freiburg1_xyz (TUM RGB-D, ../shared/data/evo), copied into tmp_path.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval
from shared_data import EVO_DATA

from uwval.comparison import compare
from uwval.io.tum import read_tum
from uwval.reports import plots

DATA = EVO_DATA
pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason="shared evo data not present")
GT = "freiburg1_xyz-groundtruth.txt"
EST = "freiburg1_xyz-rgbdslam.txt"


@pytest.fixture
def fr1(tmp_path: Path) -> tuple[Path, Path]:
    out = []
    for name in (GT, EST):
        dst = tmp_path / name
        dst.write_bytes((DATA / name).read_bytes())
        out.append(dst)
    return out[0], out[1]


@pytest.fixture
def fr1_short(tmp_path: Path) -> tuple[Path, Path]:
    """The first ~8 s of freiburg1_xyz (the command-line tests check files, not numbers)."""
    out = []
    for name, lines in ((GT, 800), (EST, 250)):
        dst = tmp_path / ("short-" + name)
        text = (DATA / name).read_text().splitlines(keepends=True)
        dst.write_text("".join(text[:lines]))
        out.append(dst)
    return out[0], out[1]


def test_histogram_counts_are_numpys_and_a_constant_error_keeps_its_scale() -> None:
    rng = np.random.default_rng(16)
    v = rng.normal(0.0, 0.01, 500)
    v[7] = np.nan
    counts, edges = plots.histogram_counts(v, bins=20)
    want, want_edges = np.histogram(v[np.isfinite(v)], bins=20)
    assert counts.tolist() == want.tolist()
    np.testing.assert_allclose(edges, want_edges)
    assert counts.sum() == 499
    # a constant 1e-12 m error: one bin about 1e-12 wide, not numpy's 1 m bar
    counts, edges = plots.histogram_counts(np.full(10, 1e-12))
    assert counts.tolist() == [10]
    assert edges[0] < 1e-12 < edges[1]
    assert edges[1] - edges[0] < 1e-9
    counts, edges = plots.histogram_counts(np.array([np.nan]))
    assert len(counts) == 0


def test_histogram_figure_draws_every_error_of_the_comparison(fr1: tuple[Path, Path]) -> None:
    res = compare(read_tum(fr1[0]), read_tum(fr1[1]), sync="nearest", max_diff=0.01)
    fig = plots.error_histogram_figure(res, "fr1")
    titles = [ax.get_title() for ax in fig.axes]
    assert titles == ["x", "y", "z", "roll", "pitch", "yaw", "position_norm", "rotation_angle"]
    for ax, (key, _, unit) in zip(fig.axes, plots.HISTOGRAM_SERIES, strict=True):
        # the drawn bars hold every sample of that error series, the x label its unit
        (bars,) = ax.patches
        heights = bars.get_path().vertices[:, 1]
        want, _ = np.histogram(res.errors[key], bins=40)
        assert heights.max() == want.max()
        assert f"({unit})" in ax.get_xlabel()
        # the mean line sits at the mean of that error
        assert ax.lines[0].get_xdata()[0] == pytest.approx(float(np.mean(res.errors[key])))
    norm_ax = fig.axes[6]
    rmse = norm_ax.lines[1].get_xdata()[0]
    assert rmse == pytest.approx(res.to_json()["position_error_norm"]["rmse"], rel=1e-12)
    plots.close([fig])


def test_trajectory_coloured_by_the_position_error(fr1: tuple[Path, Path]) -> None:
    from matplotlib.collections import LineCollection

    res = compare(read_tum(fr1[0]), read_tum(fr1[1]), sync="nearest", max_diff=0.01)
    fig = plots.trajectory_error_figure(res, "fr1")
    ax = fig.axes[0]
    (lc,) = [c for c in ax.collections if isinstance(c, LineCollection)]
    colours = np.asarray(lc.get_array())
    norm = res.errors["position_norm"]
    # one segment per consecutive pair of samples, coloured by the mean error of its ends
    assert len(colours) == len(norm) - 1
    np.testing.assert_allclose(colours, 0.5 * (norm[:-1] + norm[1:]))
    assert lc.get_clim() == (pytest.approx(norm.min()), pytest.approx(norm.max()))
    # the colour bar says what and in which unit
    assert fig.axes[1].get_ylabel() == "position error norm (m)"
    # the segments follow the Gazebo path from above (x, y)
    segs = lc.get_segments()
    np.testing.assert_allclose(segs[0][0], res.reference.position[0, :2])
    plots.close([fig])
    fig = plots.trajectory_error_figure(res, error="rotation_angle")
    assert fig.axes[1].get_ylabel() == "rotation angle (deg)"
    with pytest.raises(KeyError, match="nope"):
        plots.trajectory_error_figure(res, error="nope")


def test_compare_plot_writes_histogram_and_error_map(
    fr1_short: tuple[Path, Path], tmp_path: Path
) -> None:
    from PIL import Image

    from uwval.cli.compare_files import extra_plot_targets, plot_targets

    target = tmp_path / "figs" / "fr1.png"
    p = run_uwval("compare", *fr1_short, "--sync", "nearest", "--save_plot", target)
    assert p.returncode == 0, p.stderr
    names = ("fr1.png", "fr1_errors.png", "fr1_histogram.png", "fr1_errormap.png")
    for name in names:
        png = target.with_name(name)
        assert f"wrote {png}" in p.stdout
        with Image.open(png) as im:
            a = np.asarray(im.convert("RGB"), dtype=np.int16)
        # not blank, and the colour map puts saturated colours on the page
        assert (a.min(axis=2) < 245).mean() > 0.01, name
        if name == "fr1_errormap.png":
            sat = a.max(axis=2) - a.min(axis=2)
            assert (sat > 150).mean() > 0.01
    # default names (current folder): beside the error plot, per topic
    ((_, _, errors),) = plot_targets(["trajectory"], "trajectory", None)
    assert extra_plot_targets(errors) == (
        Path("uwval_trajectory_histogram.png"),
        Path("uwval_trajectory_errormap.png"),
    )
    two = plot_targets(["rov", "cam"], "rov", Path("o/f.png"))
    assert extra_plot_targets(two[1][2]) == (
        Path("o/f.cam_histogram.png"),
        Path("o/f.cam_errormap.png"),
    )
