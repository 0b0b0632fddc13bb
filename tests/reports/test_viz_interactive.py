"""Issue 16 (viz): ``uwval compare ... --html FILE`` writes an interactive page that works in
real headless Chromium: no console error, no network request, and a mouse-wheel zoom and a
drag (real input events sent through the DevTools protocol) change what the charts show.

Chromium is driven over ``--remote-debugging-pipe`` (fd 3 in, fd 4 out, NUL-separated JSON):
no extra Python package. Data: freiburg1_xyz (../shared/data/evo), copied into tmp_path.
"""

from __future__ import annotations

import json
import re
import shutil
import time
from pathlib import Path

import pytest
from browser import DevTools
from cli_runner import run_uwval
from shared_data import EVO_DATA

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DATA = EVO_DATA
GT = "freiburg1_xyz-groundtruth.txt"
EST = "freiburg1_xyz-rgbdslam.txt"
pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason="shared evo data not present")
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="chromium not installed (.ci/run installs it)"
)


def _copy_fr1(tmp_path: Path) -> None:
    """The first ~10 s of freiburg1_xyz into tmp_path (the page, not the numbers, is tested)."""
    for name, lines in ((GT, 1500), (EST, 300)):
        text = (DATA / name).read_text().splitlines(keepends=True)
        (tmp_path / name).write_text("".join(text[:lines]))


@pytest.fixture(scope="module")
def page(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One page for the tests of this module (the browser tests only read it)."""
    tmp_path = tmp_path_factory.mktemp("viz-page")
    _copy_fr1(tmp_path)
    out = tmp_path / "out" / "fr1.html"
    p = run_uwval(
        "compare", tmp_path / GT, tmp_path / EST, "--sync", "nearest", "--html", out, "--json"
    )
    assert p.returncode == 0, p.stderr
    assert f"wrote {out}" in p.stderr
    (out.parent / "n_samples").write_text(str(json.loads(p.stdout)["n_samples"]))
    return out


def test_page_is_self_contained(page: Path) -> None:
    html = page.read_text()
    assert "default-src 'none'" in html  # the browser itself refuses any request
    for needle in ("http://", "https://", 'src="//', "@import", '<link rel="stylesheet'):
        assert needle not in html.replace("http://www.w3.org/2000/svg", "")
    # the data is all there: one column value per aligned sample
    start = html.index('id="uwval-data">') + len('id="uwval-data">')
    data = json.loads(html[start : html.index("</script>", start)].replace("<\\/", "</"))
    (topic,) = data["topics"]
    n = int((page.parent / "n_samples").read_text())  # stdout was pure JSON
    assert n > 250
    assert len(topic["columns"]["t"]) == n == len(topic["columns"]["e_position_norm"])
    assert [c["title"].split(" ")[0] for c in topic["charts"]] == [
        "Position",
        "Rotation",
        "Trajectory",
    ]


def _view(dt: DevTools, chart: str) -> list[float]:
    text = dt.js(f"document.getElementById('{chart}').getAttribute('data-view')")
    return [float(v) for v in text.split(",")]


def _centre(dt: DevTools, chart: str) -> tuple[float, float]:
    r = dt.js(
        f"(() => {{ const e = document.getElementById('{chart}'); e.scrollIntoView();"
        " const r = e.getBoundingClientRect(); return [r.left + r.width / 2, r.top + r.height / 2];"
        " })()"
    )
    return float(r[0]), float(r[1])


@needs_chromium
def test_zoom_and_pan_in_headless_chromium(page: Path, tmp_path: Path) -> None:
    dt = DevTools(tmp_path / "profile")
    try:
        dt.call("Page.navigate", {"url": page.as_uri()})
        dt.wait_event("Page.loadEventFired")
        assert dt.js("document.body.getAttribute('data-ready')") == "3"
        # every chart drew its lines
        n_paths = dt.js(
            "Array.from(document.querySelectorAll('svg.chart path:not(.cbin)'))"
            ".filter(p => (p.getAttribute('d') || '').length > 1000).length"
        )
        assert n_paths == 9  # 4 position + 4 rotation series + Unity's path
        # Gazebo's path coloured by the position error (evo's colour map): one path per colour
        # bin, the lowest and the highest bins hold the smallest and the largest error
        bins = dt.js(
            "Array.from(document.querySelectorAll('#chart-0-2 path.cbin'))"
            ".map(p => [p.getAttribute('stroke'), (p.getAttribute('d') || '').length])"
        )
        assert len(bins) == 32
        assert bins[0][1] > 0 and bins[-1][1] > 0
        assert sum(1 for _, n in bins if n) >= 10
        assert len({colour for colour, _ in bins}) >= 30

        # wheel over the trajectory: both axes zoom in about the pointer, equal scale kept
        traj = "chart-0-2"
        before = _view(dt, traj)
        ticks_before = dt.js(f"document.getElementById('{traj}').textContent")
        x, y = _centre(dt, traj)
        dt.mouse("mouseWheel", x, y, deltaX=0, deltaY=-300)
        after = _view(dt, traj)
        assert after[1] - after[0] < 0.7 * (before[1] - before[0])
        assert after[3] - after[2] < 0.7 * (before[3] - before[2])
        ratio_before = (before[1] - before[0]) / (before[3] - before[2])
        ratio_after = (after[1] - after[0]) / (after[3] - after[2])
        assert ratio_after == pytest.approx(ratio_before, rel=1e-6)
        assert dt.js(f"document.getElementById('{traj}').textContent") != ticks_before

        # wheel over the position-error chart: the time axis zooms, the rotation chart follows
        pos, rot = "chart-0-0", "chart-0-1"
        full = _view(dt, pos)
        x, y = _centre(dt, pos)
        dt.mouse("mouseWheel", x, y, deltaX=0, deltaY=-400)
        zoomed = _view(dt, pos)
        assert zoomed[1] - zoomed[0] < 0.6 * (full[1] - full[0])
        assert _view(dt, rot)[:2] == pytest.approx(zoomed[:2])

        # the pointer over a time chart reads the values of the nearest sample
        dt.mouse("mouseMoved", x, y)
        readout = dt.js(f"document.querySelector('#{pos} text.readout').textContent")
        assert re.fullmatch(r"t = [\d.]+ s: x \S+, y \S+, z \S+, norm \|p\| \S+ m", readout)

        # drag to the left: the window moves later in time by the same width
        dt.mouse("mousePressed", x, y, button="left", buttons=1, clickCount=1)
        dt.mouse("mouseMoved", x - 150, y, button="left", buttons=1)
        dt.mouse("mouseReleased", x - 150, y, button="left", buttons=0, clickCount=1)
        panned = _view(dt, pos)
        assert panned[0] > zoomed[0]
        assert panned[1] - panned[0] == pytest.approx(zoomed[1] - zoomed[0], rel=1e-6)

        # double-click: the whole run again
        for kind in ("mousePressed", "mouseReleased"):
            dt.mouse(kind, x, y, button="left", buttons=1, clickCount=1)
        for kind in ("mousePressed", "mouseReleased"):
            dt.mouse(kind, x, y, button="left", buttons=1, clickCount=2)
        assert _view(dt, pos)[:2] == pytest.approx(full[:2])

        # the buttons: zoom in halves the time window about its centre, reset restores it
        dt.js("document.querySelector('#topic-0 .zoom-in').click()")
        half = _view(dt, pos)
        assert half[1] - half[0] == pytest.approx((full[1] - full[0]) / 2, rel=1e-6)
        dt.js("document.querySelectorAll('#topic-0 .zoom-reset')[0].click()")
        assert _view(dt, pos)[:2] == pytest.approx(full[:2])

        # 20,000 samples in view are drawn thinned (min and max per pixel column) and a
        # single-sample spike still shows: the envelope is that of every sample
        got = dt.js(
            """(() => {
              const c = window.uwvalCharts[0], s = c.opts.series[0];
              s.x = Array.from({length: 20000}, (_, i) => i * 0.001);
              s.y = s.x.map((t) => Math.sin(t));
              s.y[12345] = 5;
              c.setView([0, 20, -2, 6], true);
              const d = c.paths[0].getAttribute("d");
              const ys = d.split(/[ML]/).filter(Boolean).map((p) => Number(p.split(" ")[1]));
              return [ys.length, Math.min(...ys), c.py(5), c.pw];
            })()"""
        )
        n_points, top_px, spike_px, pw = got
        assert n_points <= 2 * (pw + 2)
        assert top_px == pytest.approx(spike_px, abs=0.01)

        shot = dt.call("Page.captureScreenshot", {"format": "png"})["data"]
        assert len(shot) > 10_000
        assert dt.problems() == []
        # the page itself is the only request: no script, style, font or data fetched
        assert set(dt.requests()) == {page.as_uri()}
    finally:
        dt.close()


@needs_chromium
def test_the_devtools_checks_do_catch_errors_and_requests(tmp_path: Path) -> None:
    # negative control: a page with a script error and a fetch is flagged by the same checks
    bad = tmp_path / "bad.html"
    bad.write_text(
        "<!DOCTYPE html><html><body><img src='http://127.0.0.1:9/x.png'>"
        "<script>undefinedFunction();</script></body></html>"
    )
    dt = DevTools(tmp_path / "profile")
    try:
        dt.call("Page.navigate", {"url": bad.as_uri()})
        dt.wait_event("Page.loadEventFired")
        time.sleep(0.3)
        dt.js("1")  # collect the events sent meanwhile
        assert any("undefinedFunction" in p for p in dt.problems()), dt.problems()
        assert "http://127.0.0.1:9/x.png" in dt.requests()
    finally:
        dt.close()


def test_html_option_errors_are_one_line(tmp_path: Path) -> None:
    _copy_fr1(tmp_path)
    p = run_uwval("compare", tmp_path / GT, tmp_path / EST, "--html", tmp_path / "page.txt")
    assert p.returncode == 2
    assert p.stderr.strip().splitlines() == [
        f"error: --html {tmp_path / 'page.txt'}: the page's name must end in .html"
    ]
    blocker = tmp_path / "file"
    blocker.write_text("")
    p = run_uwval("compare", tmp_path / GT, tmp_path / EST, "--html", blocker / "x.html")
    assert p.returncode == 2
    assert "x.html" in p.stderr
    assert "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1


def test_payload_thins_long_runs_and_keeps_gaps() -> None:
    from types import SimpleNamespace

    import numpy as np

    from uwval.reports.interactive import topic_payload

    n = 1001
    pos = np.zeros((n, 3))
    pos[:, 0] = np.linspace(0.0, 10.0, n)
    err = {k: np.full(n, 0.5) for k in ("x", "y", "z", "roll", "pitch", "yaw")}
    err["x"][3] = np.nan  # a masked sample: a gap in the line, null in the JSON
    pair = SimpleNamespace(
        t=np.arange(n, dtype=np.int64) * 10_000_000,  # 100 Hz
        reference=SimpleNamespace(position=pos),
        other=SimpleNamespace(position=pos + np.array([0.0, 0.3, 0.4])),
        errors=err,
    )
    p = topic_payload("rov", pair, max_points=100)
    assert p["stride"] == 11
    cols = p["columns"]
    assert len(cols["t"]) == 91 == len(cols["ref_x"])  # 1001 / 11
    assert cols["t"][1] == pytest.approx(0.11)
    # the norm is computed from the positions when the comparison does not carry it
    assert cols["e_position_norm"][0] == pytest.approx(0.5)
    assert "e_rotation_angle" not in cols
    full = topic_payload("rov", pair)
    assert full["stride"] == 1
    assert full["columns"]["e_x"][3] is None
    json.dumps(full, allow_nan=False)  # strict JSON: no NaN literal for the browser to choke on


def test_batch_refuses_html(tmp_path: Path) -> None:
    (tmp_path / "exp").mkdir()
    p = run_uwval("compare", "--batch", tmp_path / "exp", "--html", tmp_path / "x.html")
    assert p.returncode == 2
    assert p.stderr.strip() == "error: --html applies to one comparison, not to --batch"


@needs_chromium
def test_page_passes_the_report_pages_chromium_checks(page: Path, tmp_path: Path) -> None:
    # the same helper and checks as report.html (tests/test_report.py): a real screenshot
    # with ink, no console message
    from browser import _chromium, _console_errors, _ink

    shot, log = _chromium(page, tmp_path)
    assert _console_errors(log) == []
    ink, std = _ink(shot)
    assert ink > 0.02, "screenshot is blank"
    assert std > 10


def test_file_names_are_text_not_markup(tmp_path: Path) -> None:
    # a file name is shown as written: escaped in the page, never markup or script
    _copy_fr1(tmp_path)
    evil = tmp_path / "<img src=x onerror=alert(1)>.txt"
    (tmp_path / EST).rename(evil)
    out = tmp_path / "p.html"
    p = run_uwval("compare", tmp_path / GT, evil, "--html", out)
    assert p.returncode == 0, p.stderr
    html = out.read_text()
    assert "<img src=x" not in html
    assert "&lt;img src=x onerror=alert(1)&gt;.txt" in html
